#pragma once
/// @file
/// @brief The balloon's flat working copy between two remeshing passes: positions, state, the
/// one-ring in CSR form and face normals, so the per-iteration loop needs no halfedge walks.

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "segment/internal/balloon_mesh.h"

namespace sonomesh::segment::internal {

struct FlatArrays {
  std::vector<Vec3f> pos;
  std::vector<Vec3f> next_pos;
  std::vector<float> cost;
  std::vector<StopReason> reason;
  std::vector<Vec3f> anchor;
  std::vector<float> path;
  std::vector<float> floor_level;
  std::vector<std::int64_t> marked_voxel;
  std::vector<Vec3f> normal;  // vertex normals of the last iteration
  std::vector<std::array<std::uint32_t, 3>> tri;
  std::vector<Vec3f> face_normal;
  // One-ring: for vertex v, entries ring_begin[v] .. ring_begin[v+1]-1, each an outgoing edge with
  // its far vertex and the faces on its two sides (for H(PQ) and for equation (2)). Empty, and
  // the evolution state above unset, for a vertex that had stopped when they were extracted.
  std::vector<std::uint32_t> ring_begin;
  std::vector<std::uint32_t> ring_vertex;
  std::vector<std::uint32_t> ring_face_left;
  std::vector<std::uint32_t> ring_face_right;
};

/// Copies `bm` (no deleted elements: indices are array indices) into `a`. Only vertices still
/// moving get a ring and evolution state, so a pass costs what the moving front costs. Each ring
/// runs clockwise from the vertex's outgoing halfedge, the order every sum over it keeps.
void extract(const BalloonMesh& bm, FlatArrays& a);

/// Back into the mesh for a remeshing pass: the vertices of `window` (those moving when the
/// arrays were extracted, the only ones the evolution changes).
void write_back(const FlatArrays& a, std::span<const std::uint32_t> window, BalloonMesh& bm);

}  // namespace sonomesh::segment::internal
