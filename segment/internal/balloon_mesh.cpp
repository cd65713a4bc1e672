// The balloon's halfedge mesh: construction, validation, and the remeshing of method.md §3.
#include "segment/internal/balloon_mesh.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <initializer_list>
#include <set>
#include <stdexcept>
#include <utility>

namespace sonomesh::segment::internal {
namespace {

// Vector arithmetic in OpenMesh's VectorT order (sums left to right; Eigen's unrolled reductions
// pair the last two terms first): the split/collapse decisions stay bit for bit what they were.
float dot(const Vec3f& a, const Vec3f& b) { return a.x() * b.x() + a.y() * b.y() + a.z() * b.z(); }
float sqrnorm(const Vec3f& a) { return dot(a, a); }
float norm(const Vec3f& a) { return std::sqrt(sqrnorm(a)); }
Vec3f cross(const Vec3f& a, const Vec3f& b) {
  return Vec3f(a.y() * b.z() - a.z() * b.y(), a.z() * b.x() - a.x() * b.z(),
               a.x() * b.y() - a.y() * b.x());
}
Vec3f divided(const Vec3f& a, float s) { return Vec3f(a.x() / s, a.y() / s, a.z() / s); }

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

// Swap-with-last compaction of one element kind (OpenMesh's order, so that indices after a pass
// are the same as they were with it): the k-th deleted element from the front swaps with the k-th
// live one from the back, while the hole lies before it, i.e. every hole below the new size is
// filled from at or beyond it. `deleted` holds 1 for a deleted element (swap() moves the flags
// too). Fills tail_map[old − new size] = new index for the live elements that moved and returns
// the new size. The holes are found with memchr and the map covers only the tail: a scan of
// every flag and a full identity map were ~40 % of a collection's instructions (128³ torus), for
// the few dozen elements a remeshing pass deletes.
template <typename Swap>
std::uint32_t compact(const std::vector<std::uint8_t>& deleted, std::uint32_t n_deleted, Swap swap,
                      std::vector<std::uint32_t>& tail_map) {
  const auto n = static_cast<std::uint32_t>(deleted.size());
  const std::uint32_t size = n - n_deleted;
  tail_map.assign(n_deleted, kInvalidIndex);
  const std::uint8_t* flags = deleted.data();
  std::uint32_t hole = 0, tail = n;
  while (hole < size) {
    const void* found = std::memchr(flags + hole, 1, size - hole);
    if (found == nullptr) break;
    hole = static_cast<std::uint32_t>(static_cast<const std::uint8_t*>(found) - flags);
    // A hole below the new size has a live partner at or beyond it (they are equally many).
    do --tail;
    while (flags[tail] != 0);
    swap(hole, tail);
    tail_map[tail - size] = hole;
    ++hole;
  }
  return size;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// BalloonMesh

void BalloonMesh::clear() { *this = BalloonMesh(); }

int BalloonMesh::valence(Vertex v) const {
  const Halfedge start = halfedge(v);
  if (!start.valid()) return 0;
  int n = 0;
  Halfedge h = start;
  do {
    ++n;
    h = cw_rotated(h);
  } while (h != start);
  return n;
}

Vertex BalloonMesh::add_vertex(const Vec3f& p_mm) {
  points_mm_.push_back(p_mm);
  states_.emplace_back();
  vertex_halfedge_.emplace_back();
  vertex_deleted_.push_back(0);
  return {n_vertices() - 1};
}

Halfedge BalloonMesh::new_edge(Vertex from, Vertex to) {
  halfedge_vertex_.push_back(to);
  halfedge_vertex_.push_back(from);
  halfedge_next_.resize(halfedge_next_.size() + 2);
  halfedge_face_.resize(halfedge_face_.size() + 2);
  edge_deleted_.push_back(0);
  return {n_halfedges() - 2};
}

Face BalloonMesh::new_face() {
  face_halfedge_.emplace_back();
  face_deleted_.push_back(0);
  return {n_faces() - 1};
}

bool BalloonMesh::is_boundary(Vertex v) const {
  const Halfedge h = halfedge(v);
  return !(h.valid() && face(h).valid());
}

Halfedge BalloonMesh::find_halfedge(Vertex from, Vertex to) const {
  const Halfedge start = halfedge(from);
  if (!start.valid()) return {};
  Halfedge h = start;
  do {
    if (to_vertex(h) == to) return h;
    h = cw_rotated(h);
  } while (h != start);
  return {};
}

// The halfedge whose next is h. Only add_triangle() needs it, on boundary halfedges (where
// next(next(h)) is not the answer), so it is found by rotating around from_vertex(h) rather than
// stored for every halfedge.
Halfedge BalloonMesh::boundary_prev(Halfedge h) const {
  Halfedge g = h;
  while (true) {
    const Halfedge n = cw_rotated(g);
    if (n == h) return opposite(g);
    g = n;
  }
}

// A boundary vertex keeps a boundary halfedge as its outgoing one, where add_triangle() looks for
// the gap to fill.
void BalloonMesh::adjust_outgoing_halfedge(Vertex v) {
  const Halfedge start = halfedge(v);
  if (!start.valid()) return;
  Halfedge h = start;
  do {
    if (is_boundary(h)) {
      vertex_halfedge_[v.idx] = h;
      return;
    }
    h = cw_rotated(h);
  } while (h != start);
}

// OpenMesh's PolyConnectivity::add_face for three vertices, step for step: the outgoing halfedge
// each vertex ends up with decides where its one-ring starts, and with it the order of the sums
// the evolution takes over the ring.
Face BalloonMesh::add_triangle(Vertex a, Vertex b, Vertex c) {
  if (a == b || b == c || a == c) throw std::invalid_argument("add_triangle: repeated vertex");
  const std::array<Vertex, 3> vs{a, b, c};
  struct Side {
    Halfedge h;
    bool is_new = false;
    bool needs_adjust = false;
  };
  std::array<Side, 3> side;
  std::array<std::pair<Halfedge, Halfedge>, 18> next_cache;
  int n_cache = 0;
  auto cache = [&](Halfedge from, Halfedge to) { next_cache[n_cache++] = {from, to}; };

  for (int i = 0; i < 3; ++i) {
    const int ii = (i + 1) % 3;
    if (!is_boundary(vs[i])) throw std::invalid_argument("add_triangle: complex vertex");
    side[i].h = find_halfedge(vs[i], vs[ii]);
    side[i].is_new = !side[i].h.valid();
    if (!side[i].is_new && !is_boundary(side[i].h))
      throw std::invalid_argument("add_triangle: complex edge");
  }
  // Two existing edges that are not consecutive around their vertex: move the patch between them
  // out of the way.
  for (int i = 0; i < 3; ++i) {
    const int ii = (i + 1) % 3;
    if (side[i].is_new || side[ii].is_new) continue;
    const Halfedge inner_prev = side[i].h, inner_next = side[ii].h;
    if (next(inner_prev) == inner_next) continue;
    Halfedge boundary_prev_h = opposite(inner_next);
    do {
      boundary_prev_h = opposite(next(boundary_prev_h));
    } while (!is_boundary(boundary_prev_h));
    const Halfedge boundary_next_h = next(boundary_prev_h);
    if (boundary_prev_h == inner_prev)
      throw std::invalid_argument("add_triangle: patch re-linking failed");
    const Halfedge patch_start = next(inner_prev), patch_end = boundary_prev(inner_next);
    cache(boundary_prev_h, patch_start);
    cache(patch_end, boundary_next_h);
    cache(inner_prev, inner_next);
  }
  for (int i = 0; i < 3; ++i)
    if (side[i].is_new) side[i].h = new_edge(vs[i], vs[(i + 1) % 3]);

  const Face f = new_face();
  face_halfedge_[f.idx] = side[2].h;
  for (int i = 0; i < 3; ++i) {
    const int ii = (i + 1) % 3;
    const Vertex vh = vs[ii];
    const Halfedge inner_prev = side[i].h, inner_next = side[ii].h;
    const int id = (side[i].is_new ? 1 : 0) | (side[ii].is_new ? 2 : 0);
    if (id != 0) {
      const Halfedge outer_prev = opposite(inner_next), outer_next = opposite(inner_prev);
      if (id == 1) {  // prev is new, next is old
        cache(boundary_prev(inner_next), outer_next);
        vertex_halfedge_[vh.idx] = outer_next;
      } else if (id == 2) {  // next is new, prev is old
        const Halfedge boundary_next_h = next(inner_prev);
        cache(outer_prev, boundary_next_h);
        vertex_halfedge_[vh.idx] = boundary_next_h;
      } else if (!halfedge(vh).valid()) {  // both new, isolated vertex
        vertex_halfedge_[vh.idx] = outer_next;
        cache(outer_prev, outer_next);
      } else {  // both new, boundary vertex
        const Halfedge boundary_next_h = halfedge(vh);
        cache(boundary_prev(boundary_next_h), outer_next);
        cache(outer_prev, boundary_next_h);
      }
      cache(inner_prev, inner_next);
    } else {
      side[ii].needs_adjust = halfedge(vh) == inner_next;
    }
    halfedge_face_[side[i].h.idx] = f;
  }
  for (int i = 0; i < n_cache; ++i) halfedge_next_[next_cache[i].first.idx] = next_cache[i].second;
  for (int i = 0; i < 3; ++i)
    if (side[i].needs_adjust) adjust_outgoing_halfedge(vs[i]);
  return f;
}

void BalloonMesh::set_triangle(Face f, Halfedge a, Halfedge b, Halfedge c) {
  face_halfedge_[f.idx] = a;
  for (const Halfedge h : {a, b, c}) halfedge_face_[h.idx] = f;
  halfedge_next_[a.idx] = b;
  halfedge_next_[b.idx] = c;
  halfedge_next_[c.idx] = a;
}

// OpenMesh's TriConnectivity::split for an interior edge: which elements are new and which
// outgoing/face halfedges change follow it exactly.
void BalloonMesh::split(Edge e, Vertex v) {
  // Halfedge h0 of e runs v2 -> v0 in face f0 (v2, v0, v1), its opposite o0 in f3 (v0, v2, v3).
  // e keeps the half towards v0 (h0 then runs v -> v0); new edges join v to v2, v1 and v3.
  const Halfedge h0 = halfedge(e, 0), o0 = halfedge(e, 1);
  const Halfedge h1 = next(h0), h2 = next(h1), o1 = next(o0), o2 = next(o1);
  const Vertex v1 = to_vertex(h1), v2 = to_vertex(o0), v3 = to_vertex(o1);  // before o0 points at v
  const Face f0 = face(h0), f3 = face(o0);
  // Created in OpenMesh's order, so the new indices (and with them the results) are its.
  const Halfedge e1 = new_edge(v, v2), t1 = opposite(e1);
  const Halfedge e0 = new_edge(v, v1), t0 = opposite(e0);
  const Face f1 = new_face();
  const Halfedge e2 = new_edge(v, v3), t2 = opposite(e2);
  const Face f2 = new_face();
  vertex_halfedge_[v.idx] = h0;
  halfedge_vertex_[o0.idx] = v;
  set_triangle(f0, h0, h1, t0);  // (v, v0, v1)
  set_triangle(f1, h2, t1, e0);  // (v1, v2, v), new
  set_triangle(f2, o1, t2, e1);  // (v2, v3, v), new
  set_triangle(f3, o0, e2, o2);  // (v0, v, v3)
  if (halfedge(v2) == h0) vertex_halfedge_[v2.idx] = t1;
}

bool BalloonMesh::is_collapse_ok(Halfedge h) const {
  if (is_deleted(edge(h))) return false;
  const Halfedge o = opposite(h);
  const Vertex v0 = to_vertex(o), v1 = to_vertex(h);
  if (is_deleted(v0) || is_deleted(v1) || is_boundary(h) || is_boundary(o)) return false;
  const Vertex vl = to_vertex(next(h)), vr = to_vertex(next(o));
  if (vl == vr) return false;
  // The one-rings of v0 and v1 may share only vl and vr: a third common neighbour would join the
  // two edges to it into one edge with three or four faces (a pinch, or a second sheet).
  const Halfedge start = halfedge(v0);
  Halfedge g = start;
  do {
    const Vertex q = to_vertex(g);
    if (q != v1 && q != vl && q != vr && find_halfedge(q, v1).valid()) return false;
    g = cw_rotated(g);
  } while (g != start);
  // vl and vr each lose an edge. On a closed manifold a valence-3 vl (or vr) with the link
  // condition met means the whole mesh is a tetrahedron, and a collapse leaves two triangles
  // glued back to back.
  if (valence(vl) <= 3 || valence(vr) <= 3) return false;
  if (n_live_vertices() <= 4) return false;
  return true;
}

// OpenMesh's PolyConnectivity::collapse (collapse_edge, then collapse_loop on both sides) for a
// closed triangle mesh, reduced to its end state: the same edges, faces and outgoing halfedges
// survive, so the pass after it and garbage_collection() see the same indices as before.
void BalloonMesh::collapse(Halfedge h) {
  const Halfedge h0 = h, h1 = next(h0), h2 = next(h1);
  const Halfedge o0 = opposite(h0), o1 = next(o0), o2 = next(o1);
  const Vertex v0 = to_vertex(o0), v1 = to_vertex(h0), vl = to_vertex(h1), vr = to_vertex(o1);
  const Face fh = face(h0), fo = face(o0);

  // Every halfedge into v0 now ends at v1.
  const Halfedge start = halfedge(v0);
  Halfedge g = start;
  do {
    halfedge_vertex_[opposite(g).idx] = v1;
    g = cw_rotated(g);
  } while (g != start);

  // The triangles on both sides of h become 2-loops; each loop's surviving halfedge (h1 on the
  // left, o2 on the right) takes its opposite's place in the triangle beyond.
  auto replace = [&](Halfedge keep, Halfedge gone) {
    const Halfedge gone_next = next(gone), gone_prev = prev(gone);
    const Face beyond = face(gone);
    halfedge_next_[keep.idx] = gone_next;
    halfedge_next_[gone_prev.idx] = keep;
    halfedge_face_[keep.idx] = beyond;
    if (halfedge(beyond) == gone) face_halfedge_[beyond.idx] = keep;
  };
  replace(h1, opposite(h2));
  replace(o2, opposite(o1));
  vertex_halfedge_[vl.idx] = opposite(h1);
  vertex_halfedge_[vr.idx] = o2;
  vertex_halfedge_[v1.idx] = opposite(o2);
  vertex_halfedge_[v0.idx] = {};

  vertex_deleted_[v0.idx] = 1;
  for (const Halfedge dh : {h0, h2, o1}) edge_deleted_[edge(dh).idx] = 1;
  for (const Face df : {fh, fo}) {
    face_deleted_[df.idx] = 1;
    face_halfedge_[df.idx] = {};
  }
  deleted_vertices_ += 1;
  deleted_edges_ += 3;
  deleted_faces_ += 2;
}

void BalloonMesh::garbage_collection() {
  if (!has_garbage()) return;
  std::vector<std::uint32_t> vmap, emap, fmap;  // indexed by old index − new size
  const std::uint32_t nv = compact(
      vertex_deleted_, deleted_vertices_,
      [&](std::uint32_t i, std::uint32_t j) {
        std::swap(points_mm_[i], points_mm_[j]);
        std::swap(states_[i], states_[j]);
        std::swap(vertex_halfedge_[i], vertex_halfedge_[j]);
        std::swap(vertex_deleted_[i], vertex_deleted_[j]);
      },
      vmap);
  const std::uint32_t ne = compact(
      edge_deleted_, deleted_edges_,
      [&](std::uint32_t i, std::uint32_t j) {
        for (std::uint32_t s = 0; s < 2; ++s) {
          std::swap(halfedge_vertex_[2 * i + s], halfedge_vertex_[2 * j + s]);
          std::swap(halfedge_next_[2 * i + s], halfedge_next_[2 * j + s]);
          std::swap(halfedge_face_[2 * i + s], halfedge_face_[2 * j + s]);
        }
        std::swap(edge_deleted_[i], edge_deleted_[j]);
      },
      emap);
  const std::uint32_t nf = compact(
      face_deleted_, deleted_faces_,
      [&](std::uint32_t i, std::uint32_t j) {
        std::swap(face_halfedge_[i], face_halfedge_[j]);
        std::swap(face_deleted_[i], face_deleted_[j]);
      },
      fmap);

  points_mm_.resize(nv);
  states_.resize(nv);
  vertex_halfedge_.resize(nv);
  vertex_deleted_.resize(nv);
  halfedge_vertex_.resize(2 * ne);
  halfedge_next_.resize(2 * ne);
  halfedge_face_.resize(2 * ne);
  edge_deleted_.resize(ne);
  face_halfedge_.resize(nf);
  face_deleted_.resize(nf);

  // Compaction fills holes with elements from the tail only, so every live element below the new
  // size kept its index, and only references to an element that moved are stale. Each of those
  // lies next to the element it names, so they are found from the moved elements, not by a pass
  // over every halfedge (that pass was 8 % of the balloon's instructions at 128³, for the few
  // dozen elements a remeshing pass moves). `renew` maps a halfedge's references; it leaves
  // current ones alone, so an entry may be renewed more than once. A halfedge moves with its edge
  // and keeps its side.
  auto new_halfedge = [&](Halfedge h) {
    return (h.idx >> 1) < ne ? h : Halfedge{2 * emap[(h.idx >> 1) - ne] + (h.idx & 1u)};
  };
  auto renew = [&](std::uint32_t i) {
    if (halfedge_vertex_[i].idx >= nv) halfedge_vertex_[i] = Vertex{vmap[halfedge_vertex_[i].idx - nv]};
    if (halfedge_next_[i].valid()) halfedge_next_[i] = new_halfedge(halfedge_next_[i]);
    if (halfedge_face_[i].valid() && halfedge_face_[i].idx >= nf)
      halfedge_face_[i] = Face{fmap[halfedge_face_[i].idx - nf]};
  };
  // Renews every halfedge of h's loop (a triangle, or a boundary while add_triangle() builds),
  // the last of which is h's predecessor, whose next named h.
  auto renew_loop = [&](std::uint32_t h) {
    std::uint32_t g = h;
    do {
      renew(g);
      g = halfedge_next_[g].idx;
    } while (g != h);
  };
  for (const std::uint32_t e : emap) {
    if (e == kInvalidIndex) continue;  // a deleted element of the tail
    for (std::uint32_t h = 2 * e; h < 2 * e + 2; ++h) {
      renew(h ^ 1u);
      Halfedge& out = vertex_halfedge_[halfedge_vertex_[h ^ 1u].idx];  // of h's from-vertex
      out = new_halfedge(out);
      renew_loop(h);
      if (!halfedge_face_[h].valid()) continue;  // a boundary while add_triangle() builds
      Halfedge& held = face_halfedge_[halfedge_face_[h].idx];  // of h's face
      held = new_halfedge(held);
    }
  }
  for (const std::uint32_t v : vmap) {  // the halfedges into it: the twins of its outgoing ones
    if (v == kInvalidIndex || !vertex_halfedge_[v].valid()) continue;
    const std::uint32_t start = vertex_halfedge_[v].idx;
    std::uint32_t g = start;
    do {
      renew(g);
      renew(g ^ 1u);
      g = halfedge_next_[g ^ 1u].idx;
    } while (g != start);
  }
  for (const std::uint32_t f : fmap)
    if (f != kInvalidIndex) renew_loop(face_halfedge_[f].idx);
  deleted_vertices_ = deleted_edges_ = deleted_faces_ = 0;
}

// ---------------------------------------------------------------------------------------------
// Construction, validation

void make_uv_sphere(BalloonMesh& out, const Vec3f& centre_mm, float radius_mm, int segments,
                    int bands) {
  if (segments < 3 || bands < 2 || !(radius_mm > 0.0f))
    throw std::invalid_argument("make_uv_sphere: need segments >= 3, bands >= 2, radius > 0");
  out.clear();
  const Vertex north = out.add_vertex(centre_mm + Vec3f(0.0f, 0.0f, radius_mm));
  std::vector<std::vector<Vertex>> rings;
  for (int k = 1; k < bands; ++k) {
    const double theta = M_PI * k / bands;
    std::vector<Vertex> ring;
    for (int j = 0; j < segments; ++j) {
      const double phi = 2.0 * M_PI * j / segments;
      const Vec3f p_mm(static_cast<float>(radius_mm * std::sin(theta) * std::cos(phi)),
                       static_cast<float>(radius_mm * std::sin(theta) * std::sin(phi)),
                       static_cast<float>(radius_mm * std::cos(theta)));
      ring.push_back(out.add_vertex(centre_mm + p_mm));
    }
    rings.push_back(std::move(ring));
  }
  const Vertex south = out.add_vertex(centre_mm - Vec3f(0.0f, 0.0f, radius_mm));
  // Orientation: counter-clockwise seen from outside (checked by validate()'s signed volume).
  for (int j = 0; j < segments; ++j) {
    const int jn = (j + 1) % segments;
    out.add_triangle(north, rings.front()[j], rings.front()[jn]);
    for (std::size_t k = 0; k + 1 < rings.size(); ++k) {
      const Vertex a = rings[k][j], b = rings[k][jn], d = rings[k + 1][j], cc = rings[k + 1][jn];
      out.add_triangle(a, d, cc);
      out.add_triangle(a, cc, b);
    }
    out.add_triangle(south, rings.back()[jn], rings.back()[j]);
  }
  for (std::uint32_t i = 0; i < out.n_vertices(); ++i) out.state({i}).anchor_mm = out.point_mm({i});
}

void from_plain_mesh(const Mesh& plain, BalloonMesh& out) {
  out.clear();
  for (const Vec3f& p_mm : plain.vertices) out.state(out.add_vertex(p_mm)).anchor_mm = p_mm;
  for (const auto& t : plain.triangles) {
    if (t[0] >= plain.vertices.size() || t[1] >= plain.vertices.size() ||
        t[2] >= plain.vertices.size())
      throw std::invalid_argument("from_plain_mesh: triangle index out of range");
    out.add_triangle({t[0]}, {t[1]}, {t[2]});
  }
}

int euler_characteristic(const BalloonMesh& mesh) {
  int v = 0, e = 0, f = 0;
  for (std::uint32_t i = 0; i < mesh.n_vertices(); ++i) v += !mesh.is_deleted(Vertex{i});
  for (std::uint32_t i = 0; i < mesh.n_edges(); ++i) e += !mesh.is_deleted(Edge{i});
  for (std::uint32_t i = 0; i < mesh.n_faces(); ++i) f += !mesh.is_deleted(Face{i});
  return v - e + f;
}

std::string validate(const BalloonMesh& mesh) {
  const std::uint32_t nv = mesh.n_vertices(), nh = mesh.n_halfedges(), nf = mesh.n_faces();
  auto bad_vertex = [&](Vertex v) { return !(v.idx < nv) || mesh.is_deleted(v); };
  auto bad_face = [&](Face f) { return !(f.idx < nf) || mesh.is_deleted(f); };
  auto bad_halfedge = [&](Halfedge h) { return !(h.idx < nh) || mesh.is_deleted(mesh.edge(h)); };

  // Halfedges: closed triangles, twins reversed.
  std::vector<int> outgoing(nv, 0);
  for (std::uint32_t i = 0; i < nh; ++i) {
    const Halfedge h{i};
    if (mesh.is_deleted(mesh.edge(h))) continue;
    const std::string at = " at halfedge " + std::to_string(i);
    if (bad_vertex(mesh.to_vertex(h)) || bad_vertex(mesh.from_vertex(h)))
      return "halfedge to a deleted vertex" + at;
    if (mesh.is_boundary(h)) return "boundary halfedge" + at;
    if (bad_face(mesh.face(h))) return "halfedge of a deleted face" + at;
    const Halfedge n1 = mesh.next(h);
    if (bad_halfedge(n1) || bad_halfedge(mesh.next(n1))) return "next halfedge deleted" + at;
    if (mesh.next(mesh.next(n1)) != h) return "face that is not a triangle" + at;
    if (mesh.face(n1) != mesh.face(h)) return "face loop with two faces" + at;
    if (mesh.from_vertex(n1) != mesh.to_vertex(h)) return "next does not continue" + at;
    ++outgoing[mesh.from_vertex(h).idx];
  }
  // Vertices: the rotation around the outgoing halfedge reaches all of them (manifold).
  int n_live = 0;
  for (std::uint32_t i = 0; i < nv; ++i) {
    const Vertex v{i};
    if (mesh.is_deleted(v)) continue;
    ++n_live;
    const Halfedge start = mesh.halfedge(v);
    if (!start.valid()) return "isolated vertex " + std::to_string(i);
    if (bad_halfedge(start) || mesh.from_vertex(start) != v)
      return "vertex with a wrong outgoing halfedge " + std::to_string(i);
    int around = 0;
    Halfedge h = start;
    do {
      if (++around > outgoing[i]) break;
      h = mesh.cw_rotated(h);
    } while (h != start);
    if (around != outgoing[i]) return "non-manifold vertex " + std::to_string(i);
    if (around < 3) return "vertex of valence < 3: " + std::to_string(i);
  }
  if (n_live < 4) return "fewer than 4 vertices";
  std::set<std::pair<std::uint32_t, std::uint32_t>> edges;
  for (std::uint32_t i = 0; i < mesh.n_edges(); ++i) {
    const Edge e{i};
    if (mesh.is_deleted(e)) continue;
    std::uint32_t a = mesh.from_vertex(mesh.halfedge(e, 0)).idx;
    std::uint32_t b = mesh.to_vertex(mesh.halfedge(e, 0)).idx;
    if (a == b) return "loop edge";
    if (a > b) std::swap(a, b);
    if (!edges.insert({a, b}).second) return "duplicate edge";
  }
  std::set<std::array<std::uint32_t, 3>> faces;
  double volume6 = 0.0;
  for (std::uint32_t i = 0; i < nf; ++i) {
    const Face f{i};
    if (mesh.is_deleted(f)) continue;
    const Halfedge h = mesh.halfedge(f);
    if (bad_halfedge(h) || mesh.face(h) != f) return "face with a wrong halfedge";
    std::array<std::uint32_t, 3> idx{mesh.to_vertex(h).idx, mesh.to_vertex(mesh.next(h)).idx,
                                     mesh.to_vertex(mesh.next(mesh.next(h))).idx};
    if (idx[0] == idx[1] || idx[1] == idx[2] || idx[0] == idx[2]) return "degenerate face";
    volume6 += dot(mesh.point_mm({idx[0]}), cross(mesh.point_mm({idx[1]}), mesh.point_mm({idx[2]})));
    std::sort(idx.begin(), idx.end());
    if (!faces.insert(idx).second) return "duplicate face";
  }
  const int chi = n_live - static_cast<int>(edges.size()) + static_cast<int>(faces.size());
  if (chi != 2) return "Euler characteristic " + std::to_string(chi) + " != 2";
  if (!(volume6 > 0.0)) return "non-positive enclosed volume (inward oriented?)";
  return {};
}

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
  const Vec3f mid_mm = onto_to ? bm.point_mm(v_to) : Vec3f((bm.point_mm(v_from) + bm.point_mm(v_to)) * 0.5f);
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

Mesh to_plain_mesh(const BalloonMesh& mesh) {
  Mesh out;
  std::vector<std::uint32_t> index(mesh.n_vertices(), 0);
  for (std::uint32_t i = 0; i < mesh.n_vertices(); ++i) {
    if (mesh.is_deleted(Vertex{i})) continue;
    index[i] = static_cast<std::uint32_t>(out.vertices.size());
    out.vertices.push_back(mesh.point_mm({i}));
  }
  for (std::uint32_t i = 0; i < mesh.n_faces(); ++i) {
    if (mesh.is_deleted(Face{i})) continue;
    const Halfedge h = mesh.halfedge(Face{i});
    out.triangles.push_back({index[mesh.to_vertex(h).idx], index[mesh.to_vertex(mesh.next(h)).idx],
                             index[mesh.to_vertex(mesh.next(mesh.next(h))).idx]});
  }
  return out;
}

}  // namespace sonomesh::segment::internal
