#include <gtest/gtest.h>

#include "shapes.h"

namespace sonomesh::reconstruct {
namespace {

TEST(Topology, UvSphereCountsAreExact) {
  const int segments = 10, bands = 11;  // method.md §1: 102 vertices, 200 triangles
  const Topology t = analyze_topology(test::uv_sphere(Vec3f::Zero(), 10.0f, segments, bands));
  EXPECT_EQ(t.vertices, 102);
  EXPECT_EQ(t.faces, 200);
  EXPECT_EQ(t.edges, 300);
  EXPECT_EQ(t.euler, 2);
  EXPECT_EQ(t.genus, 0);
  EXPECT_EQ(t.components, 1);
  EXPECT_TRUE(t.watertight);
  EXPECT_TRUE(t.manifold);
  EXPECT_GT(t.volume_ml, 0.0);
}

TEST(Topology, VolumeOfAFineSphereMatchesAnalytic) {
  const Topology t = analyze_topology(test::uv_sphere(Vec3f(5, 6, 7), 10.0f, 128, 64));
  const double analytic = 4.0 / 3.0 * test::kPi * 1000.0 / 1000.0;
  EXPECT_NEAR(t.volume_ml, analytic, 0.01 * analytic);
}

TEST(Topology, ThicknessOfASphereIsItsRadius) {
  EXPECT_NEAR(mesh::thickness_mm(test::uv_sphere(Vec3f(5, 6, 7), 10.0f, 128, 64)), 10.0, 0.1);
  EXPECT_EQ(mesh::thickness_mm(Mesh{}), 0.0);
}

TEST(Topology, TorusGridHasGenusOne) {
  const int nu = 24, nv = 12;
  Mesh m;
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) {
      const float u = 2 * test::kPi * i / nu, v = 2 * test::kPi * j / nv;
      m.vertices.emplace_back((10 + 3 * std::cos(v)) * std::cos(u),
                              (10 + 3 * std::cos(v)) * std::sin(u), 3 * std::sin(v));
    }
  auto id = [&](int i, int j) { return std::uint32_t((i % nu) * nv + (j % nv)); };
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) {
      m.triangles.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1)});
      m.triangles.push_back({id(i, j), id(i + 1, j + 1), id(i, j + 1)});
    }
  const Topology t = analyze_topology(m);
  EXPECT_EQ(t.euler, 0);
  EXPECT_EQ(t.genus, 1);
  EXPECT_TRUE(t.watertight);
  EXPECT_TRUE(t.manifold);
  EXPECT_GT(t.volume_ml, 0.0);
}

TEST(Topology, HoleAndFlippedTriangleBreakWatertightness) {
  Mesh open = test::uv_sphere(Vec3f::Zero(), 5.0f, 10, 11);
  open.triangles.pop_back();
  EXPECT_FALSE(analyze_topology(open).watertight);
  Mesh flipped = test::uv_sphere(Vec3f::Zero(), 5.0f, 10, 11);
  std::swap(flipped.triangles[7][1], flipped.triangles[7][2]);
  const Topology t = analyze_topology(flipped);
  EXPECT_FALSE(t.watertight);
  EXPECT_FALSE(t.manifold);
}

TEST(Topology, TwoSpheresSharingAVertexAreNotManifold) {
  Mesh a = test::uv_sphere(Vec3f::Zero(), 5.0f, 10, 11);
  const Mesh b =
      test::uv_sphere(Vec3f(0, 0, -10), 5.0f, 10, 11);  // b's north pole = a's south pole
  const auto offset = static_cast<std::uint32_t>(a.vertices.size());
  const auto a_south = offset - 1;
  a.vertices.insert(a.vertices.end(), b.vertices.begin(), b.vertices.end());
  for (auto t : b.triangles) {
    for (auto& v : t) v = (v == 0) ? a_south : v + offset;
    a.triangles.push_back(t);
  }
  const Topology t = analyze_topology(a);
  EXPECT_TRUE(t.watertight);  // every edge still has its two opposite faces
  EXPECT_FALSE(t.manifold);   // but the shared pole has two separate fans
  EXPECT_EQ(t.components, 1);
}

TEST(Topology, RejectsOutOfRangeIndices) {
  Mesh m = test::uv_sphere(Vec3f::Zero(), 5.0f, 10, 11);
  m.triangles[3][2] = 999;
  EXPECT_THROW(analyze_topology(m), std::invalid_argument);
}

TEST(Encloses, InsideAndOutsideOfASphere) {
  const Mesh m = test::uv_sphere(Vec3f(1, 2, 3), 5.0f, 16, 12);
  EXPECT_TRUE(encloses(m, Vec3f(1, 2, 3)));
  EXPECT_TRUE(encloses(m, Vec3f(4, 2, 3)));
  EXPECT_FALSE(encloses(m, Vec3f(7, 2, 3)));
  EXPECT_FALSE(encloses(m, Vec3f(1, 2, -3)));
}

TEST(RasterizeLabels, SphereVoxelCountMatchesAnalyticVolume) {
  const float R = 10.0f;
  const Vec3f c(12.1f, 11.9f, 12.05f);
  const Mesh m = test::uv_sphere(c, R, 96, 48);
  const volume::Volume like(volume::Vec3i(48, 48, 50), Vec3f(0.5f, 0.5f, 0.5f), Vec3f::Zero(),
                            volume::VoxelType::UInt16);
  const volume::Volume labels = rasterize_labels(m, like);
  ASSERT_EQ(labels.type(), volume::VoxelType::UInt8);
  EXPECT_EQ(labels.dims(), like.dims());
  std::size_t count = 0, wrong = 0;
  for (int k = 0; k < 50; ++k)
    for (int j = 0; j < 48; ++j)
      for (int i = 0; i < 48; ++i) {
        const bool in = labels.u8()[labels.linear_index(i, j, k)] != 0;
        count += in;
        const float d = (labels.index_to_mm(Vec3f(i, j, k)) - c).norm();
        if (std::abs(d - R) > 0.1f && in != (d < R)) ++wrong;  // away from the faceted wall
      }
  const double analytic = 4.0 / 3.0 * test::kPi * R * R * R / (0.125);
  EXPECT_NEAR(double(count), analytic, 0.02 * analytic);
  EXPECT_EQ(wrong, 0u);
}

}  // namespace
}  // namespace sonomesh::reconstruct
