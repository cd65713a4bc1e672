// The needle tunnel at 64³: the simulator's needle is 2.5 voxels across there, narrower than what
// a reconstruction on the voxel grid keeps open (reconstruct/thin_feature_test.cpp), so the
// pipeline only gets genus 1 if the reconstruction refines its grid for it. That refinement is
// opt-in (PoissonOptions::min_feature_cells, off by default: it also keeps spurious handles).
// Also the other way: a thick target's reconstructions on cells coarser than its voxels.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <tuple>

#include "daemon/internal/metrics.h"
#include "daemon/internal/stages.h"
#include "daemon/pipeline.h"
#include "sim/sim.h"

namespace sonomesh::daemon {
namespace {

class PipelineThinTunnel : public ::testing::TestWithParam<std::uint32_t> {};

TEST_P(PipelineThinTunnel, CystNeedleAt64KeepsTheTunnel) {
  const sim::Phantom phantom =
      sim::make_phantom({.phantom = "cyst-needle", .size_vox = 64, .seed = GetParam()});
  ASSERT_EQ(phantom.genus, 1);
  PipelineConfig config;
  config.poisson.min_feature_cells = 4.0f;
  const PipelineResult result = run_pipeline(phantom.image, phantom.seed_mm, config);
  ASSERT_TRUE(result.ok) << result.error;
  EXPECT_TRUE(result.topology.watertight);
  EXPECT_EQ(result.topology.components, 1);
  EXPECT_EQ(result.topology.genus, 1);
  // Opening the tunnel must not cost the shape: 0.949-0.960 over these seeds, 0.953-0.961 when the
  // tunnel closed.
  ASSERT_TRUE(result.labels.has_value());
  EXPECT_GE(internal::dice(*result.labels, phantom.truth), 0.93);
}

INSTANTIATE_TEST_SUITE_P(SpeckleSeeds, PipelineThinTunnel, ::testing::Values(1u, 2u, 3u, 4u));

// With the default options at contrast 0.5 the first reconstruction closed the 64³ needle's
// tunnel and the result was called ok at genus 0; there is no probe sector here and so no
// shadow to say a needle is there. The fitted surface passed over the needle whole, which opens
// it (docs/stopping.md item 14).
TEST_P(PipelineThinTunnel, CystNeedleAt64AndContrastHalfIsOpenedOrFlagged) {
  const sim::Phantom phantom = sim::make_phantom(
      {.phantom = "cyst-needle", .size_vox = 64, .contrast = 0.5f, .seed = GetParam()});
  ASSERT_EQ(phantom.genus, 1);
  const PipelineResult result = run_pipeline(phantom.image, phantom.seed_mm, PipelineConfig{});
  ASSERT_TRUE(result.ok) << result.error;
  EXPECT_TRUE(result.topology.genus == 1 || !result.quality_ok);
  ASSERT_TRUE(result.labels.has_value());
  EXPECT_GE(internal::dice(*result.labels, phantom.truth), 0.92);
}

// Seeded 0.45 of the radius off the centre beside the needle, the 64³ cyst-needle read a grain of
// 0.90-0.99 mm (1.8-2 voxels; 0.71 at the centre): the needle crossing the cube lengthened the
// correlation, the pre-filter followed it, and the tunnel closed into a groove (genus 0, called
// ok, Dice 0.97-0.98). Measured without the cube's bright voxels the grain reads 0.66-0.73 mm and
// the pre-filter stays at one voxel (docs/stopping.md departure 1, "Without the needle").
TEST(PipelineThinTunnel, ANeedleBesideTheSeedLeavesThePreFilterFine) {
  for (const auto& [contrast, offset] :
       {std::pair(0.5f, Vec3f(0, 0, 0.45f)), std::pair(0.7f, Vec3f(0, 0, 0.45f)),
        std::pair(0.7f, Vec3f(-0.45f, 0, 0))}) {
    const sim::Phantom phantom = sim::make_phantom(
        {.phantom = "cyst-needle", .size_vox = 64, .contrast = contrast, .seed = 1});
    const float radius_mm = static_cast<float>(internal::equivalent_radius_mm(phantom.truth));
    const PipelineResult r =
        run_pipeline(phantom.image, phantom.seed_mm + radius_mm * offset, PipelineConfig{});
    ASSERT_TRUE(r.ok) << contrast << ": " << r.error;
    EXPECT_LE(r.smooth_sigma_mm, phantom.image.spacing_mm().minCoeff()) << contrast;
    EXPECT_EQ(r.topology.genus, 1) << contrast << " " << offset.transpose();
  }
}

// The fitted surface is made again on cells 1.25 times the voxel, coarser for a thick target (a
// 96³ sphere, about 23 voxels thick), and not for a thin one (a 64³ double torus, about 7).
TEST(PipelineResurface, ThickTargetsOnCoarserCells) {
  for (const auto& [name, size, coarsest] :
       {std::tuple("sphere", 96, 1.5f), std::tuple("double-torus", 64, 1.25f)}) {
    const sim::Phantom phantom = sim::make_phantom({.phantom = name, .size_vox = size});
    const PipelineConfig config;
    const PipelineResult r = run_pipeline(phantom.image, phantom.seed_mm, config);
    ASSERT_TRUE(r.ok) << name << ": " << r.error;
    const auto again =
        internal::resurfaced(phantom.image, r.mesh, phantom.genus, phantom.seed_mm, config, true);
    ASSERT_TRUE(again.has_value()) << name;
    const float vox_mm = phantom.image.spacing_mm().minCoeff();
    EXPECT_NEAR(again->cell_mm, coarsest * vox_mm, 0.01f * vox_mm) << name;
    EXPECT_EQ(again->topology.genus, phantom.genus) << name;
  }
}

// A thick target is reconstructed first on cells coarser than its voxels, its surface made again
// from the fitted one; a needle's tunnel through the cyst brings the cells back to the voxel.
TEST(PipelineFirstCell, CoarserForAThickTargetTheVoxelForANeedlesTunnel) {
  for (const char* name : {"sphere", "cyst-needle"}) {
    const sim::Phantom phantom = sim::make_phantom({.phantom = name, .size_vox = 96});
    const PipelineResult r = run_pipeline(phantom.image, phantom.seed_mm, PipelineConfig{});
    ASSERT_TRUE(r.ok) << name << ": " << r.error;
    const float vox_mm = phantom.image.spacing_mm().minCoeff();
    if (phantom.genus == 0) {
      EXPECT_GE(r.grid_cell_mm, 1.25f * vox_mm) << name;
    } else {
      EXPECT_LE(r.grid_cell_mm, vox_mm) << name;
    }
    EXPECT_TRUE(r.resurfaced) << name;
    EXPECT_EQ(r.topology.genus, phantom.genus) << name;
    ASSERT_TRUE(r.labels.has_value());
    EXPECT_GE(internal::dice(*r.labels, phantom.truth), 0.97) << name;
  }
}

// A dark cavity (a ball of 24 voxels' radius) crossed by three columns of tissue, 2.5 voxels in
// radius, each from wall to wall beside the seed, and with `needle` a brighter needle through it
// too: a ventricle with its trabeculae, a cyst with its needle. uint8, 72³ of 1 mm.
volume::Volume cavity_with_columns(bool needle) {
  using volume::Vec3i;
  volume::Volume v(Vec3i(72, 72, 72), Vec3f(1, 1, 1), Vec3f(0, 0, 0), volume::VoxelType::UInt8);
  for (int k = 0; k < 72; ++k)
    for (int j = 0; j < 72; ++j)
      for (int i = 0; i < 72; ++i) {
        const Vec3f d(i - 36.0f, j - 36.0f, k - 36.0f);
        const bool column = std::hypot(d.x() - 11.0f, d.y()) < 2.5f ||
                            std::hypot(d.y() + 11.0f, d.z() - 5.0f) < 2.5f ||
                            std::hypot(d.z() + 11.0f, d.x() + 6.0f) < 2.5f;
        const bool pierced = needle && std::hypot(d.x() + 4.0f, d.z() - 8.0f) < 1.5f;
        const float level = pierced ? 230.0f : (d.norm() < 24.0f && !column ? 20.0f : 100.0f);
        // A little texture, the same on every run.
        const float texture = 6.0f * std::sin(0.9f * i + 1.3f * j) * std::cos(1.1f * k + 0.7f * i);
        v.u8()[v.linear_index(i, j, k)] = static_cast<std::uint8_t>(level + texture);
      }
  return v;
}

bool has_reason(const PipelineResult& r, const std::string& reason) {
  return std::find(r.quality_reasons.begin(), r.quality_reasons.end(), reason) !=
         r.quality_reasons.end();
}

// More handles than a target has: the tunnels round the columns of tissue are filled (a reader's
// contour takes them in), the needle's stays, and the result says so and is suspect.
TEST(PipelineTissueColumns, AreFilledWhereTheHandlesAreImplausibleAndTheNeedleStays) {
  for (const bool needle : {false, true}) {
    const volume::Volume v = cavity_with_columns(needle);
    PipelineConfig config;
    config.want_labels = false;
    // (The texture is no speckle: its 2-voxel period, read beside the columns as a grain, would
    // set the pre-filter. The volumes this stands for take one voxel.)
    config.smooth_sigma_mm = 1.0f;
    const PipelineResult r = run_pipeline(v, Vec3f(36, 36, 36), config);
    ASSERT_TRUE(r.ok) << r.error;
    EXPECT_TRUE(r.tissue_columns_filled) << "needle " << needle;
    EXPECT_EQ(r.topology.genus, needle ? 1 : 0);
    EXPECT_TRUE(r.topology.watertight);
    EXPECT_TRUE(has_reason(r, "tissue columns filled")) << "needle " << needle;
    EXPECT_FALSE(has_reason(r, "implausible genus")) << "needle " << needle;
  }
}

// At 0.4 mm the 96³ echo cyst-needle's grain is 1.5 voxels, and the balloon's fronts that went
// round the needle stopped on the inside's grains a cell or two apart: a sheet of outside from
// the needle's tunnel to the wall, one handle more, called ok (genus 2 on 12 of the 19 phases
// t = 2.1-3.9 s, 8 of them ok). The sheet is filled (docs/stopping.md item 11).
TEST(PipelineFrontsSheet, AnEchoCystNeedleAtFourTenthsOfAMillimetreHasOneHandle) {
  for (const float time_s : {2.2f, 2.4f}) {
    const sim::PhantomSpec spec{.phantom = "cyst-needle",
                                .size_vox = 96,
                                .spacing_mm = Vec3f::Constant(0.4f),
                                .contrast = 0.5f,
                                .time_s = time_s};
    const sim::Phantom phantom = sim::make_phantom(sim::with_echo_realism(spec));
    const PipelineResult r = run_pipeline(phantom.image, phantom.seed_mm, PipelineConfig{});
    ASSERT_TRUE(r.ok && r.labels) << "t " << time_s << ": " << r.error;
    EXPECT_EQ(r.topology.genus, 1) << "t " << time_s;
    EXPECT_GE(internal::dice(*r.labels, phantom.truth), 0.93) << "t " << time_s;
  }
}

}  // namespace
}  // namespace sonomesh::daemon
