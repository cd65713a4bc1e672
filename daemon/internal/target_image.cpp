// The image the balloon sees: polarity, inversion, the no-data region (docs/stopping.md).
#include "daemon/internal/target_image.h"

#include <algorithm>
#include <array>
#include <cmath>

namespace sonomesh::daemon::internal {
namespace {

using volume::Vec3i;
using volume::Volume;

// Below this share of the volume a zero region is speckle or a corner, not a sector's outside.
constexpr double kMinNoDataFraction = 0.02;
// How far the data is continued into the no-data region: beyond the smoothing's reach (4 sigma
// of at most 3 voxels) with room for the balloon's last steps.
constexpr int kFillLayers = 16;

// Mean of the raw input over a cube of half-width r voxels around voxel c (clipped at the border).
float cube_mean(const Volume& input, const Vec3i& c, int r) {
  const Vec3i lo = (c.array() - r).max(0), hi = (c.array() + r).min(input.dims().array() - 1);
  double sum = 0.0;
  int n = 0;
  for (int k = lo.z(); k <= hi.z(); ++k)
    for (int j = lo.y(); j <= hi.y(); ++j)
      for (int i = lo.x(); i <= hi.x(); ++i, ++n) sum += input.value(i, j, k);
  return n > 0 ? static_cast<float>(sum / n) : 0.0f;
}

// Calls f(i, j, k) for every voxel on the grid's six faces (some edge voxels twice).
template <typename F>
void for_each_border_voxel(const Vec3i& d, F&& f) {
  for (int k = 0; k < d.z(); ++k)
    for (int j = 0; j < d.y(); ++j) {
      const bool face = k == 0 || j == 0 || k == d.z() - 1 || j == d.y() - 1;
      if (face)
        for (int i = 0; i < d.x(); ++i) f(i, j, k);
      else {
        f(0, j, k);
        f(d.x() - 1, j, k);
      }
    }
}

}  // namespace

std::vector<std::uint8_t> no_data_mask(const Volume& input) {
  const Vec3i d = input.dims();
  std::vector<std::uint8_t> mask;
  if (input.empty()) return mask;
  // On the border only first (faces, not the whole grid): a volume without a zero there (the
  // simulator's) has no sector's outside and costs a few thousand lookups, not a pass.
  bool border_zero = false;
  for_each_border_voxel(
      d, [&](int i, int j, int k) { border_zero = border_zero || input.value(i, j, k) == 0.0f; });
  if (!border_zero) return mask;
  std::vector<std::uint32_t> queue;
  // The zeros once, as a byte per voxel (Volume::value per lookup was most of the flood's time).
  mask.resize(input.voxel_count());
  switch (input.type()) {
    case volume::VoxelType::UInt8: {
      const auto& v = input.u8();
      for (std::size_t i = 0; i < v.size(); ++i) mask[i] = v[i] == 0 ? 2 : 0;
      break;
    }
    case volume::VoxelType::UInt16: {
      const auto& v = input.u16();
      for (std::size_t i = 0; i < v.size(); ++i) mask[i] = v[i] == 0 ? 2 : 0;
      break;
    }
    default: {
      const auto& v = input.f32();
      for (std::size_t i = 0; i < v.size(); ++i) mask[i] = v[i] == 0.0f ? 2 : 0;
    }
  }
  // 2: a zero not (yet) reached from the border; 1: reached (no data).
  auto push = [&](int i, int j, int k) {
    const std::size_t at = input.linear_index(i, j, k);
    if (mask[at] != 2) return;
    mask[at] = 1;
    queue.push_back(static_cast<std::uint32_t>(at));
  };
  for_each_border_voxel(d, push);
  if (queue.empty()) return {};  // no zero on the border: no sector's outside
  for (std::size_t q = 0; q < queue.size(); ++q) {
    const std::uint32_t at = queue[q];
    const int i = static_cast<int>(at % d.x()), j = static_cast<int>((at / d.x()) % d.y()),
              k = static_cast<int>(at / (static_cast<std::size_t>(d.x()) * d.y()));
    if (i > 0) push(i - 1, j, k);
    if (i + 1 < d.x()) push(i + 1, j, k);
    if (j > 0) push(i, j - 1, k);
    if (j + 1 < d.y()) push(i, j + 1, k);
    if (k > 0) push(i, j, k - 1);
    if (k + 1 < d.z()) push(i, j, k + 1);
  }
  if (static_cast<double>(queue.size()) <
      kMinNoDataFraction * static_cast<double>(input.voxel_count()))
    return {};
  for (std::uint8_t& m : mask) m = m == 1 ? 1 : 0;
  return mask;
}

TargetPolarity decide_polarity(const Volume& input, const Vec3f& seed_mm, float grain_mm) {
  const float vox_mm = input.spacing_mm().minCoeff();
  const int r = std::clamp(static_cast<int>(std::lround(grain_mm / vox_mm)), 1, 3);
  const Vec3i seed = input.mm_to_index(seed_mm).array().round().cast<int>();
  const float level = cube_mean(input, seed, r + 1);
  // A departure: 40 % of the seed's level (at least 2 grey levels) for two samples running. Speckle
  // averaged over a grain stays within it; walls in echo and organs in CT differ by more.
  const float margin = std::max(0.4f * std::abs(level), 2.0f);
  const float golden = static_cast<float>(M_PI * (3.0 - std::sqrt(5.0)));
  constexpr int kRays = 64;
  const int max_steps = std::max(input.dims().maxCoeff(), 8);
  int up = 0, down = 0;
  for (int q = 0; q < kRays; ++q) {
    const float z = 1.0f - 2.0f * (q + 0.5f) / kRays;
    const float rad = std::sqrt(std::max(0.0f, 1.0f - z * z));
    const Vec3f dir(rad * std::cos(golden * q), rad * std::sin(golden * q), z);
    int run = 0, sign = 0;
    for (int s = r + 1; s < max_steps; ++s) {
      const Vec3f p = seed_mm + (static_cast<float>(s) * vox_mm) * dir;
      if (!input.contains_mm(p)) break;
      const float m = cube_mean(input, input.mm_to_index(p).array().round().cast<int>(), r);
      const int here = m > level + margin ? 1 : m < level - margin ? -1 : 0;
      run = here != 0 && here == sign ? run + 1 : (here != 0 ? 1 : 0);
      sign = here;
      if (run >= 2) break;
    }
    if (run >= 2) (sign > 0 ? up : down) += 1;
  }
  return down > up ? TargetPolarity::Bright : TargetPolarity::Dark;
}

bool working_image(const Volume& input, TargetPolarity target,
                   const std::vector<std::uint8_t>& no_data, Volume& out) {
  const bool bright = target == TargetPolarity::Bright;
  if (!bright && no_data.empty()) return false;
  out = Volume(input.dims(), input.spacing_mm(), input.origin_mm(), volume::VoxelType::Float32);
  out.set_direction(input.direction());
  std::vector<float>& v =
      out.f32();  // (converted in place: to_float's copy was a second 4 B/voxel)
  switch (input.type()) {
    case volume::VoxelType::UInt8:
      std::copy(input.u8().begin(), input.u8().end(), v.begin());
      break;
    case volume::VoxelType::UInt16:
      std::copy(input.u16().begin(), input.u16().end(), v.begin());
      break;
    default:
      std::copy(input.f32().begin(), input.f32().end(), v.begin());
  }
  if (bright) {
    // I' = max − I: the brightest voxel becomes black, a bright organ a dark one in brighter
    // surroundings, and the balloon's rules (relative cost, tissue level) apply unchanged.
    const float top = *std::max_element(v.begin(), v.end());
    for (float& x : v) x = top - x;
    return true;
  }
  // No data: what lies at the sector's edge is taken to continue outwards (each no-data voxel
  // within kFillLayers of the data takes the value of the data nearest to it, by a breadth-first
  // sweep from the edge). That adds no wall of its own, so the wall levels the balloon measures
  // are the data's. A balloon that still runs out past the filled band meets the zeros and leaks.
  const Vec3i d = input.dims();
  const std::size_t nx = static_cast<std::size_t>(d.x()), ny = static_cast<std::size_t>(d.y()),
                    nz = static_cast<std::size_t>(d.z()), nxy = nx * ny;
  std::vector<std::uint32_t> layer, next;
  auto neighbours = [&](std::size_t at, auto&& f) {
    const std::size_t i = at % nx, j = (at / nx) % ny, k = at / nxy;
    if (i > 0) f(at - 1);
    if (i + 1 < nx) f(at + 1);
    if (j > 0) f(at - nx);
    if (j + 1 < ny) f(at + nx);
    if (k > 0) f(at - nxy);
    if (k + 1 < nz) f(at + nxy);
  };
  std::vector<std::uint8_t> open(no_data.begin(), no_data.end());  // 1: still to fill
  for (std::size_t at = 0; at < v.size(); ++at) {
    if (open[at]) continue;
    bool edge = false;
    neighbours(at, [&](std::size_t to) { edge = edge || open[to]; });
    if (edge) layer.push_back(static_cast<std::uint32_t>(at));
  }
  for (int pass = 0; pass < kFillLayers && !layer.empty(); ++pass) {
    next.clear();
    for (const std::uint32_t at : layer)
      neighbours(at, [&](std::size_t to) {
        if (!open[to]) return;
        open[to] = 0;
        v[to] = v[at];
        next.push_back(static_cast<std::uint32_t>(to));
      });
    layer.swap(next);
  }
  return true;
}

}  // namespace sonomesh::daemon::internal
