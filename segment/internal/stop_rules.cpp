// The wall snap and the cost scale's floor (stop_rules.h).
#include "segment/internal/stop_rules.h"

#include <Eigen/Geometry>
#include <array>
#include <limits>

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

NormalCross::NormalCross(const Vec3f& normal, float step) : n(normal), step_mm(step) {
  const Vec3f helper = std::abs(n.x()) < 0.9f ? Vec3f::UnitX() : Vec3f::UnitY();
  u = n.cross(helper).normalized() * step_mm;
  w = n.cross(u).normalized() * step_mm;
}

float NormalCross::mean(const ImageSampler& sampler, const Vec3f& p, int k0, int k1) const {
  float sum = 0.0f;
  for (int k = k0; k <= k1; ++k) {
    const Vec3f c = p + (static_cast<float>(k) * step_mm) * n;
    sum += sampler.value(c) + sampler.value(c + u) + sampler.value(c - u) + sampler.value(c + w) +
           sampler.value(c - w);
  }
  return sum / static_cast<float>(5 * (k1 - k0 + 1));
}

// A cross of five samples at 1, 2 and 3 voxels ahead and behind: 15 samples each side average
// out a grain, and ahead of a wall they lie in the tissue. The ratio alone would let a vertex
// that got past a wall run on in the tissue (ahead and behind alike there); the grey level alone
// would let it through a wall in a shadow. A sample brighter than the tissue on the normal is a
// thin bright structure (a needle), which a grain is not.
bool RegionVeto::still_inside(const ImageSampler& sampler, const Vec3f& p, const Vec3f& n) const {
  if (ratio <= 0.0f) return false;
  for (int k = 1; k <= 3; ++k)
    if (sampler.value(p + (static_cast<float>(k) * step_mm) * n) > peak) return false;
  const NormalCross cross(n, step_mm);
  const float ahead = cross.mean(sampler, p, 1, 3), behind = cross.mean(sampler, p, -3, -1);
  return ahead < ratio * behind && ahead < level;
}

// Most vertices are far from a wall: three samples on the normal ahead and behind decide that
// before the crosses are read (below this fraction of the wall level they never clear it).
constexpr float kPreTest = 0.8f;
// How far along a thin bright structure bright_ahead looks (voxels).
constexpr float kLineReachVox = 3.0f;
// A channel: wall on both sides of the vertex, kChannelRadiusVox away across its normal.
constexpr float kChannelRadiusVox = 2.5f;
// Behind a vertex darker than this fraction of the target's level is a shadow.
constexpr float kShadowFraction = 0.5f;

// Both the near and the far cross must clear the wall level: a grain brightens one of them, a
// wall both. The level is the seed region's, not one scaled by the mean behind the vertex: a
// darker patch of blood-pool speckle behind lowered a scaled level into the blood (at 96³,
// contrast 0.5: pits that folded the balloon until the leak bound), and in a shadow Ψ_cost's
// stop stands anyway.
bool LevelStop::wall_ahead(const ImageSampler& sampler, const Vec3f& p, const Vec3f& n,
                           float& wall_level) const {
  float ahead = 0.0f;
  for (int k = 1; k <= 3; ++k) ahead += sampler.value(p + (static_cast<float>(k) * step_mm) * n);
  if (ahead < kPreTest * 3.0f * level) return false;
  const NormalCross cross(n, step_mm);
  if (cross.mean(sampler, p, 1, 3) <= level || cross.mean(sampler, p, 4, 6) <= level) return false;
  wall_level = level;
  return true;
}

// A thin bright structure is a line or a sheet: from its brightest point on the normal, the
// image stays above half its height (over the target's level) 3 voxels away on both sides along
// at least one direction across the normal. A speckle grain that bright is round and smaller.
bool LevelStop::bright_ahead(const ImageSampler& sampler, const Vec3f& p, const Vec3f& n) const {
  Vec3f top = p;
  float top_value = -std::numeric_limits<float>::max();
  for (int k = 1; k <= 6; ++k) {
    const Vec3f q = p + (0.5f * static_cast<float>(k) * step_mm) * n;
    const float value = sampler.value(q);
    if (value > top_value) top_value = value, top = q;
  }
  if (top_value <= peak) return false;
  const float half = 0.5f * (top_value + target);
  for (const Vec3f& a : NormalCross(n, kLineReachVox * step_mm).across())
    if (sampler.value(top + a) > half && sampler.value(top - a) > half) return true;
  return false;
}

bool LevelStop::in_shadow(const ImageSampler& sampler, const Vec3f& p, const Vec3f& n) const {
  return NormalCross(n, step_mm).mean(sampler, p, -3, -1) < kShadowFraction * target;
}

// Pairs of crosses kChannelRadiusVox across the normal on either side: in the open target they
// lie at the vertex's own depth, inside; in a channel or a slab narrower than twice that both
// lie in the wall.
bool LevelStop::in_channel(const ImageSampler& sampler, const Vec3f& p, const Vec3f& n) const {
  // Each side is a cross of five samples (on the side and a voxel along n and along n × a).
  auto side = [&](const Vec3f& q, const Vec3f& a) {
    const Vec3f along = step_mm * n, beside = step_mm * n.cross(a.normalized());
    return (sampler.value(q) + sampler.value(q + along) + sampler.value(q - along) +
            sampler.value(q + beside) + sampler.value(q - beside)) /
           5.0f;
  };
  for (const Vec3f& a : NormalCross(n, kChannelRadiusVox * step_mm).across())
    if (side(p + a, a) > level && side(p - a, a) > level) return true;
  return false;
}

// Quarter-voxel steps along the normal; the vertex ends half a step before the first cross
// above the wall level, the level's crossing to within an eighth of a voxel.
Vec3f LevelStop::snap(const ImageSampler& sampler, const Vec3f& p, const Vec3f& n, float wall_level,
                      float ahead_mm) const {
  const NormalCross cross(n, step_mm);
  const float quarter_mm = 0.25f * step_mm;
  const int steps = static_cast<int>(std::floor(ahead_mm / quarter_mm + 1e-3f));
  for (int j = 0; j <= steps; ++j) {
    const Vec3f q = p + (static_cast<float>(j) * quarter_mm) * n;
    if (cross.mean(sampler, q, 0, 0) <= wall_level) continue;
    const Vec3f at = j == 0 ? p : Vec3f(q - (0.5f * quarter_mm) * n);
    return at.cwiseMax(box_lo).cwiseMin(box_hi);
  }
  return p;
}

LevelStop level_stop(const BalloonOptions& o, float vox_mm, float seed_level, float tissue_level,
                     const Vec3f& box_lo, const Vec3f& box_hi) {
  LevelStop s;
  if (o.level_stop_fraction <= 0.0f || !(seed_level > 0.0f) || !(tissue_level > seed_level))
    return s;
  s.level = seed_level + o.level_stop_fraction * (tissue_level - seed_level);
  s.peak = tissue_level;
  s.target = seed_level;
  s.step_mm = vox_mm;
  s.box_lo = box_lo;
  s.box_hi = box_hi;
  return s;
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
