// The balloon's halfedge mesh: elements, triangles, split, collapse, garbage collection.
#include "segment/internal/balloon_mesh.h"

#include <algorithm>
#include <cstring>
#include <utility>

namespace sonomesh::segment::internal {
namespace {

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

// The index maps of one garbage collection, each indexed by old index − new size, and the new
// sizes.
struct BalloonMesh::Compaction {
  std::vector<std::uint32_t> vmap, emap, fmap;
  std::uint32_t nv = 0, ne = 0, nf = 0;
  // A halfedge moves with its edge and keeps its side.
  Halfedge halfedge(Halfedge h) const {
    return (h.idx >> 1) < ne ? h : Halfedge{2 * emap[(h.idx >> 1) - ne] + (h.idx & 1u)};
  }
};

BalloonMesh::Compaction BalloonMesh::compact_all() {
  Compaction c;
  c.nv = compact(
      vertex_deleted_, deleted_vertices_,
      [&](std::uint32_t i, std::uint32_t j) {
        std::swap(points_mm_[i], points_mm_[j]);
        std::swap(states_[i], states_[j]);
        std::swap(vertex_halfedge_[i], vertex_halfedge_[j]);
        std::swap(vertex_deleted_[i], vertex_deleted_[j]);
      },
      c.vmap);
  c.ne = compact(
      edge_deleted_, deleted_edges_,
      [&](std::uint32_t i, std::uint32_t j) {
        for (std::uint32_t s = 0; s < 2; ++s) {
          std::swap(halfedge_vertex_[2 * i + s], halfedge_vertex_[2 * j + s]);
          std::swap(halfedge_next_[2 * i + s], halfedge_next_[2 * j + s]);
          std::swap(halfedge_face_[2 * i + s], halfedge_face_[2 * j + s]);
        }
        std::swap(edge_deleted_[i], edge_deleted_[j]);
      },
      c.emap);
  c.nf = compact(
      face_deleted_, deleted_faces_,
      [&](std::uint32_t i, std::uint32_t j) {
        std::swap(face_halfedge_[i], face_halfedge_[j]);
        std::swap(face_deleted_[i], face_deleted_[j]);
      },
      c.fmap);
  points_mm_.resize(c.nv);
  states_.resize(c.nv);
  vertex_halfedge_.resize(c.nv);
  vertex_deleted_.resize(c.nv);
  halfedge_vertex_.resize(2 * c.ne);
  halfedge_next_.resize(2 * c.ne);
  halfedge_face_.resize(2 * c.ne);
  edge_deleted_.resize(c.ne);
  face_halfedge_.resize(c.nf);
  face_deleted_.resize(c.nf);
  return c;
}

// Maps halfedge i's references; current ones are left alone, so an entry may be renewed more
// than once.
void BalloonMesh::renew(const Compaction& c, std::uint32_t i) {
  if (halfedge_vertex_[i].idx >= c.nv)
    halfedge_vertex_[i] = Vertex{c.vmap[halfedge_vertex_[i].idx - c.nv]};
  if (halfedge_next_[i].valid()) halfedge_next_[i] = c.halfedge(halfedge_next_[i]);
  if (halfedge_face_[i].valid() && halfedge_face_[i].idx >= c.nf)
    halfedge_face_[i] = Face{c.fmap[halfedge_face_[i].idx - c.nf]};
}

// Renews every halfedge of h's loop (a triangle, or a boundary while add_triangle() builds), the
// last of which is h's predecessor, whose next named h.
void BalloonMesh::renew_loop(const Compaction& c, std::uint32_t h) {
  std::uint32_t g = h;
  do {
    renew(c, g);
    g = halfedge_next_[g].idx;
  } while (g != h);
}

// Compaction fills holes with elements from the tail only, so every live element below the new
// size kept its index, and only references to an element that moved are stale. Each of those lies
// next to the element it names, so they are found from the moved elements, not by a pass over
// every halfedge, which costs more than the few dozen elements a remeshing pass moves.
void BalloonMesh::renew_moved(const Compaction& c) {
  for (const std::uint32_t e : c.emap) {
    if (e == kInvalidIndex) continue;  // a deleted element of the tail
    for (std::uint32_t h = 2 * e; h < 2 * e + 2; ++h) {
      renew(c, h ^ 1u);
      Halfedge& out = vertex_halfedge_[halfedge_vertex_[h ^ 1u].idx];  // of h's from-vertex
      out = c.halfedge(out);
      renew_loop(c, h);
      if (!halfedge_face_[h].valid()) continue;  // a boundary while add_triangle() builds
      Halfedge& held = face_halfedge_[halfedge_face_[h].idx];  // of h's face
      held = c.halfedge(held);
    }
  }
  for (const std::uint32_t v : c.vmap) {  // the halfedges into it: the twins of its outgoing ones
    if (v == kInvalidIndex || !vertex_halfedge_[v].valid()) continue;
    const std::uint32_t start = vertex_halfedge_[v].idx;
    std::uint32_t g = start;
    do {
      renew(c, g);
      renew(c, g ^ 1u);
      g = halfedge_next_[g ^ 1u].idx;
    } while (g != start);
  }
  for (const std::uint32_t f : c.fmap)
    if (f != kInvalidIndex) renew_loop(c, face_halfedge_[f].idx);
}

void BalloonMesh::garbage_collection() {
  if (!has_garbage()) return;
  renew_moved(compact_all());
  deleted_vertices_ = deleted_edges_ = deleted_faces_ = 0;
}

}  // namespace sonomesh::segment::internal
