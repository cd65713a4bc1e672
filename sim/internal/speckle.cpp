#include "sim/internal/speckle.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <mutex>

#include "sim/internal/parallel.h"

namespace sonomesh::sim::internal {

std::uint64_t mix64(std::uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

GaussianPairs::GaussianPairs(std::uint64_t seed) : state_(mix64(seed)) {}

std::uint64_t GaussianPairs::next_bits() {
  // SplitMix64: one add and a finaliser per draw; passes BigCrush and is trivially portable.
  state_ += 0x9E3779B97F4A7C15ull;
  std::uint64_t z = state_;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

void GaussianPairs::next(float& a, float& b) {
  // One 64-bit draw gives both uniforms (24 bits each are all a float can use); float math keeps
  // the speckle field cheap. Tails reach ~5.8 sigma, plenty for an image quantised to 8 bits.
  constexpr float kTwoPi = 6.2831853f;
  const std::uint64_t bits = next_bits();
  const float u1 = (static_cast<float>(bits >> 40) + 1.0f) * 0x1.0p-24f;                // (0, 1]
  const float u2 = static_cast<float>((bits >> 16) & 0xFFFFFFu) * 0x1.0p-24f;          // [0, 1)
  const float r = std::sqrt(-2.0f * std::log(u1));
  a = r * std::cos(kTwoPi * u2);
  b = r * std::sin(kTwoPi * u2);
}

namespace {

using Taps = std::vector<float>;  // 2 r + 1 normalised Gaussian weights

// Radius of the taps for a sigma: 2 up to sigma 1 voxel (the simple mode's five taps, so its field
// keeps its bytes), else 2.5 sigma, where the weight has fallen below 5 %.
int taps_radius(float sigma_vox) {
  return sigma_vox <= 1.0f ? 2 : static_cast<int>(std::ceil(2.5f * sigma_vox));
}

Taps gaussian_taps(float sigma, int radius) {
  Taps w(2 * radius + 1);
  float sum = 0.0f;
  for (int t = -radius; t <= radius; ++t) {
    w[t + radius] = std::exp(-0.5f * static_cast<float>(t * t) / (sigma * sigma));
    sum += w[t + radius];
  }
  for (float& x : w) x /= sum;
  return w;
}

float sum_of_squares(const Taps& w) {
  float s = 0.0f;
  for (float x : w) s += x * x;
  return s;
}

// Smooths interleaved complex samples (re, im) along one axis, keeping only outputs whose whole
// kernel lies inside the input: the input is generated with a margin of kRadius per side, so the
// field is statistically the same at the border as in the middle.
std::vector<float> smooth_valid(const std::vector<float>& in, volume::Vec3i& dims, int axis,
                                const Taps& w) {
  const int kRadius = static_cast<int>(w.size() / 2);
  const volume::Vec3i in_dims = dims;
  volume::Vec3i out_dims = in_dims;
  out_dims[axis] -= 2 * kRadius;
  const std::size_t in_stride[3] = {1, static_cast<std::size_t>(in_dims.x()),
                                    static_cast<std::size_t>(in_dims.x()) * in_dims.y()};
  std::vector<float> out(2 * static_cast<std::size_t>(out_dims.x()) * out_dims.y() * out_dims.z());
  const int nx = out_dims.x(), ny = out_dims.y();
  parallel_chunks(0, out_dims.z(), [&](int k0, int k1) {
    for (int k = k0; k < k1; ++k)
      for (int j = 0; j < ny; ++j) {
        // Input index of output (0, j, k): the axis coordinate is offset by kRadius, then back.
        const std::size_t in_row = static_cast<std::size_t>(k) * in_stride[2] + static_cast<std::size_t>(j) * in_stride[1];
        const std::size_t out_row = (static_cast<std::size_t>(k) * ny + j) * nx;
        for (int i = 0; i < nx; ++i) {
          const std::size_t centre = in_row + static_cast<std::size_t>(i) * in_stride[0] + kRadius * in_stride[axis];
          float re = 0.0f, im = 0.0f;
          for (int t = -kRadius; t <= kRadius; ++t) {
            const std::size_t src = centre + static_cast<std::ptrdiff_t>(t) * static_cast<std::ptrdiff_t>(in_stride[axis]);
            re += w[t + kRadius] * in[2 * src];
            im += w[t + kRadius] * in[2 * src + 1];
          }
          out[2 * (out_row + i)] = re;
          out[2 * (out_row + i) + 1] = im;
        }
      }
  });
  dims = out_dims;
  return out;
}

std::shared_ptr<const std::vector<float>> build_field(std::uint32_t seed, const volume::Vec3i& dims,
                                                      const Vec3f& sigma_vox) {
  const Taps wx = gaussian_taps(sigma_vox.x(), taps_radius(sigma_vox.x()));
  const Taps wy = gaussian_taps(sigma_vox.y(), taps_radius(sigma_vox.y()));
  const Taps wz = gaussian_taps(sigma_vox.z(), taps_radius(sigma_vox.z()));
  const volume::Vec3i radius(static_cast<int>(wx.size() / 2), static_cast<int>(wy.size() / 2),
                             static_cast<int>(wz.size() / 2));
  volume::Vec3i padded = dims + 2 * radius;
  const std::size_t slice = static_cast<std::size_t>(padded.x()) * padded.y();
  std::vector<float> a(2 * slice * padded.z());
  // One generator per padded z slice, seeded from (seed, k): the same bytes for any thread count.
  parallel_chunks(0, padded.z(), [&](int k0, int k1) {
    for (int k = k0; k < k1; ++k) {
      GaussianPairs gauss(mix64(static_cast<std::uint64_t>(seed) << 32) ^ static_cast<std::uint64_t>(k));
      float* p = a.data() + 2 * slice * k;
      for (std::size_t t = 0; t < slice; ++t) gauss.next(p[2 * t], p[2 * t + 1]);
    }
  });
  a = smooth_valid(a, padded, 0, wx);
  a = smooth_valid(a, padded, 1, wy);
  a = smooth_valid(a, padded, 2, wz);
  // Each smoothed component has variance sum(w^2); |c| is then Rayleigh with mean
  // sigma * sqrt(pi / 2). Dividing by that mean makes the field a unit-mean multiplier.
  const float sigma = std::sqrt(sum_of_squares(wx) * sum_of_squares(wy) * sum_of_squares(wz));
  const float inv_mean = 1.0f / (sigma * std::sqrt(3.14159265358979f / 2.0f));
  const std::size_t out_slice = static_cast<std::size_t>(dims.x()) * dims.y();
  auto field = std::make_shared<std::vector<float>>(out_slice * dims.z());
  parallel_chunks(0, dims.z(), [&](int k0, int k1) {
    for (std::size_t t = out_slice * k0; t < out_slice * k1; ++t)
      (*field)[t] = std::sqrt(a[2 * t] * a[2 * t] + a[2 * t + 1] * a[2 * t + 1]) * inv_mean;
  });
  return field;
}

}  // namespace

std::shared_ptr<const std::vector<float>> speckle_field(std::uint32_t seed, const volume::Vec3i& dims,
                                                        const Vec3f& sigma_vox) {
  // Two fields are kept: a simple-mode and an echo-mode stream alternate between at most two.
  struct Entry {
    std::uint32_t seed = 0;
    volume::Vec3i dims = volume::Vec3i::Zero();
    Vec3f sigma = Vec3f::Zero();
    std::shared_ptr<const std::vector<float>> field;
  };
  static std::mutex mutex;
  static Entry cache[2];
  static int next_slot = 0;
  std::lock_guard lock(mutex);
  for (const Entry& e : cache)
    if (e.field && e.seed == seed && e.dims == dims && e.sigma == sigma_vox) return e.field;
  Entry& slot = cache[next_slot];
  next_slot = 1 - next_slot;
  slot = Entry{seed, dims, sigma_vox, build_field(seed, dims, sigma_vox)};
  return slot.field;
}

}  // namespace sonomesh::sim::internal
