// The open patch (daemon/internal/target_image.h): the share of a surface that looks into the
// target's inside, and how a needle's shadow beyond the wall is told from it.
#include <gtest/gtest.h>

#include "daemon/internal/target_image.h"
#include "reconstruct/reconstruct.h"

namespace sonomesh::daemon::internal {
namespace {

using volume::Vec3f;
using volume::Vec3i;

constexpr float kTarget = 30.0f, kTissue = 100.0f;

// A dark ball of radius 16 voxels in tissue, 64³ of 1 mm; below a needle at the centre's depth
// (z > 32, within 6 voxels of the plane x = 32) everything is darkened to `shadow` of itself.
volume::Volume shadowed_ball(float shadow) {
  volume::Volume v(Vec3i(64, 64, 64), Vec3f(1, 1, 1), Vec3f(0, 0, 0), volume::VoxelType::Float32);
  for (int k = 0; k < 64; ++k)
    for (int j = 0; j < 64; ++j)
      for (int i = 0; i < 64; ++i) {
        const float r = Vec3f(i - 32.0f, j - 32.0f, k - 32.0f).norm();
        const bool shadowed = k > 32 && std::abs(i - 32) <= 6;
        v.f32()[v.linear_index(i, j, k)] =
            (r < 16.0f ? kTarget : kTissue) * (shadowed ? shadow : 1);
      }
  return v;
}

// The surface of a ball of `radius_vox` round the volume's centre (outward normals).
segment::Mesh ball_surface(float radius_vox) {
  volume::Volume field(Vec3i(64, 64, 64), Vec3f(1, 1, 1), Vec3f(0, 0, 0),
                       volume::VoxelType::Float32);
  for (int k = 0; k < 64; ++k)
    for (int j = 0; j < 64; ++j)
      for (int i = 0; i < 64; ++i)
        field.f32()[field.linear_index(i, j, k)] =
            radius_vox - Vec3f(i - 32.0f, j - 32.0f, k - 32.0f).norm();
  return reconstruct::marching_cubes(field, 0.0f);
}

TEST(OpenPatch, AWallInANeedlesShadowIsOpenOnlyAgainstTheTargetsLevel) {
  const volume::Volume image = shadowed_ball(0.35f);  // tissue 35 there: within 0.15 of 70
  const segment::Mesh wall = ball_surface(15.5f);
  const float plain = open_patch(image, wall, kTarget, kTissue);
  const float local = open_patch(image, wall, kTarget, kTissue, 1, true);
  EXPECT_GT(plain, 0.02f);
  EXPECT_LT(local, 0.002f);
  EXPECT_LT(open_patch(shadowed_ball(1.0f), wall, kTarget, kTissue), 0.002f);
}

TEST(OpenPatch, ASurfaceShortOfTheWallIsOpenEitherWay) {
  const volume::Volume image = shadowed_ball(0.35f);
  const segment::Mesh stalled = ball_surface(8.0f);
  EXPECT_GT(open_patch(image, stalled, kTarget, kTissue), 0.5f);
  EXPECT_GT(open_patch(image, stalled, kTarget, kTissue, 1, true), 0.5f);
}

}  // namespace
}  // namespace sonomesh::daemon::internal
