// The coarse-to-fine cold start (coarse_start.h).
#include "daemon/internal/coarse_start.h"

#include <algorithm>
#include <chrono>
#include <utility>
#include <vector>

#include "daemon/internal/clock.h"
#include "mesh/parallel.h"

namespace sonomesh::daemon::internal {
namespace {

// "leaked", with the balloon's own words when it has them (a balloon rolled back to before its
// leak has none).
std::string leaked(const segment::BalloonResult& balloon) {
  return balloon.error.empty() ? "leaked" : "leaked: " + balloon.error;
}

// Why a coarse balloon cannot start the fine pass, or empty.
std::string coarse_failure(const segment::BalloonResult& coarse) {
  if (coarse.stats.leaked) return "coarse pass " + leaked(coarse);
  if (!coarse.error.empty()) return "coarse pass: " + coarse.error;
  if (coarse.mesh.vertices.empty()) return "coarse pass: no balloon";
  return {};
}

}  // namespace

CoarseStartOptions coarse_start_options(const PipelineConfig& config) {
  return {.inset_vox = config.coarse_start_inset_vox,
          .min_coarse_vox = config.coarse_start_min_vox,
          .max_levels = config.coarse_start_max_levels,
          .finest_when_needed = config.coarse_start_finest_when_needed,
          .stand_in_min_vox = config.coarse_start_stand_in_min_vox};
}

bool downsample_by_two(const volume::Volume& smoothed, int min_vox, volume::Volume& coarse) {
  if (smoothed.type() != volume::VoxelType::Float32) return false;
  const volume::Vec3i dims = smoothed.dims() / 2;
  if (dims.minCoeff() < min_vox) return false;
  const volume::Vec3f spacing_mm = 2.0f * smoothed.spacing_mm();
  const volume::Vec3f origin_mm = smoothed.origin_mm() + 0.5f * smoothed.spacing_mm();
  if (coarse.type() != volume::VoxelType::Float32 || coarse.dims() != dims ||
      coarse.spacing_mm() != spacing_mm)
    coarse = volume::Volume(dims, spacing_mm, origin_mm, volume::VoxelType::Float32);
  coarse.set_origin_mm(origin_mm);
  const float* in = smoothed.f32().data();
  float* out = coarse.f32().data();
  const std::size_t nx = smoothed.dims().x();
  const std::size_t slab = nx * smoothed.dims().y();
  // Slabs of the coarse grid on both cores: the loop only streams memory.
  mesh::parallel_chunks(0, dims.z(), mesh::default_threads(), [&](int k0, int k1, int) {
    for (int k = k0; k < k1; ++k)
      for (int j = 0; j < dims.y(); ++j) {
        const float* r00 = in + (2 * static_cast<std::size_t>(k)) * slab + 2 * j * nx;
        const float* r01 = r00 + nx;
        const float* r10 = r00 + slab;
        const float* r11 = r10 + nx;
        float* o = out + coarse.linear_index(0, j, k);
        for (int i = 0; i < dims.x(); ++i) {
          const int a = 2 * i, b = 2 * i + 1;
          o[i] = 0.125f * (((r00[a] + r00[b]) + (r01[a] + r01[b])) +
                           ((r10[a] + r10[b]) + (r11[a] + r11[b])));
        }
      }
  });
  return true;
}

namespace {

// The pyramid above `smoothed`: each level `smoothed` averaged over 2×2×2 blocks once more,
// while every axis keeps min_vox voxels and at most max_levels of them. Returns the count.
int build_pyramid(const volume::Volume& smoothed, const CoarseStartOptions& options,
                  std::vector<volume::Volume>& pyramid) {
  if (pyramid.size() < static_cast<std::size_t>(options.max_levels))
    pyramid.resize(static_cast<std::size_t>(options.max_levels));
  int levels = 0;
  const volume::Volume* finer = &smoothed;
  while (levels < options.max_levels &&
         downsample_by_two(*finer, options.min_coarse_vox, pyramid[levels]))
    finer = &pyramid[levels++];
  return levels;
}

// `passes` bounded to `growth` times `coarse`'s area.
segment::BalloonOptions bounded(segment::BalloonOptions passes, const segment::Mesh& coarse,
                                float growth) {
  passes.max_area_mm2 = growth * static_cast<float>(mesh::surface_area_mm2(coarse));
  return passes;
}

// Whether `balloon`, from `coarse`, the grid above `smoothed`, stands for the pass on
// `smoothed`, whose last voxel or two to the wall the reinflation and the wall fit then take
// (docs/tuning.md, "Coarse-to-fine cold start"). It must have ended clean: converged, no seal, no
// restart, none at the limit, at most 1 % still moving. Its fronts must not have met unless
// `seams_decided` (it is itself a finer pass): only a finer pass decides a seam, and seams the
// coarsest grid decided made wrong handles called ok. And the contrast at full resolution must
// not be low, where a coarser balloon stops on the blood pool's speckle. Its stats then take the
// full resolution's levels, which the later stages and the verdict read.
bool stands_for_finest(const volume::Volume& smoothed, const volume::Volume& coarse,
                       const volume::Vec3f& seed_mm, const segment::BalloonOptions& options,
                       int least_vox, bool seams_decided, segment::BalloonResult& balloon) {
  using segment::StopReason;
  const segment::BalloonStats& stats = balloon.stats;
  const auto count = [&](StopReason reason) { return std::ranges::count(balloon.stop, reason); };
  if (coarse.dims().minCoeff() < least_vox || !balloon.converged || stats.leak_seals > 0 ||
      stats.crumple_restarts > 0 || (!seams_decided && count(StopReason::SelfIntersection) > 0) ||
      count(StopReason::IterationLimit) > 0 ||
      100 * count(StopReason::Moving) > static_cast<std::ptrdiff_t>(balloon.stop.size()))
    return false;
  segment::BalloonStats fine = stats;
  if (!segment::measure_seed_region(smoothed, seed_mm, options, fine).empty() ||
      segment::low_contrast(fine))
    return false;
  balloon.stats = fine;
  return true;
}

// One attempt: the cold balloon on level `top` of the pyramid (level 0 is `smoothed`), then a
// warm pass on every finer level. Returns why it failed (then `balloon` is not to be used).
std::string from_level(const volume::Volume& smoothed, const std::vector<volume::Volume>& pyramid,
                       int top, const volume::Vec3f& seed_mm, const segment::BalloonOptions& passes,
                       const CoarseStartOptions& options, const std::stop_token& stop,
                       segment::BalloonResult& balloon, CoarseStartReport& report) {
  auto grid = [&](int level) -> const volume::Volume& {
    return level == 0 ? smoothed : pyramid[level - 1];
  };
  if (!grid(top).contains_mm(seed_mm)) return "the seed lies outside the coarse grid";
  auto t = Clock::now();
  balloon = segment::inflate_balloon(grid(top), seed_mm, passes, stop);
  report.coarse_ms += ms_since(t);
  report.coarse_iterations = balloon.stats.iterations;
  if (stop.stop_requested()) return {};
  if (std::string why = coarse_failure(balloon); !why.empty()) return why;
  t = Clock::now();
  for (int level = top - 1; level >= 0; --level) {
    if (level == 0 && options.finest_when_needed &&
        stands_for_finest(smoothed, grid(1), seed_mm, passes, options.stand_in_min_vox, top > 1,
                          balloon)) {
      report.finest_skipped = true;
      return {};
    }
    const float inset_mm = options.inset_vox * grid(level).spacing_mm().minCoeff();
    segment::BalloonResult finer = segment::inflate_balloon_from(
        grid(level), balloon.mesh, seed_mm, bounded(passes, balloon.mesh, options.max_area_growth),
        {.inset_mm = inset_mm, .start_stop = balloon.stop, .replay_vox = options.replay_vox}, stop);
    report.fine_ms += ms_since(t);
    t = Clock::now();
    if (finer.start_unsafe) return "level " + std::to_string(level) + " " + finer.error;
    if (finer.stats.leaked) return "level " + std::to_string(level) + " " + leaked(finer);
    // (A refusal at full resolution is the plain cold start's as well: the same seed region.)
    if (!finer.error.empty() && level > 0)
      return "level " + std::to_string(level) + ": " + finer.error;
    balloon = std::move(finer);
    if (!balloon.error.empty() || stop.stop_requested()) return {};
  }
  return {};
}

}  // namespace

segment::BalloonResult coarse_to_fine_balloon(const volume::Volume& smoothed,
                                              std::vector<volume::Volume>& pyramid,
                                              const volume::Vec3f& seed_mm,
                                              const segment::BalloonOptions& options,
                                              const CoarseStartOptions& coarse_options,
                                              const std::stop_token& stop,
                                              CoarseStartReport& report) {
  report = {};
  const auto t = Clock::now();
  const int levels = build_pyramid(smoothed, coarse_options, pyramid);
  report.downsample_ms = ms_since(t);
  segment::BalloonOptions passes = options;
  passes.stall_window_iterations =
      std::min(options.stall_window_iterations, coarse_options.stall_window_iterations);
  // From the coarsest level down: a failed attempt (a wall the coarse grid blurred away, a
  // leak) gives the next finer level its chance, the plain cold start comes last.
  segment::BalloonResult balloon;
  std::string why;
  for (int top = levels; top >= 1; --top) {
    const std::string failed =
        from_level(smoothed, pyramid, top, seed_mm, passes, coarse_options, stop, balloon, report);
    if (failed.empty()) {
      report.used = balloon.error.empty();
      report.levels = top;
      return balloon;
    }
    why += (why.empty() ? "" : "; ") + failed;
  }
  report.fallback_reason = std::move(why);
  const auto t_plain = Clock::now();
  balloon = segment::inflate_balloon(smoothed, seed_mm, options, stop);
  report.fine_ms += ms_since(t_plain);
  return balloon;
}

}  // namespace sonomesh::daemon::internal
