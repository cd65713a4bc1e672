// The warm start's check of its start mesh (segment/internal/warm_start.h): samples on speckle
// grains pass where the level stop runs, a start past the wall does not.
#include "segment/internal/warm_start.h"

#include <gtest/gtest.h>

#include <random>
#include <string>

#include "segment/internal/balloon_evolution.h"
#include "segment/segment.h"

using namespace sonomesh;
using segment::internal::StartAllowance;
using volume::Vec3f;

namespace {

constexpr int kSize = 48;
constexpr float kVoxMm = 0.5f;
constexpr float kPool = 50.0f, kTissue = 100.0f, kGrain = 150.0f;
constexpr float kWallLevel = 0.5f * (kPool + kTissue);
constexpr float kCavityMm = 8.0f;  // the pool's radius round the centre
const Vec3f kCentre = Vec3f::Constant(0.5f * kSize * kVoxMm);

// A pool with 2×2×2-voxel grains brighter than the tissue scattered over a twentieth of it (on
// about 6 % of the start samples below, as blood-pool speckle at contrast 0.5 puts 3.6-5.4 %), in
// tissue beyond kCavityMm.
volume::Volume grainy_cavity() {
  volume::Volume v({kSize, kSize, kSize}, Vec3f::Constant(kVoxMm), Vec3f::Zero(),
                   volume::VoxelType::Float32);
  std::mt19937 random(7);
  std::bernoulli_distribution grain(0.05 / 8);
  for (int k = 0; k < kSize; ++k)
    for (int j = 0; j < kSize; ++j)
      for (int i = 0; i < kSize; ++i) {
        const bool pool = (v.index_to_mm(Vec3f(i, j, k)) - kCentre).norm() < kCavityMm;
        v.f32()[v.linear_index(i, j, k)] = pool ? kPool : kTissue;
      }
  for (int k = 0; k + 1 < kSize; ++k)
    for (int j = 0; j + 1 < kSize; ++j)
      for (int i = 0; i + 1 < kSize; ++i) {
        if ((v.index_to_mm(Vec3f(i, j, k)) - kCentre).norm() > kCavityMm - 1.5f || !grain(random))
          continue;
        for (int c = 0; c < 8; ++c)
          v.f32()[v.linear_index(i + (c & 1), j + (c >> 1 & 1), k + (c >> 2))] = kGrain;
      }
  return v;
}

std::string check(const volume::Volume& image, float radius_mm, const StartAllowance& allow) {
  const segment::internal::BalloonMesh start = segment::internal::start_sphere(kCentre, radius_mm);
  const segment::internal::StepKernel box(segment::BalloonOptions{}, image, kVoxMm);
  return segment::internal::check_start_safe(start, segment::internal::ImageSampler(image),
                                             segment::internal::CostScale{}, kWallLevel, box,
                                             allow);
}

}  // namespace

// A start inside the pool has samples on grains, more than the share allows: the region test
// lets them pass, the point test alone does not.
TEST(WarmStartCheck, GrainsOfThePoolPassTheRegionTest) {
  const volume::Volume image = grainy_cavity();
  const StartAllowance share_only{.share = 0.02f};
  const StartAllowance region{.share = 0.02f, .region_mm = 2.0f * kVoxMm};
  EXPECT_NE(check(image, 5.0f, share_only), "");
  EXPECT_EQ(check(image, 5.0f, region), "");
}

// A start past the wall, in the tissue, fails either way.
TEST(WarmStartCheck, AStartPastTheWallFailsTheRegionTest) {
  const volume::Volume image = grainy_cavity();
  const StartAllowance region{.share = 0.02f, .region_mm = 2.0f * kVoxMm};
  EXPECT_NE(check(image, kCavityMm + 1.5f, region), "");
}
