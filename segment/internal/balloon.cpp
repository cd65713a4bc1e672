// The balloon's first pass (method.md §1-3): the seed region's statistics decide the stop
// thresholds and S^0, then BalloonEvolution inflates it.
#include <algorithm>
#include <cmath>
#include <optional>
#include <stdexcept>
#include <string>

#include "segment/internal/balloon_evolution.h"
#include "segment/internal/leak_seal.h"
#include "segment/internal/warm_interior.h"
#include "segment/internal/warm_start.h"
#include "segment/segment.h"

namespace sonomesh::segment {
namespace {

using namespace internal;

// The share of a warm start's samples that may lie on speckle grains above the wall level when
// the level stop runs (64³ echo sphere at contrast 0.5: 25 of 2 954, 0.85 %).
constexpr float kLevelStartGrains = 0.02f;
// A start sample above the wall level lies on a grain when the region around it, a 3×3×3
// lattice this many voxels apart, is below the level: the grains of blood-pool speckle are
// round and about the pre-filter's size, a wall is a region (128³ echo cyst-needle at contrast
// 0.5: 3.6-5.4 % of the coarse start's samples on grains at any inset up to 6 voxels). Not at
// a low contrast, where the coarse pass's balloon is not to be trusted that far (96³ torus at
// contrast 0.3: a start so accepted ended 24 % small).
constexpr float kGrainRegionVox = 2.0f;

// The seed's surroundings, analysed in the plain scale first: the relative scale's floor needs
// the tissue level the rays estimate; then again in the scale actually used for the noise rate.
SeedRegion seed_region(const ImageSampler& sampler, const volume::Volume& smoothed,
                       const Vec3f& seed_mm, const BalloonOptions& options, float vox_mm,
                       CostScale& scale) {
  const float ball_mm = std::max(1.5f, options.initial_radius_vox) * vox_mm;
  SeedRegion seed = analyse_seed(sampler, smoothed, seed_mm, vox_mm, ball_mm, {});
  scale = cost_scale(options.relative_cost && seed.rays_hit > 0, seed.tissue_level);
  if (scale.relative) seed = analyse_seed(sampler, smoothed, seed_mm, vox_mm, ball_mm, scale);
  return seed;
}

// Why the seed cannot start a balloon, or empty: a hypoechoic target has most rays meet a clear
// rise to a tissue level well above the seed's.
std::string refusal(const SeedRegion& seed) {
  const float contrast = seed.tissue_level - seed.level;
  const float sigma_eff = std::max(seed.sigma, 0.02f * std::abs(seed.level) + 0.5f);
  if (2 * seed.rays_hit >= seed.rays && contrast > 4.0f * sigma_eff &&
      seed.level < 0.8f * seed.tissue_level)
    return {};
  // A cavity's blood-pool speckle (issue 15) widens the ball's sigma, not the contrast, and so
  // does a wall the ball reaches: where nearly every ray meets a brighter wall, 1.8 sigma and a
  // tenth darker suffice (echo phantoms at contrast 0.3: 14.6-30 grey levels darker at sigma
  // 5.4-12.7, 57-64 of 64 rays). The verdict, not this test, judges what such a seed gives: of
  // 192 seeds in echo tissue, 79 pass at 2 sigma and 83 at 1.8, every result suspect.
  if (8 * seed.rays_hit >= 7 * seed.rays && contrast > 1.8f * sigma_eff &&
      seed.level < 0.9f * seed.tissue_level)
    return {};
  return "seed is not in a hypoechoic region: mean intensity " + std::to_string(seed.level) +
         " around the seed, surroundings " +
         (seed.rays_hit > 0 ? std::to_string(seed.tissue_level) : std::string("not brighter")) +
         " (" + std::to_string(seed.rays_hit) + "/" + std::to_string(seed.rays) +
         " rays reach a brighter wall)";
}

// τ_cost is the climb from the seed's level to tau_cost_fraction of the way up to the tissue
// level, in grey levels, expressed in the cost's scale (a smoothed step edge lies at the grey
// mid point). The climb backstop (how far the image at P has risen above the darkest level on
// its path) stops a vertex that got through a wall with a low Ψ_cost before it runs on.
CostRule cost_rule(const SeedRegion& seed, const CostScale& scale, const BalloonOptions& options,
                   float vox_mm, const StepKernel& box) {
  const float contrast = seed.tissue_level - seed.level;
  auto climb_to = [&](float fraction) {
    return scale.map(seed.level + fraction * contrast) - scale.map(seed.level);
  };
  const float tau_cost =
      options.tau_cost > 0.0f ? options.tau_cost : climb_to(options.tau_cost_fraction);
  return CostRule{
      .scale = scale,
      .tau = tau_cost,
      .tau_climb = std::max(tau_cost, climb_to(options.climb_backstop_fraction)),
      .window_mm = options.cost_window_vox * vox_mm,
      .noise_per_mm = options.noise_allowance ? seed.noise_rise_per_mm : 0.0f,
      .per_axis = options.rise_per_axis,
      .region = region_veto(options, vox_mm, seed),
      .level = level_stop(options, vox_mm, seed.level, seed.tissue_level, box.box_lo, box.box_hi)};
}

void check_seed_inside(const volume::Volume& smoothed, const Vec3f& seed_mm) {
  if (!smoothed.contains_mm(seed_mm))
    throw std::invalid_argument("inflate_balloon: seed (" + std::to_string(seed_mm.x()) + ", " +
                                std::to_string(seed_mm.y()) + ", " + std::to_string(seed_mm.z()) +
                                ") mm lies outside the volume");
}

// What both starts share: the inputs checked, the seed region's statistics, the stop rule and
// the snap. `error` is set when the seed cannot start a balloon.
struct Prelude {
  Clock::time_point t0 = Clock::now();
  volume::Volume converted;
  const volume::Volume& smoothed;
  const ImageSampler sampler;
  const float vox_mm;
  CostScale scale;
  SeedRegion seed;
  CostRule cost;
  WallSnap snap;
  std::string error;

  Prelude(const volume::Volume& smoothed_in, const Vec3f& seed_mm, const BalloonOptions& options,
          BalloonStats& stats)
      : smoothed(checked(smoothed_in, seed_mm, options, converted)),
        sampler(smoothed),
        vox_mm(smoothed.spacing_mm().minCoeff()) {
    seed = seed_region(sampler, smoothed, seed_mm, options, vox_mm, scale);
    stats.seed_level = seed.level;
    stats.seed_sigma = seed.sigma;
    stats.tissue_level = seed.tissue_level;
    error = refusal(seed);
    if (!error.empty()) return;
    const StepKernel box(options, smoothed, vox_mm);
    cost = cost_rule(seed, scale, options, vox_mm, box);
    stats.noise_rise_per_mm = seed.noise_rise_per_mm;
    stats.tau_cost_used = cost.tau;
    stats.tau_climb_used = cost.tau_climb;
    snap = wall_snap(options, vox_mm, seed.tissue_level, box.box_lo, box.box_hi);
  }

  static const volume::Volume& checked(const volume::Volume& smoothed_in, const Vec3f& seed_mm,
                                       const BalloonOptions& options, volume::Volume& storage) {
    if (smoothed_in.empty()) throw std::invalid_argument("inflate_balloon: empty volume");
    check_seed_inside(smoothed_in, seed_mm);
    check_options(options);
    return as_float32(smoothed_in, storage);
  }

  // The cost rule's wall: tau_cost_fraction of the way from the seed level to the tissue's.
  float wall_level(const BalloonOptions& options) const {
    return scale.map(seed.level + options.tau_cost_fraction * (seed.tissue_level - seed.level));
  }

  BalloonResult finish(BalloonResult& result, std::string why) const {
    result.error = std::move(why);
    result.stats.elapsed_ms = ms_since(t0);
    return std::move(result);
  }
};

// A crumple is watched for where the stricter cosine is on offer, and not at a low contrast:
// there a restart's stricter test stopped the fronts at the cavity's speckle and called the
// shrunken result ok (docs/stopping.md item 18).
bool watch_for_crumple(const BalloonOptions& options, const BalloonStats& stats) {
  return options.crumple_self_intersection_cos > options.self_intersection_cos &&
         !low_contrast(stats);
}

// Inflates `start`; a leak that rolled back is sealed (leak_seal.h) and the balloon from before
// it inflated again, up to options.max_leak_seals times; a crumpled balloon inflates once more
// from `start` with the stricter self-intersection test (kept only while it may crumple).
BalloonResult evolve(const Prelude& pre, const BalloonOptions& options, BalloonMesh start,
                     BalloonResult& result, const std::stop_token& stop) {
  BalloonStats& stats = result.stats;
  const BalloonOptions strict = after_crumple(options);
  const BalloonOptions* active = &options;
  const bool watch = watch_for_crumple(options, stats);
  std::optional<BalloonEvolution> evolution;
  auto begin = [&](BalloonMesh from) {
    evolution.emplace(pre.smoothed, pre.sampler, *active, pre.cost, pre.snap, std::move(from),
                      stats);
    if (watch && active == &options) evolution->watch_for_crumple();
  };
  if (watch)
    begin(start);  // (a copy: a crumple inflates again from it)
  else
    begin(std::move(start));
  int iterations = 0;
  for (;;) {
    evolution->run(stop);
    iterations += stats.iterations;
    if (evolution->crumpled()) {
      ++stats.crumple_restarts;
      active = &strict;
      begin(std::move(start));  // (the strict balloon is not watched: at most one restart)
      continue;
    }
    if (!stats.leaked || !evolution->rolled_back() || stats.leak_seals >= options.max_leak_seals)
      break;
    std::optional<LeakSeal> seal =
        seal_leak(evolution->before_leak(), evolution->positions_mm(), pre.vox_mm);
    if (!seal) break;
    stats.leaked = false;
    ++stats.leak_seals;
    stats.sealed_vertices += seal->sealed;
    begin(std::move(seal->start));
    evolution->keep_start_before_leak();
  }
  const int last_run = stats.iterations;
  stats.iterations = iterations;
  if (stats.leaked && !evolution->rolled_back())
    return pre.finish(result, evolution->leak_message());
  evolution->take_result(result.mesh, result.stop);
  if (evolution->rolled_back()) stats.leak_rollback_iteration += iterations - last_run;
  result.converged = evolution->converged();
  return pre.finish(result, "");
}

}  // namespace

BalloonOptions after_crumple(const BalloonOptions& options) {
  BalloonOptions strict = options;
  strict.self_intersection_cos =
      std::max(options.self_intersection_cos, options.crumple_self_intersection_cos);
  return strict;
}

bool low_contrast(const BalloonStats& stats) {
  constexpr float kLowContrastLevelRatio = 0.6f;
  return stats.seed_level >= kLowContrastLevelRatio * stats.tissue_level;
}

BalloonResult inflate_balloon(const volume::Volume& smoothed_in, const Vec3f& seed_mm,
                              const BalloonOptions& options, std::stop_token stop) {
  BalloonResult result;
  BalloonStats& stats = result.stats;
  const Prelude pre(smoothed_in, seed_mm, options, stats);
  if (!pre.error.empty()) return pre.finish(result, pre.error);
  // S^0: initial_radius_vox, inside the rays' safe reach (it must start inside the object) and
  // not below one voxel.
  const float radius_mm =
      std::max(std::min(options.initial_radius_vox * pre.vox_mm, 0.8f * pre.seed.safe_radius_mm),
               1.0f * pre.vox_mm);
  stats.initial_radius_mm = radius_mm;
  return evolve(pre, options, start_sphere(seed_mm, radius_mm), result, stop);
}

std::string measure_seed_region(const volume::Volume& smoothed, const Vec3f& seed_mm,
                                const BalloonOptions& options, BalloonStats& stats) {
  return Prelude(smoothed, seed_mm, options, stats).error;
}

BalloonResult inflate_balloon_from(const volume::Volume& smoothed_in, const Mesh& start_mesh,
                                   const Vec3f& seed_mm, const BalloonOptions& options,
                                   const WarmStartOptions& warm, std::stop_token stop) {
  BalloonResult result;
  BalloonStats& stats = result.stats;
  stats.warm_start = true;
  const Prelude pre(smoothed_in, seed_mm, options, stats);
  if (!pre.error.empty()) return pre.finish(result, pre.error);
  auto unsafe = [&](const std::string& why) {
    result.start_unsafe = true;
    return pre.finish(result, "warm start not safe: " + why);
  };
  // At least 2 voxels: the wall snap looks up to 1.5 voxels ahead, and a start on the wall's
  // flank would begin with part of the climb already behind it.
  const float inset_mm = std::max(warm.inset_mm, 2.0f * pre.vox_mm);
  const auto t_start = Clock::now();
  const StepKernel box(options, pre.smoothed, pre.vox_mm);
  const float wall_level = pre.wall_level(options);
  if (std::string why = check_walls_kept(start_mesh, warm.start_stop, pre.sampler, pre.scale,
                                         wall_level, pre.seed.level, inset_mm, pre.vox_mm, box);
      !why.empty())
    return unsafe(why);
  // The start mesh from the previous balloon's interior eroded by the inset (warm_interior.h), on
  // cells of the balloon's edge length: the extracted surface then needs few splits or collapses,
  // and the grid has a fifth of the voxels' cells. (128³ cyst-needle: voxel cells cost 3-4 times
  // as much, for the same Dice and genus.)
  BalloonMesh start;
  if (std::string why =
          eroded_start_mesh(start_mesh, seed_mm, inset_mm, options.target_edge_vox * pre.vox_mm,
                            remesh_limits(options, pre.vox_mm), start);
      !why.empty())
    return unsafe(why);
  // The level stop is not stopped by a grain above the wall level, the start need not avoid one.
  StartAllowance allow;
  if (options.level_stop_fraction > 0.0f)
    allow = {.share = kLevelStartGrains,
             .region_mm = low_contrast(stats) ? 0.0f : kGrainRegionVox * pre.vox_mm};
  if (std::string why = check_start_safe(start, pre.sampler, pre.scale, wall_level, box, allow);
      !why.empty())
    return unsafe(why);
  init_start_states(start, pre.sampler, pre.scale, pre.seed.level);
  // The replay samples a voxel apart: the smoothed image varies over a voxel or more (finer
  // steps gave the same results). Its cost part covers two of the cost's leak windows.
  if (warm.replay_vox > 0.0f)
    replay_start_states(
        start, pre.sampler, pre.cost,
        {.floor_mm = warm.replay_vox * pre.vox_mm,
         .cost_mm = std::min(warm.replay_vox, 2.0f * options.cost_window_vox) * pre.vox_mm,
         .step_mm = pre.vox_mm,
         .wall_level = wall_level},
        box, options.threads);
  stats.start_mesh_ms = ms_since(t_start);
  return evolve(pre, options, std::move(start), result, stop);
}

BalloonResult inflate_balloon(const volume::Volume& image, float sigma_mm, const Vec3f& seed_mm,
                              const BalloonOptions& options, std::stop_token stop) {
  if (image.empty()) throw std::invalid_argument("inflate_balloon: empty volume");
  if (!image.contains_mm(seed_mm))
    throw std::invalid_argument("inflate_balloon: seed lies outside the volume");
  const volume::Volume smoothed = volume::smooth_gaussian(image, sigma_mm);
  return inflate_balloon(smoothed, seed_mm, options, std::move(stop));
}

}  // namespace sonomesh::segment
