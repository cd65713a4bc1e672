// The wall snap and the cost scale's floor (stop_rules.h).
#include "segment/internal/stop_rules.h"

#include <Eigen/Geometry>
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

// A cross of five samples (on the normal and ±1 voxel across it) at 1, 2 and 3 voxels ahead and
// behind: 15 samples each side average out a grain, and ahead of a wall they lie in the tissue.
// The ratio alone would let a vertex that got past a wall run on in the tissue (ahead and behind
// alike there); the grey level alone would let it through a wall in a shadow. A sample brighter
// than the tissue on the normal is a thin bright structure (a needle), which a grain is not.
bool RegionVeto::still_inside(const ImageSampler& sampler, const Vec3f& p, const Vec3f& n) const {
  if (ratio <= 0.0f) return false;
  const Vec3f helper = std::abs(n.x()) < 0.9f ? Vec3f::UnitX() : Vec3f::UnitY();
  const Vec3f u = n.cross(helper).normalized() * step_mm, w = n.cross(u);
  const std::array<Vec3f, 5> cross = {Vec3f::Zero(), u, -u, w, -w};
  float ahead = 0.0f, behind = 0.0f;
  for (int k = 1; k <= 3; ++k)
    for (const Vec3f& c : cross) {
      const Vec3f along = (static_cast<float>(k) * step_mm) * n;
      const float value = sampler.value(p + along + c);
      if (c == Vec3f::Zero() && value > peak) return false;
      ahead += value;
      behind += sampler.value(p - along + c);
    }
  return ahead < ratio * behind && ahead < 15.0f * level;
}

RegionVeto region_veto(const BalloonOptions& o, float vox_mm, float seed_level,
                       float tissue_level) {
  RegionVeto r;
  if (o.region_fraction <= 0.0f || !(seed_level > 0.0f) || !(tissue_level > seed_level)) return r;
  r.ratio = 1.0f + o.region_fraction * (tissue_level / seed_level - 1.0f);
  r.level = seed_level + o.region_fraction * (tissue_level - seed_level);
  r.peak = tissue_level;
  r.step_mm = vox_mm;
  return r;
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
