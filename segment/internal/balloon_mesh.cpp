// The balloon's halfedge mesh: construction, validation, and the remeshing of method.md §3.
#include "segment/internal/balloon_mesh.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <set>
#include <sstream>
#include <stdexcept>
#include <utility>

namespace sonomesh::segment::internal {
namespace {

using OMVec = OpenMesh::Vec3f;

StopReason merged_stop(StopReason a, StopReason b) {
  // Self-intersection dominates: a vertex between a type-1 vertex and anything stopped lies in
  // the region where two fronts met, and the opening step (method.md §4) should cut it out.
  return static_cast<StopReason>(std::max(static_cast<int>(a), static_cast<int>(b)));
}

VertexState merged_state(const VertexState& a, const VertexState& b) {
  VertexState s;
  s.cost = 0.5f * (a.cost + b.cost);
  s.path_mm = 0.5f * (a.path_mm + b.path_mm);
  // method.md §3: a vertex between two stopped vertices is stopped; otherwise it moves on.
  if (a.reason != StopReason::Moving && b.reason != StopReason::Moving)
    s.reason = merged_stop(a.reason, b.reason);
  return s;
}

OMVec unit_normal(const OMVec& a, const OMVec& b, const OMVec& c) {
  OMVec n = OpenMesh::cross(b - a, c - a);
  const float len = n.norm();
  return len > 0.0f ? n / len : OMVec(0, 0, 0);
}

bool has_moving_end(const BalloonMesh& bm, TriMesh::HalfedgeHandle h) {
  const TriMesh& m = bm.mesh();
  return bm.state(m.from_vertex_handle(h)).reason == StopReason::Moving ||
         bm.state(m.to_vertex_handle(h)).reason == StopReason::Moving;
}

}  // namespace

BalloonMesh::BalloonMesh() { mesh_.add_property(state_, "balloon:state"); }

void make_uv_sphere(BalloonMesh& out, const Vec3f& centre_mm, float radius_mm, int segments,
                    int bands) {
  if (segments < 3 || bands < 2 || !(radius_mm > 0.0f))
    throw std::invalid_argument("make_uv_sphere: need segments >= 3, bands >= 2, radius > 0");
  TriMesh& m = out.mesh();
  m.clear();
  const OMVec c(centre_mm.x(), centre_mm.y(), centre_mm.z());
  const auto north = m.add_vertex(c + OMVec(0, 0, radius_mm));
  std::vector<std::vector<TriMesh::VertexHandle>> rings;
  for (int k = 1; k < bands; ++k) {
    const double theta = M_PI * k / bands;
    std::vector<TriMesh::VertexHandle> ring;
    for (int j = 0; j < segments; ++j) {
      const double phi = 2.0 * M_PI * j / segments;
      const OMVec p(static_cast<float>(radius_mm * std::sin(theta) * std::cos(phi)),
                    static_cast<float>(radius_mm * std::sin(theta) * std::sin(phi)),
                    static_cast<float>(radius_mm * std::cos(theta)));
      ring.push_back(m.add_vertex(c + p));
    }
    rings.push_back(std::move(ring));
  }
  const auto south = m.add_vertex(c - OMVec(0, 0, radius_mm));
  // Orientation: counter-clockwise seen from outside (checked by validate()'s signed volume).
  for (int j = 0; j < segments; ++j) {
    const int jn = (j + 1) % segments;
    m.add_face(north, rings.front()[j], rings.front()[jn]);
    for (std::size_t k = 0; k + 1 < rings.size(); ++k) {
      const auto a = rings[k][j], b = rings[k][jn], d = rings[k + 1][j], cc = rings[k + 1][jn];
      m.add_face(a, d, cc);
      m.add_face(a, cc, b);
    }
    m.add_face(south, rings.back()[jn], rings.back()[j]);
  }
  for (auto v : m.vertices()) {
    const auto& p = m.point(v);
    out.state(v) = VertexState{};
    out.state(v).anchor_mm = Vec3f(p[0], p[1], p[2]);
  }
}

int euler_characteristic(const TriMesh& mesh) {
  int v = 0, e = 0, f = 0;
  for (auto vh : mesh.vertices()) { (void)vh; ++v; }
  for (auto eh : mesh.edges()) { (void)eh; ++e; }
  for (auto fh : mesh.faces()) { (void)fh; ++f; }
  return v - e + f;
}

std::string validate(const TriMesh& mesh) {
  std::ostringstream why;
  int nv = 0;
  for (auto v : mesh.vertices()) {
    ++nv;
    if (mesh.is_isolated(v)) return "isolated vertex " + std::to_string(v.idx());
    if (mesh.is_boundary(v)) return "boundary vertex " + std::to_string(v.idx());
    if (!mesh.is_manifold(v)) return "non-manifold vertex " + std::to_string(v.idx());
    if (mesh.valence(v) < 3) return "vertex of valence < 3: " + std::to_string(v.idx());
  }
  if (nv < 4) return "fewer than 4 vertices";
  // Halfedges through their edges: the halfedges themselves carry no status flags here.
  for (auto e : mesh.edges()) {
    for (int side = 0; side < 2; ++side) {
      const auto h = mesh.halfedge_handle(e, side);
      if (mesh.is_boundary(h)) return "boundary halfedge " + std::to_string(h.idx());
      if (mesh.status(mesh.to_vertex_handle(h)).deleted() ||
          mesh.status(mesh.from_vertex_handle(h)).deleted())
        return "halfedge to a deleted vertex";
      if (mesh.status(mesh.face_handle(h)).deleted()) return "halfedge of a deleted face";
      // Consistent orientation: the twin runs the other way.
      const auto o = mesh.opposite_halfedge_handle(h);
      if (mesh.to_vertex_handle(o) != mesh.from_vertex_handle(h)) return "twin not reversed";
    }
  }
  std::set<std::pair<int, int>> edges;
  for (auto e : mesh.edges()) {
    const auto h = mesh.halfedge_handle(e, 0);
    int a = mesh.from_vertex_handle(h).idx(), b = mesh.to_vertex_handle(h).idx();
    if (a == b) return "loop edge";
    if (a > b) std::swap(a, b);
    if (!edges.insert({a, b}).second) return "duplicate edge";
  }
  std::set<std::array<int, 3>> faces;
  double volume6 = 0.0;
  for (auto f : mesh.faces()) {
    std::array<int, 3> idx{};
    std::array<OMVec, 3> p;
    int i = 0;
    for (auto v : mesh.fv_range(f)) {
      if (i == 3) return "face with more than 3 vertices";
      idx[i] = v.idx();
      p[i] = mesh.point(v);
      ++i;
    }
    if (i != 3) return "face with fewer than 3 vertices";
    if (idx[0] == idx[1] || idx[1] == idx[2] || idx[0] == idx[2]) return "degenerate face";
    volume6 += OpenMesh::dot(p[0], OpenMesh::cross(p[1], p[2]));
    std::sort(idx.begin(), idx.end());
    if (!faces.insert(idx).second) return "duplicate face";
  }
  const int chi = nv - static_cast<int>(edges.size()) + static_cast<int>(faces.size());
  if (chi != 2) return "Euler characteristic " + std::to_string(chi) + " != 2";
  if (!(volume6 > 0.0)) return "non-positive enclosed volume (inward oriented?)";
  return {};
}

TriMesh::VertexHandle split_edge_midpoint(BalloonMesh& bm, TriMesh::EdgeHandle e) {
  TriMesh& m = bm.mesh();
  const auto h = m.halfedge_handle(e, 0);
  const auto a = m.from_vertex_handle(h), b = m.to_vertex_handle(h);
  VertexState s = merged_state(bm.state(a), bm.state(b));
  const auto mid = (m.point(a) + m.point(b)) * 0.5f;
  s.anchor_mm = 0.5f * (bm.state(a).anchor_mm + bm.state(b).anchor_mm);
  const auto vn = m.add_vertex(mid);
  m.split(e, vn);  // the 2-to-4 split of the paper's REFINEMENT
  bm.state(vn) = s;
  return vn;
}

bool collapse_edge_midpoint(BalloonMesh& bm, TriMesh::HalfedgeHandle h, float max_edge_mm) {
  TriMesh& m = bm.mesh();
  if (m.status(m.edge_handle(h)).deleted()) return false;
  // The link condition (OpenMesh's is_collapse_ok) keeps the mesh a 2-manifold of genus 0: it
  // refuses collapses that would pinch a vertex or join two sheets (e.g. a valence-3 tip).
  if (!m.is_collapse_ok(h)) return false;
  const auto v_from = m.from_vertex_handle(h), v_to = m.to_vertex_handle(h);
  if (m.valence(v_from) + m.valence(v_to) < 8) return false;  // result would have valence < 4
  // Where exactly one end has stopped, the moving end melts into the stopped one: a stopped vertex
  // sits on the wall (or where the fronts met) and must neither leave it nor start moving again.
  // Otherwise both melt into the midpoint (the paper's COARSENING).
  const StopReason r_from = bm.state(v_from).reason, r_to = bm.state(v_to).reason;
  if (r_to == StopReason::Moving && r_from != StopReason::Moving) return false;  // try the twin
  const bool onto_to = r_from == StopReason::Moving && r_to != StopReason::Moving;
  const OMVec mid = onto_to ? m.point(v_to) : (m.point(v_from) + m.point(v_to)) * 0.5f;
  const auto f_left = m.face_handle(h), f_right = m.face_handle(m.opposite_halfedge_handle(h));
  // No fold, no sliver, no over-long edge: every surviving triangle around either end must keep
  // roughly its orientation after both ends move to the midpoint.
  for (auto v : {v_from, v_to}) {
    for (auto f : m.vf_range(v)) {
      if (f == f_left || f == f_right) continue;
      std::array<OMVec, 3> before, after;
      int i = 0;
      for (auto fv : m.fv_range(f)) {
        before[i] = m.point(fv);
        after[i] = (fv == v_from || fv == v_to) ? mid : before[i];
        ++i;
      }
      const OMVec nb = unit_normal(before[0], before[1], before[2]);
      const OMVec na_raw = OpenMesh::cross(after[1] - after[0], after[2] - after[0]);
      const float area2 = na_raw.norm();
      if (!(area2 > 1e-12f)) return false;
      if (OpenMesh::dot(nb, na_raw / area2) < 0.5f) return false;
    }
    for (auto q : m.vv_range(v)) {
      if (q == v_from || q == v_to) continue;
      if ((m.point(q) - mid).norm() > max_edge_mm) return false;
    }
  }
  VertexState s = onto_to ? bm.state(v_to) : merged_state(bm.state(v_from), bm.state(v_to));
  if (!onto_to) {
    // Ψ_cost only grows along a path; the merged vertex continues the longer of the two. (With
    // the average, a vertex that remeshing splits off and melts back every pass never reaches
    // τ_cost and cycles until the iteration limit.)
    s.cost = std::max(bm.state(v_from).cost, bm.state(v_to).cost);
    s.path_mm = std::max(bm.state(v_from).path_mm, bm.state(v_to).path_mm);
    s.anchor_mm = 0.5f * (bm.state(v_from).anchor_mm + bm.state(v_to).anchor_mm);
  }
  m.collapse(h);  // v_from disappears into v_to (the paper's COARSENING "melting")
  m.set_point(v_to, mid);
  bm.state(v_to) = s;
  return true;
}

RemeshCounts remesh(BalloonMesh& bm, const RemeshLimits& limits) {
  TriMesh& m = bm.mesh();
  RemeshCounts counts;
  const float max2 = limits.max_edge_mm * limits.max_edge_mm;
  const float min2 = limits.min_edge_mm * limits.min_edge_mm;
  // Refinement. Splitting at the midpoint halves the edge; the new edges to the opposite vertices
  // can still be long in slivers, so repeat a few passes.
  for (int pass = 0; pass < 4; ++pass) {
    const int n_edges = static_cast<int>(m.n_edges());
    int splits = 0;
    for (int i = 0; i < n_edges; ++i) {
      const TriMesh::EdgeHandle e(i);
      if (m.status(e).deleted()) continue;
      const auto h = m.halfedge_handle(e, 0);
      if (!has_moving_end(bm, h)) continue;
      if ((m.point(m.to_vertex_handle(h)) - m.point(m.from_vertex_handle(h))).sqrnorm() > max2) {
        split_edge_midpoint(bm, e);
        ++splits;
      }
    }
    counts.splits += splits;
    if (splits == 0) break;
  }
  // Coarsening. 4/5 L below and 4/3 L above (Botsch and Kobbelt 2004): a collapse of an edge
  // shorter than 4/5 L cannot create an edge longer than 4/3 L in a regular neighbourhood, and
  // the max-edge check in collapse_edge_midpoint() guarantees it elsewhere, so the two passes
  // do not undo each other.
  if (limits.min_edge_mm > 0.0f) {
    const int n_edges = static_cast<int>(m.n_edges());
    for (int i = 0; i < n_edges; ++i) {
      const TriMesh::EdgeHandle e(i);
      if (m.status(e).deleted()) continue;
      const auto h = m.halfedge_handle(e, 0);
      if (!has_moving_end(bm, h)) continue;
      if ((m.point(m.to_vertex_handle(h)) - m.point(m.from_vertex_handle(h))).sqrnorm() >= min2)
        continue;
      if (collapse_edge_midpoint(bm, h, limits.max_edge_mm) ||
          collapse_edge_midpoint(bm, m.opposite_halfedge_handle(h), limits.max_edge_mm))
        ++counts.collapses;
    }
  }
  // Only collapses delete elements; a pass without any leaves the handles as they are.
  if (counts.collapses > 0) m.garbage_collection();
  return counts;
}

Mesh to_plain_mesh(const TriMesh& mesh) {
  Mesh out;
  std::vector<std::uint32_t> index(mesh.n_vertices(), 0);
  for (auto v : mesh.vertices()) {
    index[v.idx()] = static_cast<std::uint32_t>(out.vertices.size());
    const auto& p = mesh.point(v);
    out.vertices.emplace_back(p[0], p[1], p[2]);
  }
  for (auto f : mesh.faces()) {
    std::array<std::uint32_t, 3> t{};
    int i = 0;
    for (auto v : mesh.fv_range(f)) t[i++] = index[v.idx()];
    out.triangles.push_back(t);
  }
  return out;
}

}  // namespace sonomesh::segment::internal
