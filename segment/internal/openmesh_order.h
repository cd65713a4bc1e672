#pragma once
/// @file
/// @brief Vector arithmetic in OpenMesh's VectorT order for the balloon mesh's geometric tests.

#include <cmath>

#include "segment/mesh.h"

namespace sonomesh::segment::internal::openmesh_order {

// Vector arithmetic in OpenMesh's VectorT order (sums left to right; Eigen's unrolled reductions
// pair the last two terms first): the split/collapse decisions stay bit for bit what they were.
inline float dot(const Vec3f& a, const Vec3f& b) {
  return a.x() * b.x() + a.y() * b.y() + a.z() * b.z();
}
inline float sqrnorm(const Vec3f& a) { return dot(a, a); }
inline float norm(const Vec3f& a) { return std::sqrt(sqrnorm(a)); }
inline Vec3f cross(const Vec3f& a, const Vec3f& b) {
  return Vec3f(a.y() * b.z() - a.z() * b.y(), a.z() * b.x() - a.x() * b.z(),
               a.x() * b.y() - a.y() * b.x());
}
inline Vec3f divided(const Vec3f& a, float s) { return Vec3f(a.x() / s, a.y() / s, a.z() / s); }

}  // namespace sonomesh::segment::internal::openmesh_order
