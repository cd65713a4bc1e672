// A needle that ends inside the target (its tip in the cyst's middle) makes a dent: a handle it
// cannot explain is filled (false_tunnels.cpp), one left is never called ok (quality.cpp, "needle
// ends inside"), and its walls inside the surface are its dent, not a missing tunnel. A needle
// through the cyst is not flagged. Numbers behind the cases: docs/results.md.
#include <gtest/gtest.h>

#include <algorithm>
#include <string>

#include "daemon/internal/metrics.h"
#include "daemon/pipeline.h"
#include "sim/sim.h"

namespace sonomesh::daemon {
namespace {

// The 0.4 mm breathing echo cyst-needle at 2.1 s, the needle through it (reach 1) or withdrawn
// to its middle (reach 0).
sim::Phantom cyst_needle(float reach) {
  sim::PhantomSpec spec{.phantom = "cyst-needle", .size_vox = 96};
  spec.spacing_mm = Vec3f::Constant(0.4f);
  spec.contrast = 0.5f;
  spec.time_s = 2.1f;
  spec.needle_reach = reach;
  return sim::make_phantom(sim::with_echo_realism(spec));
}

bool flagged(const PipelineResult& result) {
  return std::ranges::find(result.quality_reasons, "needle ends inside") !=
         result.quality_reasons.end();
}

// Seeds 1.6 mm off the deepest point, along +x, +y and +z: on main each gave genus 1, called ok.
const Vec3f kOffsets_mm[] = {{1.6f, 0.0f, 0.0f}, {0.0f, 1.6f, 0.0f}, {0.0f, 0.0f, 1.6f}};

TEST(NeedleEnds, AHandleWhereTheNeedleEndsInsideIsNeverOk) {
  const sim::Phantom phantom = cyst_needle(0.0f);
  ASSERT_EQ(phantom.genus, 0);
  for (const Vec3f& offset : kOffsets_mm) {
    const PipelineResult result = run_pipeline(phantom.image, phantom.seed_mm + offset, {});
    ASSERT_TRUE(result.ok) << result.error;
    ASSERT_TRUE(result.needle_ends_mm) << "the shadow search found no needle";
    if (result.topology.genus == 0) continue;
    EXPECT_TRUE(flagged(result)) << "genus " << result.topology.genus << " at offset "
                                 << offset.transpose();
    EXPECT_FALSE(result.quality_ok);
  }
}

// Seeds 1.2 and 2 mm off the deepest point along ±x, ±y, ±z. Before the fill and the dent's
// walls, 5 of the 12 were ok and 6 kept the tip's handle (genus 1, suspect); now 11 are ok, all
// genus 0. Which seeds come out which way changes with the seed's last bits (docs/results.md):
// the test counts.
TEST(NeedleEnds, ANeedleEndingInsideMakesADentCalledOk) {
  const sim::Phantom phantom = cyst_needle(0.0f);
  int dented = 0;
  for (const float off_mm : {1.2f, 2.0f})
    for (int axis = 0; axis < 3; ++axis)
      for (const float sign : {1.0f, -1.0f}) {
        const Vec3f offset = sign * off_mm * Vec3f::Unit(axis);
        PipelineConfig config;
        config.want_labels = true;
        const PipelineResult result = run_pipeline(phantom.image, phantom.seed_mm + offset, config);
        ASSERT_TRUE(result.ok && result.labels) << result.error;
        if (!result.quality_ok) continue;
        EXPECT_EQ(result.topology.genus, 0) << "offset " << offset.transpose();
        EXPECT_GE(internal::dice(*result.labels, phantom.truth), 0.9)
            << "offset " << offset.transpose();
        ++dented;
      }
  EXPECT_GE(dented, 9);
}

// The 0.5 mm one of seed 2 at 2.4 s: the balloon's seam drew the dent 7 voxels on past the tip
// and a handle formed beyond it, which the line 4 voxels past the tip does not reach (genus 1,
// called ok, when only that point was tested).
TEST(NeedleEnds, AHandleBeyondASeamPastTheTipIsNeverOk) {
  sim::PhantomSpec spec{.phantom = "cyst-needle", .size_vox = 96, .seed = 2};
  spec.contrast = 0.5f;
  spec.time_s = 2.4f;
  spec.needle_reach = 0.0f;
  const sim::Phantom phantom = sim::make_phantom(sim::with_echo_realism(spec));
  const PipelineResult result = run_pipeline(phantom.image, phantom.seed_mm, {});
  ASSERT_TRUE(result.ok) << result.error;
  if (result.topology.genus == 0) return;
  EXPECT_TRUE(flagged(result)) << "genus " << result.topology.genus;
  EXPECT_FALSE(result.quality_ok);
}

TEST(NeedleEnds, ANeedleThroughTheTargetIsNotFlagged) {
  const sim::Phantom phantom = cyst_needle(1.0f);
  ASSERT_EQ(phantom.genus, 1);
  for (const Vec3f& offset : kOffsets_mm) {
    const PipelineResult result = run_pipeline(phantom.image, phantom.seed_mm + offset, {});
    ASSERT_TRUE(result.ok) << result.error;
    ASSERT_TRUE(result.needle_ends_mm) << "the shadow search found no needle";
    EXPECT_EQ(result.topology.genus, 1) << "offset " << offset.transpose();
    EXPECT_FALSE(flagged(result)) << "offset " << offset.transpose();
  }
}

}  // namespace
}  // namespace sonomesh::daemon
