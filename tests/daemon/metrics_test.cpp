#include "daemon/internal/metrics.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <utility>
#include <vector>

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

// A Float32 field positive inside balls (radius minus the distance to the nearest centre).
Volume balls(const Vec3i& dims, float cell_mm, const std::vector<std::pair<Vec3f, float>>& b) {
  Volume field(dims, Vec3f::Constant(cell_mm), Vec3f::Zero(), volume::VoxelType::Float32);
  for (int k = 0; k < dims.z(); ++k)
    for (int j = 0; j < dims.y(); ++j)
      for (int i = 0; i < dims.x(); ++i) {
        float value = -1e9f;
        for (const auto& [centre_mm, radius_mm] : b)
          value = std::max(value, radius_mm - (Vec3f(i, j, k) * cell_mm - centre_mm).norm());
        field.f32()[field.linear_index(i, j, k)] = value;
      }
  return field;
}

TEST(DeepestInside, IsTheCentreOfABall) {
  const Volume field = balls(Vec3i(32, 30, 28), 1.0f, {{Vec3f(13, 15, 12), 8.0f}});
  const auto deepest =
      deepest_inside(field, 0.0f, Vec3f(5, 7, 4), Vec3f(21, 23, 20), Vec3f(10, 15, 12), 1.0f);
  ASSERT_TRUE(deepest.has_value());
  EXPECT_LE((deepest->position_mm - Vec3f(13, 15, 12)).norm(), 1.0f);
  EXPECT_NEAR(deepest->depth_mm, 9.0f, 1.0f);  // radius 8 plus the half cell to the first outside
}

TEST(DeepestInside, KeepsToThePartAroundTheSeed) {
  // A large ball and a small one in the same box; the seed is in the small one.
  const Volume field =
      balls(Vec3i(48, 32, 32), 1.0f, {{Vec3f(14, 16, 16), 10.0f}, {Vec3f(36, 16, 16), 5.0f}});
  const auto deepest =
      deepest_inside(field, 0.0f, Vec3f(4, 6, 6), Vec3f(41, 26, 26), Vec3f(35, 17, 16), 1.0f);
  ASSERT_TRUE(deepest.has_value());
  EXPECT_LE((deepest->position_mm - Vec3f(36, 16, 16)).norm(), 1.0f);
}

TEST(DeepestInside, SubsamplesAFineFieldToTheStep) {
  // Cells of 0.25 mm searched at 1 mm: four cells per lattice step, the centre within a step.
  const Volume field = balls(Vec3i(64, 64, 64), 0.25f, {{Vec3f(8, 8.3f, 7.6f), 5.0f}});
  const auto deepest =
      deepest_inside(field, 0.0f, Vec3f(3, 3, 2.5f), Vec3f(13, 13, 12.5f), Vec3f(8, 8, 8), 1.0f);
  ASSERT_TRUE(deepest.has_value());
  EXPECT_LE((deepest->position_mm - Vec3f(8, 8.3f, 7.6f)).norm(), 1.0f);
  EXPECT_NEAR(deepest->depth_mm, 5.0f, 1.0f);
}

TEST(DeepestInside, NothingInsideHasNone) {
  const Volume field = balls(Vec3i(8, 8, 8), 1.0f, {{Vec3f(40, 40, 40), 2.0f}});
  EXPECT_FALSE(deepest_inside(field, 0.0f, Vec3f(0, 0, 0), Vec3f(7, 7, 7), Vec3f(4, 4, 4), 1.0f));
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
