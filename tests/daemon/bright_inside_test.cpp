// The tracked surface's check for a bright structure inside (internal::deep_on_a_line): a
// needle's deep voxels lie along one line and fill it, a web of blood-pool speckle's do neither.
#include "daemon/internal/bright_inside.h"

#include <gtest/gtest.h>

#include <cmath>

namespace sonomesh::daemon::internal {
namespace {

constexpr int kSize = 48;
constexpr float kRadiusVox = 20.0f;  // the surface: a sphere at the grid's centre
constexpr float kDark = 20.0f, kBright = 100.0f;

Vec3f centre() { return Vec3f::Constant(0.5f * (kSize - 1)); }

volume::Volume dark_inside() {
  volume::Volume v(Vec3i::Constant(kSize), Vec3f::Constant(0.5f), Vec3f::Zero(),
                   volume::VoxelType::Float32);
  for (float& x : v.f32()) x = kDark;
  return v;
}

InsideRegion sphere_region() {
  return {.lo = Vec3i::Zero(),
          .hi = Vec3i::Constant(kSize - 1),
          .inside = [](const Vec3i& v) { return (v.cast<float>() - centre()).norm() < kRadiusVox; },
          .mid_level = 0.5f * (kDark + kBright)};
}

template <typename Bright>
void paint(volume::Volume& v, Bright bright) {
  for (int z = 0; z < kSize; ++z)
    for (int y = 0; y < kSize; ++y)
      for (int x = 0; x < kSize; ++x)
        if (bright(Vec3f(x, y, z))) v.f32()[v.linear_index(x, y, z)] = kBright;
}

TEST(BrightInside, ANeedlesDeepVoxelsLieOnALine) {
  volume::Volume image = dark_inside();
  const Vec3f axis = Vec3f(0.866f, 0.2f, 0.5f).normalized();
  paint(image, [&](const Vec3f& p) {
    const Vec3f r = p - centre();
    return (r - r.dot(axis) * axis).norm() <= 1.5f;  // a needle 3 voxels across
  });
  const InsideRegion region = sphere_region();
  const BrightStructure needle = deepest_bright_structure(image, region);
  ASSERT_GT(needle.deep_vox, 100);
  const DeepLine line = deep_on_a_line(image, region, needle);
  EXPECT_GE(10 * line.voxels, 9 * needle.deep_vox) << line.voxels << " of " << needle.deep_vox;
  EXPECT_LE(line.voxels, needle.deep_vox);
  // Across the 20 mm sphere, less the needle's ends where it is not deep.
  EXPECT_GE(line.length_mm, 15.0f);
  EXPECT_LE(line.length_mm, 20.5f);
}

TEST(BrightInside, AWebOfSpeckleHasFewDeepVoxelsOnAnyLine) {
  volume::Volume image = dark_inside();
  // Thin strands every 6 voxels along each axis, all joined: one structure through the inside.
  auto on_strand = [](float a, float b) {
    return std::abs(std::remainder(a, 6.0f)) < 0.6f && std::abs(std::remainder(b, 6.0f)) < 0.6f;
  };
  paint(image, [&](const Vec3f& p) {
    return on_strand(p.x(), p.y()) || on_strand(p.y(), p.z()) || on_strand(p.x(), p.z());
  });
  const InsideRegion region = sphere_region();
  const BrightStructure web = deepest_bright_structure(image, region);
  ASSERT_GT(web.deep_vox, 1000);
  const DeepLine line = deep_on_a_line(image, region, web);
  EXPECT_LT(8 * line.voxels, web.deep_vox) << line.voxels << " of " << web.deep_vox;
  EXPECT_GT(line.voxels, 0);
}

}  // namespace
}  // namespace sonomesh::daemon::internal
