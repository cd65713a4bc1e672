// Remeshing (method.md §3): split long edges, collapse short ones under the link condition.
#include <algorithm>
#include <cmath>
#include <initializer_list>

#include "segment/internal/balloon_mesh.h"
#include "segment/internal/openmesh_order.h"

namespace sonomesh::segment::internal {
namespace {

using namespace openmesh_order;

StopReason merged_stop(StopReason a, StopReason b) {
  // Self-intersection dominates: a vertex between a type-1 vertex and anything stopped lies in
  // the region where two fronts met, and the opening step (method.md §4) should cut it out.
  return static_cast<StopReason>(std::max(static_cast<int>(a), static_cast<int>(b)));
}

VertexState merged_state(const VertexState& a, const VertexState& b) {
  VertexState s;
  s.cost = 0.5f * (a.cost + b.cost);
  s.path_mm = 0.5f * (a.path_mm + b.path_mm);
  s.floor_level = std::min(a.floor_level, b.floor_level);
  // method.md §3: a vertex between two stopped vertices is stopped; otherwise it moves on.
  if (a.reason != StopReason::Moving && b.reason != StopReason::Moving)
    s.reason = merged_stop(a.reason, b.reason);
  return s;
}

Vec3f unit_normal(const Vec3f& a, const Vec3f& b, const Vec3f& c) {
  const Vec3f n = cross(b - a, c - a);
  const float len = norm(n);
  return len > 0.0f ? divided(n, len) : Vec3f::Zero();
}

bool has_moving_end(const BalloonMesh& bm, Halfedge h) {
  return bm.state(bm.from_vertex(h)).reason == StopReason::Moving ||
         bm.state(bm.to_vertex(h)).reason == StopReason::Moving;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Remeshing

Vertex split_edge_midpoint(BalloonMesh& bm, Edge e) {
  const Halfedge h = BalloonMesh::halfedge(e, 0);
  const Vertex a = bm.from_vertex(h), b = bm.to_vertex(h);
  VertexState s = merged_state(bm.state(a), bm.state(b));
  s.anchor_mm = 0.5f * (bm.state(a).anchor_mm + bm.state(b).anchor_mm);
  const Vertex vn = bm.add_vertex((bm.point_mm(a) + bm.point_mm(b)) * 0.5f);
  bm.split(e, vn);  // the 2-to-4 split of the paper's REFINEMENT
  bm.state(vn) = s;
  return vn;
}

// Whether test(g) holds for every outgoing halfedge g of each vertex in `vs`, in ring order,
// stopping at the first that fails.
template <typename Test>
bool every_outgoing(const BalloonMesh& bm, std::initializer_list<Vertex> vs, Test test) {
  for (const Vertex v : vs) {
    const Halfedge start = bm.halfedge(v);
    Halfedge g = start;
    do {
      if (!test(g)) return false;
      g = bm.cw_rotated(g);
    } while (g != start);
  }
  return true;
}

bool collapse_edge_midpoint(BalloonMesh& bm, Halfedge h, float max_edge_mm) {
  if (bm.is_deleted(BalloonMesh::edge(h))) return false;
  // (Every test below only refuses, so their order is free: the cheap ones come first.)
  const Vertex v_from = bm.from_vertex(h), v_to = bm.to_vertex(h);
  // Where exactly one end has stopped, the moving end melts into the stopped one: a stopped vertex
  // sits on the wall (or where the fronts met) and must neither leave it nor start moving again.
  // Otherwise both melt into the midpoint (the paper's COARSENING).
  const StopReason r_from = bm.state(v_from).reason, r_to = bm.state(v_to).reason;
  if (r_to == StopReason::Moving && r_from != StopReason::Moving) return false;  // try the twin
  const bool onto_to = r_from == StopReason::Moving && r_to != StopReason::Moving;
  const Vec3f mid_mm =
      onto_to ? bm.point_mm(v_to) : Vec3f((bm.point_mm(v_from) + bm.point_mm(v_to)) * 0.5f);
  // No over-long edge: no neighbour of either end may end up further than ε_max from the merged
  // vertex. Tested before the rest: it refuses about nine in ten attempts (128³ phantoms: 47000-
  // 64000 refusals for 5000-6000 collapses), and a pass over the two rings is its whole cost.
  const bool short_enough = every_outgoing(bm, {v_from, v_to}, [&](Halfedge g) {
    const Vertex q = bm.to_vertex(g);
    return q == v_from || q == v_to || !(norm(bm.point_mm(q) - mid_mm) > max_edge_mm);
  });
  if (!short_enough) return false;
  if (bm.valence(v_from) + bm.valence(v_to) < 8) return false;  // result would have valence < 4
  // The link condition keeps the mesh a 2-manifold of genus 0: it refuses collapses that would
  // pinch a vertex or join two sheets (e.g. a valence-3 tip).
  if (!bm.is_collapse_ok(h)) return false;
  const Face f_left = bm.face(h), f_right = bm.face(BalloonMesh::opposite(h));
  // No fold, no sliver: every surviving triangle around either end must keep roughly its
  // orientation after both ends move to the midpoint.
  const bool no_fold = every_outgoing(bm, {v_from, v_to}, [&](Halfedge g) {
    const Face f = bm.face(g);
    if (f == f_left || f == f_right) return true;
    std::array<Vec3f, 3> before, after;
    Halfedge fh = bm.halfedge(f);
    for (int i = 0; i < 3; ++i, fh = bm.next(fh)) {
      const Vertex fv = bm.to_vertex(fh);
      before[i] = bm.point_mm(fv);
      after[i] = (fv == v_from || fv == v_to) ? mid_mm : before[i];
    }
    const Vec3f nb = unit_normal(before[0], before[1], before[2]);
    const Vec3f na_raw = cross(after[1] - after[0], after[2] - after[0]);
    const float area2 = norm(na_raw);
    return area2 > 1e-12f && !(dot(nb, divided(na_raw, area2)) < 0.5f);
  });
  if (!no_fold) return false;
  VertexState s = onto_to ? bm.state(v_to) : merged_state(bm.state(v_from), bm.state(v_to));
  if (!onto_to) {
    // Ψ_cost only grows along a path; the merged vertex continues the longer of the two. (With
    // the average, a vertex that remeshing splits off and melts back every pass never reaches
    // τ_cost and cycles until the iteration limit.)
    s.cost = std::max(bm.state(v_from).cost, bm.state(v_to).cost);
    s.path_mm = std::max(bm.state(v_from).path_mm, bm.state(v_to).path_mm);
    s.floor_level = std::min(bm.state(v_from).floor_level, bm.state(v_to).floor_level);
    s.anchor_mm = 0.5f * (bm.state(v_from).anchor_mm + bm.state(v_to).anchor_mm);
  }
  bm.collapse(h);  // v_from disappears into v_to (the paper's COARSENING "melting")
  bm.point_mm(v_to) = mid_mm;
  bm.state(v_to) = s;
  return true;
}

RemeshCounts remesh(BalloonMesh& bm, const RemeshLimits& limits) {
  RemeshCounts counts;
  const float max2 = limits.max_edge_mm * limits.max_edge_mm;
  const float min2 = limits.min_edge_mm * limits.min_edge_mm;
  auto length2 = [&](Halfedge h) {
    return sqrnorm(bm.point_mm(bm.to_vertex(h)) - bm.point_mm(bm.from_vertex(h)));
  };
  // The edges with a moving end, ascending, found from the moving vertices' rings: once most of
  // the balloon rests on the wall, a pass costs what its moving front costs, not the whole mesh.
  std::vector<std::uint32_t> candidates;
  {
    std::vector<std::uint8_t> seen(bm.n_edges(), 0);
    for (std::uint32_t i = 0; i < bm.n_vertices(); ++i) {
      const Vertex v{i};
      if (bm.is_deleted(v) || bm.state(v).reason != StopReason::Moving) continue;
      const Halfedge start = bm.halfedge(v);
      Halfedge g = start;
      do {
        const std::uint32_t e = BalloonMesh::edge(g).idx;
        if (!seen[e]) {
          seen[e] = 1;
          candidates.push_back(e);
        }
        g = bm.cw_rotated(g);
      } while (g != start);
    }
    std::sort(candidates.begin(), candidates.end());
  }
  const std::uint32_t edges_before_splits = bm.n_edges();
  // Refinement. Splitting at the midpoint halves the edge; the new edges to the opposite vertices
  // can still be long in slivers, so repeat a few passes. Only an edge made by the last pass, or
  // the kept half of one it split, can be too long in the next.
  std::vector<std::uint32_t> pass_edges = candidates, next_pass;
  for (int pass = 0; pass < 4 && !pass_edges.empty(); ++pass) {
    const std::uint32_t n_edges = bm.n_edges();
    next_pass.clear();
    for (const std::uint32_t i : pass_edges) {
      const Edge e{i};
      if (bm.is_deleted(e)) continue;
      const Halfedge h = BalloonMesh::halfedge(e, 0);
      if (!has_moving_end(bm, h) || !(length2(h) > max2)) continue;
      split_edge_midpoint(bm, e);
      ++counts.splits;
      next_pass.push_back(i);
    }
    for (std::uint32_t i = n_edges; i < bm.n_edges(); ++i) next_pass.push_back(i);
    std::swap(pass_edges, next_pass);
  }
  // Coarsening. 4/5 L below and 4/3 L above (Botsch and Kobbelt 2004): a collapse of an edge
  // shorter than 4/5 L cannot create an edge longer than 4/3 L in a regular neighbourhood, and
  // the max-edge check in collapse_edge_midpoint() guarantees it elsewhere, so the two passes
  // do not undo each other. Over the candidates and every edge the splits made, ascending.
  if (limits.min_edge_mm > 0.0f) {
    for (std::uint32_t i = edges_before_splits; i < bm.n_edges(); ++i) candidates.push_back(i);
    for (const std::uint32_t i : candidates) {
      const Edge e{i};
      if (bm.is_deleted(e)) continue;
      const Halfedge h = BalloonMesh::halfedge(e, 0);
      if (!has_moving_end(bm, h)) continue;
      if (length2(h) >= min2) continue;
      if (collapse_edge_midpoint(bm, h, limits.max_edge_mm) ||
          collapse_edge_midpoint(bm, BalloonMesh::opposite(h), limits.max_edge_mm))
        ++counts.collapses;
    }
  }
  // Only collapses delete elements; a pass without any leaves the indices as they are.
  if (counts.collapses > 0) bm.garbage_collection();
  return counts;
}
}  // namespace sonomesh::segment::internal
