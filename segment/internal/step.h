#pragma once
/// @file
/// @brief What both balloon passes share around the Euler step S^{n+1} = S^n + h·(λ·U + μ·n):
/// the step itself, the volume's usable box, unit face normals, input checks and timing.

#include <Eigen/Geometry>
#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "segment/segment.h"

namespace sonomesh::segment::internal {

using Clock = std::chrono::steady_clock;

/// Grains of the balloon's parallel loops (mesh::Workers): 128 for the per-vertex evolution and
/// A_t lookups (1-2 thousand instructions per vertex), 512 for the light loops (normals, copies).
/// One grain of 512 for all left the fronts of a few hundred vertices on one core.
inline constexpr std::size_t kHeavyGrain = 128, kLightGrain = 512;

inline double ms_since(Clock::time_point t) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t).count();
}

/// The explicit Euler step and the box a vertex may move in: half a voxel inside the
/// voxel-centre box, as there is no data beyond.
struct StepKernel {
  float h = 0.0f, lambda = 0.0f, mu_mm = 0.0f;
  Vec3f box_lo = Vec3f::Zero(), box_hi = Vec3f::Zero();

  StepKernel(const BalloonOptions& o, const volume::Volume& grid, float vox_mm)
      : h(o.time_step),
        lambda(o.umbrella_weight),
        mu_mm(o.inflation_vox * vox_mm),
        box_lo(grid.min_mm() + Vec3f::Constant(0.5f * vox_mm)),
        box_hi(grid.max_mm() - Vec3f::Constant(0.5f * vox_mm)) {}

  /// d = h·(λ·U(P) + μ·n) for the umbrella vector U(P) and the vertex normal n.
  Vec3f step(const Vec3f& umbrella, const Vec3f& n) const {
    return h * (lambda * umbrella + mu_mm * n);
  }
  bool outside(const Vec3f& p) const {
    return (p.array() < box_lo.array()).any() || (p.array() > box_hi.array()).any();
  }
};

/// Unit normal of triangle t (counter-clockwise from outside); zero for a degenerate one.
inline Vec3f unit_face_normal(const std::vector<Vec3f>& pos,
                              const std::array<std::uint32_t, 3>& t) {
  const Vec3f n = (pos[t[1]] - pos[t[0]]).cross(pos[t[2]] - pos[t[0]]);
  const float len = n.norm();
  return len > 0.0f ? Vec3f(n / len) : Vec3f::Zero();
}

/// @throws std::invalid_argument for options out of range (segment.h).
void check_options(const BalloonOptions& o);
/// The sampler reads Float32: other types are converted once into `storage`.
const volume::Volume& as_float32(const volume::Volume& v, volume::Volume& storage);

}  // namespace sonomesh::segment::internal
