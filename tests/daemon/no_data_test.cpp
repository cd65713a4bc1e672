// The no-data region kept from volume to volume (internal::update_no_data): the same mask and the
// same working image as made afresh, kept only while it still holds.
#include <gtest/gtest.h>

#include <cstdint>
#include <random>
#include <vector>

#include "daemon/internal/target_image.h"

namespace sonomesh::daemon {
namespace {

using internal::NoDataRegion;

// 40³ of speckle-like data 1-255 with zeros at x >= cut (a sector's outside) and a few zeros inside
// the data (dark speckle, not no data); `seed` varies the data, not the zeros.
volume::Volume sector_volume(int cut, unsigned seed) {
  volume::Volume v({40, 40, 40}, {0.5f, 0.5f, 0.5f}, {0, 0, 0}, volume::VoxelType::UInt8);
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> grey(1, 255);
  for (int k = 0; k < 40; ++k)
    for (int j = 0; j < 40; ++j)
      for (int i = 0; i < 40; ++i)
        v.u8()[v.linear_index(i, j, k)] = i >= cut ? 0 : static_cast<std::uint8_t>(grey(rng));
  for (int k = 5; k < 35; k += 7) v.u8()[v.linear_index(10, 20, k)] = 0;
  return v;
}

// The working image `input` gives with `region`.
std::vector<float> working(const volume::Volume& input, const NoDataRegion& region) {
  volume::Volume out;
  EXPECT_TRUE(internal::working_image(input, TargetPolarity::Dark, region, out));
  return out.f32();
}

TEST(NoDataRegion, IsKeptWhileTheSectorStaysAndFloodedAgainWhenItMoves) {
  NoDataRegion region;
  const volume::Volume first = sector_volume(30, 1);
  EXPECT_FALSE(internal::update_no_data(first, region));
  EXPECT_EQ(region.mask, internal::no_data_mask(first));
  ASSERT_FALSE(region.mask.empty());

  // Other data, the same zeros: kept, and the image is what a fresh region makes.
  const volume::Volume second = sector_volume(30, 2);
  EXPECT_TRUE(internal::update_no_data(second, region));
  EXPECT_EQ(region.mask, internal::no_data_mask(second));
  NoDataRegion fresh;
  internal::update_no_data(second, fresh);
  EXPECT_EQ(working(second, region), working(second, fresh));

  // The sector's edge moved one voxel in (a zero beside the region): flooded again.
  const volume::Volume wider = sector_volume(29, 3);
  EXPECT_FALSE(internal::update_no_data(wider, region));
  EXPECT_EQ(region.mask, internal::no_data_mask(wider));

  // ... and one voxel out again (data where the region was): flooded again.
  EXPECT_FALSE(internal::update_no_data(second, region));
  EXPECT_EQ(region.mask, internal::no_data_mask(second));
  EXPECT_EQ(working(second, region), working(second, fresh));
}

TEST(NoDataRegion, AVolumeWithoutOneKeepsNone) {
  NoDataRegion region;
  internal::update_no_data(sector_volume(30, 1), region);
  const volume::Volume full = sector_volume(40, 4);  // data everywhere but the inside zeros
  EXPECT_FALSE(internal::update_no_data(full, region));
  EXPECT_TRUE(region.mask.empty());
  volume::Volume out;
  EXPECT_FALSE(internal::working_image(full, TargetPolarity::Dark, region, out));
}

}  // namespace
}  // namespace sonomesh::daemon
