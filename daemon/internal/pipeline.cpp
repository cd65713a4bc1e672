// The per-volume pipeline (method.md §0-6): smooth -> balloon -> opening -> Kazhdan FFT
// reconstruction -> marching cubes -> topology, labels, deepest interior point.
#include "daemon/pipeline.h"

#include <algorithm>
#include <chrono>
#include <exception>
#include <future>
#include <vector>

#include "daemon/internal/bright_inside.h"
#include "daemon/internal/coarse_start.h"
#include "daemon/internal/metrics.h"
#include "daemon/internal/opinions.h"
#include "daemon/internal/stages.h"
#include "daemon/internal/target_image.h"
#include "daemon/internal/track.h"

namespace sonomesh::daemon {
namespace {

using internal::Clock;
using internal::ms_since;

// Fewer oriented samples than this cannot describe a closed surface (the initial balloon alone has
// 102 vertices); the FFT solve would only produce noise.
constexpr std::size_t kMinSamples = 20;

void count_stops(const std::vector<segment::StopReason>& stop, StopCounts& counts) {
  for (segment::StopReason reason : stop) switch (reason) {
      case segment::StopReason::Moving:
        ++counts.moving;
        break;
      case segment::StopReason::Boundary:
        ++counts.boundary;
        break;
      case segment::StopReason::Curvature:
        ++counts.curvature;
        break;
      case segment::StopReason::SelfIntersection:
        ++counts.self_intersection;
        break;
      case segment::StopReason::IterationLimit:
        ++counts.iteration_limit;
        break;
    }
}

}  // namespace

const char* to_string(TargetPolarity target) {
  switch (target) {
    case TargetPolarity::Dark:
      return "dark";
    case TargetPolarity::Bright:
      return "bright";
    case TargetPolarity::Auto:
      return "auto";
  }
  return "dark";
}

PipelineResult run_pipeline(const volume::Volume& input, const Vec3f& seed_mm,
                            const PipelineConfig& config, std::stop_token stop) {
  PipelineBuffers buffers;
  return run_pipeline(input, seed_mm, config, buffers, std::move(stop));
}

PipelineResult run_pipeline(const volume::Volume& input, const Vec3f& seed_mm,
                            const PipelineConfig& config, PipelineBuffers& buffers,
                            std::stop_token stop) {
  return run_pipeline(input, seed_mm, config, buffers, nullptr, std::move(stop));
}

namespace internal {

reconstruct::PoissonOptions poisson_options(const PipelineConfig& config,
                                            const volume::Volume& input) {
  reconstruct::PoissonOptions poisson = config.poisson;
  if (config.cell_from_voxel) poisson.cell_mm = input.spacing_mm().minCoeff();
  return poisson;
}

float thick_cell_scale(const segment::Mesh& surface, float vox_mm) {
  constexpr float kThickVox = 12.0f, kCoarsestCell = 1.5f;
  const double thickness_vox = mesh::thickness_mm(surface) / vox_mm;
  return std::clamp(static_cast<float>(thickness_vox) / kThickVox, 1.0f, kCoarsestCell);
}

}  // namespace internal

namespace {

// The cold start: coarse to fine when configured (coarse_start.h), else from the small sphere.
segment::BalloonResult cold_balloon(PipelineBuffers& buffers, const Vec3f& seed_mm,
                                    const PipelineConfig& config, const std::stop_token& stop,
                                    PipelineResult& result) {
  if (!config.coarse_start)
    return segment::inflate_balloon(buffers.smoothed, seed_mm, config.balloon, stop);
  return internal::coarse_to_fine_balloon(buffers.smoothed, buffers.pyramid, seed_mm,
                                          config.balloon, internal::coarse_start_options(config),
                                          stop, result.coarse_start);
}

// §1-3: the balloon, from the warm start's mesh when one is given and safe on this volume, else
// from the small sphere at the seed (the fallback says why in start_reason).
segment::BalloonResult balloon_stage(PipelineBuffers& buffers, const Vec3f& seed_mm,
                                     const PipelineConfig& config, const WarmStart* warm,
                                     const std::stop_token& stop, PipelineResult& result) {
  const auto t = Clock::now();
  segment::BalloonResult balloon;
  if (warm) {
    balloon = segment::inflate_balloon_from(
        buffers.smoothed, warm->balloon, seed_mm, config.balloon,
        {.inset_mm = warm->inset_mm, .start_stop = warm->balloon_stop}, stop);
    result.warm_start = !balloon.start_unsafe && !balloon.stats.leaked;
    if (balloon.start_unsafe) result.start_reason = balloon.error;
    // A warm balloon that leaked (seen once at 128³ cyst-needle, 20 volumes/s, 3 volumes after
    // its start balloon) is not the target's: the cold start gets its chance.
    if (balloon.stats.leaked) result.start_reason = "warm start leaked: " + balloon.error;
  }
  if (!warm || !result.warm_start) balloon = cold_balloon(buffers, seed_mm, config, stop, result);
  result.timings.balloon_ms = ms_since(t);
  result.balloon = std::move(balloon.mesh);
  result.balloon_stop = std::move(balloon.stop);
  result.balloon_stats = balloon.stats;
  result.balloon_converged = balloon.converged;
  result.balloon_iterations = balloon.stats.iterations;
  count_stops(result.balloon_stop, result.stop_counts);
  return balloon;
}

// Seed tracking's next seed, from what the reconstruction has: the deepest point of χ > iso
// within the surface's box, around the seed, on a lattice of about the input's voxel, rounded to
// the nearest voxel centre as the labels' was. (From the labels it took a rasterisation on the
// input grid and a distance transform of it: 15-23 ms of a 128³ volume, and the labels only for
// that.) The reinflation moves the surface out by under two voxels, which does not move the
// deepest point of a target worth tracking, so the box is the reconstructed surface's.
std::optional<internal::DeepestPoint> deepest_point(const volume::Volume& indicator, float iso,
                                                    const mesh::Box& box, const Vec3f& seed_mm,
                                                    const volume::Volume& input) {
  auto deepest = internal::deepest_inside(indicator, iso, box.lo_mm, box.hi_mm, seed_mm,
                                          input.spacing_mm().minCoeff());
  if (deepest)
    deepest->position_mm =
        input.index_to_mm(input.mm_to_index(deepest->position_mm).array().round().matrix());
  return deepest;
}

// The first reconstruction's cell: coarser than the voxel for a thick target (thick_cell_scale).
// That surface carries the topology to the reinflation and the wall fit; the one returned is made
// again from the fitted surface (resurface_stage). A feature narrower than kFeatureCells of the
// coarser cells (a needle's tunnel, a column of tissue) spans that many of finer ones, never
// finer than the voxel: without, the simple 96³ breathing cyst-needle lost its tunnel on 5 of
// 60 volumes. (At 4 the 128³ cyst-needle's tunnel, 3.8 voxels, kept voxel cells; at 3 it gets
// 1.17 voxels and keeps its genus on every case of the accuracy sweeps.)
void coarser_for_thick(const segment::Mesh& balloon, float vox_mm,
                       reconstruct::PoissonOptions& poisson) {
  constexpr float kFeatureCells = 3.0f;
  const float scale = internal::thick_cell_scale(balloon, vox_mm);
  if (scale <= 1.0f) return;
  poisson.cell_mm *= scale;
  if (poisson.min_feature_cells > 0.0f) return;  // (a configured search stands)
  poisson.min_feature_cells = kFeatureCells;
  poisson.min_cell_fraction = 1.0f / scale;
}

// §4-5: opening at the self-intersections, then Kazhdan's FFT reconstruction and marching cubes
// on a grid of the volume's voxel size (coarser for a thick target: coarser_for_thick; finer where
// the opened balloon has a gap or solid too thin for it: a needle's tunnel); then tunnels no wall
// explains filled (close_false_tunnels), unless the genus is no higher than `known_genus` (a warm
// start's previous result). Returns the error, empty if there is a surface.
std::string surface_stage(const volume::Volume& input, const volume::Volume& smoothed,
                          const Vec3f& seed_mm, const PipelineConfig& config,
                          std::optional<int> known_genus, PipelineResult& result,
                          reconstruct::SurfaceResult& surface) {
  const auto t = Clock::now();
  const segment::PointCloud samples =
      reconstruct::open_balloon(result.balloon, result.balloon_stop);
  result.timings.opening_ms = ms_since(t);
  result.opened_points = static_cast<int>(samples.points.size());
  if (samples.points.size() < kMinSamples)
    return "the balloon left only " + std::to_string(samples.points.size()) +
           " oriented points after the opening";
  reconstruct::PoissonOptions poisson = internal::poisson_options(config, input);
  if (config.cell_from_voxel && config.wall_fit && config.resurface)
    coarser_for_thick(result.balloon, input.spacing_mm().minCoeff(), poisson);
  surface = reconstruct::reconstruct_surface(samples, seed_mm, poisson);
  if (!surface.mesh.triangles.empty()) {
    const int genus_before = surface.topology.genus;
    // (A needle cast a shadow in this volume and the surface has no tunnel for it.)
    const bool needle_seen = result.shadow_voxels > 0 && genus_before == 0;
    result.bright_inside_opened = internal::open_bright_inside(
        smoothed, samples, seed_mm, poisson, result.balloon_stats, needle_seen, surface);
    result.bright_inside_left =
        result.bright_inside_opened && surface.topology.genus <= genus_before;
  }
  result.timings.reconstruct_ms = surface.reconstruct_ms;
  // A warm result of the previous result's genus has no handle to explain.
  if (!(known_genus && surface.topology.genus <= *known_genus)) {
    const auto t_tunnels = Clock::now();
    internal::close_false_tunnels(smoothed, seed_mm, config.balloon.threads, result, surface);
    surface.mesh_ms += ms_since(t_tunnels);
  }
  result.timings.mesh_ms = surface.mesh_ms;
  result.grid_dims = Vec3i(surface.grid_dims[0], surface.grid_dims[1], surface.grid_dims[2]);
  result.grid_cell_mm = surface.cell_mm;
  result.grid_feature_mm = surface.feature_mm;
  result.mesh = std::move(surface.mesh);
  result.topology = surface.topology;
  result.enclosed_volume_ml = surface.topology.volume_ml;
  if (result.mesh.triangles.empty()) return "the reconstruction produced no surface";
  if (!surface.seed_enclosed) return "the reconstructed surface does not enclose the seed";
  return {};
}

// Beyond the paper: the second balloon pass from the reconstruction back to the wall, then the
// wall fit (segment::fit_to_wall), which places each vertex where the image averaged over the
// surface around it crosses half way to the wall: a balloon vertex stops on the first speckle
// grain that reaches its stop level, so the pass alone ends short of the wall; then the fit on the
// unsmoothed image (internal::fit_unsmoothed). They move vertices only, so the topology's counts
// stay; the enclosed volume is measured again. The pass needs a closed manifold (its
// precondition): a surface that is not one is kept as reconstructed.
void reinflate_stage(const volume::Volume& input, PipelineBuffers& buffers,
                     const PipelineConfig& config, const std::stop_token& stop,
                     PipelineResult& result) {
  if (!(config.reinflate || config.wall_fit) || !result.topology.manifold) return;
  const auto t = Clock::now();
  if (config.reinflate) {
    segment::BalloonResult second =
        segment::reinflate(buffers.smoothed, result.mesh, result.balloon_stats, config.balloon,
                           config.reinflate_pass, stop);
    if (stop.stop_requested()) return;
    result.mesh = std::move(second.mesh);
  }
  if (config.wall_fit)
    result.mesh = segment::fit_to_wall(buffers.smoothed, result.mesh, result.balloon_stats,
                                       config.wall_fit_options, config.balloon.threads);
  if (config.wall_fit && config.fit_unsmoothed)
    internal::fit_unsmoothed(input, buffers, config, result);
  result.timings.reinflate_ms = ms_since(t);
  result.topology.volume_ml = reconstruct::enclosed_volume_ml(result.mesh);
  result.enclosed_volume_ml = result.topology.volume_ml;
}

// §6: labels on the input grid, for callers that want them (files, OpenIGTLink).
void labels_stage(const volume::Volume& input, PipelineResult& result) {
  const auto t = Clock::now();
  result.labels = reconstruct::rasterize_labels(result.mesh, input);
  result.timings.labels_ms += ms_since(t);
}

// Whether this volume tracks the previous result's surface: there is one, the chain it belongs
// to is not at its length yet, and no χ is wanted (tracking makes none).
bool trackable(const PipelineConfig& config, const WarmStart* warm) {
  return warm && warm->previous && !config.want_indicator &&
         warm->previous->tracking.chain < config.track_max_chain;
}

}  // namespace

namespace internal {

std::string balloon_step(const Vec3f& seed_mm, const PipelineConfig& config,
                         PipelineBuffers& buffers, const WarmStart* warm,
                         const std::stop_token& stop, PipelineResult& result) {
  result.stop_rule = config.balloon.level_stop_fraction > 0.0f ? "level" : "cost";
  const segment::BalloonResult balloon =
      balloon_stage(buffers, seed_mm, config, warm, stop, result);
  if (stop.stop_requested()) return "stopped";
  return balloon.error.empty() ? "" : "balloon: " + balloon.error;
}

std::string surface_steps(const volume::Volume& input, const Vec3f& seed_mm,
                          const PipelineConfig& config, PipelineBuffers& buffers,
                          const WarmStart* warm, const std::stop_token& stop,
                          PipelineResult& result) {
  reconstruct::SurfaceResult surface;
  std::string error =
      surface_stage(input, buffers.smoothed, seed_mm, config,
                    result.warm_start ? warm->genus : std::nullopt, result, surface);
  // A warm result without a surface, or of another genus than the last (seen once at 128³
  // cyst-needle, 20 volumes/s: genus 0 where the target has 1), gets a cold start instead.
  if (result.warm_start && warm->genus &&
      (!error.empty() || result.topology.genus != *warm->genus)) {
    result.warm_start = false;
    result.start_reason =
        error.empty() ? "warm start changed the genus to " + std::to_string(result.topology.genus)
                      : "warm start: " + error;
    result.stop_counts = {};
    const double warm_ms = result.timings.balloon_ms;
    const segment::BalloonResult cold =
        balloon_stage(buffers, seed_mm, config, nullptr, stop, result);
    result.timings.balloon_ms += warm_ms;
    if (stop.stop_requested()) return "stopped";
    if (!cold.error.empty()) return "balloon: " + cold.error;
    error = surface_stage(input, buffers.smoothed, seed_mm, config, std::nullopt, result, surface);
  }
  if (!error.empty()) return error;
  // The deepest point reads χ and the reinflation the smoothed volume, each its own result: the
  // two run at once, because neither keeps both cores busy.
  const auto t_deepest = Clock::now();
  auto deepest = std::async(std::launch::async, [&, box = mesh::bounding_box(result.mesh)] {
    auto point = deepest_point(surface.indicator, surface.iso, box, seed_mm, input);
    return std::pair(point, ms_since(t_deepest));
  });
  reinflate_stage(input, buffers, config, stop, result);
  if (config.wall_fit && !stop.stop_requested())
    resurface_stage(input, buffers.smoothed, seed_mm, config, result);
  const auto [point, deepest_ms] = deepest.get();
  result.timings.labels_ms = deepest_ms;
  if (point) {
    result.deepest_interior_mm = point->position_mm;
    result.deepest_depth_mm = point->depth_mm;
  }
  if (config.want_indicator) {
    for (float& value : surface.indicator.f32()) value -= surface.iso;  // the surface is level 0
    result.indicator = std::move(surface.indicator);
  }
  return stop.stop_requested() ? "stopped" : "";
}

std::string segment_stages(const volume::Volume& input, const Vec3f& seed_mm,
                           const PipelineConfig& config, PipelineBuffers& buffers,
                           const WarmStart* warm, const std::stop_token& stop,
                           PipelineResult& result) {
  std::string error = balloon_step(seed_mm, config, buffers, warm, stop, result);
  return error.empty() ? surface_steps(input, seed_mm, config, buffers, warm, stop, result) : error;
}

}  // namespace internal

namespace {

// A stream whose balloon crumpled starts its balloons strict, not to crumple and inflate twice.
PipelineConfig after_crumple(PipelineConfig config) {
  config.balloon = segment::after_crumple(config.balloon);
  return config;
}

PipelineResult run_volume(const volume::Volume& input, const Vec3f& seed_mm,
                          const PipelineConfig& configured, PipelineBuffers& buffers,
                          const WarmStart* warm, std::stop_token stop) {
  const auto start = Clock::now();
  PipelineResult result;
  static const std::vector<std::uint8_t> kNoData;
  const std::vector<std::uint8_t>* no_data = &kNoData;  // (set in §0)
  using internal::Judge;
  const Judge judge = [&](PipelineResult& r, std::string error) {
    r.ok = error.empty();
    r.error = std::move(error);
    internal::quality_verdict(input, buffers.smoothed, *no_data, seed_mm, r);
  };
  bool judged = false;  // the second opinion's comparison has given `result` its verdict
  auto finish = [&](std::string error) {
    if (!judged) judge(result, std::move(error));
    result.timings.total_ms = ms_since(start);
    return std::move(result);
  };
  if (input.empty()) return finish("the volume is empty");
  // The balloon's own precondition (it throws for a seed outside the volume); checked here so a
  // tracked seed that drifted out becomes a failed volume, not an exception.
  if (!seed_mm.allFinite() || !input.contains_mm(seed_mm))
    return finish("the seed lies outside the volume");
  // A volume tracking one that lifted no shadow skips the search (10 ms at 128³, 40-60 on
  // tomaat), one that lifted a shadow looks near the last casters (about 5 ms): a needle that
  // comes in makes the tracker refuse, and the balloon's image has it after the whole search.
  const bool track = trackable(configured, warm);
  using internal::ShadowSearch;
  const ShadowSearch search = !track                               ? ShadowSearch::Whole
                              : warm->previous->shadow_voxels == 0 ? ShadowSearch::None
                                                                   : ShadowSearch::NearLast;
  // A tracked volume's readers look near the last surface: only that region is smoothed.
  const std::optional<internal::IndexBox> region =
      track ? std::optional(internal::tracked_region(input, *warm->previous)) : std::nullopt;
  no_data = &internal::smooth_stage(input, seed_mm, configured, buffers, result, search,
                                    region ? &*region : nullptr);
  if (stop.stop_requested()) return finish("stopped");
  const PipelineConfig config = internal::with_probe_apex(configured, buffers, result);
  if (track) {
    try {
      result.tracking.refused =
          internal::track_surface(input, seed_mm, config, buffers, *warm->previous, judge, result);
    } catch (const std::exception& e) {  // (then the balloon segments the volume)
      result.tracking.refused = std::string("tracking failed: ") + e.what();
    }
    judged = result.tracking.refused.empty();
    if (judged) return finish("");
    const double tracked_ms = result.timings.smooth_ms;  // (the balloon reads the whole volume)
    no_data = &internal::smooth_stage(input, seed_mm, config, buffers, result);
    result.timings.smooth_ms += tracked_ms;
  }
  // A tracked result carries the balloon of its chain's first volume, which the target has moved
  // on from since (a warm balloon from it came out at Dice 0.975 where a cold one gives 0.984):
  // the balloon starts cold, and its ok result is not asked again for a tube (the level stop's
  // second opinion leaked for 2 s on the 128³ cyst-needle, whose open patch breathes 0.6-3.9 %).
  const bool stale = warm && warm->previous && warm->previous->tracking.chain > 0;
  const PipelineResult* known_target = stale ? warm->previous.get() : nullptr;
  if (stale) {
    result.tracking.balloon_stale = true;
    result.start_reason = "the last balloon is " +
                          std::to_string(warm->previous->tracking.chain + 1) + " volumes old";
    warm = nullptr;
  }
  std::string error = internal::segment_opinions(input, seed_mm, config, buffers, warm, stop, judge,
                                                 result, judged, known_target);
  if (judged && result.second_opinion && !config.smooth_sigma_mm &&
      config.coarse_retry_grains > 0.0f && internal::wants_coarse_retry(result))
    internal::coarse_retry(input, seed_mm, config, buffers, stop, judge, result, error);
  if (!error.empty()) return finish(std::move(error));
  if (config.want_labels) labels_stage(input, result);
  if (!judged) judge(result, "");
  judged = true;
  if (config.track_max_chain > 0 && result.quality_ok)
    internal::measure_tracking_base(input, buffers, config, result);
  return finish("");
}

}  // namespace

PipelineResult run_pipeline(const volume::Volume& input, const Vec3f& seed_mm,
                            const PipelineConfig& config, PipelineBuffers& buffers,
                            const WarmStart* warm, std::stop_token stop) {
  const bool strict = warm && warm->crumpled;
  PipelineResult result = run_volume(input, seed_mm, strict ? after_crumple(config) : config,
                                     buffers, warm, std::move(stop));
  result.crumpled = result.crumpled || strict || result.balloon_stats.crumple_restarts > 0;
  return result;
}

}  // namespace sonomesh::daemon
