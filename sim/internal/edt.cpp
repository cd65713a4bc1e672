#include "sim/internal/edt.h"

#include <algorithm>
#include <limits>

#include "sim/internal/parallel.h"

namespace sonomesh::sim::internal {
namespace {

// 1D lower envelope of parabolas (Felzenszwalb & Huttenlocher 2012) on samples spaced `h` mm,
// plus the virtual background just outside both ends of the line. f and d have length n.
void envelope_1d(const float* f, float* d, int n, float h, std::vector<int>& v,
                 std::vector<float>& z) {
  v.resize(n);
  z.resize(n + 1);
  const float h2 = h * h;
  int k = 0;
  v[0] = 0;
  z[0] = -std::numeric_limits<float>::infinity();
  z[1] = std::numeric_limits<float>::infinity();
  // f is finite everywhere (pass 1 bounds it by the border), so the envelope stops at z[0] = -inf.
  auto meet = [&](int q, int p) {
    return ((f[q] + h2 * q * q) - (f[p] + h2 * p * p)) / (2.0f * h2 * (q - p));
  };
  for (int q = 1; q < n; ++q) {
    float s = meet(q, v[k]);
    while (s <= z[k]) {
      --k;
      s = meet(q, v[k]);
    }
    ++k;
    v[k] = q;
    z[k] = s;
    z[k + 1] = std::numeric_limits<float>::infinity();
  }
  k = 0;
  for (int q = 0; q < n; ++q) {
    while (z[k + 1] < q) ++k;
    const float dq = static_cast<float>(q - v[k]);
    const float border = h2 * static_cast<float>(std::min(q + 1, n - q)) * std::min(q + 1, n - q);
    d[q] = std::min(h2 * dq * dq + f[v[k]], border);
  }
}

}  // namespace

std::vector<float> squared_distance_inside_mm2(const volume::Volume& labels) {
  const auto& lab = labels.u8();
  const volume::Vec3i dims = labels.dims();
  const volume::Vec3f h = labels.spacing_mm();
  const int nx = dims.x(), ny = dims.y(), nz = dims.z();
  const std::size_t slice = static_cast<std::size_t>(nx) * ny;
  std::vector<float> d(lab.size());

  // Pass 1, x: exact 1D distance to background by two scans (no parabolas needed).
  parallel_chunks(0, nz, [&](int k0, int k1) {
    for (int k = k0; k < k1; ++k)
      for (int j = 0; j < ny; ++j) {
        const std::size_t row =
            static_cast<std::size_t>(k) * slice + static_cast<std::size_t>(j) * nx;
        int last = -1;  // virtual background left of the row
        for (int i = 0; i < nx; ++i) {
          if (lab[row + i] == 0) last = i;
          d[row + i] = static_cast<float>(i - last);
        }
        last = nx;
        for (int i = nx - 1; i >= 0; --i) {
          if (lab[row + i] == 0) last = i;
          const float g = std::min(d[row + i], static_cast<float>(last - i)) * h.x();
          d[row + i] = g * g;
        }
      }
  });

  // Passes 2 and 3, y then z: parabola envelopes on gathered lines.
  auto pass = [&](int axis) {
    const int n = dims[axis];
    const std::size_t stride = axis == 1 ? static_cast<std::size_t>(nx) : slice;
    const int outer = axis == 1 ? nz : ny;
    parallel_chunks(0, outer, [&](int o0, int o1) {
      std::vector<float> f(n), out(n), z;
      std::vector<int> v;
      for (int o = o0; o < o1; ++o)
        for (int i = 0; i < nx; ++i) {
          const std::size_t base = axis == 1 ? static_cast<std::size_t>(o) * slice + i
                                             : static_cast<std::size_t>(o) * nx + i;
          for (int t = 0; t < n; ++t) f[t] = d[base + t * stride];
          envelope_1d(f.data(), out.data(), n, h[axis], v, z);
          for (int t = 0; t < n; ++t) d[base + t * stride] = out[t];
        }
    });
  };
  pass(1);
  pass(2);
  return d;
}

}  // namespace sonomesh::sim::internal
