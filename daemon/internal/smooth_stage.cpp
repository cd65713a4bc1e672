// §0, the smoothing (stages.h): what the balloon sees and its pre-filter.
#include "daemon/internal/shadow_gain.h"
#include "daemon/internal/stages.h"
#include "daemon/internal/target_image.h"

namespace sonomesh::daemon::internal {
namespace {

// The pre-filter's sigma: the speckle's grain where it is clearly coarser than a voxel (at least
// 1.75 voxels), else one voxel of the finest axis. The simple simulator's grain reads up to 1.62
// voxels next to the needle, where smoothing at it closes the 64³ tunnel; real scan-converted
// echo reads 2.1. A correlation longer than 3 voxels is structure filling the measured cube, not
// a grain: one voxel too. docs/stopping.md has the measurements.
constexpr float kMaxSpeckleGrainMm = 3.0f;
constexpr float kMinGrainVox = 1.75f, kMaxGrainVox = 3.0f;

float pre_filter_sigma_mm(const volume::Volume& input, float grain_mm) {
  const float vox_mm = input.spacing_mm().minCoeff();
  const float grain_vox = grain_mm / vox_mm;
  // (Above 3 mm it is not a probe's speckle either, whose grain is its resolution cell, ~0.3-1.5
  // mm: the 4.8× downsampled Philips volume reads 6.6 mm, and smoothing at that leaked.)
  const bool grain = grain_vox >= kMinGrainVox && grain_vox <= kMaxGrainVox;
  return grain && grain_mm <= kMaxSpeckleGrainMm ? grain_mm : vox_mm;
}

// The cube the grain is measured in (volume::speckle_grain_mm's default), how far round a bright
// voxel the needle it belongs to reaches (a 64³ phantom's needle is 2.5-3.75 voxels across), and
// how many bright voxels in the cube make a structure rather than a grain or two.
constexpr int kGrainCubeVox = 6, kNeedleReachVox = 2, kMinBrightVoxels = 20;
// Without a sector's levels, a bright voxel's 7-voxel cross lies over this many times the
// volume's median (as a caster's over the sector's: shadow_gain.h).
constexpr float kBrightOverMedian = 1.5f;

// The grain measured again without the bright voxels in and beside the cube round the seed (their
// 7-voxel cross over `level` in the Float32 `image`, BrightMask) and what lies within
// kNeedleReachVox of them. A needle crossing the cube lengthens the correlation (64³ echo
// cyst-needles seeded off the centre read 0.88-1.03 mm, 0.79-0.85 from the centre), and a
// pre-filter at that grain closes the needle's tunnel into a groove the surface wraps (genus 0,
// called ok).
float grain_without_needle(const volume::Volume& image, const Vec3f& seed_mm, float level,
                           float grain_mm) {
  const Vec3i d = image.dims();
  const Vec3i c = image.mm_to_index(seed_mm).array().round().cast<int>();
  std::vector<std::size_t> bright;
  BrightMask(image, level)
      .scan({c - Vec3i::Constant(kGrainCubeVox + kNeedleReachVox),
             c + Vec3i::Constant(kGrainCubeVox + kNeedleReachVox)},
            1, bright);
  if (bright.size() < kMinBrightVoxels) return grain_mm;
  // Which voxels of the cube (edge 2·kGrainCubeVox + 1 round c) lie within reach of one.
  constexpr int kEdge = 2 * kGrainCubeVox + 1;
  const Vec3i lo = c - Vec3i::Constant(kGrainCubeVox);
  std::vector<std::uint8_t> excluded(kEdge * kEdge * kEdge, 0);
  for (const std::size_t voxel : bright) {
    const Vec3i p = index_of(d, voxel) - lo;
    const Vec3i from = (p.array() - kNeedleReachVox).max(0);
    const Vec3i to = (p.array() + kNeedleReachVox).min(kEdge - 1);
    for (int k = from.z(); k <= to.z(); ++k)
      for (int j = from.y(); j <= to.y(); ++j)
        for (int i = from.x(); i <= to.x(); ++i) excluded[(k * kEdge + j) * kEdge + i] = 1;
  }
  return volume::speckle_grain_mm(image, seed_mm, kGrainCubeVox, [&](const Vec3i& v) {
    const Vec3i p = v - lo;
    return (p.array() >= 0).all() && (p.array() < kEdge).all() &&
           excluded[(p.z() * kEdge + p.y()) * kEdge + p.x()] != 0;
  });
}

// The same for a dark target without a sector (no shadow search to say a needle is there), where
// the grain would set a coarser pre-filter than one voxel: the simple simulator's 64³
// cyst-needles seeded off the centre read 0.90-0.99 mm beside the needle. `scratch` receives the
// input as Float32.
float grain_without_bright(const volume::Volume& input, const Vec3f& seed_mm, float grain_mm,
                           volume::Volume& scratch) {
  if (pre_filter_sigma_mm(input, grain_mm) <= input.spacing_mm().minCoeff()) return grain_mm;
  copy_as_float32(input, scratch);
  std::vector<float> sample;
  const std::vector<float>& v = scratch.f32();
  for (std::size_t i = 0; i < v.size(); i += 8) sample.push_back(v[i]);
  const float level = kBrightOverMedian * quantile(std::move(sample), 0.5f);
  return level > 0.0f ? grain_without_needle(scratch, seed_mm, level, grain_mm) : grain_mm;
}

// What smoothing `region` reads at the widest pre-filter smooth_stage may choose: the configured
// one, else the widest grain pre_filter_sigma_mm takes.
IndexBox read_by_smoothing(const volume::Volume& input, const PipelineConfig& config,
                           const IndexBox& region) {
  const float widest_mm =
      config.smooth_sigma_mm.value_or(kMaxGrainVox * input.spacing_mm().minCoeff());
  const Vec3i reach = volume::smoothing_reach_vox(input, widest_mm);
  return {region.lo - reach, region.hi + reach};
}

}  // namespace

const std::vector<std::uint8_t>& smooth_stage(const volume::Volume& input, const Vec3f& seed_mm,
                                              const PipelineConfig& config,
                                              PipelineBuffers& buffers, PipelineResult& result,
                                              ShadowSearch search, const IndexBox* region) {
  static const NoDataRegion kNone;
  const auto t = Clock::now();
  result.speckle_grain_mm = volume::speckle_grain_mm(input, seed_mm, kGrainCubeVox);
  result.target = config.target == TargetPolarity::Auto
                      ? internal::decide_polarity(input, seed_mm, result.speckle_grain_mm)
                      : config.target;
  // A probe's zeros outside its sector are no data, darker than any dark target: a wall for it.
  const bool dark = result.target == TargetPolarity::Dark;
  if (dark) internal::update_no_data(input, buffers.no_data);
  const NoDataRegion& no_data = dark ? buffers.no_data : kNone;
  const bool rewritten = internal::working_image(input, result.target, no_data, buffers.working);
  if (rewritten && config.shadow_gain && search != ShadowSearch::None && no_data.apex_mm) {
    std::optional<IndexBox> near;
    if (search == ShadowSearch::NearLast && buffers.shadow_casters)
      near = IndexBox{buffers.shadow_casters->first, buffers.shadow_casters->second};
    const std::optional<IndexBox> lifted =
        region ? std::optional(read_by_smoothing(input, config, *region)) : std::nullopt;
    const ShadowGain gain =
        compensate_shadows(buffers.working, no_data.mask, *no_data.apex_mm, config.balloon.threads,
                           near ? &*near : nullptr, lifted ? &*lifted : nullptr);
    result.shadow_factor = gain.shadow_factor;
    result.shadow_voxels = gain.voxels;
    result.needle_ends_mm = gain.ends_mm;
    buffers.shadow_casters.reset();
    if (gain.casters_box)
      buffers.shadow_casters = std::pair(gain.casters_box->lo, gain.casters_box->hi);
    if (gain.casters > 0)
      result.speckle_grain_mm = grain_without_needle(buffers.working, seed_mm, gain.bright_level,
                                                     result.speckle_grain_mm);
  } else if (dark && !no_data.apex_mm && !rewritten) {
    result.speckle_grain_mm =
        grain_without_bright(input, seed_mm, result.speckle_grain_mm, buffers.working);
  }
  const float sigma_mm =
      config.smooth_sigma_mm.value_or(pre_filter_sigma_mm(input, result.speckle_grain_mm));
  result.smooth_sigma_mm = sigma_mm;
  const volume::Volume& image = rewritten ? buffers.working : input;
  if (region)
    volume::smooth_gaussian(image, sigma_mm, region->lo, region->hi + Vec3i::Ones(),
                            buffers.smoothed);
  else
    volume::smooth_gaussian(image, sigma_mm, buffers.smoothed);
  result.timings.smooth_ms = ms_since(t);
  return no_data.mask;
}

PipelineConfig with_probe_apex(const PipelineConfig& config, const PipelineBuffers& buffers,
                               const PipelineResult& result) {
  PipelineConfig c = config;
  c.wall_fit_options.probe_apex_mm.reset();
  if (result.target == TargetPolarity::Dark)
    c.wall_fit_options.probe_apex_mm = buffers.no_data.apex_mm;
  return c;
}

namespace {

// Whether smooth_stage smoothed buffers.working for `first` rather than the input itself.
bool rewritten(const PipelineResult& first, const PipelineBuffers& buffers) {
  static const NoDataRegion kNone;
  // (The no-data region is the first pass's for a dark target; a bright one has none.)
  const bool dark = first.target == TargetPolarity::Dark;
  return needs_working_image(first.target, dark ? buffers.no_data : kNone);
}

}  // namespace

void smooth_again(const volume::Volume& input, const PipelineResult& first, float sigma_mm,
                  PipelineBuffers& buffers, PipelineResult& result) {
  const auto t = Clock::now();
  result.speckle_grain_mm = first.speckle_grain_mm;
  result.smooth_sigma_mm = sigma_mm;
  result.target = first.target;
  result.shadow_factor = first.shadow_factor;
  result.shadow_voxels = first.shadow_voxels;
  result.needle_ends_mm = first.needle_ends_mm;
  volume::smooth_gaussian(rewritten(first, buffers) ? buffers.working : input, sigma_mm,
                          buffers.smoothed);
  result.timings.smooth_ms = ms_since(t);
}

const volume::Volume& unsmoothed_image(const volume::Volume& input, const PipelineResult& first,
                                       PipelineBuffers& buffers) {
  if (!rewritten(first, buffers)) copy_as_float32(input, buffers.working);
  return buffers.working;
}

}  // namespace sonomesh::daemon::internal
