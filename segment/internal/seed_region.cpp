// Image statistics around the seed: the default τ_cost and the hypoechoic-seed check.
#include <algorithm>
#include <cmath>
#include <vector>

#include "segment/internal/image_sampler.h"

namespace sonomesh::segment::internal {
namespace {

float median(std::vector<float> v) {
  if (v.empty()) return 0.0f;
  const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  return *mid;
}

// Mean and standard deviation in the ball around the seed, on a half-voxel lattice. False when
// no sample of the ball lies in the volume.
bool ball_statistics(const ImageSampler& sampler, const volume::Volume& grid, const Vec3f& seed_mm,
                     float voxel_mm, float ball_radius_mm, SeedRegion& r) {
  const float step = 0.5f * voxel_mm;
  const int n = static_cast<int>(std::ceil(ball_radius_mm / step));
  double sum = 0.0, sum2 = 0.0;
  int count = 0;
  for (int k = -n; k <= n; ++k)
    for (int j = -n; j <= n; ++j)
      for (int i = -n; i <= n; ++i) {
        const Vec3f d(i * step, j * step, k * step);
        if (d.norm() > ball_radius_mm) continue;
        const Vec3f p = seed_mm + d;
        if (!grid.contains_mm(p)) continue;
        const double v = sampler.value(p);
        sum += v;
        sum2 += v * v;
        ++count;
      }
  if (count == 0) return false;
  const double mean = sum / count;
  r.level = static_cast<float>(mean);
  r.sigma = static_cast<float>(std::sqrt(std::max(0.0, sum2 / count - mean * mean)));
  return true;
}

// The rays' samples from the seed out to the volume's edge, half-voxel steps.
struct RayProfiles {
  std::vector<std::vector<float>> values;
  // Per ray and sample: max(0, <∇I, step along the ray>), the increment of Ψ_cost exactly as a
  // vertex computes it (central-difference gradient, not sample differences, which keep more of
  // the speckle's high frequencies and overstate the rate).
  std::vector<std::vector<float>> rises;
  std::vector<float> upper_quartiles;  // per ray of at least 8 samples
};

// Rays in Fibonacci-sphere directions.
RayProfiles cast_rays(const ImageSampler& sampler, const volume::Volume& grid, const Vec3f& seed_mm,
                      float step_mm, const CostScale& scale, int ray_count) {
  const float golden = static_cast<float>(M_PI * (3.0 - std::sqrt(5.0)));
  RayProfiles rays;
  rays.values.resize(static_cast<std::size_t>(ray_count));
  rays.rises.resize(static_cast<std::size_t>(ray_count));
  for (int q = 0; q < ray_count; ++q) {
    const float z = 1.0f - 2.0f * (q + 0.5f) / ray_count;
    const float rad = std::sqrt(std::max(0.0f, 1.0f - z * z));
    const float phi = golden * q;
    const Vec3f dir(rad * std::cos(phi), rad * std::sin(phi), z);
    auto& profile = rays.values[static_cast<std::size_t>(q)];
    auto& rise = rays.rises[static_cast<std::size_t>(q)];
    for (float t = 0.0f;; t += step_mm) {
      const Vec3f p = seed_mm + t * dir;
      if (!grid.contains_mm(p)) break;
      float value;
      Vec3f grad;
      sampler.value_and_gradient(p, value, grad);
      profile.push_back(value);
      rise.push_back(std::max(0.0f, grad.dot(dir) * step_mm) * scale.weight(value));
    }
    if (profile.size() >= 8) {
      std::vector<float> sorted = profile;
      const auto at = sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() * 3 / 4);
      std::nth_element(sorted.begin(), at, sorted.end());
      rays.upper_quartiles.push_back(*at);
    }
  }
  return rays;
}

// The wall: the first sample from which the profile stays above `crossing` for `sustain`
// samples (speckle blobs inside the target are shorter than that after smoothing); -1 if none.
int first_sustained_rise(const std::vector<float>& profile, float crossing, int sustain) {
  const int n_s = static_cast<int>(profile.size());
  for (int s = 0; s + sustain <= n_s; ++s) {
    bool above = true;
    for (int t = s; t < s + sustain && above; ++t)
      above = profile[static_cast<std::size_t>(t)] > crossing;
    if (above) return s;
  }
  return -1;
}

// What the rays' walls say, accumulated over the rays.
struct WallStatistics {
  std::vector<float> tissue, rates;
  double inside_sum = 0.0;
  std::size_t inside_count = 0;
  float safe_mm = 1e30f;
  int rays_hit = 0;
};

// One ray's wall: the tissue level just beyond it, the samples clearly before it (they give the
// target's level) and their positive rises per mm (the rate at which speckle alone raises
// Ψ_cost inside the target).
void add_ray(const std::vector<float>& profile, const std::vector<float>& rise, float crossing,
             int sustain, float step_mm, WallStatistics& w) {
  const int n_s = static_cast<int>(profile.size());
  const int hit = first_sustained_rise(profile, crossing, sustain);
  w.safe_mm = std::min(w.safe_mm, (hit >= 0 ? hit : n_s) * step_mm);
  if (hit < 0) return;
  const int from = hit + sustain / 2, to = std::min(n_s, hit + 6 * sustain);
  if (to - from < 2) return;
  ++w.rays_hit;
  w.tissue.push_back(median(std::vector<float>(profile.begin() + from, profile.begin() + to)));
  const int inside_end =
      std::min(hit - 2 * sustain, static_cast<int>(0.6f * static_cast<float>(hit)));
  for (int s = 0; s < inside_end; ++s) w.inside_sum += profile[static_cast<std::size_t>(s)];
  if (inside_end > 0) w.inside_count += static_cast<std::size_t>(inside_end);
  if (inside_end >= 4) {
    float sum = 0.0f;
    for (int s = 0; s < inside_end; ++s) sum += rise[static_cast<std::size_t>(s)];
    w.rates.push_back(sum / (inside_end * step_mm));
  }
}

}  // namespace

SeedRegion analyse_seed(const ImageSampler& sampler, const volume::Volume& grid,
                        const Vec3f& seed_mm, float voxel_mm, float ball_radius_mm,
                        const CostScale& scale, int ray_count) {
  SeedRegion r;
  if (!ball_statistics(sampler, grid, seed_mm, voxel_mm, ball_radius_mm, r)) return r;
  // A noise-free image has sigma 0; a floor keeps "a few sigma above" meaningful there.
  const float sigma_eff = std::max(r.sigma, 0.02f * std::abs(r.level) + 0.5f);
  const float step = 0.5f * voxel_mm;
  const RayProfiles rays = cast_rays(sampler, grid, seed_mm, step, scale, ray_count);
  r.rays = ray_count;
  // First guess of the tissue level: the rays' upper quartiles (a ray from a seed in a target
  // smaller than the volume spends a good part of its length in tissue). It only places the
  // wall-crossing threshold; the per-ray levels refine it.
  const float tissue_guess = median(rays.upper_quartiles);
  const float crossing = r.level + 0.5f * std::max(tissue_guess - r.level, 3.0f * sigma_eff);
  const int sustain = static_cast<int>(std::ceil(2.0f * voxel_mm / step));  // two voxels
  WallStatistics w;
  for (std::size_t q = 0; q < rays.values.size(); ++q)
    add_ray(rays.values[q], rays.rises[q], crossing, sustain, step, w);
  r.rays_hit = w.rays_hit;
  r.tissue_level = median(w.tissue);
  // The target's level from the rays' samples clearly inside it (hundreds of samples along 64
  // directions) rather than the ball's few dozen within two voxels of the seed: one speckle blob
  // there moved the ball's mean by ±10 % from seed to seed (64³ sphere: 32-39 grey levels), and
  // τ_cost with it, so the balloon stopped 0.08-0.52 voxel inside the wall depending on the
  // speckle at the seed alone (now 0.23-0.39). The ball's level placed the rays' wall crossing.
  if (w.inside_count >= 64)
    r.level = static_cast<float>(w.inside_sum / static_cast<double>(w.inside_count));
  r.noise_rise_per_mm = median(w.rates);
  r.safe_radius_mm = std::max(0.0f, w.safe_mm - voxel_mm);
  return r;
}

}  // namespace sonomesh::segment::internal
