#include "daemon/internal/metrics.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <stdexcept>
#include <thread>

namespace sonomesh::daemon::internal {
namespace {

using volume::Vec3f;
using volume::Vec3i;
using volume::Volume;

// Finite stand-in for "no feature": keeps the parabola intersections below free of inf - inf.
constexpr float kFar = 1e20f;

// Below this many cells a pass runs on one thread: starting the threads costs more than they
// save on the deepest-point search's box.
constexpr std::size_t kParallelCells = std::size_t{1} << 21;

// Runs body(first, last) over [0, n) lines of `length` cells split across the cores: two workers
// on the CI's two cores roughly halve a whole volume's transform.
template <typename Body>
void parallel_lines(std::size_t n, std::size_t length, Body body) {
  const std::size_t workers = std::clamp<std::size_t>(std::thread::hardware_concurrency(), 1, 8);
  if (workers == 1 || n < 64 || n * length < kParallelCells) {
    body(std::size_t{0}, n);
    return;
  }
  std::vector<std::jthread> threads;
  const std::size_t chunk = (n + workers - 1) / workers;
  for (std::size_t w = 0; w < workers; ++w) {
    const std::size_t first = w * chunk;
    const std::size_t last = std::min(n, first + chunk);
    if (first >= last) break;
    threads.emplace_back([=] { body(first, last); });
  }
}

// One-dimensional lower envelope of parabolas (Felzenszwalb & Huttenlocher): out[p] =
// min_q ((p - q)·s)² + f[q]. v, z are scratch of size n and n + 1.
void edt_1d(const float* f, float* out, int n, float s, int* v, float* z) {
  const float s2 = s * s;
  int k = 0;
  v[0] = 0;
  z[0] = -std::numeric_limits<float>::max();
  z[1] = std::numeric_limits<float>::max();
  for (int q = 1; q < n; ++q) {
    // Intersection of the parabolas rooted at q and v[k], in index units; z[0] is -max, so the
    // loop never pops the first parabola.
    auto intersect = [&](int r) {
      return ((f[q] + s2 * q * q) - (f[r] + s2 * r * r)) / (2.0f * s2 * (q - r));
    };
    float inter = intersect(v[k]);
    while (inter <= z[k]) {
      --k;
      inter = intersect(v[k]);
    }
    ++k;
    v[k] = q;
    z[k] = inter;
    z[k + 1] = std::numeric_limits<float>::max();
  }
  k = 0;
  for (int p = 0; p < n; ++p) {
    while (z[k + 1] < static_cast<float>(p)) ++k;
    const float d = static_cast<float>(p - v[k]) * s;
    out[p] = std::min(kFar, d * d + f[v[k]]);
  }
}

// Along the first axis the values are still 0 (a feature) or kFar: the lower envelope is then
// the squared distance to the nearest feature on the line, found by one sweep each way.
void nearest_feature_1d(const float* f, float* out, int n, float s) {
  int last = -1;
  for (int p = 0; p < n; ++p) {
    if (f[p] == 0.0f) last = p;
    const float d = static_cast<float>(p - last) * s;
    out[p] = last < 0 ? kFar : std::min(kFar, d * d);
  }
  last = -1;
  for (int p = n - 1; p >= 0; --p) {
    if (f[p] == 0.0f) last = p;
    const float d = static_cast<float>(last - p) * s;
    if (last >= 0) out[p] = std::min(out[p], d * d);
  }
}

// Applies edt_1d along `axis` of a dense float grid in place; axis 0 must come first, on a grid of
// 0 and kFar only. A line without a positive value is its own transform.
void transform_axis(std::vector<float>& grid, const Vec3i& dims, int axis, float s) {
  const int n = dims[axis];
  const std::size_t stride = axis == 0   ? 1
                             : axis == 1 ? static_cast<std::size_t>(dims.x())
                                         : static_cast<std::size_t>(dims.x()) * dims.y();
  const int a = axis == 0 ? 1 : 0;  // the two other axes enumerate the lines
  const int b = axis == 2 ? 1 : 2;
  const std::size_t lines = static_cast<std::size_t>(dims[a]) * dims[b];
  parallel_lines(lines, static_cast<std::size_t>(n), [&](std::size_t first, std::size_t last) {
    std::vector<float> f(n), out(n), z(n + 1);
    std::vector<int> v(n);
    for (std::size_t line = first; line < last; ++line) {
      Vec3i ijk = Vec3i::Zero();
      ijk[a] = static_cast<int>(line % dims[a]);
      ijk[b] = static_cast<int>(line / dims[a]);
      const std::size_t base =
          (static_cast<std::size_t>(ijk.z()) * dims.y() + ijk.y()) * dims.x() + ijk.x();
      bool positive = false;
      for (int p = 0; p < n; ++p) {
        f[p] = grid[base + p * stride];
        positive = positive || f[p] > 0.0f;
      }
      if (!positive) continue;
      if (axis == 0)
        nearest_feature_1d(f.data(), out.data(), n, s);
      else
        edt_1d(f.data(), out.data(), n, s, v.data(), z.data());
      for (int p = 0; p < n; ++p) grid[base + p * stride] = out[p];
    }
  });
}

void require_same_grid(const Volume& a, const Volume& b) {
  if (a.dims() != b.dims()) throw std::invalid_argument("label volumes have different dimensions");
}

// Label volumes are UInt8 (rasterize_labels, the simulator's truth, label files); direct access
// keeps the full-volume scans at memory speed.
const std::vector<std::uint8_t>& label_data(const Volume& labels) {
  if (labels.type() != volume::VoxelType::UInt8)
    throw std::invalid_argument("label volume must be UInt8");
  return labels.u8();
}

// Inside voxels with a 6-neighbour outside or on the border of the volume.
std::vector<bool> boundary_of(const Volume& labels) {
  const Vec3i d = labels.dims();
  const auto& data = label_data(labels);
  auto inside = [&](int i, int j, int k) { return data[labels.linear_index(i, j, k)] != 0; };
  std::vector<bool> boundary(labels.voxel_count(), false);
  for (int k = 0; k < d.z(); ++k)
    for (int j = 0; j < d.y(); ++j)
      for (int i = 0; i < d.x(); ++i) {
        if (!inside(i, j, k)) continue;
        const bool border =
            i == 0 || j == 0 || k == 0 || i == d.x() - 1 || j == d.y() - 1 || k == d.z() - 1;
        if (border || !inside(i - 1, j, k) || !inside(i + 1, j, k) || !inside(i, j - 1, k) ||
            !inside(i, j + 1, k) || !inside(i, j, k - 1) || !inside(i, j, k + 1))
          boundary[labels.linear_index(i, j, k)] = true;
      }
  return boundary;
}

// Box of the field's cells, subsampled by `stride` per axis, that the deepest-point search runs
// on: cells lo + stride ⊙ c for c in [0, dims).
struct Lattice {
  Vec3i lo, stride, dims;
};

Lattice lattice_of(const Volume& field, const Vec3f& lo_mm, const Vec3f& hi_mm, float step_mm) {
  Lattice l;
  const Vec3i last = field.dims() - Vec3i::Ones();
  const Vec3f lo_u = field.mm_to_index(lo_mm), hi_u = field.mm_to_index(hi_mm);
  Vec3i hi;
  for (int a = 0; a < 3; ++a) {
    l.stride[a] = std::max(1, static_cast<int>(step_mm / field.spacing_mm()[a] + 1e-3f));
    l.lo[a] = std::clamp(static_cast<int>(std::floor(lo_u[a])) - 1, 0, last[a]);
    hi[a] = std::clamp(static_cast<int>(std::ceil(hi_u[a])) + 1, l.lo[a], last[a]);
    l.dims[a] = (hi[a] - l.lo[a]) / l.stride[a] + 1;
  }
  return l;
}

// Marks as outside (0) the inside cells (kFar) of the framed grid `d2` that are not 6-connected
// to the inside cell at or next to `start`; none when there is no such cell (nothing is cut off).
void keep_component(std::vector<float>& d2, const Vec3i& fd, const Vec3i& start) {
  const std::size_t sy = fd.x(), sz = sy * fd.y();
  auto at = [&](const Vec3i& c) { return c.z() * sz + c.y() * sy + c.x(); };
  std::size_t first = d2.size();
  for (int dz = -1; dz <= 1 && first == d2.size(); ++dz)
    for (int dy = -1; dy <= 1 && first == d2.size(); ++dy)
      for (int dx = -1; dx <= 1 && first == d2.size(); ++dx) {
        const Vec3i c = (start + Vec3i(dx, dy, dz)).cwiseMax(1).cwiseMin(fd - Vec3i::Constant(2));
        if (d2[at(c)] == kFar) first = at(c);
      }
  if (first == d2.size()) return;
  std::vector<std::uint8_t> reached(d2.size(), 0);
  std::vector<std::uint32_t> queue{static_cast<std::uint32_t>(first)};
  reached[first] = 1;
  // The frame is outside, so a neighbour index never leaves the grid.
  const std::ptrdiff_t steps[6] = {1,
                                   -1,
                                   static_cast<std::ptrdiff_t>(sy),
                                   -static_cast<std::ptrdiff_t>(sy),
                                   static_cast<std::ptrdiff_t>(sz),
                                   -static_cast<std::ptrdiff_t>(sz)};
  for (std::size_t q = 0; q < queue.size(); ++q)
    for (const std::ptrdiff_t step : steps) {
      const std::size_t n = queue[q] + step;
      if (d2[n] != kFar || reached[n]) continue;
      reached[n] = 1;
      queue.push_back(static_cast<std::uint32_t>(n));
    }
  for (std::size_t n = 0; n < d2.size(); ++n)
    if (!reached[n]) d2[n] = 0.0f;
}

}  // namespace

std::vector<float> squared_distance_transform_mm2(const std::vector<bool>& feature,
                                                  const Vec3i& dims, const Vec3f& spacing_mm) {
  const std::size_t n = static_cast<std::size_t>(dims.x()) * dims.y() * dims.z();
  if (feature.size() != n) throw std::invalid_argument("feature size does not match dims");
  std::vector<float> grid(n);
  for (std::size_t idx = 0; idx < n; ++idx) grid[idx] = feature[idx] ? 0.0f : kFar;
  for (int axis = 0; axis < 3; ++axis) transform_axis(grid, dims, axis, spacing_mm[axis]);
  for (float& value : grid)
    if (value >= kFar) value = std::numeric_limits<float>::infinity();
  return grid;
}

std::optional<DeepestPoint> deepest_inside(const Volume& field, float iso, const Vec3f& lo_mm,
                                           const Vec3f& hi_mm, const Vec3f& seed_mm,
                                           float step_mm) {
  if (field.type() != volume::VoxelType::Float32)
    throw std::invalid_argument("deepest_inside: the field must be Float32");
  if (field.empty()) return std::nullopt;
  const Lattice l = lattice_of(field, lo_mm, hi_mm, step_mm);
  // The lattice inside a one-cell frame of "outside": cells beyond the box count as outside, and
  // every cell has the frame within reach, so none stays at kFar after the transform.
  const Vec3i fd = l.dims + Vec3i::Constant(2);
  auto fidx = [&](int i, int j, int k) {
    return (static_cast<std::size_t>(k) * fd.y() + j) * fd.x() + i;
  };
  std::vector<float> d2(static_cast<std::size_t>(fd.prod()), 0.0f);
  const auto& values = field.f32();
  bool any = false;
  for (int k = 0; k < l.dims.z(); ++k)
    for (int j = 0; j < l.dims.y(); ++j) {
      const std::size_t row =
          field.linear_index(l.lo.x(), l.lo.y() + j * l.stride.y(), l.lo.z() + k * l.stride.z());
      float* out = d2.data() + fidx(1, j + 1, k + 1);
      for (int i = 0; i < l.dims.x(); ++i) {
        const bool inside = values[row + static_cast<std::size_t>(i) * l.stride.x()] > iso;
        out[i] = inside ? kFar : 0.0f;
        any = any || inside;
      }
    }
  if (!any) return std::nullopt;
  const Vec3f seed_c =
      (field.mm_to_index(seed_mm) - l.lo.cast<float>()).cwiseQuotient(l.stride.cast<float>());
  keep_component(d2, fd, seed_c.array().round().cast<int>().matrix() + Vec3i::Ones());
  const Vec3f cell_mm = field.spacing_mm().cwiseProduct(l.stride.cast<float>());
  for (int axis = 0; axis < 3; ++axis) transform_axis(d2, fd, axis, cell_mm[axis]);
  float best = 0.0f;
  Vec3i best_c = Vec3i::Zero();
  for (int k = 1; k <= l.dims.z(); ++k)
    for (int j = 1; j <= l.dims.y(); ++j)
      for (int i = 1; i <= l.dims.x(); ++i)
        if (const float value = d2[fidx(i, j, k)]; value > best) {
          best = value;
          best_c = Vec3i(i - 1, j - 1, k - 1);
        }
  if (best <= 0.0f) return std::nullopt;
  const Vec3i cell = l.lo + l.stride.cwiseProduct(best_c);
  return DeepestPoint{field.index_to_mm(cell.cast<float>()), std::sqrt(best)};
}

double dice(const Volume& a, const Volume& b) {
  require_same_grid(a, b);
  const auto& da = label_data(a);
  const auto& db = label_data(b);
  std::size_t na = 0, nb = 0, both = 0;
  for (std::size_t idx = 0; idx < da.size(); ++idx) {
    const bool ia = da[idx] != 0, ib = db[idx] != 0;
    na += ia;
    nb += ib;
    both += ia && ib;
  }
  if (na + nb == 0) return 1.0;
  return 2.0 * static_cast<double>(both) / static_cast<double>(na + nb);
}

double equivalent_radius_mm(const Volume& labels) {
  std::size_t inside = 0;
  for (const std::uint8_t v : label_data(labels)) inside += v != 0;
  const double volume_mm3 =
      static_cast<double>(inside) * static_cast<double>(labels.spacing_mm().prod());
  return std::cbrt(3.0 * volume_mm3 / (4.0 * M_PI));
}

SurfaceDistances surface_distances(const Volume& a, const Volume& b) {
  require_same_grid(a, b);
  const auto ba = boundary_of(a), bb = boundary_of(b);
  SurfaceDistances result;
  if (std::find(ba.begin(), ba.end(), true) == ba.end() ||
      std::find(bb.begin(), bb.end(), true) == bb.end())
    return result;
  const Vec3f unit = Vec3f::Ones();  // voxels, whatever the spacing
  const auto to_a = squared_distance_transform_mm2(ba, a.dims(), unit);
  const auto to_b = squared_distance_transform_mm2(bb, a.dims(), unit);
  std::vector<double> pooled;
  for (std::size_t idx = 0; idx < ba.size(); ++idx) {
    if (ba[idx]) pooled.push_back(std::sqrt(static_cast<double>(to_b[idx])));
    if (bb[idx]) pooled.push_back(std::sqrt(static_cast<double>(to_a[idx])));
  }
  double sum = 0.0;
  for (double value : pooled) sum += value;
  result.mean_vox = sum / static_cast<double>(pooled.size());
  std::sort(pooled.begin(), pooled.end());
  const std::size_t p95 =
      static_cast<std::size_t>(std::ceil(0.95 * static_cast<double>(pooled.size()))) - 1;
  result.hd95_vox = pooled[std::min(p95, pooled.size() - 1)];
  result.max_vox = pooled.back();
  result.valid = true;
  return result;
}

}  // namespace sonomesh::daemon::internal
