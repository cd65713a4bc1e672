#pragma once
/// @file
/// @brief Trilinear sampling of the smoothed image and its gradient in one pass (shared weights),
/// clamped at the border like volume::sample_mm. The per-vertex loop samples the gradient once per
/// vertex per iteration, so this avoids separate lookups through volume::sample_mm.

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <vector>

#include "volume/volume.h"

namespace sonomesh::segment::internal {

using volume::Vec3f;
using volume::Vec3i;

class ImageSampler {
 public:
  /// `image` must be a Float32 volume (the caller converts) and outlive the sampler. The gradient
  /// is volume::central_gradient's (central differences, one-sided at the borders), taken at the
  /// eight corners of each sample as they are read: bit for bit what trilinear sampling of the
  /// three gradient volumes gives, without their 12 bytes per voxel (at 256³ a fresh process
  /// spent more on first-touching those than on the balloon's reads of them).
  explicit ImageSampler(const volume::Volume& image)
      : dims_(image.dims()),
        origin_mm_(image.origin_mm()),
        inv_spacing_(image.spacing_mm().cwiseInverse()),
        img_(image.f32().data()) {
    set_up_corners();
  }

  float value(const Vec3f& p_mm) const {
    float f[3];
    const float* p = img_ + cell(p_mm, f);
    const float x1 = f[0], x0 = 1.0f - f[0], y1 = f[1], y0 = 1.0f - f[1];
    const float z1 = f[2], z0 = 1.0f - f[2];
    const float w[8] = {x0 * y0 * z0, x1 * y0 * z0, x0 * y1 * z0, x1 * y1 * z0,
                        x0 * y0 * z1, x1 * y0 * z1, x0 * y1 * z1, x1 * y1 * z1};
    float v = 0.0f;
    for (int i = 0; i < 8; ++i) v += w[i] * p[corner_offset_[i]];  // corners()'s weights and order
    return v;
  }

  Vec3f gradient(const Vec3f& p_mm) const {
    float v;
    Vec3f grad;
    value_and_gradient(p_mm, v, grad);
    return grad;
  }

  /// Value and gradient with one set of weights.
  void value_and_gradient(const Vec3f& p_mm, float& value, Vec3f& grad) const {
    const Corners c = corners(p_mm);
    float v = 0.0f, x = 0.0f, y = 0.0f, z = 0.0f;
    for (int i = 0; i < 8; ++i) {
      const float* p = img_ + c.idx[i];
      const Diff& dx = c.diff[0][i & 1];
      const Diff& dy = c.diff[1][(i >> 1) & 1];
      const Diff& dz = c.diff[2][(i >> 2) & 1];
      v += c.w[i] * p[0];
      x += c.w[i] * ((p[dx.hi] - p[dx.lo]) * dx.scale);
      y += c.w[i] * ((p[dy.hi] - p[dy.lo]) * dy.scale);
      z += c.w[i] * ((p[dz.hi] - p[dz.lo]) * dz.scale);
    }
    value = v;
    grad = Vec3f(x, y, z);
  }

  const Vec3i& dims() const { return dims_; }

 private:
  // The two samples of a voxel's difference along one axis (offsets from the voxel) and
  // 1 / their distance in mm; zero on a one-voxel axis.
  struct Diff {
    std::ptrdiff_t lo, hi;
    float scale;
  };
  struct Corners {
    std::size_t idx[8];
    float w[8];
    Diff diff[3][2];  // per axis, of the lower and the upper corner along it
  };

  // volume::central_gradient's rule for voxel c of an axis of n voxels.
  Diff diff(int c, int a) const {
    const int n = dims_[a];
    const auto stride = static_cast<std::ptrdiff_t>(stride_[a]);
    if (n == 1) return {0, 0, 0.0f};
    if (c == 0) return {0, stride, inv_spacing_[a]};
    if (c == n - 1) return {-stride, 0, inv_spacing_[a]};
    return {-stride, stride, half_inv_spacing_[a]};
  }

  // The cell holding p (clamped into the volume): its lower corner's index, and p's fraction
  // across it per axis in `f` (the corner's index per axis in `i0`, when given).
  std::size_t cell(const Vec3f& p_mm, float f[3], int i0[3] = nullptr) const {
    std::size_t base = 0;
    for (int a = 0; a < 3; ++a) {
      const float u = std::clamp((p_mm[a] - origin_mm_[a]) * inv_spacing_[a], 0.0f, max_index_[a]);
      const int i = std::min(static_cast<int>(u), last_cell_[a]);
      f[a] = std::min(u - static_cast<float>(i), 1.0f);
      base += static_cast<std::size_t>(i) * stride_[a];
      if (i0) i0[a] = i;
    }
    return base;
  }

  // The eight corners as one base index plus fixed offsets (set up once per sampler): the
  // per-axis index arithmetic is done once per sample, not once per corner.
  Corners corners(const Vec3f& p_mm) const {
    Corners c;
    float f[3];
    int i0[3];
    const std::size_t base = cell(p_mm, f, i0);
    for (int a = 0; a < 3; ++a) {
      c.diff[a][0] = diff(i0[a], a);
      c.diff[a][1] = diff(std::min(i0[a] + 1, dims_[a] - 1), a);
    }
    const float x1 = f[0], x0 = 1.0f - f[0], y1 = f[1], y0 = 1.0f - f[1];
    const float z1 = f[2], z0 = 1.0f - f[2];
    const float w[8] = {x0 * y0 * z0, x1 * y0 * z0, x0 * y1 * z0, x1 * y1 * z0,
                        x0 * y0 * z1, x1 * y0 * z1, x0 * y1 * z1, x1 * y1 * z1};
    for (int i = 0; i < 8; ++i) {
      c.idx[i] = base + corner_offset_[i];
      c.w[i] = w[i];
    }
    return c;
  }

  void set_up_corners() {
    std::size_t step[3];
    for (int a = 0; a < 3; ++a) {
      const int n = dims_[a];
      max_index_[a] = static_cast<float>(n - 1);
      last_cell_[a] = std::max(n - 2, 0);  // the lower corner of the last cell
      half_inv_spacing_[a] = 0.5f * inv_spacing_[a];
      stride_[a] = a == 0 ? 1
                   : a == 1
                       ? static_cast<std::size_t>(dims_.x())
                       : static_cast<std::size_t>(dims_.x()) * static_cast<std::size_t>(dims_.y());
      step[a] = n > 1 ? stride_[a] : 0;  // a single-voxel axis has no upper corner
    }
    for (int i = 0; i < 8; ++i)
      corner_offset_[i] =
          ((i & 1) ? step[0] : 0) + ((i & 2) ? step[1] : 0) + ((i & 4) ? step[2] : 0);
  }

  Vec3i dims_;
  Vec3f origin_mm_;
  Vec3f inv_spacing_;
  const float* img_;
  float max_index_[3];
  float half_inv_spacing_[3];
  int last_cell_[3];
  std::size_t stride_[3];
  std::size_t corner_offset_[8];
};

/// What the image says around the seed: the basis of the default τ_cost and of the "seed is not
/// in a hypoechoic region" refusal.
/// The intensity scale the boundary cost accumulates in. Plain: grey levels (the paper's Ψ_cost).
/// Relative: F(I) = I/f below the floor f, 1 + ln(I/f) above, so dF = dI / max(I, f): a rise
/// counts relative to the level it starts from. Ultrasound attenuation and acoustic shadows are
/// multiplicative, so in this scale a wall in a needle's shadow (all levels × 0.3) rises as much
/// as an unshadowed one.
struct CostScale {
  bool relative = false;
  float floor = 1.0f;
  float weight(float intensity) const {
    return relative ? 1.0f / std::max(intensity, floor) : 1.0f;
  }
  float map(float intensity) const {
    if (!relative) return intensity;
    return intensity < floor ? intensity / floor : 1.0f + std::log(intensity / floor);
  }
};

struct SeedRegion {
  float level = 0.0f;         // mean smoothed intensity of the target: the rays' samples well
                              // before their wall (the ball's mean if they have too few)
  float sigma = 0.0f;         // standard deviation in the ball around the seed
  float tissue_level = 0.0f;  // median over rays of the level just beyond the first rise
  int rays = 0;
  int rays_hit = 0;                // rays that found a sustained rise to a brighter level
  float safe_radius_mm = 0.0f;     // distance along the rays that stays at the seed's level
  float noise_rise_per_mm = 0.0f;  // median over rays of the positive rise per mm (in the cost
                                   // scale) inside the target: what speckle adds to Ψ_cost per mm
};

/// Samples a ball of `ball_radius_mm` around the seed and `ray_count` rays out to the volume edge.
SeedRegion analyse_seed(const ImageSampler& sampler, const volume::Volume& grid,
                        const Vec3f& seed_mm, float voxel_mm, float ball_radius_mm,
                        const CostScale& scale, int ray_count = 64);

}  // namespace sonomesh::segment::internal
