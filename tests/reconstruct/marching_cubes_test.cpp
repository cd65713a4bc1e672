#include <gtest/gtest.h>

#include <random>

#include "shapes.h"

namespace sonomesh::reconstruct {
namespace {

using test::kPi;

TEST(MarchingCubes, SphereFieldGivesClosedOutwardGenusZeroSurface) {
  const float R = 15.0f;
  const Vec3f c(24.3f, 23.7f, 24.1f);
  const auto f =
      test::field(48, 1.0f, Vec3f::Zero(), [&](const Vec3f& p) { return R - (p - c).norm(); });
  const Mesh m = marching_cubes(f, 0.0f);
  const Topology t = analyze_topology(m);
  EXPECT_TRUE(t.watertight);
  EXPECT_TRUE(t.manifold);
  EXPECT_EQ(t.components, 1);
  EXPECT_EQ(t.euler, 2);
  EXPECT_EQ(t.genus, 0);
  const double analytic_ml = 4.0 / 3.0 * kPi * R * R * R / 1000.0;
  EXPECT_NEAR(t.volume_ml, analytic_ml, 0.02 * analytic_ml);  // positive: triangles face outward
  double err = 0.0;
  for (const auto& v : m.vertices) err = std::max(err, double(std::abs((v - c).norm() - R)));
  EXPECT_LT(err, 0.1);  // linear interpolation of a distance field: well under a voxel
}

TEST(MarchingCubes, TorusFieldHasGenusOne) {
  const Vec3f c(20.2f, 19.8f, 20.1f);
  const auto f = test::field(40, 1.0f, Vec3f::Zero(), [&](const Vec3f& p) {
    const Vec3f q = p - c;
    return 4.5f - std::hypot(std::hypot(q.x(), q.y()) - 11.0f, q.z());
  });
  const Topology t = analyze_topology(marching_cubes(f, 0.0f));
  EXPECT_TRUE(t.watertight);
  EXPECT_TRUE(t.manifold);
  EXPECT_EQ(t.components, 1);
  EXPECT_EQ(t.genus, 1);
  const double analytic_ml = 2 * kPi * kPi * 11.0 * 4.5 * 4.5 / 1000.0;
  EXPECT_NEAR(t.volume_ml, analytic_ml, 0.03 * analytic_ml);
}

TEST(MarchingCubes, RandomFieldsStayWatertightAndManifold) {
  // Noise makes every ambiguous face and cube configuration occur many times over.
  std::mt19937 rng(12345);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  for (int trial = 0; trial < 4; ++trial) {
    auto f = test::field(20, 0.7f, Vec3f(1, 2, 3), [&](const Vec3f&) { return u(rng); });
    const Mesh m = marching_cubes(f, 0.1f * trial);
    const Topology t = analyze_topology(m);
    ASSERT_GT(t.faces, 1000);
    EXPECT_TRUE(t.watertight) << "trial " << trial;
    EXPECT_TRUE(t.manifold) << "trial " << trial;
    for (const auto& tri : m.triangles) {
      ASSERT_NE(tri[0], tri[1]);
      ASSERT_NE(tri[1], tri[2]);
      ASSERT_NE(tri[0], tri[2]);
    }
    EXPECT_GT(t.volume_ml, 0.0);
  }
}

TEST(MarchingCubes, EverySignPatternOfTwoNeighbouringCubesIsWatertight) {
  // A 5x4x4 grid whose 12 interior samples form two cubes sharing a face (the border counts as
  // outside): all 4096 sign patterns, each with two random magnitude draws so the asymptotic
  // decider goes both ways on ambiguous faces.
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> mag(0.05f, 1.0f);
  volume::Volume f(volume::Vec3i(5, 4, 4), Vec3f::Ones(), Vec3f::Zero(),
                   volume::VoxelType::Float32);
  int failures = 0;
  for (int pattern = 1; pattern < 4096; ++pattern)
    for (int draw = 0; draw < 2; ++draw) {
      std::fill(f.f32().begin(), f.f32().end(), -1.0f);
      int bit = 0;
      for (int k = 1; k <= 2; ++k)
        for (int j = 1; j <= 2; ++j)
          for (int i = 1; i <= 3; ++i, ++bit)
            f.f32()[f.linear_index(i, j, k)] = ((pattern >> bit) & 1 ? 1.0f : -1.0f) * mag(rng);
      const Topology t = analyze_topology(marching_cubes(f, 0.0f));
      if (!t.watertight || !t.manifold || !(t.volume_ml > 0.0)) ++failures;
    }
  EXPECT_EQ(failures, 0);
}

TEST(MarchingCubes, SurfaceTouchingTheGridBorderIsClosedThere) {
  // A half-space crossing the whole grid: border samples count as outside, so it closes.
  const auto f = test::field(16, 1.0f, Vec3f::Zero(), [](const Vec3f& p) { return 7.5f - p.z(); });
  const Topology t = analyze_topology(marching_cubes(f, 0.0f));
  EXPECT_TRUE(t.watertight);
  EXPECT_TRUE(t.manifold);
  EXPECT_EQ(t.genus, 0);
  EXPECT_GT(t.volume_ml, 0.0);
}

TEST(MarchingCubes, RejectsNonFloatVolumes) {
  const volume::Volume v(volume::Vec3i(8, 8, 8), Vec3f::Ones(), Vec3f::Zero(),
                         volume::VoxelType::UInt8);
  EXPECT_THROW(marching_cubes(v, 0.5f), std::invalid_argument);
}

TEST(Components, SeedPicksTheSphereAroundIt) {
  const Vec3f a(12, 20, 20), b(30, 20, 20);
  const auto f = test::field(42, 1.0f, Vec3f::Zero(), [&](const Vec3f& p) {
    return std::max(6.0f - (p - a).norm(), 8.0f - (p - b).norm());
  });
  const Mesh m = marching_cubes(f, 0.0f);
  EXPECT_EQ(connected_components(m).size(), 2u);
  bool enclosed = false;
  const Mesh picked = component_enclosing(m, a, &enclosed);
  EXPECT_TRUE(enclosed);
  EXPECT_NEAR(analyze_topology(picked).volume_ml, 4.0 / 3.0 * kPi * 216.0 / 1000.0, 0.05 * 0.905);
  const Mesh fallback = component_enclosing(m, Vec3f(21, 35, 20), &enclosed);
  EXPECT_FALSE(enclosed);  // the seed is outside both: the larger sphere is kept
  EXPECT_NEAR(analyze_topology(fallback).volume_ml, 4.0 / 3.0 * kPi * 512.0 / 1000.0, 0.05 * 2.14);
}

}  // namespace
}  // namespace sonomesh::reconstruct
