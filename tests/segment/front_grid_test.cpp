// FrontGrid (A_t): first mark wins, readers on several threads, sparse memory.
#include "segment/internal/front_grid.h"

#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <thread>

using namespace sonomesh::volume;
using sonomesh::segment::internal::FrontGrid;

TEST(FrontGrid, FirstMarkWinsAndKeepsItsNormal) {
  const Volume like(Vec3i(32, 32, 32), Vec3f(0.5f, 0.5f, 0.5f), Vec3f(0, 0, 0), VoxelType::Float32);
  FrontGrid grid(like);
  const Vec3f up = Vec3f(0.0f, 0.6f, 0.8f);
  EXPECT_TRUE(grid.mark(Vec3i(3, 4, 5), up));
  EXPECT_FALSE(grid.mark(Vec3i(3, 4, 5), -up)) << "a later front must not overwrite the first";
  EXPECT_TRUE(grid.mark(Vec3i(31, 31, 31), Vec3f::Zero()));  // a zero normal still marks
  EXPECT_EQ(grid.marked_count(), 2u);

  const FrontGrid::Reader reader(grid);
  Vec3f n;
  ASSERT_TRUE(reader.normal(Vec3i(3, 4, 5), n));
  EXPECT_LT((n - up).norm(), 1.5f / 127.0f) << "normals are stored to 1/127";
  EXPECT_TRUE(reader.marked(Vec3i(31, 31, 31)));
  EXPECT_FALSE(reader.marked(Vec3i(3, 4, 6)));
  EXPECT_FALSE(reader.normal(Vec3i(0, 0, 0), n));

  const Volume labels = grid.to_labels();
  EXPECT_EQ(labels.value(3, 4, 5), 1.0f);
  EXPECT_EQ(labels.value(31, 31, 31), 1.0f);
  EXPECT_EQ(labels.value(3, 4, 6), 0.0f);
}

TEST(FrontGrid, ReadersOnSeveralThreadsSeeTheSameMarks) {
  const Volume like(Vec3i(64, 64, 64), Vec3f(1, 1, 1), Vec3f(0, 0, 0), VoxelType::Float32);
  FrontGrid grid(like);
  // A spherical shell, as a front leaves it, with outward normals.
  std::size_t shell = 0;
  for (int k = 0; k < 64; ++k)
    for (int j = 0; j < 64; ++j)
      for (int i = 0; i < 64; ++i) {
        const Vec3f d(i - 32.0f, j - 32.0f, k - 32.0f);
        if (std::abs(d.norm() - 10.0f) < 1.0f) shell += grid.mark(Vec3i(i, j, k), d.normalized());
      }
  EXPECT_EQ(grid.marked_count(), shell);
  // Sparse: memory follows the swept region. The tree's upper nodes cost ~0.3 MB whatever the
  // size, so the comparison is on a 128^3 grid (dense, at 4 bytes per voxel: 8 MB).
  const Volume large(Vec3i(128, 128, 128), Vec3f(1, 1, 1), Vec3f(0, 0, 0), VoxelType::Float32);
  FrontGrid sparse(large);
  const FrontGrid::Reader copy_from(grid);
  for (int k = 0; k < 64; ++k)
    for (int j = 0; j < 64; ++j)
      for (int i = 0; i < 64; ++i) {
        Vec3f n;
        if (copy_from.normal(Vec3i(i, j, k), n)) sparse.mark(Vec3i(i, j, k), n);
      }
  EXPECT_EQ(sparse.marked_count(), shell);
  EXPECT_LT(sparse.memory_bytes(), 128u * 128u * 128u * 4u / 8u);

  std::atomic<std::size_t> seen{0}, wrong{0};
  auto scan = [&](int k0, int k1) {
    const FrontGrid::Reader reader(grid);
    for (int k = k0; k < k1; ++k)
      for (int j = 0; j < 64; ++j)
        for (int i = 0; i < 64; ++i) {
          Vec3f n;
          if (!reader.normal(Vec3i(i, j, k), n)) continue;
          ++seen;
          const Vec3f d = Vec3f(i - 32.0f, j - 32.0f, k - 32.0f).normalized();
          if (n.dot(d) < 0.99f) ++wrong;
        }
  };
  std::thread a(scan, 0, 32), b(scan, 32, 64);
  a.join();
  b.join();
  EXPECT_EQ(seen.load(), shell);
  EXPECT_EQ(wrong.load(), 0u);
}
