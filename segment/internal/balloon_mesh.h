#pragma once
/// @file
/// @brief The balloon's halfedge mesh (OpenMesh), its per-vertex state, and remeshing
/// (Botsch and Kobbelt 2004 style split/collapse with the link condition). Private to segment/.

// OpenMesh verifies every property access with a dynamic_cast (typeinfo string compares) unless
// NDEBUG is set; our Release build keeps assertions on, which made remeshing ~5x slower
// (perf: memcmp under PropertyContainer::property). Its own asserts are switched off for its
// headers only; ours stay on (<cassert> is re-included below).
#ifndef NDEBUG
#define SONOMESH_RESTORE_ASSERT
#define NDEBUG
#endif
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>
#ifdef SONOMESH_RESTORE_ASSERT
#undef NDEBUG
#undef SONOMESH_RESTORE_ASSERT
#include <cassert>
#endif

#include <cstdint>
#include <string>

#include "segment/mesh.h"

namespace sonomesh::segment::internal {

struct BalloonTraits : public OpenMesh::DefaultTraits {
  using Point = OpenMesh::Vec3f;
  using Normal = OpenMesh::Vec3f;
  VertexAttributes(OpenMesh::Attributes::Status);
  EdgeAttributes(OpenMesh::Attributes::Status);
  FaceAttributes(OpenMesh::Attributes::Status);
  HalfedgeAttributes(OpenMesh::Attributes::PrevHalfedge);
};

using TriMesh = OpenMesh::TriMesh_ArrayKernelT<BalloonTraits>;

/// Evolution state carried by every balloon vertex through remeshing.
struct VertexState {
  float cost = 0.0f;                        // accumulated boundary cost Ψ_cost (grey levels)
  StopReason reason = StopReason::Moving;   // Moving while k = 1
  Vec3f anchor_mm = Vec3f::Zero();          // position at the start of the stall window
  float path_mm = 0.0f;                     // length of the path travelled
};

/// OpenMesh mesh plus the property handle of the vertex state.
class BalloonMesh {
 public:
  BalloonMesh();
  TriMesh& mesh() { return mesh_; }
  const TriMesh& mesh() const { return mesh_; }
  VertexState& state(TriMesh::VertexHandle v) { return mesh_.property(state_, v); }
  const VertexState& state(TriMesh::VertexHandle v) const { return mesh_.property(state_, v); }

 private:
  TriMesh mesh_;
  OpenMesh::VPropHandleT<VertexState> state_;
};

/// UV sphere of `segments` meridians and `bands` latitude bands (poles are single vertices):
/// segments*(bands-1)+2 vertices, 2*segments*(bands-1) triangles, outward oriented.
/// 10 and 11 give the paper's 102 vertices and 200 triangles.
void make_uv_sphere(BalloonMesh& out, const Vec3f& centre_mm, float radius_mm, int segments = 10,
                    int bands = 11);

/// Validity as the balloon needs it: no boundary, every vertex manifold with valence >= 3, no
/// degenerate or duplicate faces/edges, V - E + F = 2, positive enclosed volume (outward).
/// Returns an empty string if valid, otherwise what is wrong.
std::string validate(const TriMesh& mesh);

/// Euler characteristic V - E + F of the (garbage-collected) mesh.
int euler_characteristic(const TriMesh& mesh);

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
TriMesh::VertexHandle split_edge_midpoint(BalloonMesh& bm, TriMesh::EdgeHandle e);

/// Collapses the halfedge's edge to its midpoint if the link condition holds, no adjacent triangle
/// folds over or degenerates, and no resulting edge exceeds `max_edge_mm`. Returns whether it did.
/// Leaves deleted elements behind (call garbage_collection()).
bool collapse_edge_midpoint(BalloonMesh& bm, TriMesh::HalfedgeHandle h, float max_edge_mm);

/// One remeshing pass: split edges longer than max, then collapse edges shorter than min, then
/// garbage collection. Only edges with a moving end are considered: an edge between two stopped
/// vertices no longer changes, and was already checked when its last end stopped. The mesh stays closed, manifold, genus 0, outward oriented.
RemeshCounts remesh(BalloonMesh& bm, const RemeshLimits& limits);

/// Plain arrays (garbage-collected mesh expected).
Mesh to_plain_mesh(const TriMesh& mesh);

}  // namespace sonomesh::segment::internal
