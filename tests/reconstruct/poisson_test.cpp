#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <thread>

#include "reconstruct/internal/fft_plans.h"
#include "shapes.h"

namespace sonomesh::reconstruct {
namespace {

using test::kPi;

double mean_sphere_error(const Mesh& m, const Vec3f& c, float R) {
  double sum = 0.0;
  for (const auto& v : m.vertices) sum += std::abs((v - c).norm() - R);
  return sum / double(m.vertices.size());
}

TEST(Poisson, SphereWithOutwardNormalsIsInsideAtTheCentre) {
  const Vec3f c(3.2f, -1.7f, 0.9f);
  const IndicatorGrid g = poisson_indicator(test::sphere_samples(c, 8.0f, 3000), {.cell_mm = 0.5f});
  ASSERT_EQ(g.chi.type(), volume::VoxelType::Float32);
  EXPECT_EQ(g.chi.spacing_mm(), Vec3f::Constant(0.5f));
  // χ is larger inside: the centre is above the iso-value, the grid corner below it.
  EXPECT_GT(volume::sample_mm(g.chi, c), g.iso);
  EXPECT_LT(g.chi.value(0, 0, 0), g.iso);
  // Scaled as an indicator: about one unit from outside to inside.
  EXPECT_NEAR(volume::sample_mm(g.chi, c) - g.chi.value(0, 0, 0), 1.0f, 0.15f);
}

TEST(Poisson, SphereIsReconstructedWithinAQuarterCell) {
  const Vec3f c(3.2f, -1.7f, 0.9f);
  const float R = 10.0f, cell = 0.5f;
  const SurfaceResult r =
      reconstruct_surface(test::sphere_samples(c, R, 5000), c, {.cell_mm = cell});
  EXPECT_TRUE(r.seed_enclosed);
  EXPECT_EQ(r.components_before_selection, 1);
  EXPECT_TRUE(r.topology.watertight);
  EXPECT_TRUE(r.topology.manifold);
  EXPECT_EQ(r.topology.genus, 0);
  EXPECT_LE(mean_sphere_error(r.mesh, c, R), 0.25 * cell);
  const double analytic = 4.0 / 3.0 * kPi * R * R * R / 1000.0;
  EXPECT_NEAR(r.topology.volume_ml, analytic, 0.03 * analytic);
  EXPECT_EQ(r.grid_dims[0], r.indicator.dims().x());
}

TEST(Poisson, TorusComesOutWithGenusOne) {
  const Vec3f c(-2.0f, 1.0f, 4.0f);
  const float R = 9.0f, rr = 3.5f, cell = 0.5f;
  const PointCloud s = test::torus_samples(c, R, rr, 240, 96);
  const SurfaceResult r = reconstruct_surface(s, c + Vec3f(R, 0, 0), {.cell_mm = cell});
  EXPECT_TRUE(r.seed_enclosed);
  EXPECT_TRUE(r.topology.watertight);
  EXPECT_TRUE(r.topology.manifold);
  EXPECT_EQ(r.topology.components, 1);
  EXPECT_EQ(r.topology.genus, 1);
  double sum = 0.0;
  for (const auto& v : r.mesh.vertices) sum += test::torus_distance(v, c, R, rr);
  EXPECT_LE(sum / r.mesh.vertices.size(), 0.25 * cell);
  // The hole stays open: its centre is not enclosed.
  EXPECT_FALSE(encloses(r.mesh, c));
}

TEST(Poisson, SpherePiercedByANeedleChannelHasGenusOne) {
  // The biopsy case of DESIGN.md: a solid sphere with a straight channel through it.
  const float R = 9.0f, a = 2.0f, zc = std::sqrt(R * R - a * a);
  PointCloud s;
  const PointCloud ball = test::sphere_samples(Vec3f::Zero(), R, 6000);
  for (std::size_t i = 0; i < ball.points.size(); ++i) {
    if (std::hypot(ball.points[i].x(), ball.points[i].y()) < a) continue;  // the channel's mouths
    s.points.push_back(ball.points[i]);
    s.normals.push_back(ball.normals[i]);
    s.area_mm2.push_back(ball.area_mm2[i]);
  }
  const int nu = 40, nzs = 90;
  for (int i = 0; i < nu; ++i)
    for (int k = 0; k < nzs; ++k) {
      const float u = 2 * kPi * (i + 0.5f) / nu, z = -zc + 2 * zc * (k + 0.5f) / nzs;
      const Vec3f radial(std::cos(u), std::sin(u), 0.0f);
      s.points.push_back(a * radial + Vec3f(0, 0, z));
      s.normals.push_back(-radial);  // out of the solid = into the channel
      s.area_mm2.push_back(2 * kPi * a / nu * 2 * zc / nzs);
    }
  const SurfaceResult r = reconstruct_surface(s, Vec3f(5.5f, 0, 0), {.cell_mm = 0.4f});
  EXPECT_TRUE(r.seed_enclosed);
  EXPECT_TRUE(r.topology.watertight);
  EXPECT_TRUE(r.topology.manifold);
  EXPECT_EQ(r.topology.components, 1);
  EXPECT_EQ(r.topology.genus, 1);
  EXPECT_FALSE(encloses(r.mesh, Vec3f::Zero()));  // the channel is open
}

TEST(Poisson, SphereWithACapRemovedIsClosedAgain) {
  // What opening leaves behind: samples with a hole where the balloon met itself.
  const Vec3f c(0, 0, 0);
  const float R = 8.0f;
  PointCloud all = test::sphere_samples(c, R, 4000), cut;
  for (std::size_t i = 0; i < all.points.size(); ++i) {
    if (all.points[i].z() > 0.6f * R) continue;
    cut.points.push_back(all.points[i]);
    cut.normals.push_back(all.normals[i]);
    cut.area_mm2.push_back(all.area_mm2[i]);
  }
  const SurfaceResult r = reconstruct_surface(cut, c, {.cell_mm = 0.5f});
  EXPECT_TRUE(r.seed_enclosed);
  EXPECT_TRUE(r.topology.watertight);
  EXPECT_TRUE(r.topology.manifold);
  EXPECT_EQ(r.topology.genus, 0);
  EXPECT_EQ(r.topology.components, 1);
  // Below the cut the sphere is still where it was (within half a cell).
  double sum = 0.0;
  int n = 0;
  for (const auto& v : r.mesh.vertices)
    if (v.z() < 0.2f * R) {
      sum += std::abs((v - c).norm() - R);
      ++n;
    }
  ASSERT_GT(n, 100);
  EXPECT_LE(sum / n, 0.25);
}

TEST(Poisson, FarFromTheOriginNothingWrapsAround) {
  const Vec3f c(1000.0f, -500.0f, 250.0f);
  const float R = 6.0f, cell = 0.4f;
  const SurfaceResult r =
      reconstruct_surface(test::sphere_samples(c, R, 3000), c, {.cell_mm = cell});
  EXPECT_EQ(r.components_before_selection, 1);  // no ghost surface from the periodic images
  EXPECT_EQ(r.topology.genus, 0);
  EXPECT_LE(mean_sphere_error(r.mesh, c, R), 0.25 * cell);
  // Nothing near the padded box faces.
  const Vec3f lo = r.indicator.min_mm(), hi = r.indicator.max_mm();
  const float margin = 0.1f * 2 * R;
  for (const auto& v : r.mesh.vertices) {
    ASSERT_TRUE(((v - lo).array() > margin).all());
    ASSERT_TRUE(((hi - v).array() > margin).all());
  }
  // The whole boundary of the grid is outside.
  const auto& d = r.indicator.dims();
  for (int k = 0; k < d.z(); k += d.z() - 1)
    for (int j = 0; j < d.y(); ++j)
      for (int i = 0; i < d.x(); ++i) ASSERT_LT(r.indicator.value(i, j, k), r.iso);
}

TEST(Poisson, CentralDifferenceModeIsAlsoWithinAQuarterCell) {
  const Vec3f c(0.3f, 0.2f, -0.1f);
  const float R = 10.0f, cell = 0.5f;
  const SurfaceResult r =
      reconstruct_surface(test::sphere_samples(c, R, 5000), c,
                          {.cell_mm = cell, .divergence = DivergenceMode::CentralDifference});
  EXPECT_TRUE(r.topology.watertight);
  EXPECT_EQ(r.topology.genus, 0);
  EXPECT_LE(mean_sphere_error(r.mesh, c, R), 0.25 * cell);
}

TEST(Poisson, GridDimsAreFftFriendlyAndPadded) {
  const Vec3f c(0, 0, 0);
  const IndicatorGrid g =
      poisson_indicator(test::sphere_samples(c, 7.0f, 1000), {.cell_mm = 0.45f});
  for (int a = 0; a < 3; ++a) {
    int n = g.chi.dims()[a];
    for (int p : {2, 3, 5})
      while (n % p == 0) n /= p;
    EXPECT_EQ(n, 1) << g.chi.dims()[a];
    EXPECT_GE((g.chi.dims()[a] - 1) * 0.45f, 14.0f * 1.2f);  // ≥ 10% margin on each side
  }
}

TEST(Poisson, MaxGridDimCoarsensTheCell) {
  const IndicatorGrid g = poisson_indicator(test::sphere_samples(Vec3f::Zero(), 20.0f, 2000),
                                            {.cell_mm = 0.1f, .max_grid_dim = 64});
  EXPECT_LE(g.chi.dims().maxCoeff(), 64);
  EXPECT_GT(g.cell_mm, 0.1f);
}

TEST(Poisson, SecondCallReusesTheCachedPlans) {
  const PointCloud s = test::sphere_samples(Vec3f(1, 2, 3), 5.0f, 800);
  const PoissonOptions o{.cell_mm = 0.37f};  // a grid size no other test uses
  poisson_indicator(s, o);
  const auto before = internal::fft_plan_stats();
  poisson_indicator(s, o);
  const auto after = internal::fft_plan_stats();
  EXPECT_EQ(after.plans_created, before.plans_created);
  EXPECT_GT(after.cache_hits, before.cache_hits);
}

TEST(Poisson, ConcurrentCallsShareOnePlanPerGridSize) {
  // A stretched cloud gives a grid shape no other test uses, so the plans are new here.
  PointCloud s = test::sphere_samples(Vec3f(-1, 0, 2), 4.0f, 600);
  for (auto& p : s.points) p = Vec3f(0.4f * p.x(), 3.1f * p.y(), p.z());
  const PoissonOptions o{.cell_mm = 0.29f};
  const auto before = internal::fft_plan_stats();
  IndicatorGrid a, b;
  std::thread t1([&] { a = poisson_indicator(s, o); });
  std::thread t2([&] { b = poisson_indicator(s, o); });
  t1.join();
  t2.join();
  EXPECT_EQ(internal::fft_plan_stats().plans_created - before.plans_created, 2u);  // r2c + c2r
  ASSERT_EQ(a.chi.dims(), b.chi.dims());
  EXPECT_EQ(a.chi.f32(), b.chi.f32());
  EXPECT_EQ(a.iso, b.iso);
}

TEST(Poisson, RejectsBadInput) {
  PointCloud s = test::sphere_samples(Vec3f::Zero(), 5.0f, 100);
  EXPECT_THROW(poisson_indicator(PointCloud{}), std::invalid_argument);
  EXPECT_THROW(poisson_indicator(s, {.padding_fraction = 0.05f}), std::invalid_argument);
  EXPECT_THROW(poisson_indicator(s, {.cell_mm = 0.0f}), std::invalid_argument);
  PointCloud weightless = s;
  std::fill(weightless.area_mm2.begin(), weightless.area_mm2.end(), 0.0f);
  EXPECT_THROW(poisson_indicator(weightless), std::invalid_argument);
  s.area_mm2.pop_back();
  EXPECT_THROW(poisson_indicator(s), std::invalid_argument);
  PointCloud nan = test::sphere_samples(Vec3f::Zero(), 5.0f, 100);
  nan.points[3].x() = std::nanf("");
  EXPECT_THROW(poisson_indicator(nan), std::invalid_argument);
}

}  // namespace
}  // namespace sonomesh::reconstruct

namespace sonomesh::reconstruct {
namespace {

TEST(Outputs, LabelsAndIndicatorOfAReconstructedSphere) {
  // method.md §6: a label volume on the input grid and the indicator as an OpenVDB grid.
  const Vec3f c(12.0f, 12.5f, 11.8f);
  const float R = 8.0f;
  const SurfaceResult r =
      reconstruct_surface(test::sphere_samples(c, R, 4000), c, {.cell_mm = 0.5f});
  const volume::Volume input(volume::Vec3i(48, 50, 48), Vec3f::Constant(0.5f), Vec3f::Zero(),
                             volume::VoxelType::UInt8);
  const volume::Volume labels = rasterize_labels(r.mesh, input);
  std::size_t count = 0;
  for (auto v : labels.u8()) count += v;
  const double analytic = 4.0 / 3.0 * kPi * R * R * R / 0.125;
  EXPECT_NEAR(double(count), analytic, 0.02 * analytic);
  EXPECT_EQ(labels.u8()[labels.linear_index(24, 25, 24)], 1);
  EXPECT_EQ(labels.u8()[labels.linear_index(2, 2, 2)], 0);
  const auto path = std::filesystem::temp_directory_path() /
                    ("sonomesh_reconstruct_chi_" + std::to_string(::getpid()) + ".vdb");
  const auto error = volume::write_vdb(r.indicator, path, "chi");
  EXPECT_FALSE(error.has_value()) << error->message;
  EXPECT_GT(std::filesystem::file_size(path), 1000u);
  std::filesystem::remove(path);
}

}  // namespace
}  // namespace sonomesh::reconstruct
