// Volume type, smoothing, gradients and sampling.
#include "volume/volume.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

using namespace sonomesh::volume;

TEST(Volume, IndexAndMillimetresMapBothWays) {
  const Volume v(Vec3i(4, 5, 6), Vec3f(0.5f, 1.0f, 2.0f), Vec3f(10.0f, 20.0f, 30.0f),
                 VoxelType::UInt8);
  const Vec3f p = v.index_to_mm(Vec3f(1, 2, 3));
  EXPECT_FLOAT_EQ(p.x(), 10.5f);
  EXPECT_FLOAT_EQ(p.y(), 22.0f);
  EXPECT_FLOAT_EQ(p.z(), 36.0f);
  EXPECT_TRUE(v.mm_to_index(p).isApprox(Vec3f(1, 2, 3)));
  EXPECT_EQ(v.linear_index(1, 2, 3), std::size_t{1 + 4 * (2 + 5 * 3)});
}

namespace {

// Mass-weighted mean and variance (in voxels) of a non-negative volume along each axis.
void moments(const Volume& v, Vec3d& mean, Vec3d& var, double& mass) {
  mass = 0;
  mean.setZero();
  var.setZero();
  const Vec3i d = v.dims();
  for (int k = 0; k < d.z(); ++k)
    for (int j = 0; j < d.y(); ++j)
      for (int i = 0; i < d.x(); ++i) {
        const double w = v.value(i, j, k);
        mass += w;
        mean += w * Vec3d(i, j, k);
      }
  mean /= mass;
  for (int k = 0; k < d.z(); ++k)
    for (int j = 0; j < d.y(); ++j)
      for (int i = 0; i < d.x(); ++i) {
        const double w = v.value(i, j, k);
        const Vec3d r = Vec3d(i, j, k) - mean;
        var += w * r.cwiseProduct(r);
      }
  var /= mass;
}

Volume linear_ramp(const Vec3i& dims, const Vec3f& spacing, const Vec3f& origin, const Vec3f& a,
                   float c) {
  Volume v(dims, spacing, origin, VoxelType::Float32);
  for (int k = 0; k < dims.z(); ++k)
    for (int j = 0; j < dims.y(); ++j)
      for (int i = 0; i < dims.x(); ++i)
        v.f32()[v.linear_index(i, j, k)] = a.dot(v.index_to_mm(Vec3f(i, j, k))) + c;
  return v;
}

}  // namespace

TEST(Smoothing, ImpulseSpreadsWithVarianceSigmaVoxSquaredOnAnisotropicGrid) {
  // sigma 2 mm on spacing (0.5, 1, 2) mm is 4, 2 and 1 voxels.
  Volume v(Vec3i(49, 41, 33), Vec3f(0.5f, 1.0f, 2.0f), Vec3f(-3, 2, 7), VoxelType::Float32);
  v.f32()[v.linear_index(24, 20, 16)] = 1000.0f;
  const Volume s = smooth_gaussian(v, 2.0f);
  ASSERT_EQ(s.type(), VoxelType::Float32);
  EXPECT_EQ(s.dims(), v.dims());
  EXPECT_EQ(s.spacing_mm(), v.spacing_mm());
  EXPECT_EQ(s.origin_mm(), v.origin_mm());
  Vec3d mean, var;
  double mass;
  moments(s, mean, var, mass);
  EXPECT_NEAR(mass, 1000.0, 0.1);
  EXPECT_NEAR(mean.x(), 24.0, 1e-3);
  EXPECT_NEAR(mean.y(), 20.0, 1e-3);
  EXPECT_NEAR(mean.z(), 16.0, 1e-3);
  EXPECT_NEAR(var.x(), 16.0, 16.0 * 0.02);
  EXPECT_NEAR(var.y(), 4.0, 4.0 * 0.02);
  EXPECT_NEAR(var.z(), 1.0, 1.0 * 0.02);
  // Separable Gaussian: the profile along x through the peak is a Gaussian of sigma 4 voxels.
  const float peak = s.value(24, 20, 16);
  EXPECT_NEAR(s.value(28, 20, 16) / peak, std::exp(-0.5f), 0.01f);
  EXPECT_NEAR(s.value(24, 22, 16) / peak, std::exp(-0.5f), 0.01f);
  EXPECT_NEAR(s.value(24, 20, 17) / peak, std::exp(-0.5f), 0.02f);
}

TEST(Smoothing, LinearRampIsUnchangedAwayFromBordersAndIntegerTypesMatchFloat) {
  const Vec3i dims(40, 36, 30);
  const Volume ramp =
      linear_ramp(dims, Vec3f(1, 1, 1), Vec3f(0, 0, 0), Vec3f(1.5f, 2.0f, 2.5f), 10.0f);
  const Volume s = smooth_gaussian(ramp, 1.5f);
  const int r = 7;  // > 4 sigma
  for (int k = r; k < dims.z() - r; k += 3)
    for (int j = r; j < dims.y() - r; j += 3)
      for (int i = r; i < dims.x() - r; i += 3)
        ASSERT_NEAR(s.value(i, j, k), ramp.value(i, j, k), 1e-3f) << i << " " << j << " " << k;

  Volume u8(dims, Vec3f(1, 1, 1), Vec3f(0, 0, 0), VoxelType::UInt8);
  Volume u16(dims, Vec3f(1, 1, 1), Vec3f(0, 0, 0), VoxelType::UInt16);
  Volume f(dims, Vec3f(1, 1, 1), Vec3f(0, 0, 0), VoxelType::Float32);
  std::mt19937 rng(3);
  for (std::size_t n = 0; n < f.voxel_count(); ++n) {
    const auto val = static_cast<std::uint8_t>(rng() % 256);
    u8.u8()[n] = val;
    u16.u16()[n] = val;
    f.f32()[n] = val;
  }
  const Volume a = smooth_gaussian(u8, 1.0f), b = smooth_gaussian(u16, 1.0f),
               c = smooth_gaussian(f, 1.0f);
  for (std::size_t n = 0; n < f.voxel_count(); n += 97) {
    ASSERT_NEAR(a.f32()[n], c.f32()[n], 1e-3f);
    ASSERT_NEAR(b.f32()[n], c.f32()[n], 1e-3f);
  }
  // Replicated borders: a constant volume stays constant everywhere, corners included.
  Volume constant(Vec3i(9, 8, 7), Vec3f(1, 1, 1), Vec3f(0, 0, 0), VoxelType::UInt8);
  std::fill(constant.u8().begin(), constant.u8().end(), std::uint8_t{42});
  const Volume sc = smooth_gaussian(constant, 3.0f);
  for (float x : sc.f32()) ASSERT_NEAR(x, 42.0f, 1e-3f);
}

TEST(Smoothing, NonPositiveSigmaOnlyConverts) {
  Volume v(Vec3i(5, 4, 3), Vec3f(1, 1, 1), Vec3f(0, 0, 0), VoxelType::UInt16);
  v.u16()[7] = 300;
  const Volume s = smooth_gaussian(v, 0.0f);
  ASSERT_EQ(s.type(), VoxelType::Float32);
  EXPECT_EQ(s.f32()[7], 300.0f);
  EXPECT_EQ(s.f32()[8], 0.0f);
  EXPECT_THROW(smooth_gaussian(Volume{}, 1.0f), std::invalid_argument);
}

namespace {

// The sampled, normalised Gaussian of processing.cpp: radius max(1, ceil(4 sigma)), one tap
// below 1e-3 voxels.
std::vector<double> reference_kernel(double sigma_vox) {
  if (sigma_vox < 1e-3) return {1.0};
  const int radius = std::max(1, static_cast<int>(std::ceil(4.0 * sigma_vox)));
  std::vector<double> k(2 * radius + 1);
  double sum = 0.0;
  for (int i = -radius; i <= radius; ++i)
    sum += k[i + radius] = std::exp(-0.5 * i * i / (sigma_vox * sigma_vox));
  for (double& w : k) w /= sum;
  return k;
}

// Straightforward 3D correlation with the product kernel, indices clamped (replicated borders).
std::vector<double> reference_smooth(const Volume& v, float sigma_mm) {
  const Vec3i d = v.dims();
  const std::vector<double> kx = reference_kernel(sigma_mm / v.spacing_mm().x());
  const std::vector<double> ky = reference_kernel(sigma_mm / v.spacing_mm().y());
  const std::vector<double> kz = reference_kernel(sigma_mm / v.spacing_mm().z());
  const int rx = static_cast<int>(kx.size()) / 2, ry = static_cast<int>(ky.size()) / 2,
            rz = static_cast<int>(kz.size()) / 2;
  std::vector<double> out(v.voxel_count());
  for (int k = 0; k < d.z(); ++k)
    for (int j = 0; j < d.y(); ++j)
      for (int i = 0; i < d.x(); ++i) {
        double acc = 0.0;
        for (int c = -rz; c <= rz; ++c)
          for (int b = -ry; b <= ry; ++b)
            for (int a = -rx; a <= rx; ++a)
              acc += kx[a + rx] * ky[b + ry] * kz[c + rz] *
                     v.value(std::clamp(i + a, 0, d.x() - 1), std::clamp(j + b, 0, d.y() - 1),
                             std::clamp(k + c, 0, d.z() - 1));
        out[v.linear_index(i, j, k)] = acc;
      }
  return out;
}

}  // namespace

TEST(Smoothing, MatchesNaiveTripleLoopWithReplicatedBordersForUInt8AndFloat32) {
  // sigma 1 mm on (1, 0.8, 1.5) mm is 1, 1.25 and 0.67 voxels. On (4, 4, 0.15) mm it is 0.25
  // voxels in x and y (3 taps) and 6.7 in z: 55 taps (> 17 slices, so mostly border), which takes
  // the sepFilter2D path of the z pass instead of filter2D.
  for (const Vec3f& spacing : {Vec3f(1.0f, 0.8f, 1.5f), Vec3f(4.0f, 4.0f, 0.15f)}) {
    Volume u8(Vec3i(24, 20, 17), spacing, Vec3f(1, -2, 3), VoxelType::UInt8);
    Volume f32(u8.dims(), spacing, u8.origin_mm(), VoxelType::Float32);
    std::mt19937 rng(11);
    for (std::size_t n = 0; n < u8.voxel_count(); ++n) {
      u8.u8()[n] = static_cast<std::uint8_t>(rng());
      f32.f32()[n] = static_cast<float>(rng() % 100000) / 391.0f;  // 0 .. 255.7, not integers
    }
    for (const Volume* v : {&u8, &f32}) {
      const Volume s = smooth_gaussian(*v, 1.0f);
      const std::vector<double> ref = reference_smooth(*v, 1.0f);
      for (std::size_t n = 0; n < ref.size(); ++n)
        ASSERT_NEAR(s.f32()[n], ref[n], 1e-4) << "voxel " << n << " spacing z " << spacing.z();
    }
  }
}

TEST(Gradient, LinearRampIsExactInMillimetresIncludingBorders) {
  const Vec3f a(2.0f, 3.0f, -1.0f);
  const Volume ramp =
      linear_ramp(Vec3i(12, 10, 8), Vec3f(0.5f, 1.25f, 2.0f), Vec3f(-4, 1, 3), a, 5.0f);
  const Gradient g = central_gradient(ramp);
  ASSERT_EQ(g.gx.dims(), ramp.dims());
  for (std::size_t n = 0; n < ramp.voxel_count(); ++n) {
    ASSERT_NEAR(g.gx.f32()[n], 2.0f, 1e-3f);
    ASSERT_NEAR(g.gy.f32()[n], 3.0f, 1e-3f);
    ASSERT_NEAR(g.gz.f32()[n], -1.0f, 1e-3f);
  }
  // A quadratic along x: central differences are exact inside, one-sided at the ends.
  Volume q(Vec3i(6, 2, 1), Vec3f(1, 1, 1), Vec3f(0, 0, 0), VoxelType::UInt8);
  for (int i = 0; i < 6; ++i)
    q.u8()[q.linear_index(i, 0, 0)] = q.u8()[q.linear_index(i, 1, 0)] = i * i;
  const Gradient gq = central_gradient(q);
  EXPECT_FLOAT_EQ(gq.gx.value(0, 0, 0), 1.0f);
  EXPECT_FLOAT_EQ(gq.gx.value(3, 0, 0), 6.0f);
  EXPECT_FLOAT_EQ(gq.gx.value(5, 1, 0), 9.0f);
  EXPECT_FLOAT_EQ(gq.gy.value(3, 0, 0), 0.0f);
  EXPECT_FLOAT_EQ(gq.gz.value(3, 0, 0), 0.0f);  // single slice
}

TEST(Sampling, TrilinearIsExactOnLinearFunctionsAndClampsOutside) {
  const Vec3f a(0.7f, -1.3f, 2.1f);
  const Volume ramp =
      linear_ramp(Vec3i(10, 9, 8), Vec3f(0.5f, 1.0f, 1.5f), Vec3f(1, -2, 3), a, 4.0f);
  const Gradient g = central_gradient(ramp);
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> ux(0, 9), uy(0, 8), uz(0, 7);
  for (int n = 0; n < 500; ++n) {
    const Vec3f p = ramp.index_to_mm(Vec3f(ux(rng), uy(rng), uz(rng)));
    ASSERT_NEAR(sample_mm(ramp, p), a.dot(p) + 4.0f, 1e-3f);
    ASSERT_TRUE(sample_gradient_mm(g, p).isApprox(a, 1e-4f));
  }
  // Outside: clamped to the box of voxel centres.
  const Vec3f far = ramp.max_mm() + Vec3f(10, 20, 30);
  EXPECT_NEAR(sample_mm(ramp, far), a.dot(ramp.max_mm()) + 4.0f, 1e-3f);
  const Vec3f below = ramp.min_mm() - Vec3f(5, 0, 0) + Vec3f(0, 1, 1.5f);
  EXPECT_NEAR(sample_mm(ramp, below), a.dot(ramp.min_mm() + Vec3f(0, 1, 1.5f)) + 4.0f, 1e-3f);
  EXPECT_TRUE(sample_gradient_mm(g, far).isApprox(a, 1e-4f));
  // Exact at voxel centres, for every voxel type.
  Volume u16(Vec3i(3, 3, 3), Vec3f(2, 2, 2), Vec3f(0, 0, 0), VoxelType::UInt16);
  u16.u16()[u16.linear_index(2, 1, 0)] = 1000;
  EXPECT_FLOAT_EQ(sample_mm(u16, Vec3f(4, 2, 0)), 1000.0f);
  EXPECT_FLOAT_EQ(sample_mm(u16, Vec3f(3, 2, 0)), 500.0f);
  // Degenerate single-voxel axes still sample.
  Volume flat(Vec3i(4, 4, 1), Vec3f(1, 1, 1), Vec3f(0, 0, 0), VoxelType::UInt8);
  flat.u8()[flat.linear_index(1, 1, 0)] = 8;
  EXPECT_FLOAT_EQ(sample_mm(flat, Vec3f(1.5f, 1.0f, 3.0f)), 4.0f);
}

// The box's voxels as the whole volume's smoothing gives them, at the faces and inside; the rest
// untouched. (Anisotropic spacing: a kernel of its own length per axis.)
TEST(Smoothing, ABoxIsSmoothedAsTheWholeVolumeAndNothingElse) {
  Volume v(Vec3i(40, 36, 30), Vec3f(0.5f, 0.4f, 0.7f), Vec3f(1, 2, 3), VoxelType::UInt8);
  std::mt19937 rng(5);
  for (auto& x : v.u8()) x = static_cast<std::uint8_t>(rng());
  const Volume whole = smooth_gaussian(v, 1.1f);
  for (const auto& [lo, hi] : {std::pair(Vec3i(5, 7, 9), Vec3i(31, 22, 20)),
                               std::pair(Vec3i(-4, 0, 12), Vec3i(12, 50, 30))}) {
    Volume out(v.dims(), v.spacing_mm(), v.origin_mm(), VoxelType::Float32);
    std::fill(out.f32().begin(), out.f32().end(), -1.0f);
    smooth_gaussian(v, 1.1f, lo, hi, out);
    int inside = 0;
    for (int k = 0; k < 30; ++k)
      for (int j = 0; j < 36; ++j)
        for (int i = 0; i < 40; ++i) {
          const std::size_t at = v.linear_index(i, j, k);
          const Vec3i p(i, j, k);
          if ((p.array() >= lo.array()).all() && (p.array() < hi.array()).all()) {
            ++inside;
            ASSERT_NEAR(out.f32()[at], whole.f32()[at], 1e-4f) << i << " " << j << " " << k;
          } else {
            ASSERT_EQ(out.f32()[at], -1.0f) << i << " " << j << " " << k;
          }
        }
    EXPECT_GT(inside, 1000);
  }
}

TEST(Smoothing, IntoOverloadsReuseBuffersAndMatchFreshResults) {
  Volume v(Vec3i(20, 18, 16), Vec3f(1.0f, 0.8f, 1.5f), Vec3f(1, 2, 3), VoxelType::UInt8);
  std::mt19937 rng(4);
  for (auto& x : v.u8()) x = static_cast<std::uint8_t>(rng());
  const Volume fresh = smooth_gaussian(v, 1.2f);
  Volume out(v.dims(), v.spacing_mm(), Vec3f(9, 9, 9), VoxelType::Float32);
  const float* buffer = out.f32().data();
  smooth_gaussian(v, 1.2f, out);
  EXPECT_EQ(out.f32().data(), buffer);  // reused
  EXPECT_EQ(out.f32(), fresh.f32());
  EXPECT_EQ(out.origin_mm(), v.origin_mm());
  Volume wrong(Vec3i(2, 2, 2), Vec3f(1, 1, 1), Vec3f(0, 0, 0), VoxelType::UInt16);
  smooth_gaussian(v, 1.2f, wrong);  // replaced by a volume of the right kind
  EXPECT_EQ(wrong.f32(), fresh.f32());
  EXPECT_EQ(wrong.spacing_mm(), v.spacing_mm());
  EXPECT_THROW(smooth_gaussian(out, 1.0f, out), std::invalid_argument);

  const Gradient g1 = central_gradient(fresh);
  Gradient g2;
  central_gradient(fresh, g2);
  const float* gy = g2.gy.f32().data();
  central_gradient(fresh, g2);
  EXPECT_EQ(g2.gy.f32().data(), gy);
  EXPECT_EQ(g1.gx.f32(), g2.gx.f32());
  EXPECT_EQ(g1.gy.f32(), g2.gy.f32());
  EXPECT_EQ(g1.gz.f32(), g2.gz.f32());
}
