#pragma once
/// @file
/// @brief The boundary cost's stop rule and the wall snap, shared by the balloon's first pass and
/// by reinflate (segment.h documents the options; docs/tuning.md the measurements).

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "segment/internal/image_sampler.h"
#include "segment/segment.h"

namespace sonomesh::segment::internal {

/// The increment of Ψ_cost for a step d through a point with gradient g, before the scale's
/// weight: the paper's max(0, <g, d>), or summed per grid axis (BalloonOptions::rise_per_axis).
inline float rise_along(const Vec3f& g, const Vec3f& d, bool per_axis) {
  if (!per_axis) return std::max(0.0f, g.dot(d));
  return std::max(0.0f, g.x() * d.x()) + std::max(0.0f, g.y() * d.y()) +
         std::max(0.0f, g.z() * d.z());
}

/// The relative scale floors intensities at 10 % of the tissue level (BalloonOptions).
CostScale cost_scale(bool relative, float tissue_level);

/// The region term (BalloonOptions::region_fraction): whether the image ahead of a vertex at p
/// with normal n still looks like the inside, so the boundary cost's stop is overruled.
struct RegionVeto {
  float ratio = 0.0f;  // ahead/behind below this: still inside; 0 = off
  float level = 0.0f;  // ...and the mean ahead below this grey level (past a wall: tissue)
  float peak = 0.0f;   // ...and no sample on the normal ahead above this (a needle, not a grain)
  float step_mm = 0.0f;

  bool still_inside(const ImageSampler& sampler, const Vec3f& p, const Vec3f& n) const;
};

RegionVeto region_veto(const BalloonOptions& o, float vox_mm, float seed_level, float tissue_level);
inline RegionVeto region_veto(const BalloonOptions& o, float vox_mm, const SeedRegion& seed) {
  return region_veto(o, vox_mm, seed.level, seed.tissue_level);
}

/// Means over crosses of five samples (on the normal and ±1 voxel across it) at whole voxels
/// along the normal n from p: a grain averages out over the cross, a wall does not.
struct NormalCross {
  Vec3f n, u, w;
  float step_mm;

  NormalCross(const Vec3f& normal, float step);
  /// Mean of the crosses at k·step_mm along n for k in [k0, k1] (negative: behind p).
  float mean(const ImageSampler& sampler, const Vec3f& p, int k0, int k1) const;
  /// Four directions across n, 45° apart, each step_mm long.
  std::array<Vec3f, 4> across() const { return {u, w, (u + w) * 0.7071f, (u - w) * 0.7071f}; }
};

/// The level stop (BalloonOptions::level_stop_fraction): the region ahead of a vertex is the
/// wall when the crosses 1-3 and 4-6 voxels ahead are both above `level`.
struct LevelStop {
  float level = 0.0f;  // the target's level plus the fraction of its contrast; 0 = off
  float step_mm = 0.0f;
  Vec3f box_lo, box_hi;  // the volume's usable box

  float peak = 0.0f;    // bright_ahead: the least height of a thin bright structure (a needle)
  float target = 0.0f;  // the target's level

  bool on() const { return level > 0.0f; }
  /// Whether a thin bright structure (a line or a sheet) lies on the normal within 3 voxels
  /// ahead of p: the one wall the level stop misses (its far cross lies beyond it), so Ψ_cost's
  /// stop stands there.
  bool bright_ahead(const ImageSampler& sampler, const Vec3f& p, const Vec3f& n) const;
  /// Whether the wall is ahead of p; then sets `wall_level` to the level (the snap's).
  bool wall_ahead(const ImageSampler& sampler, const Vec3f& p, const Vec3f& n,
                  float& wall_level) const;
  /// Whether the image behind p is well below the target's level (a shadow): there the
  /// relative Ψ_cost, which scales with the shadow, decides.
  bool in_shadow(const ImageSampler& sampler, const Vec3f& p, const Vec3f& n) const;
  /// Whether p lies in a channel or a slab through the wall (a gap): on both sides of p, 2.5
  /// voxels away along one of four directions across the normal, the image is above the level.
  bool in_channel(const ImageSampler& sampler, const Vec3f& p, const Vec3f& n) const;
  /// Where the cross along n first rises above wall_level, within `ahead_mm` (p if nowhere).
  Vec3f snap(const ImageSampler& sampler, const Vec3f& p, const Vec3f& n, float wall_level,
             float ahead_mm) const;
};

LevelStop level_stop(const BalloonOptions& o, float vox_mm, float seed_level, float tissue_level,
                     const Vec3f& box_lo, const Vec3f& box_hi);

/// Ψ_cost with its thresholds (method.md §2 and the departures BalloonOptions names).
struct CostRule {
  CostScale scale;
  float tau = 0.0f;           // τ_cost
  float tau_climb = 0.0f;     // the climb backstop
  float window_mm = 0.0f;     // 0: the plain sum
  float noise_per_mm = 0.0f;  // 0: no noise allowance
  bool per_axis = false;      // BalloonOptions::rise_per_axis
  RegionVeto region;          // BalloonOptions::region_fraction
  LevelStop level;            // BalloonOptions::level_stop_fraction

  /// Advances one vertex by the Euler step d from p: its Ψ_cost, darkest level and path. Returns
  /// the fraction of d to take (1 unless it stops inside the step) and sets `stopped`.
  /// (Inline: it runs per vertex and iteration.)
  float advance(const ImageSampler& sampler, const Vec3f& p, const Vec3f& d, float& cost,
                float& floor_level, float& path_mm, bool& stopped) const {
    // Ψ_cost += max(0, <∇I, S^{n+1} − S^n>) with the gradient at the step's midpoint (the rise
    // over the step to second order; taken at S^n it lags on a wall's rising flank).
    float value;
    Vec3f grad;
    sampler.value_and_gradient(p + 0.5f * d, value, grad);
    const float step_mm = d.norm();
    const float level = scale.map(value);
    floor_level = std::min(floor_level, level);
    const float decayed = window_mm > 0.0f ? cost * std::exp(-step_mm / window_mm) : cost;
    const float rise = rise_along(grad, d, per_axis) * scale.weight(value);
    cost = decayed + rise;
    const float travelled_mm = path_mm + step_mm;
    float threshold = tau;
    if (noise_per_mm > 0.0f)
      threshold += window_mm > 0.0f
                       ? noise_per_mm * window_mm * (1.0f - std::exp(-travelled_mm / window_mm))
                       : noise_per_mm * travelled_mm;
    // Where Ψ_cost crosses τ_cost inside the step, the vertex stops at the crossing (the rise
    // taken as even along the step), so where it stops does not depend on the step length.
    float t = 1.0f;
    if (cost > threshold && rise > 0.0f) t = std::clamp((threshold - decayed) / rise, 0.0f, 1.0f);
    path_mm += t * step_mm;
    stopped = cost > threshold || level - floor_level > tau_climb;
    return t;
  }

  /// advance(), then the region term: a stop while the image ahead along the normal n still
  /// looks like the inside is overruled and the vertex takes the whole step. With the level stop
  /// on, Ψ_cost's stop stands only before a thin bright structure and in a shadow, and the level
  /// stop decides the rest; it sets `level_wall` (0 when it did not fire: the stop, if any, is
  /// Ψ_cost's or the channel's, and the wall snap applies).
  float step(const ImageSampler& sampler, const Vec3f& p, const Vec3f& d, const Vec3f& n,
             float& cost, float& floor_level, float& path_mm, bool& stopped,
             float& level_wall) const {
    level_wall = 0.0f;
    float t = advance(sampler, p, d, cost, floor_level, path_mm, stopped);
    if (stopped && (level.on() ? (!level.bright_ahead(sampler, p + t * d, n) &&
                                  !level.in_shadow(sampler, p + t * d, n))
                               : region.still_inside(sampler, p + t * d, n))) {
      stopped = false;
      path_mm += (1.0f - t) * d.norm();
      t = 1.0f;
    }
    if (!stopped && level.on())
      stopped = level.wall_ahead(sampler, p + t * d, n, level_wall) ||
                level.in_channel(sampler, p + t * d, n);
    return t;
  }
};

/// Where a vertex the boundary cost stopped ends (BalloonOptions::snap_to_wall): the peak of the
/// image's slope along its normal nearest to the stop, within [-back, +ahead]; p itself where
/// there is no steep enough peak (no wall to snap to).
struct WallSnap {
  bool on = false;
  float back_mm = 0.0f, ahead_mm = 0.0f, step_mm = 0.0f;
  float min_relative_slope_per_mm = 0.0f;  // <∇I, n> / I, per mm
  float level_floor = 1.0f;                // I floored at this (a black target)
  Vec3f box_lo, box_hi;                    // the volume's usable box (no data beyond)

  static constexpr int kMaxSamples = 4 * 8 + 1;  // back + ahead <= 8 voxels (check_options)

  /// `ahead_limit_mm` shortens the window ahead (reinflate's move bound).
  Vec3f apply(const ImageSampler& sampler, const Vec3f& p, const Vec3f& n,
              float ahead_limit_mm = std::numeric_limits<float>::max()) const;
};

WallSnap wall_snap(const BalloonOptions& o, float vox_mm, float tissue_level, const Vec3f& box_lo,
                   const Vec3f& box_hi);

}  // namespace sonomesh::segment::internal
