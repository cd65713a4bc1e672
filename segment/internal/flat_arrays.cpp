// Halfedge mesh <-> the evolution's flat arrays (flat_arrays.h).
#include "segment/internal/flat_arrays.h"

#include <cassert>

namespace sonomesh::segment::internal {

void extract(const BalloonMesh& bm, FlatArrays& a) {
  assert(!bm.has_garbage());
  const std::size_t nv = bm.n_vertices(), nh = bm.n_halfedges(), nf = bm.n_faces();
  const auto to = bm.halfedge_vertices();
  const auto next = bm.halfedge_nexts();
  const auto face = bm.halfedge_faces();
  const auto out = bm.vertex_halfedges();
  a.pos.assign(bm.points_mm().begin(), bm.points_mm().end());
  a.next_pos.resize(nv);
  a.cost.resize(nv);
  a.reason.resize(nv);
  a.anchor.resize(nv);
  a.path.resize(nv);
  a.floor_level.resize(nv);
  a.marked_voxel.resize(nv);
  a.normal.assign(nv, Vec3f::Zero());
  a.ring_begin.resize(nv + 1);
  a.ring_vertex.resize(nh);  // room for every ring
  a.ring_face_left.resize(nh);
  a.ring_face_right.resize(nh);
  const auto states = bm.states();
  std::uint32_t r = 0;
  for (std::size_t v = 0; v < nv; ++v) {
    a.ring_begin[v] = r;
    a.reason[v] = states[v].reason;
    if (a.reason[v] != StopReason::Moving) continue;  // an empty ring
    a.cost[v] = states[v].cost;
    a.anchor[v] = states[v].anchor_mm;
    a.path[v] = states[v].path_mm;
    a.floor_level[v] = states[v].floor_level;
    a.marked_voxel[v] = states[v].marked_voxel;
    const std::uint32_t start = out[v].idx;
    std::uint32_t h = start;
    do {
      a.ring_vertex[r] = to[h].idx;
      a.ring_face_left[r] = face[h].idx;
      a.ring_face_right[r] = face[h ^ 1u].idx;
      ++r;
      h = next[h ^ 1u].idx;  // clockwise to the next outgoing halfedge
    } while (h != start);
  }
  a.ring_begin[nv] = r;  // (the ring arrays keep their full size: no zeroing when regrown)
  const auto face_h = bm.face_halfedges();
  a.tri.resize(nf);
  a.face_normal.resize(nf);
  for (std::size_t f = 0; f < nf; ++f) {
    const std::uint32_t h0 = face_h[f].idx, h1 = next[h0].idx, h2 = next[h1].idx;
    a.tri[f] = {to[h0].idx, to[h1].idx, to[h2].idx};
  }
}

void write_back(const FlatArrays& a, std::span<const std::uint32_t> window, BalloonMesh& bm) {
  const auto points = bm.points_mm();
  const auto states = bm.states();
  for (const std::uint32_t v : window) {
    points[v] = a.pos[v];
    states[v] = {.cost = a.cost[v],
                 .reason = a.reason[v],
                 .anchor_mm = a.anchor[v],
                 .path_mm = a.path[v],
                 .floor_level = a.floor_level[v],
                 .marked_voxel = a.marked_voxel[v]};
  }
}

}  // namespace sonomesh::segment::internal
