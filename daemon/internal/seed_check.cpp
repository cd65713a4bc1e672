// Seed validation: is a point usable as the balloon's starting point in this volume?
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <vector>

#include "daemon/internal/target_image.h"
#include "daemon/pipeline.h"

namespace sonomesh::daemon {
namespace {

using volume::Vec3f;
using volume::Vec3i;
using volume::Volume;

std::string format_point(const Vec3f& p) {
  char buffer[96];
  std::snprintf(buffer, sizeof buffer, "(%.2f, %.2f, %.2f)", p.x(), p.y(), p.z());
  return buffer;
}

// f(value) for every `step`-th voxel along each axis that `no_data` (empty, or one flag per voxel)
// leaves in, in memory order: the voxel type is resolved once, not per voxel (Volume::value per
// voxel cost more than the histogram itself).
template <typename F>
void for_each_sample(const Volume& input, int step, const std::vector<std::uint8_t>& no_data,
                     F&& f) {
  const Vec3i d = input.dims();
  auto walk = [&](const auto& data) {
    for (int k = 0; k < d.z(); k += step)
      for (int j = 0; j < d.y(); j += step) {
        const std::size_t row = input.linear_index(0, j, k);
        if (no_data.empty())  // (the common case, kept free of the test per voxel)
          for (int i = 0; i < d.x(); i += step) f(static_cast<float>(data[row + i]));
        else
          for (int i = 0; i < d.x(); i += step)
            if (!no_data[row + i]) f(static_cast<float>(data[row + i]));
      }
  };
  switch (input.type()) {
    case volume::VoxelType::UInt8:
      return walk(input.u8());
    case volume::VoxelType::UInt16:
      return walk(input.u16());
    default:
      return walk(input.f32());
  }
}

// Otsu's threshold on a subsampled histogram: splits the volume into the dark class (target,
// background) and the bright class (tissue) whatever their proportions. Subsampling every second
// voxel per axis keeps this at a few ms for 256³ and changes the threshold by less than a bin.
// A probe's no-data region is left out: its zeros would be the dark class, and the split would
// fall between no data and the image, under a low-contrast target's own level
// (docs/stopping.md item 3).
float otsu_threshold(const Volume& input, const std::vector<std::uint8_t>& no_data) {
  const int step = input.voxel_count() > 200000 ? 2 : 1;
  float lo = std::numeric_limits<float>::max(), hi = std::numeric_limits<float>::lowest();
  for_each_sample(input, step, no_data, [&](float v) {
    lo = std::min(lo, v);
    hi = std::max(hi, v);
  });
  if (!(hi > lo)) return hi;
  constexpr int kBins = 256;
  std::array<double, kBins> histogram{};
  const float scale = (kBins - 1) / (hi - lo);
  double total = 0.0;
  for_each_sample(input, step, no_data, [&](float v) {
    histogram[static_cast<int>((v - lo) * scale)] += 1.0;
    total += 1.0;
  });
  double sum_all = 0.0;
  for (int b = 0; b < kBins; ++b) sum_all += b * histogram[b];
  double weight_dark = 0.0, sum_dark = 0.0, best_variance = -1.0;
  int best_bin = 0;
  for (int b = 0; b < kBins; ++b) {
    weight_dark += histogram[b];
    sum_dark += b * histogram[b];
    const double weight_bright = total - weight_dark;
    if (weight_dark == 0.0 || weight_bright == 0.0) continue;
    const double mean_dark = sum_dark / weight_dark;
    const double mean_bright = (sum_all - sum_dark) / weight_bright;
    const double variance =
        weight_dark * weight_bright * (mean_dark - mean_bright) * (mean_dark - mean_bright);
    if (variance > best_variance) {
      best_variance = variance;
      best_bin = b;
    }
  }
  return lo + (static_cast<float>(best_bin) + 0.5f) / scale;
}

// Mean over the 5³ neighbourhood of `centre` (single speckle voxels are bright inside a dark cyst
// too, so the decision needs a local average, not one voxel), `no_data` voxels left out; NaN when
// none is left.
float local_mean(const Volume& input, const Vec3i& centre,
                 const std::vector<std::uint8_t>& no_data) {
  double sum = 0.0;
  int count = 0;
  for (int dk = -2; dk <= 2; ++dk)
    for (int dj = -2; dj <= 2; ++dj)
      for (int di = -2; di <= 2; ++di) {
        const Vec3i p = centre + Vec3i(di, dj, dk);
        if (!input.contains_index(p)) continue;
        if (!no_data.empty() && no_data[input.linear_index(p.x(), p.y(), p.z())]) continue;
        sum += input.value(p.x(), p.y(), p.z());
        ++count;
      }
  return count > 0 ? static_cast<float>(sum / count) : std::numeric_limits<float>::quiet_NaN();
}

}  // namespace

std::optional<std::string> check_seed(const Volume& input, const Vec3f& seed_mm,
                                      TargetPolarity target) {
  if (input.empty()) return "the volume is empty";
  if (!seed_mm.allFinite()) return "the seed is not a finite point";
  if (!input.contains_mm(seed_mm))
    return "seed " + format_point(seed_mm) + " mm is outside the volume " +
           format_point(input.min_mm()) + ".." + format_point(input.max_mm()) + " mm";
  // Auto: the pipeline decides from the seed. Bright: Otsu's one split does not separate a bright
  // organ from the fat around it when the volume has brighter classes still (CT: the spleen at 56,
  // the split at 60 between soft tissue and contrast, bone); the balloon's own check on the
  // inverted image decides.
  if (target != TargetPolarity::Dark) return std::nullopt;
  const Vec3i centre = input.mm_to_index(seed_mm).array().round().cast<int>();
  const std::vector<std::uint8_t> none;
  float local = local_mean(input, centre, none), threshold = otsu_threshold(input, none);
  if (local <= threshold && local != 0.0f) return std::nullopt;
  // A refusal, or a seed among zeros, is judged again without a probe's no-data region (its zeros
  // would be Otsu's dark class); the flood for it is left to these cases, as the daemon checks
  // the seed of every volume.
  const std::vector<std::uint8_t> no_data = internal::no_data_mask(input);
  if (!no_data.empty()) {
    local = local_mean(input, centre, no_data);
    if (std::isnan(local))
      return "seed " + format_point(seed_mm) +
             " mm lies where the probe has no data (outside its sector); place it inside the "
             "target";
    threshold = otsu_threshold(input, no_data);
  }
  if (!(local > threshold)) return std::nullopt;
  char buffer[160];
  std::snprintf(buffer, sizeof buffer,
                " mm lies in bright tissue (local mean %.1f above the target/tissue threshold "
                "%.1f); place it inside the dark target",
                local, threshold);
  return "seed " + format_point(seed_mm) + buffer;
}

}  // namespace sonomesh::daemon
