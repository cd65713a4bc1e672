// The image the balloon sees: polarity, inversion, the no-data region (docs/stopping.md).
#include "daemon/internal/target_image.h"

#include <algorithm>
#include <array>
#include <cmath>

#include "daemon/internal/shadow_gain.h"

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

// Calls f(voxels) with the input's voxel vector of its own type.
template <typename F>
void with_voxels(const Volume& input, F&& f) {
  switch (input.type()) {
    case volume::VoxelType::UInt8:
      return f(input.u8());
    case volume::VoxelType::UInt16:
      return f(input.u16());
    case volume::VoxelType::Float32:
      return f(input.f32());
  }
}

// A grid of dims `d` inside a one-voxel margin: a cell's neighbours are fixed offsets, with no
// bounds test, where the margin is never entered.
class PaddedGrid {
 public:
  explicit PaddedGrid(const Vec3i& d)
      : d_(d), nx_(static_cast<std::size_t>(d.x()) + 2), nxy_(nx_ * (d.y() + 2)) {}
  std::size_t size() const { return nxy_ * (d_.z() + 2); }
  std::size_t index(int i, int j, int k) const {
    return (k + 1) * nxy_ + (j + 1) * nx_ + static_cast<std::size_t>(i + 1);
  }
  // From a cell to the same cell of the four rows beside its row (y ± 1, z ± 1).
  std::array<std::ptrdiff_t, 4> row_steps() const {
    const auto x = static_cast<std::ptrdiff_t>(nx_), xy = static_cast<std::ptrdiff_t>(nxy_);
    return {x, -x, xy, -xy};
  }
  // f(at, p) for every voxel: `at` as Volume::linear_index, `p` its index here.
  template <typename F>
  void for_each_voxel(F&& f) const {
    std::size_t at = 0;
    for (int k = 0; k < d_.z(); ++k)
      for (int j = 0; j < d_.y(); ++j) {
        const std::size_t p = index(0, j, k);
        for (int i = 0; i < d_.x(); ++i, ++at) f(at, p + i);
      }
  }

 private:
  Vec3i d_;
  std::size_t nx_, nxy_;
};

// Marks 2 → 1 in `cells` (on `grid`, its margin not 2) for every cell connected through 2s to a
// 2 on the border of the grid's dims `d`; returns how many. A scanline flood: it takes whole runs
// along x and queues one cell per run found beside them, so it streams rows rather than hopping
// through the volume voxel by voxel.
std::size_t flood_rows(const PaddedGrid& grid, const Vec3i& d, std::vector<std::uint8_t>& cells) {
  std::vector<std::pair<std::size_t, std::size_t>> runs;  // [first, last] cells
  std::size_t reached = 0;
  auto take_run = [&](std::size_t p) {
    if (cells[p] != 2) return;
    std::size_t first = p, last = p;
    while (cells[first - 1] == 2) --first;
    while (cells[last + 1] == 2) ++last;
    std::fill(cells.begin() + first, cells.begin() + last + 1, 1);
    reached += last - first + 1;
    runs.emplace_back(first, last);
  };
  for_each_border_voxel(d, [&](int i, int j, int k) { take_run(grid.index(i, j, k)); });
  while (!runs.empty()) {
    const auto [first, last] = runs.back();
    runs.pop_back();
    for (const std::ptrdiff_t step : grid.row_steps())
      for (std::size_t p = first; p <= last; ++p) take_run(p + step);
  }
  return reached;
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
  // The zeros once, a byte per cell of the padded grid the flood runs on. 2: a zero not (yet)
  // reached from the border; 1: reached (no data).
  const PaddedGrid grid(d);
  std::vector<std::uint8_t> padded(grid.size(), 0);
  with_voxels(input, [&](const auto& v) {
    grid.for_each_voxel([&](std::size_t at, std::size_t p) { padded[p] = v[at] == 0 ? 2 : 0; });
  });
  const std::size_t reached = flood_rows(grid, d, padded);
  if (reached == 0) return {};  // no zero on the border: no sector's outside
  if (static_cast<double>(reached) < kMinNoDataFraction * static_cast<double>(input.voxel_count()))
    return {};
  mask.resize(input.voxel_count());
  grid.for_each_voxel([&](std::size_t at, std::size_t p) { mask[at] = padded[p] == 1 ? 1 : 0; });
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

namespace {

using FillPlan = std::vector<std::pair<std::uint32_t, std::uint32_t>>;

// The no-data fill's plan over `mask` on a grid of dims `d`: each no-data voxel within kFillLayers
// of the data with the voxel it copies (the data nearest to it, by a breadth-first sweep from
// the data's edge), in the order the copies are to be made.
FillPlan fill_plan(const Vec3i& d, const std::vector<std::uint8_t>& mask) {
  const std::size_t nx = static_cast<std::size_t>(d.x()), ny = static_cast<std::size_t>(d.y()),
                    nz = static_cast<std::size_t>(d.z()), nxy = nx * ny;
  auto neighbours = [&](std::size_t at, auto&& f) {
    const std::size_t i = at % nx, j = (at / nx) % ny, k = at / nxy;
    if (i > 0) f(at - 1);
    if (i + 1 < nx) f(at + 1);
    if (j > 0) f(at - nx);
    if (j + 1 < ny) f(at + nx);
    if (k > 0) f(at - nxy);
    if (k + 1 < nz) f(at + nxy);
  };
  std::vector<std::uint8_t> open(mask);  // 1: still to fill
  std::vector<std::uint32_t> layer, next;
  std::size_t at = 0;  // (the data's edge by rows: no index arithmetic per voxel)
  for (std::size_t k = 0; k < nz; ++k)
    for (std::size_t j = 0; j < ny; ++j)
      for (std::size_t i = 0; i < nx; ++i, ++at)
        if (!open[at] && ((i > 0 && open[at - 1]) || (i + 1 < nx && open[at + 1]) ||
                          (j > 0 && open[at - nx]) || (j + 1 < ny && open[at + nx]) ||
                          (k > 0 && open[at - nxy]) || (k + 1 < nz && open[at + nxy])))
          layer.push_back(static_cast<std::uint32_t>(at));
  FillPlan plan;
  for (int pass = 0; pass < kFillLayers && !layer.empty(); ++pass) {
    next.clear();
    for (const std::uint32_t from : layer)
      neighbours(from, [&](std::size_t to) {
        if (!open[to]) return;
        open[to] = 0;
        plan.emplace_back(static_cast<std::uint32_t>(to), from);
        next.push_back(static_cast<std::uint32_t>(to));
      });
    layer.swap(next);
  }
  return plan;
}

// Whether `mask` (non-empty) is no_data_mask(input) still: every voxel of it is zero, and no
// other zero lies beside it or on the border, where the flood would go on or start anew.
bool still_holds(const Volume& input, const std::vector<std::uint8_t>& mask) {
  const Vec3i d = input.dims();
  const std::size_t nx = static_cast<std::size_t>(d.x()), ny = static_cast<std::size_t>(d.y()),
                    nz = static_cast<std::size_t>(d.z()), nxy = nx * ny;
  bool holds = true;
  with_voxels(input, [&](const auto& v) {
    std::size_t at = 0;
    for (std::size_t k = 0; k < nz && holds; ++k)
      for (std::size_t j = 0; j < ny && holds; ++j)
        for (std::size_t i = 0; i < nx; ++i, ++at) {
          if (mask[at] || v[at] != 0) {
            holds = holds && (!mask[at] || v[at] == 0);
            continue;
          }
          const bool border =
              i == 0 || j == 0 || k == 0 || i + 1 == nx || j + 1 == ny || k + 1 == nz;
          holds = holds && !border && !mask[at - 1] && !mask[at + 1] && !mask[at - nx] &&
                  !mask[at + nx] && !mask[at - nxy] && !mask[at + nxy];
        }
  });
  return holds;
}

}  // namespace

bool update_no_data(const Volume& input, NoDataRegion& region) {
  if (!region.mask.empty() && region.dims == input.dims() && still_holds(input, region.mask))
    return true;
  region.dims = input.dims();
  region.mask = no_data_mask(input);
  region.fill = region.mask.empty() ? FillPlan{} : fill_plan(input.dims(), region.mask);
  region.apex_mm = sector_apex_mm(input, region.mask);
  return false;
}

bool needs_working_image(TargetPolarity target, const NoDataRegion& no_data) {
  return target == TargetPolarity::Bright || !no_data.mask.empty();
}

void copy_as_float32(const Volume& input, Volume& out) {
  // (A buffer of the right size is kept: a fresh one is zero-filled first, then written again.)
  if (out.type() != volume::VoxelType::Float32 || out.dims() != input.dims() ||
      out.spacing_mm() != input.spacing_mm())
    out = Volume(input.dims(), input.spacing_mm(), input.origin_mm(), volume::VoxelType::Float32);
  out.set_origin_mm(input.origin_mm());
  out.set_direction(input.direction());
  std::vector<float>& v = out.f32();
  with_voxels(input, [&](const auto& in) { std::copy(in.begin(), in.end(), v.begin()); });
}

bool working_image(const Volume& input, TargetPolarity target, const NoDataRegion& no_data,
                   Volume& out) {
  if (!needs_working_image(target, no_data)) return false;
  const bool bright = target == TargetPolarity::Bright;
  copy_as_float32(input, out);
  std::vector<float>& v = out.f32();
  if (bright) {
    // I' = max − I: the brightest voxel becomes black, a bright organ a dark one in brighter
    // surroundings, and the balloon's rules (relative cost, tissue level) apply unchanged.
    const float top = *std::max_element(v.begin(), v.end());
    for (float& x : v) x = top - x;
    return true;
  }
  // No data: what lies at the sector's edge is taken to continue outwards (the fill's plan).
  // That adds no wall of its own, so the wall levels the balloon measures are the data's. A
  // balloon that still runs out past the filled band meets the zeros and leaks.
  for (const auto& [to, from] : no_data.fill) v[to] = v[from];
  return true;
}

}  // namespace sonomesh::daemon::internal
