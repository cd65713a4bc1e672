#include <gtest/gtest.h>

#include "volume/volume.h"

using namespace sonomesh::volume;

TEST(Volume, IndexAndMillimetresMapBothWays) {
  const Volume v(Vec3i(4, 5, 6), Vec3f(0.5f, 1.0f, 2.0f), Vec3f(10.0f, 20.0f, 30.0f), VoxelType::UInt8);
  const Vec3f p = v.index_to_mm(Vec3f(1, 2, 3));
  EXPECT_FLOAT_EQ(p.x(), 10.5f);
  EXPECT_FLOAT_EQ(p.y(), 22.0f);
  EXPECT_FLOAT_EQ(p.z(), 36.0f);
  EXPECT_TRUE(v.mm_to_index(p).isApprox(Vec3f(1, 2, 3)));
  EXPECT_EQ(v.linear_index(1, 2, 3), std::size_t{1 + 4 * (2 + 5 * 3)});
}
