// Gradients, the speckle grain and trilinear sampling (smoothing.cpp smooths).
#include <algorithm>
#include <array>
#include <cmath>
#include <opencv2/core.hpp>
#include <optional>
#include <stdexcept>

#include "volume/internal/float_output.h"
#include "volume/volume.h"

namespace sonomesh::volume {
namespace {

// Trilinear weights of a point in mm, clamped to the voxel-centre box.
struct Trilinear {
  std::size_t i000;        // linear index of the lower corner
  std::size_t dx, dy, dz;  // offsets to the upper neighbour along each axis (0 on a 1-voxel axis)
  float fx, fy, fz;
};

inline Trilinear trilinear(const Vec3i& dims, const Vec3f& spacing, const Vec3f& origin,
                           const Vec3f& p_mm) {
  Trilinear t;
  const std::size_t nx = static_cast<std::size_t>(dims.x());
  const std::size_t nxy = nx * static_cast<std::size_t>(dims.y());
  int base[3];
  float frac[3];
  for (int a = 0; a < 3; ++a) {
    const float hi = static_cast<float>(dims[a] - 1);
    float u = (p_mm[a] - origin[a]) / spacing[a];
    // NaN falls through both comparisons; std::clamp semantics are fine but be explicit.
    if (!(u > 0.0f)) u = 0.0f;
    if (u > hi) u = hi;
    int b = static_cast<int>(u);
    if (b > dims[a] - 2) b = std::max(0, dims[a] - 2);
    base[a] = b;
    frac[a] = u - static_cast<float>(b);
  }
  t.i000 = static_cast<std::size_t>(base[2]) * nxy + static_cast<std::size_t>(base[1]) * nx +
           static_cast<std::size_t>(base[0]);
  t.dx = dims.x() > 1 ? 1 : 0;
  t.dy = dims.y() > 1 ? nx : 0;
  t.dz = dims.z() > 1 ? nxy : 0;
  t.fx = frac[0];
  t.fy = frac[1];
  t.fz = frac[2];
  return t;
}

template <typename T>
inline float interpolate(const T* d, const Trilinear& t) {
  const std::size_t i = t.i000;
  const float c00 = static_cast<float>(d[i]) +
                    t.fx * (static_cast<float>(d[i + t.dx]) - static_cast<float>(d[i]));
  const float c10 =
      static_cast<float>(d[i + t.dy]) +
      t.fx * (static_cast<float>(d[i + t.dy + t.dx]) - static_cast<float>(d[i + t.dy]));
  const std::size_t j = i + t.dz;
  const float c01 = static_cast<float>(d[j]) +
                    t.fx * (static_cast<float>(d[j + t.dx]) - static_cast<float>(d[j]));
  const float c11 =
      static_cast<float>(d[j + t.dy]) +
      t.fx * (static_cast<float>(d[j + t.dy + t.dx]) - static_cast<float>(d[j + t.dy]));
  const float c0 = c00 + t.fy * (c10 - c00);
  const float c1 = c01 + t.fy * (c11 - c01);
  return c0 + t.fz * (c1 - c0);
}

}  // namespace

using internal::prepare_float;

Gradient central_gradient(const Volume& input) {
  Gradient g;
  central_gradient(input, g);
  return g;
}

void central_gradient(const Volume& input, Gradient& g) {
  if (input.empty()) throw std::invalid_argument("central_gradient: empty volume");
  if (&input == &g.gx || &input == &g.gy || &input == &g.gz)
    throw std::invalid_argument("central_gradient: output aliases input");
  const Vec3i& dims = input.dims();
  const int nx = dims.x(), ny = dims.y(), nz = dims.z();
  prepare_float(input, g.gx);
  prepare_float(input, g.gy);
  prepare_float(input, g.gz);
  std::vector<float> converted;
  const float* f = nullptr;
  if (input.type() == VoxelType::Float32) {
    f = input.f32().data();
  } else {
    converted = input.to_float();
    f = converted.data();
  }
  const Vec3f inv = input.spacing_mm().cwiseInverse();
  float* gx = g.gx.f32().data();
  float* gy = g.gy.f32().data();
  float* gz = g.gz.f32().data();
  const std::size_t sy = static_cast<std::size_t>(nx), sz = sy * ny;

  // Per row, the neighbours along y and z are whole rows: pick them (and the step, central inside,
  // one-sided at the ends, none on a 1-voxel axis) once, then run branch-free loops over x.
  struct Neighbours {
    std::ptrdiff_t lo, hi;  // row offsets of the two samples
    float scale;            // 1 / distance between them in mm (0 on a 1-voxel axis)
  };
  auto neighbours = [](int c, int n, std::ptrdiff_t stride, float inv_h) {
    if (n == 1) return Neighbours{0, 0, 0.0f};
    if (c == 0) return Neighbours{0, stride, inv_h};
    if (c == n - 1) return Neighbours{-stride, 0, inv_h};
    return Neighbours{-stride, stride, 0.5f * inv_h};
  };
  cv::parallel_for_(cv::Range(0, nz), [&](const cv::Range& r) {
    for (int k = r.start; k < r.end; ++k) {
      const Neighbours nzb = neighbours(k, nz, static_cast<std::ptrdiff_t>(sz), inv.z());
      for (int j = 0; j < ny; ++j) {
        const Neighbours nyb = neighbours(j, ny, static_cast<std::ptrdiff_t>(sy), inv.y());
        const std::size_t row = k * sz + j * sy;
        const float* p = f + row;
        float* ox = gx + row;
        float* oy = gy + row;
        float* oz = gz + row;
        for (int i = 0; i < nx; ++i) {
          oy[i] = (p[i + nyb.hi] - p[i + nyb.lo]) * nyb.scale;
          oz[i] = (p[i + nzb.hi] - p[i + nzb.lo]) * nzb.scale;
        }
        if (nx == 1) {
          ox[0] = 0.0f;
          continue;
        }
        const float half = 0.5f * inv.x();
        for (int i = 1; i < nx - 1; ++i) ox[i] = (p[i + 1] - p[i - 1]) * half;
        ox[0] = (p[1] - p[0]) * inv.x();
        ox[nx - 1] = (p[nx - 1] - p[nx - 2]) * inv.x();
      }
    }
  });
}

namespace {

// The speckle's cube (speckle_grain_mm): its bounds and which voxels take part.
struct GrainCube {
  const Volume& input;
  Vec3i lo, hi;
  const std::function<bool(const Vec3i&)>& excluded;
  bool used(int i, int j, int k) const { return !excluded || !excluded(Vec3i(i, j, k)); }
};

// The normalised autocorrelation at `lag` voxels along `step` over the cube's used pairs; nullopt
// when there is no pair.
std::optional<double> autocorrelation(const GrainCube& c, const Vec3i& step, int lag, double mean,
                                      double variance) {
  double acc = 0.0;
  std::size_t pairs = 0;
  for (int k = c.lo.z(); k <= c.hi.z() - lag * step.z(); ++k)
    for (int j = c.lo.y(); j <= c.hi.y() - lag * step.y(); ++j)
      for (int i = c.lo.x(); i <= c.hi.x() - lag * step.x(); ++i) {
        const Vec3i q = Vec3i(i, j, k) + lag * step;
        if (!c.used(i, j, k) || !c.used(q.x(), q.y(), q.z())) continue;
        acc += (c.input.value(i, j, k) - mean) * (c.input.value(q.x(), q.y(), q.z()) - mean);
        ++pairs;
      }
  if (pairs == 0) return std::nullopt;
  return acc / static_cast<double>(pairs) / variance;
}

// The lag (voxels) at which the autocorrelation along `axis` falls to one half; 0 where the axis
// holds structure.
float half_lag_vox(const GrainCube& c, int axis, int radius_vox, double mean, double variance) {
  Vec3i step = Vec3i::Zero();
  step[axis] = 1;
  double previous = 1.0;
  float lag_half = static_cast<float>(radius_vox);  // not reached within the cube
  for (int lag = 1; lag <= radius_vox; ++lag) {
    const std::optional<double> r = autocorrelation(c, step, lag, mean, variance);
    if (!r) break;
    if (*r <= 0.5 && lag_half >= static_cast<float>(radius_vox))
      lag_half =
          static_cast<float>(lag - 1) + static_cast<float>((previous - 0.5) / (previous - *r));
    // Speckle decorrelates within a few voxels; a correlation still above 0.25 at three voxels
    // is structure (a wall or tube crossing the cube along this axis), not grain: the axis is
    // not used (96³ double torus, seed in the tube: 0.47 there, and its grain read 2 voxels).
    if (lag == 3 && *r > 0.25) return 0.0f;
    if (lag >= 3 && lag_half < static_cast<float>(radius_vox)) break;
    previous = *r;
  }
  return lag_half;
}

// Per grid axis, the half lag (voxels) in the cube of `radius_vox` round voxel `c`: 0 where the
// axis holds structure. Empty when the cube has too few voxels or no variation.
std::optional<Vec3f> half_lags_vox(const Volume& input, const Vec3i& c, int radius_vox,
                                   const std::function<bool(const Vec3i&)>& excluded) {
  const GrainCube cube{input, (c.array() - radius_vox).max(0),
                       (c.array() + radius_vox).min(input.dims().array() - 1), excluded};
  double sum = 0.0, sum2 = 0.0;
  std::size_t n = 0;
  for (int k = cube.lo.z(); k <= cube.hi.z(); ++k)
    for (int j = cube.lo.y(); j <= cube.hi.y(); ++j)
      for (int i = cube.lo.x(); i <= cube.hi.x(); ++i) {
        if (!cube.used(i, j, k)) continue;
        const double v = input.value(i, j, k);
        sum += v;
        sum2 += v * v;
        ++n;
      }
  if (n < 8) return std::nullopt;
  const double mean = sum / static_cast<double>(n);
  const double variance = sum2 / static_cast<double>(n) - mean * mean;
  if (!(variance > 1e-9 * (1.0 + mean * mean))) return std::nullopt;
  Vec3f lags;
  for (int axis = 0; axis < 3; ++axis)
    lags[axis] = half_lag_vox(cube, axis, radius_vox, mean, variance);
  return lags;
}

// The axes `grain_vox` left out (0: structure in the seed's cube), read in the six cubes beside
// it, 2 radii off along each axis: the median of those that read the axis.
void read_beside(const Volume& input, const Vec3i& c, int radius_vox,
                 const std::function<bool(const Vec3i&)>& excluded, Vec3f& grain_vox) {
  std::array<std::vector<float>, 3> beside;
  for (int axis = 0; axis < 3; ++axis)
    for (const int side : {-1, 1}) {
      Vec3i at = c;
      at[axis] += side * 2 * radius_vox;
      if (!input.contains_index(at)) continue;
      if (const std::optional<Vec3f> other = half_lags_vox(input, at, radius_vox, excluded))
        for (int a = 0; a < 3; ++a)
          if ((*other)[a] > 0.0f) beside[a].push_back((*other)[a]);
    }
  for (int axis = 0; axis < 3; ++axis) {
    std::vector<float>& v = beside[axis];
    if (grain_vox[axis] > 0.0f || v.empty()) continue;
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    grain_vox[axis] = v[v.size() / 2];
  }
}

}  // namespace

float speckle_grain_mm(const Volume& input, const Vec3f& centre_mm, int radius_vox,
                       const std::function<bool(const Vec3i&)>& excluded) {
  if (input.empty() || radius_vox < 1) return 0.0f;
  const Vec3i c = input.mm_to_index(centre_mm).array().round().cast<int>();
  const std::optional<Vec3f> lags = half_lags_vox(input, c, radius_vox, excluded);
  if (!lags) return 0.0f;
  Vec3f grain_vox = *lags;
  // An axis along which the seed's cube holds structure (a thin target's walls) is read beside
  // it: along the beam the grain is finer than across it, and that axis alone would set a
  // pre-filter too fine for the lateral grain.
  if ((grain_vox.array() == 0.0f).any()) read_beside(input, c, radius_vox, excluded, grain_vox);
  float grain_mm = 0.0f;
  for (int axis = 0; axis < 3; ++axis)
    grain_mm = std::max(grain_mm, grain_vox[axis] * input.spacing_mm()[axis]);
  return grain_mm;
}

float sample_mm(const Volume& volume, const Vec3f& p_mm) {
  if (volume.empty()) throw std::invalid_argument("sample_mm: empty volume");
  const Trilinear t = trilinear(volume.dims(), volume.spacing_mm(), volume.origin_mm(), p_mm);
  switch (volume.type()) {
    case VoxelType::UInt8:
      return interpolate(volume.u8().data(), t);
    case VoxelType::UInt16:
      return interpolate(volume.u16().data(), t);
    case VoxelType::Float32:
      return interpolate(volume.f32().data(), t);
  }
  return 0.0f;
}

Vec3f sample_gradient_mm(const Gradient& gradient, const Vec3f& p_mm) {
  const Volume& gx = gradient.gx;
  if (gx.empty()) throw std::invalid_argument("sample_gradient_mm: empty gradient");
  if (gradient.gy.dims() != gx.dims() || gradient.gz.dims() != gx.dims())
    throw std::invalid_argument("sample_gradient_mm: gradient components differ in size");
  const Trilinear t = trilinear(gx.dims(), gx.spacing_mm(), gx.origin_mm(), p_mm);
  return Vec3f(interpolate(gx.f32().data(), t), interpolate(gradient.gy.f32().data(), t),
               interpolate(gradient.gz.f32().data(), t));
}

}  // namespace sonomesh::volume
