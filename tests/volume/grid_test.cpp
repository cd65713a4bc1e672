// write_vdb.
#include <gtest/gtest.h>
#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>

#include <cmath>
#include <filesystem>

#include "volume/volume.h"

using namespace sonomesh::volume;

TEST(WriteVdb, FloatGridReadsBackWithTransformAndValues) {
  const auto dir = std::filesystem::temp_directory_path() / "sonomesh_volume_vdb_test";
  std::filesystem::create_directories(dir);
  const auto path = dir / "field.vdb";
  Volume field(Vec3i(16, 12, 10), Vec3f(0.5f, 0.75f, 1.5f), Vec3f(-2, 3, 4), VoxelType::Float32);
  std::size_t nonzero = 0;
  for (int k = 0; k < 10; ++k)
    for (int j = 0; j < 12; ++j)
      for (int i = 0; i < 16; ++i)
        if ((i + j + k) % 3 == 0) {
          field.f32()[field.linear_index(i, j, k)] = 0.5f + i + 10 * j + 100 * k;
          ++nonzero;
        }
  ASSERT_FALSE(write_vdb(field, path, "density").has_value());

  openvdb::initialize();
  openvdb::io::File file(path.string());
  file.open();
  auto base = file.readGrid("density");
  file.close();
  auto grid = openvdb::gridPtrCast<openvdb::FloatGrid>(base);
  ASSERT_TRUE(grid);
  EXPECT_EQ(static_cast<std::size_t>(grid->activeVoxelCount()), nonzero);
  const openvdb::Vec3d w = grid->transform().indexToWorld(openvdb::Vec3d(2, 4, 6));
  EXPECT_NEAR(w.x(), -2 + 0.5 * 2, 1e-6);
  EXPECT_NEAR(w.y(), 3 + 0.75 * 4, 1e-6);
  EXPECT_NEAR(w.z(), 4 + 1.5 * 6, 1e-6);
  auto acc = grid->getConstAccessor();
  EXPECT_FLOAT_EQ(acc.getValue(openvdb::Coord(3, 3, 3)), 0.5f + 3 + 30 + 300);
  EXPECT_FLOAT_EQ(acc.getValue(openvdb::Coord(1, 0, 0)), 0.0f);

  // Wrong type and unwritable path are errors, not exceptions.
  const Volume u8(Vec3i(2, 2, 2), Vec3f(1, 1, 1), Vec3f(0, 0, 0), VoxelType::UInt8);
  EXPECT_TRUE(write_vdb(u8, dir / "u8.vdb").has_value());
  const auto bad = write_vdb(field, dir / "no_such_dir" / "x.vdb");
  ASSERT_TRUE(bad.has_value());
  EXPECT_EQ(bad->code, VolumeIoError::Code::IoError);
  std::filesystem::remove_all(dir);
}
