#pragma once
/// @file
/// @brief Plain mesh and point-cloud arrays: what crosses module boundaries (positions in mm).

#include <array>
#include <cstdint>
#include <vector>

#include "volume/volume.h"

namespace sonomesh::segment {

using volume::Vec3f;

/// Why a balloon vertex stopped; the values are the `stop` codes of the balloon PLY (DESIGN.md).
enum class StopReason : std::uint8_t {
  Moving = 0,            // still moving when evolution ended without a limit
  Boundary = 1,          // accumulated boundary cost Ψ_cost exceeded τ_cost
  Curvature = 2,         // edge curvature exceeded τ_curv (a spike leaking through a gap)
  SelfIntersection = 3,  // about to enter voxels the other side of the balloon already swept
  IterationLimit = 4,    // still moving at the iteration limit
};

/// Triangle mesh; triangles index `vertices` counter-clockwise seen from outside.
struct Mesh {
  std::vector<Vec3f> vertices;
  std::vector<std::array<std::uint32_t, 3>> triangles;
};

/// Oriented samples for the reconstruction: positions (mm), outward unit normals, and each
/// sample's share of the surface area in mm² (its weight in Kazhdan's splat).
struct PointCloud {
  std::vector<Vec3f> points;
  std::vector<Vec3f> normals;
  std::vector<float> area_mm2;  // same length as points
};

}  // namespace sonomesh::segment
