#pragma once
/// @file
/// @brief The balloon's halfedge mesh (purpose-built, in the shape of pmp's SurfaceMesh), its
/// per-vertex state, and remeshing (Botsch and Kobbelt 2004 style split/collapse with the link
/// condition). Private to segment/.

// Why not OpenMesh, which style.md §2.3 prefers: remeshing through it took ~70 % of the balloon's
// time (perf, 128³ phantoms: garbage_collection 24 % inclusive, collapse_edge_midpoint 22 %, the
// copy into the evolution's flat arrays 5 %). Debian's libOpenMeshCore is compiled with its
// assertions on, so every property access inside its collapse, is_collapse_ok and
// garbage_collection compares type names (memcmp alone 6.5 %), which no compile flag of ours can
// switch off. Here connectivity, positions and state are plain arrays the evolution copies (or
// reads) directly.
//
// The operations reproduce OpenMesh's element order exactly (add_face's outgoing halfedges, the
// indices split creates, what collapse keeps, garbage_collection's swap-with-last compaction) and
// the geometric tests its float arithmetic, so every split and collapse decision, and with them
// the balloon's results, are what they were with OpenMesh.

#include <cstdint>
#include <limits>
#include <span>
#include <string>
#include <vector>

#include "segment/mesh.h"

namespace sonomesh::segment::internal {

/// Evolution state carried by every balloon vertex through remeshing.
struct VertexState {
  float cost = 0.0f;                       // accumulated boundary cost Ψ_cost (grey levels)
  StopReason reason = StopReason::Moving;  // Moving while k = 1
  Vec3f anchor_mm = Vec3f::Zero();         // position at the start of the stall window
  float path_mm = 0.0f;                    // length of the path travelled
  float floor_level = 1e30f;               // darkest level met on the path (cost scale)
  std::int64_t marked_voxel = -1;          // linear index of the voxel it last marked A_t
                                           // from (-1: none yet, e.g. new from a split)
};

inline constexpr std::uint32_t kInvalidIndex = std::numeric_limits<std::uint32_t>::max();

/// A typed 32-bit index: a vertex cannot be passed where a face is meant.
template <typename Tag>
struct Index {
  std::uint32_t idx = kInvalidIndex;
  constexpr bool valid() const { return idx != kInvalidIndex; }
  constexpr bool operator==(const Index&) const = default;
};
using Vertex = Index<struct VertexTag>;
using Halfedge = Index<struct HalfedgeTag>;  // edge e owns halfedges 2e and 2e + 1
using Edge = Index<struct EdgeTag>;
using Face = Index<struct FaceTag>;

/// Indexed halfedge triangle mesh with per-vertex position (mm) and VertexState.
///
/// Every array is indexed by `.idx` and runs over deleted elements too (flagged until
/// garbage_collection()). Splits and collapses expect a closed mesh; boundaries exist only while
/// add_triangle() builds one.
class BalloonMesh {
 public:
  void clear();

  // --- Sizes (deleted elements included) ---
  std::uint32_t n_vertices() const { return static_cast<std::uint32_t>(points_mm_.size()); }
  std::uint32_t n_halfedges() const { return static_cast<std::uint32_t>(halfedge_vertex_.size()); }
  std::uint32_t n_edges() const { return n_halfedges() / 2; }
  std::uint32_t n_faces() const { return static_cast<std::uint32_t>(face_halfedge_.size()); }
  std::uint32_t n_live_vertices() const { return n_vertices() - deleted_vertices_; }
  bool has_garbage() const { return deleted_vertices_ + deleted_edges_ + deleted_faces_ > 0; }

  // --- Connectivity ---
  Vertex to_vertex(Halfedge h) const { return halfedge_vertex_[h.idx]; }
  Vertex from_vertex(Halfedge h) const { return to_vertex(opposite(h)); }
  Halfedge next(Halfedge h) const { return halfedge_next_[h.idx]; }
  Halfedge prev(Halfedge h) const { return next(next(h)); }  // triangles only
  static Halfedge opposite(Halfedge h) { return {h.idx ^ 1u}; }
  /// The next outgoing halfedge around from_vertex(h), clockwise seen from outside.
  Halfedge cw_rotated(Halfedge h) const { return next(opposite(h)); }
  Face face(Halfedge h) const { return halfedge_face_[h.idx]; }
  bool is_boundary(Halfedge h) const { return !face(h).valid(); }
  static Edge edge(Halfedge h) { return {h.idx >> 1}; }
  static Halfedge halfedge(Edge e, unsigned side) { return {2 * e.idx + side}; }
  Halfedge halfedge(Vertex v) const { return vertex_halfedge_[v.idx]; }  // outgoing
  Halfedge halfedge(Face f) const { return face_halfedge_[f.idx]; }
  bool is_deleted(Vertex v) const { return vertex_deleted_[v.idx] != 0; }
  bool is_deleted(Edge e) const { return edge_deleted_[e.idx] != 0; }
  bool is_deleted(Face f) const { return face_deleted_[f.idx] != 0; }
  int valence(Vertex v) const;

  // --- Per-vertex data ---
  Vec3f& point_mm(Vertex v) { return points_mm_[v.idx]; }
  const Vec3f& point_mm(Vertex v) const { return points_mm_[v.idx]; }
  VertexState& state(Vertex v) { return states_[v.idx]; }
  const VertexState& state(Vertex v) const { return states_[v.idx]; }

  // --- Flat arrays, for copying or reading in bulk ---
  std::span<Vec3f> points_mm() { return points_mm_; }
  std::span<const Vec3f> points_mm() const { return points_mm_; }
  std::span<VertexState> states() { return states_; }
  std::span<const VertexState> states() const { return states_; }
  std::span<const Halfedge> vertex_halfedges() const { return vertex_halfedge_; }
  std::span<const Vertex> halfedge_vertices() const { return halfedge_vertex_; }  // to-vertex
  std::span<const Halfedge> halfedge_nexts() const { return halfedge_next_; }
  std::span<const Face> halfedge_faces() const { return halfedge_face_; }
  std::span<const Halfedge> face_halfedges() const { return face_halfedge_; }

  // --- Construction ---
  Vertex add_vertex(const Vec3f& p_mm);
  /// Adds triangle (a, b, c), counter-clockwise seen from outside (OpenMesh's add_face).
  /// @throws std::invalid_argument if it would make a vertex or an edge non-manifold.
  Face add_triangle(Vertex a, Vertex b, Vertex c);

  // --- Editing (closed mesh) ---
  /// Inserts the isolated vertex `v` into edge `e`: the two triangles become four. Edge `e`
  /// keeps the half towards `e`'s to-vertex; three edges and two faces are appended.
  void split(Edge e, Vertex v);
  /// The link condition: from_vertex(h) may melt into to_vertex(h) without the mesh ceasing to
  /// be a closed 2-manifold with every valence >= 3.
  bool is_collapse_ok(Halfedge h) const;
  /// Melts from_vertex(h) into to_vertex(h) (positions and states untouched). Check
  /// is_collapse_ok() first. The vertex, three edges and two faces are flagged deleted.
  void collapse(Halfedge h);
  /// Removes the deleted elements: the last live element moves into each hole, so indices stay
  /// compact and positions and states move with their vertices.
  void garbage_collection();

 private:
  Halfedge new_edge(Vertex from, Vertex to);
  Face new_face();
  bool is_boundary(Vertex v) const;
  Halfedge find_halfedge(Vertex from, Vertex to) const;
  Halfedge boundary_prev(Halfedge h) const;
  void adjust_outgoing_halfedge(Vertex v);
  // Face f is the triangle a -> b -> c (halfedges), held by a.
  void set_triangle(Face f, Halfedge a, Halfedge b, Halfedge c);
  // garbage_collection's phases: compaction, then renewing the references to moved elements.
  struct Compaction;
  Compaction compact_all();
  void renew(const Compaction& c, std::uint32_t h);
  void renew_loop(const Compaction& c, std::uint32_t h);
  void renew_moved(const Compaction& c);

  std::vector<Vec3f> points_mm_;
  std::vector<VertexState> states_;
  std::vector<Halfedge> vertex_halfedge_;
  std::vector<std::uint8_t> vertex_deleted_;
  std::vector<Vertex> halfedge_vertex_;
  std::vector<Halfedge> halfedge_next_;
  std::vector<Face> halfedge_face_;
  std::vector<std::uint8_t> edge_deleted_;
  std::vector<Halfedge> face_halfedge_;
  std::vector<std::uint8_t> face_deleted_;
  std::uint32_t deleted_vertices_ = 0;
  std::uint32_t deleted_edges_ = 0;
  std::uint32_t deleted_faces_ = 0;
};

/// UV sphere of `segments` meridians and `bands` latitude bands (poles are single vertices):
/// segments*(bands-1)+2 vertices, 2*segments*(bands-1) triangles, outward oriented.
/// 10 and 11 give the paper's 102 vertices and 200 triangles.
void make_uv_sphere(BalloonMesh& out, const Vec3f& centre_mm, float radius_mm, int segments = 10,
                    int bands = 11);

/// Plain arrays into a mesh (states default, anchors at the vertices).
/// @throws std::invalid_argument if the triangles do not form a manifold.
void from_plain_mesh(const Mesh& plain, BalloonMesh& out);

/// Validity as the balloon needs it: no boundary, every vertex manifold with valence >= 3, no
/// degenerate or duplicate faces/edges, V - E + F = 2, positive enclosed volume (outward).
/// Deleted elements are skipped. Returns an empty string if valid, otherwise what is wrong.
std::string validate(const BalloonMesh& mesh);

/// Euler characteristic V - E + F of the live elements.
int euler_characteristic(const BalloonMesh& mesh);

struct RemeshLimits {
  float min_edge_mm = 0.0f;  // collapse below
  float max_edge_mm = 0.0f;  // split above
};

struct RemeshCounts {
  int splits = 0;
  int collapses = 0;
};

/// Splits one edge at its midpoint (two triangles become four); the new vertex inherits the
/// state of its parents (stopped only if both are stopped). Returns the new vertex.
Vertex split_edge_midpoint(BalloonMesh& bm, Edge e);

/// Collapses the halfedge's edge to its midpoint if the link condition holds, no adjacent triangle
/// folds over or degenerates, and no resulting edge exceeds `max_edge_mm`. Returns whether it did.
/// Leaves deleted elements behind (call garbage_collection()).
bool collapse_edge_midpoint(BalloonMesh& bm, Halfedge h, float max_edge_mm);

/// One remeshing pass: split edges longer than max, then collapse edges shorter than min, then
/// garbage collection. Only edges with a moving end are considered: an edge between two stopped
/// vertices no longer changes, and was already checked when its last end stopped. The mesh stays
/// closed, manifold, genus 0, outward oriented, and without deleted elements.
RemeshCounts remesh(BalloonMesh& bm, const RemeshLimits& limits);

/// Plain arrays of the live elements.
Mesh to_plain_mesh(const BalloonMesh& mesh);

}  // namespace sonomesh::segment::internal
