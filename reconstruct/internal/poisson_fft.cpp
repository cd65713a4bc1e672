// Kazhdan's FFT reconstruction (Kazhdan, "Reconstruction of Solid Models from Oriented Point
// Sets", SGP 2005), as method.md §5 fixes it.
//
// The samples' outward normals, weighted by their area, are splatted trilinearly as a vector
// field V (a density: divided by the cell volume, so χ comes out close to 1 inside and 0 outside
// up to a constant). The indicator's gradient is the smoothed inward normal field, ∇χ = −V, so
// Δχ = −∇·V and in frequency space χ̂(k) = i k·V̂(k) / |k|²: with this sign χ is larger inside.
// The Gaussian smoothing of V (sigma ≈ 1 cell) is a multiplication by exp(−σ²|k|²/2).

#include <algorithm>
#include <cmath>
#include <complex>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <string>

#include "mesh/parallel.h"
#include "reconstruct/internal/fft_plans.h"
#include "reconstruct/reconstruct.h"

namespace sonomesh::reconstruct {
namespace {

// The grid size of an axis needing n cells: the coarse ladder, so a breathing target reuses its
// FFTW plans; the fine-grained friendly size when the ladder step would pass max_grid_dim, so the
// cap does not coarsen the cell more than before.
int grid_size(int n, int max_grid_dim) {
  const int coarse = internal::fft_ladder_size(n);
  return coarse > 0 && coarse <= max_grid_dim ? coarse : internal::fft_friendly_size(n);
}

// The finer cell a thin feature needs, rounded down to cell_mm·2^(−k/8) (steps of 9 %): a feature
// whose width wavers by a few percent between volumes keeps its cell, hence its grid size.
float quantized_cell_mm(float wanted_mm, float cell_mm) {
  if (!(wanted_mm < cell_mm)) return cell_mm;
  const int k = int(std::ceil(8.0 * std::log2(double(cell_mm) / double(wanted_mm)) - 1e-6));
  return float(double(cell_mm) * std::exp2(-double(k) / 8.0));
}

void check(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument("poisson_indicator: " + what);
}

// Signed frequency (radians per mm) of FFT bin m on an axis of n bins.
inline float wave_number(int m, int n, float cell_mm) {
  const int s = m <= n / 2 ? m : m - n;
  return 2.0f * std::numbers::pi_v<float> * float(s) / (float(n) * cell_mm);
}

struct Grid {
  std::array<int, 3> dims{};
  Vec3f origin_mm;
  float cell_mm = 0.0f;
  std::size_t size() const { return std::size_t(dims[0]) * dims[1] * dims[2]; }
  std::size_t complex_size() const { return std::size_t(dims[0] / 2 + 1) * dims[1] * dims[2]; }
};

Grid make_grid(const PointCloud& s, const PoissonOptions& o, float cell_mm) {
  Eigen::Vector3d lo = s.points.front().cast<double>(), hi = lo;
  for (const auto& p : s.points) {
    lo = lo.cwiseMin(p.cast<double>());
    hi = hi.cwiseMax(p.cast<double>());
  }
  const double extent = (hi - lo).maxCoeff();
  check(extent > 0.0, "the samples span no volume (all points coincide)");
  Grid g;
  g.cell_mm = cell_mm;
  for (;;) {
    // The FFT is periodic: the margin keeps the far side of the grid from feeding back. At least
    // a few cells so the Gaussian and the splat stay clear of the wrap-around too.
    const double pad = std::max(double(o.padding_fraction) * extent, 4.0 * g.cell_mm);
    bool fits = true;
    for (int a = 0; a < 3; ++a) {
      const double span = hi[a] - lo[a] + 2.0 * pad;
      g.dims[a] = grid_size(int(std::ceil(span / g.cell_mm)) + 1, o.max_grid_dim);
      fits = fits && g.dims[a] <= o.max_grid_dim;
    }
    if (fits) break;
    g.cell_mm *= 1.1f;  // too fine for max_grid_dim: coarsen until it fits
  }
  const Eigen::Vector3d centre = 0.5 * (lo + hi);
  for (int a = 0; a < 3; ++a) g.origin_mm[a] = float(centre[a] - 0.5 * (g.dims[a] - 1) * g.cell_mm);
  return g;
}

// Trilinear weights of p in the grid: base index and fractions.
struct Stencil {
  std::size_t base;
  float fx, fy, fz;
};
inline Stencil stencil(const Grid& g, const Vec3f& p_mm) {
  const Vec3f u = (p_mm - g.origin_mm) / g.cell_mm;
  int i[3];
  float f[3];
  for (int a = 0; a < 3; ++a) {
    const float fl = std::floor(u[a]);
    i[a] = std::clamp(int(fl), 0, g.dims[a] - 2);
    f[a] = std::clamp(u[a] - float(i[a]), 0.0f, 1.0f);
  }
  return {std::size_t(i[0]) + std::size_t(g.dims[0]) * (i[1] + std::size_t(g.dims[1]) * i[2]), f[0],
          f[1], f[2]};
}

void splat(const Grid& g, const PointCloud& s, int axis, float* field) {
  const std::size_t sy = g.dims[0], sz = sy * g.dims[1];
  const float inv_cell_volume = 1.0f / (g.cell_mm * g.cell_mm * g.cell_mm);
  for (std::size_t n = 0; n < s.points.size(); ++n) {
    const float w = s.area_mm2[n] * s.normals[n][axis] * inv_cell_volume;
    if (w == 0.0f) continue;
    const Stencil st = stencil(g, s.points[n]);
    for (int c = 0; c < 8; ++c) {
      const float wx = (c & 1) ? st.fx : 1.0f - st.fx;
      const float wy = (c & 2) ? st.fy : 1.0f - st.fy;
      const float wz = (c & 4) ? st.fz : 1.0f - st.fz;
      field[st.base + (c & 1) + ((c >> 1) & 1) * sy + ((c >> 2) & 1) * sz] += w * wx * wy * wz;
    }
  }
}

float sample(const Grid& g, const float* field, const Vec3f& p_mm) {
  const std::size_t sy = g.dims[0], sz = sy * g.dims[1];
  const Stencil st = stencil(g, p_mm);
  float v = 0.0f;
  for (int c = 0; c < 8; ++c) {
    const float wx = (c & 1) ? st.fx : 1.0f - st.fx;
    const float wy = (c & 2) ? st.fy : 1.0f - st.fy;
    const float wz = (c & 4) ? st.fz : 1.0f - st.fz;
    v += field[st.base + (c & 1) + ((c >> 1) & 1) * sy + ((c >> 2) & 1) * sz] * wx * wy * wz;
  }
  return v;
}

void check_inputs(const PointCloud& s, const PoissonOptions& o) {
  check(!s.points.empty(), "no samples");
  check(s.normals.size() == s.points.size(), "normals.size() != points.size()");
  check(s.area_mm2.size() == s.points.size(), "area_mm2.size() != points.size()");
  for (std::size_t n = 0; n < s.points.size(); ++n)
    check(s.points[n].allFinite() && s.normals[n].allFinite() && std::isfinite(s.area_mm2[n]) &&
              s.area_mm2[n] >= 0.0f,
          "sample " + std::to_string(n) + " is not finite (or has a negative area)");
  double total_area = 0.0;
  for (float a : s.area_mm2) total_area += a;
  check(total_area > 0.0, "the samples carry no area (all area_mm2 are zero)");
  check(std::isfinite(o.cell_mm) && o.cell_mm > 0.0f, "cell_mm must be positive");
  check(o.padding_fraction >= 0.1f && o.padding_fraction <= 2.0f,
        "padding_fraction must be in [0.1, 2] (the FFT is periodic)");
  check(o.smoothing_cells >= 0.0f && o.smoothing_cells <= 8.0f,
        "smoothing_cells must be in [0, 8]");
  check(o.min_feature_cells >= 0.0f && o.min_feature_cells <= 16.0f,
        "min_feature_cells must be in [0, 16]");
  check(o.min_cell_fraction >= 0.1f && o.min_cell_fraction <= 1.0f,
        "min_cell_fraction must be in [0.1, 1]");
  check(o.max_grid_dim >= 16 && o.max_grid_dim <= 1024, "max_grid_dim must be in [16, 1024]");
  check(o.fft_threads >= 1 && o.fft_threads <= 64, "fft_threads must be in [1, 64]");
}

// The cell the grid uses: the requested one, or a finer one where the cloud describes a thin
// feature. A cell of one voxel blurs χ over ~2.5 voxels, which closes a tunnel a 2.5-voxel needle
// leaves; refining everywhere would cost up to 27x the FFT work, and most targets have no such
// feature. The area a feature must cover is in cells of the requested grid: 8 cells² is less than
// the wall of a tunnel 2 cells wide through a wall 2 cells thick (π·2·2 ≈ 12.6 cells²) and more
// than a few stray pairs. Sets feature_mm to the narrowest feature (infinity when none).
float chosen_cell_mm(const PointCloud& s, const PoissonOptions& o, float& feature_mm) {
  float cell_mm = o.cell_mm;
  feature_mm = std::numeric_limits<float>::infinity();
  if (o.min_feature_cells > 0.0f && o.min_cell_fraction < 1.0f) {
    constexpr float kFeatureAreaCells = 8.0f;
    feature_mm = narrowest_feature_mm(s, o.min_feature_cells * o.cell_mm,
                                      kFeatureAreaCells * o.cell_mm * o.cell_mm);
    if (std::isfinite(feature_mm))
      cell_mm = std::max(quantized_cell_mm(feature_mm / o.min_feature_cells, o.cell_mm),
                         o.min_cell_fraction * o.cell_mm);
  }
  return cell_mm;
}

// The frequency bins of the grid's real-to-complex transform with their wave numbers and the
// Gaussian factors: exp(−σ²|k|²/2) separates into three 1D tables, which keeps exp() and divisions
// out of the per-bin loops.
struct Bins {
  std::array<int, 3> d{};
  int hx = 0, threads = 1;
  std::array<std::vector<float>, 3> kv, gauss;

  Bins(const Grid& g, float sigma_mm, int threads_)
      : d(g.dims), hx(g.dims[0] / 2 + 1), threads(threads_) {
    for (int a = 0; a < 3; ++a) {
      const int n = a == 0 ? hx : d[a];
      kv[a].resize(n);
      gauss[a].resize(n);
      for (int m = 0; m < n; ++m) {
        kv[a][m] = wave_number(m, d[a], g.cell_mm);
        gauss[a][m] = std::exp(-0.5f * sigma_mm * sigma_mm * kv[a][m] * kv[a][m]);
      }
    }
  }
  // Visits every frequency bin with its wave vector: fn(index, kx, ky, kz, x, y, z).
  template <class Fn>
  void for_each(Fn&& fn) const {
    mesh::parallel_chunks(0, d[2], threads, [&](int z0, int z1, int) {
      for (int z = z0; z < z1; ++z) {
        for (int y = 0; y < d[1]; ++y) {
          const std::size_t row = (std::size_t(z) * d[1] + y) * hx;
          for (int x = 0; x < hx; ++x) fn(row + x, kv[0][x], kv[1][y], kv[2][z], x, y, z);
        }
      }
    });
  }
  // A derivative of a real signal has no meaningful Nyquist component: it is zeroed.
  bool nyquist(int m, int axis) const { return d[axis] % 2 == 0 && m == d[axis] / 2; }
};

// spectrum = i k·V̂, each axis splatted and transformed on its own.
void spectral_divergence(const Grid& g, const PointCloud& s, const PoissonOptions& o,
                         const Bins& bins, internal::FftBuffer& real,
                         internal::FftBuffer& spectrum) {
  const std::size_t n_real = g.size(), n_cplx = g.complex_size();
  internal::FftBuffer acc(2 * n_cplx);
  std::complex<float>* a = acc.complex();
  for (int axis = 0; axis < 3; ++axis) {
    std::fill(real.data(), real.data() + n_real, 0.0f);
    splat(g, s, axis, real.data());
    internal::fft_forward(g.dims, real.data(), spectrum.complex(), bins.threads,
                          o.measure_fft_plans);
    const std::complex<float>* c = spectrum.complex();
    bins.for_each([&](std::size_t i, float kx, float ky, float kz, int x, int y, int z) {
      const int m[3] = {x, y, z};
      const float k = bins.nyquist(m[axis], axis) ? 0.0f : (axis == 0 ? kx : axis == 1 ? ky : kz);
      const std::complex<float> term = std::complex<float>(0.0f, k) * c[i];  // i k_a V̂_a
      a[i] = axis == 0 ? term : a[i] + term;
    });
  }
  std::copy(a, a + n_cplx, spectrum.complex());
}

// spectrum = the transform of ∇·V by central differences on the grid.
void grid_divergence(const Grid& g, const PointCloud& s, const PoissonOptions& o, int threads,
                     internal::FftBuffer& real, internal::FftBuffer& spectrum) {
  const std::array<int, 3>& d = g.dims;
  const std::size_t n_real = g.size();
  internal::FftBuffer div(n_real);
  std::fill(div.data(), div.data() + n_real, 0.0f);
  const std::size_t stride[3] = {1, std::size_t(d[0]), std::size_t(d[0]) * d[1]};
  const float inv_2h = 0.5f / g.cell_mm;
  for (int axis = 0; axis < 3; ++axis) {
    std::fill(real.data(), real.data() + n_real, 0.0f);
    splat(g, s, axis, real.data());
    const float* v = real.data();
    float* dv = div.data();
    mesh::parallel_chunks(0, d[2], threads, [&](int z0, int z1, int) {
      for (int z = z0; z < z1; ++z)
        for (int y = 0; y < d[1]; ++y)
          for (int x = 0; x < d[0]; ++x) {
            const int c[3] = {x, y, z};
            // The splat never reaches the outermost cells (padding), so clamping is exact.
            if (c[axis] == 0 || c[axis] == d[axis] - 1) continue;
            const std::size_t p = x + stride[1] * y + stride[2] * z;
            dv[p] += (v[p + stride[axis]] - v[p - stride[axis]]) * inv_2h;
          }
    });
  }
  internal::fft_forward(d, div.data(), spectrum.complex(), threads, o.measure_fft_plans);
}

// The indicator's iso value: its area-weighted mean at the samples.
float iso_at_samples(const Grid& g, const PointCloud& s, const float* chi) {
  double weighted = 0.0, total = 0.0;
  for (std::size_t n = 0; n < s.points.size(); ++n) {
    weighted += double(s.area_mm2[n]) * sample(g, chi, s.points[n]);
    total += s.area_mm2[n];
  }
  return total > 0.0 ? float(weighted / total) : 0.0f;
}

}  // namespace

IndicatorGrid poisson_indicator(const PointCloud& s, const PoissonOptions& o) {
  check_inputs(s, o);
  float feature_mm = 0.0f;
  const Grid g = make_grid(s, o, chosen_cell_mm(s, o, feature_mm));
  const std::array<int, 3>& d = g.dims;
  const std::size_t n_real = g.size(), n_cplx = g.complex_size();
  internal::FftBuffer real(n_real), spectrum(2 * n_cplx);
  const int threads = std::min(o.fft_threads, mesh::default_threads());
  const float norm = 1.0f / float(n_real);  // FFTW's transforms are unnormalised
  const Bins bins(g, o.smoothing_cells * g.cell_mm, threads);

  if (o.divergence == DivergenceMode::Spectral)
    spectral_divergence(g, s, o, bins, real, spectrum);
  else
    grid_divergence(g, s, o, threads, real, spectrum);

  // χ̂ = (i k·V̂) / |k|² · exp(−σ²|k|²/2), χ̂(0) = 0.
  std::complex<float>* c = spectrum.complex();
  bins.for_each([&](std::size_t i, float kx, float ky, float kz, int x, int y, int z) {
    const float kk = kx * kx + ky * ky + kz * kz;
    c[i] = kk > 0.0f ? c[i] * (bins.gauss[0][x] * bins.gauss[1][y] * bins.gauss[2][z] * norm / kk)
                     : 0.0f;
  });
  internal::fft_inverse(d, c, real.data(), threads, o.measure_fft_plans);

  IndicatorGrid out;
  out.iso = iso_at_samples(g, s, real.data());
  out.cell_mm = g.cell_mm;
  out.feature_mm = feature_mm;
  out.chi = volume::Volume(volume::Vec3i(d[0], d[1], d[2]), Vec3f::Constant(g.cell_mm), g.origin_mm,
                           volume::VoxelType::Float32);
  std::copy(real.data(), real.data() + n_real, out.chi.f32().begin());
  return out;
}

}  // namespace sonomesh::reconstruct
