// The wall snap and the cost scale's floor (stop_rules.h).
#include "segment/internal/stop_rules.h"

#include <array>

namespace sonomesh::segment::internal {

CostScale cost_scale(bool relative, float tissue_level) {
  CostScale scale;
  if (relative) {
    scale.relative = true;
    scale.floor = std::max(1e-3f, 0.1f * tissue_level);
  }
  return scale;
}

// The slope is sampled on a quarter-voxel lattice and its peak refined by a parabola through the
// peak and its two neighbours. For a smoothed step edge the peak is the wall's mid level whatever
// speckle the vertex's Ψ_cost collected on the way.
Vec3f WallSnap::apply(const ImageSampler& sampler, const Vec3f& p, const Vec3f& n,
                      float ahead_limit_mm) const {
  if (!on) return p;
  const int lo = -static_cast<int>(std::lround(back_mm / step_mm));
  const int hi = static_cast<int>(std::floor(std::min(ahead_mm, ahead_limit_mm) / step_mm + 1e-3f));
  std::array<float, kMaxSamples> slope;
  std::array<bool, kMaxSamples> steep;
  for (int k = lo; k <= hi; ++k) {
    float value;
    Vec3f grad;
    sampler.value_and_gradient(p + (static_cast<float>(k) * step_mm) * n, value, grad);
    slope[k - lo] = grad.dot(n);
    steep[k - lo] = slope[k - lo] >= min_relative_slope_per_mm * std::max(value, level_floor);
  }
  // The peak nearest to the stop: a wall's slope can be lower than a speckle blob's in the
  // tissue beyond it, and the wall Ψ_cost met is the near one.
  int best = lo;  // none
  for (int k = lo + 1; k < hi; ++k) {
    const float here = slope[k - lo];
    if (!steep[k - lo] || here < slope[k - 1 - lo] || here < slope[k + 1 - lo]) continue;
    if (best == lo || std::abs(k) < std::abs(best)) best = k;
  }
  if (best == lo) return p;
  const float before = slope[best - 1 - lo], peak = slope[best - lo], after = slope[best + 1 - lo];
  const float curvature = before - 2.0f * peak + after;  // < 0 at a strict peak
  const float offset =
      curvature < 0.0f ? std::clamp(0.5f * (before - after) / curvature, -0.5f, 0.5f) : 0.0f;
  const Vec3f q = p + ((static_cast<float>(best) + offset) * step_mm) * n;
  return q.cwiseMax(box_lo).cwiseMin(box_hi);
}

WallSnap wall_snap(const BalloonOptions& o, float vox_mm, float tissue_level, const Vec3f& box_lo,
                   const Vec3f& box_hi) {
  WallSnap s;
  s.on = o.snap_to_wall;
  s.back_mm = o.snap_back_vox * vox_mm;
  s.ahead_mm = o.snap_ahead_vox * vox_mm;
  s.step_mm = 0.25f * vox_mm;
  s.min_relative_slope_per_mm = o.snap_min_slope / vox_mm;
  s.level_floor = cost_scale(true, tissue_level).floor;  // the relative cost's
  s.box_lo = box_lo;
  s.box_hi = box_hi;
  return s;
}

}  // namespace sonomesh::segment::internal
