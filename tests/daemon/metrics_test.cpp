#include "daemon/internal/metrics.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

namespace sonomesh::daemon::internal {
namespace {

using volume::Vec3f;
using volume::Vec3i;
using volume::Volume;

Volume ball(const Vec3i& dims, const Vec3f& centre_vox, float radius_vox) {
  Volume labels(dims, Vec3f::Ones(), Vec3f::Zero(), volume::VoxelType::UInt8);
  for (int k = 0; k < dims.z(); ++k)
    for (int j = 0; j < dims.y(); ++j)
      for (int i = 0; i < dims.x(); ++i)
        if ((Vec3f(i, j, k) - centre_vox).norm() <= radius_vox)
          labels.u8()[labels.linear_index(i, j, k)] = 1;
  return labels;
}

TEST(DistanceTransform, MatchesBruteForceOnAnisotropicGrid) {
  const Vec3i dims(9, 7, 5);
  const Vec3f spacing(0.5f, 1.0f, 2.0f);
  std::mt19937 rng(3);
  std::vector<bool> feature(dims.prod(), false);
  for (std::size_t n = 0; n < feature.size(); ++n) feature[n] = rng() % 17 == 0;
  feature[0] = true;
  const auto d2 = squared_distance_transform_mm2(feature, dims, spacing);
  for (int k = 0; k < dims.z(); ++k)
    for (int j = 0; j < dims.y(); ++j)
      for (int i = 0; i < dims.x(); ++i) {
        float best = std::numeric_limits<float>::infinity();
        for (int c = 0; c < dims.z(); ++c)
          for (int b = 0; b < dims.y(); ++b)
            for (int a = 0; a < dims.x(); ++a)
              if (feature[(c * dims.y() + b) * dims.x() + a])
                best =
                    std::min(best, Vec3f(i - a, j - b, k - c).cwiseProduct(spacing).squaredNorm());
        EXPECT_NEAR(d2[(k * dims.y() + j) * dims.x() + i], best, 1e-4f)
            << i << "," << j << "," << k;
      }
}

TEST(DistanceTransform, NoFeatureIsInfinitelyFar) {
  const auto d2 =
      squared_distance_transform_mm2(std::vector<bool>(8, false), Vec3i(2, 2, 2), Vec3f::Ones());
  for (float value : d2) EXPECT_TRUE(std::isinf(value));
}

TEST(DeepestInterior, IsTheCentreOfABall) {
  const Volume labels = ball(Vec3i(32, 30, 28), Vec3f(13, 15, 12), 8.0f);
  Vec3i ijk;
  float depth_mm = 0;
  ASSERT_TRUE(deepest_interior_index(labels, ijk, depth_mm));
  EXPECT_LE((ijk - Vec3i(13, 15, 12)).cast<float>().norm(), 1.0f);
  EXPECT_NEAR(depth_mm, 9.0f, 1.0f);  // radius 8 plus the half voxel to the first outside centre
}

TEST(DeepestInterior, EmptyLabelsHaveNone) {
  const Volume labels(Vec3i(8, 8, 8), Vec3f::Ones(), Vec3f::Zero(), volume::VoxelType::UInt8);
  Vec3i ijk;
  float depth_mm = 0;
  EXPECT_FALSE(deepest_interior_index(labels, ijk, depth_mm));
}

TEST(Dice, IdenticalIsOneDisjointIsZero) {
  const Volume a = ball(Vec3i(40, 40, 40), Vec3f(10, 20, 20), 6.0f);
  const Volume b = ball(Vec3i(40, 40, 40), Vec3f(30, 20, 20), 6.0f);
  EXPECT_DOUBLE_EQ(dice(a, a), 1.0);
  EXPECT_DOUBLE_EQ(dice(a, b), 0.0);
}

TEST(SurfaceDistances, OneVoxelShiftGivesAboutOneVoxel) {
  const Volume a = ball(Vec3i(40, 40, 40), Vec3f(20, 20, 20), 10.0f);
  const Volume b = ball(Vec3i(40, 40, 40), Vec3f(21, 20, 20), 10.0f);
  const SurfaceDistances same = surface_distances(a, a);
  ASSERT_TRUE(same.valid);
  EXPECT_EQ(same.mean_vox, 0.0);
  EXPECT_EQ(same.hd95_vox, 0.0);
  const SurfaceDistances shifted = surface_distances(a, b);
  ASSERT_TRUE(shifted.valid);
  // Only the caps facing ±x move by a full voxel; the sides move by much less.
  EXPECT_GT(shifted.mean_vox, 0.2);
  EXPECT_LT(shifted.mean_vox, 1.0);
  EXPECT_NEAR(shifted.max_vox, 1.0, 0.5);
}

}  // namespace
}  // namespace sonomesh::daemon::internal
