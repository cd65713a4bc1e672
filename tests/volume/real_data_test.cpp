// The real sample volumes in shared/data/real load with the geometry their SOURCE.md documents.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>

#include "volume/volume.h"

using namespace sonomesh::volume;
namespace fs = std::filesystem;

namespace {

// CI keeps shared/ beside the checkout; a missing file is a failure, not a skip.
VolumeReadResult load_real(const std::string& relative) {
  const fs::path path = fs::path(SONOMESH_SHARED_DATA) / "real" / relative;
  if (!fs::exists(path)) {
    ADD_FAILURE() << "real sample volume missing: " << path
                  << " (expected shared/data beside the project checkout)";
    return {Volume{}, VolumeIoError{VolumeIoError::Code::NotFound, path.string()}};
  }
  return read_volume(path);
}

double mean(const Volume& v) {
  double s = 0;
  for (auto x : v.u8()) s += x;
  return s / static_cast<double>(v.voxel_count());
}

}  // namespace

TEST(RealData, LidcCtLoadsWithFlippedAxesResolvedToPositiveSpacing) {
  const auto r = load_real("lidc2-ct/LIDC2.mha");
  ASSERT_TRUE(r) << r.error->message;
  const Volume& v = r.volume;
  ASSERT_EQ(v.type(), VoxelType::UInt8);
  EXPECT_EQ(v.dims(), Vec3i(256, 256, 133));
  EXPECT_NEAR(v.spacing_mm().x(), 1.40625f, 1e-4f);
  EXPECT_NEAR(v.spacing_mm().y(), 1.40625f, 1e-4f);
  EXPECT_NEAR(v.spacing_mm().z(), 2.5f, 1e-4f);
  // TransformMatrix diag(1, -1, -1), Offset (0, 360, 332.5): y and z are flipped so that the
  // file's last row/slice becomes index 0 at the lowest coordinate.
  EXPECT_NEAR(v.origin_mm().x(), 0.0f, 1e-3f);
  EXPECT_NEAR(v.origin_mm().y(), 360.0f - 255 * 1.40625f, 1e-3f);
  EXPECT_NEAR(v.origin_mm().z(), 332.5f - 132 * 2.5f, 1e-3f);
  EXPECT_NEAR(v.max_mm().y(), 360.0f, 1e-3f);
  EXPECT_NEAR(v.max_mm().z(), 332.5f, 1e-3f);
  EXPECT_NEAR(mean(v), 7.05, 0.05);
  EXPECT_EQ(*std::max_element(v.u8().begin(), v.u8().end()), 255);
  // SOURCE.md's spleen seed: file voxel (185, 107, 90) at about (260.2, 209.5, 107.5) mm.
  const Vec3f seed_mm(185 * 1.40625f, 360.0f - 107 * 1.40625f, 332.5f - 90 * 2.5f);
  const Vec3f ijk = v.mm_to_index(seed_mm);
  EXPECT_TRUE(ijk.isApprox(Vec3f(185, 255 - 107, 132 - 90), 1e-4f)) << ijk.transpose();
  const float seed_value = sample_mm(v, seed_mm);
  EXPECT_GE(seed_value, 38.0f);
  EXPECT_LE(seed_value, 75.0f);
}

TEST(RealData, SpineUltrasoundLoadsWithIdentityOrientation) {
  const auto r = load_real("plus-spine-us/SpinePhantomFreehandReconstructed.mha");
  ASSERT_TRUE(r) << r.error->message;
  const Volume& v = r.volume;
  ASSERT_EQ(v.type(), VoxelType::UInt8);
  EXPECT_EQ(v.dims(), Vec3i(147, 106, 104));
  EXPECT_TRUE(v.spacing_mm().isApprox(Vec3f(0.5f, 0.5f, 0.5f)));
  EXPECT_TRUE(v.origin_mm().isApprox(Vec3f(-74.5217f, 165.573f, 29.072f), 1e-5f));
  EXPECT_NEAR(mean(v), 19.7, 0.1);
  std::size_t zeros = 0;
  for (auto x : v.u8()) zeros += x == 0;
  EXPECT_NEAR(static_cast<double>(zeros) / v.voxel_count(), 0.71, 0.01);
  EXPECT_EQ(*std::max_element(v.u8().begin(), v.u8().end()), 251);
}
