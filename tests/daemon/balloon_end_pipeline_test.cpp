// How the balloon's first pass ends on an echo cyst-needle: once it sweeps nothing new (it stops
// early, as the iteration limit would have it), and with its folds opened rather than kept as
// walls (BalloonEvolution::open_folds; docs/stopping.md item 16).
#include <gtest/gtest.h>

#include <algorithm>
#include <string>

#include "daemon/internal/metrics.h"
#include "daemon/pipeline.h"
#include "sim/sim.h"

namespace sonomesh::daemon {
namespace {

sim::Phantom breathing_cyst_needle(int size_vox, unsigned seed, float time_s) {
  sim::PhantomSpec spec{.phantom = "cyst-needle", .size_vox = size_vox, .seed = seed};
  spec.contrast = 0.7f;
  spec.time_s = time_s;
  return sim::make_phantom(sim::with_echo_realism(spec));
}

// Ψ_cost alone, as the second opinion would replace a suspect result.
PipelineResult first_opinion(const sim::Phantom& phantom) {
  PipelineConfig config;
  config.second_opinion_level_stop = 0.0f;
  return run_pipeline(phantom.image, phantom.seed_mm, config);
}

bool has_reason(const PipelineResult& r, const std::string& reason) {
  return std::find(r.quality_reasons.begin(), r.quality_reasons.end(), reason) !=
         r.quality_reasons.end();
}

// 96³, seed 4, t = 0.8 s (2026-12-05): ~125 vertices trade places in the crease by the needle
// from iteration ~440 on; A_t stops growing and the pass ends at 500 of 2000 iterations, with the
// same surface (Dice 0.962 either way) and the same verdict as at the limit.
TEST(BalloonEndPipeline, ABalloonThatSweepsNothingNewEndsAsTheLimitWould) {
  const sim::Phantom phantom = breathing_cyst_needle(96, 4, 0.8f);
  const PipelineResult r = first_opinion(phantom);
  ASSERT_TRUE(r.ok) << r.error;
  EXPECT_TRUE(r.balloon_stats.swept_out);
  EXPECT_LT(r.balloon_iterations, 1000);
  EXPECT_GT(r.stop_counts.iteration_limit, 0);
  EXPECT_TRUE(has_reason(r, "iteration limit"));
  EXPECT_EQ(r.topology.genus, 1);
  ASSERT_TRUE(r.labels);
  EXPECT_GE(internal::dice(*r.labels, phantom.truth), 0.95);
}

// 128³ (the fold needs the needle's shadow this many voxels wide; at 96³, also at 0.67 mm, the
// balloon does not fold), seed 1, t = 4.6 s: the balloon stops at the far edge of the needle's
// shadow inside the cyst, its other side fills the cyst behind that stop, and the two layers fold.
// Kept as a wall, the fold cut the cyst's far part off: Dice 0.898, volume −14 %; opened, 0.972.
TEST(BalloonEndPipeline, AFoldBehindTheNeedlesShadowIsOpenedNotKeptAsAWall) {
  const sim::Phantom phantom = breathing_cyst_needle(128, 1, 4.6f);
  const PipelineResult r = first_opinion(phantom);
  ASSERT_TRUE(r.ok) << r.error;
  EXPECT_EQ(r.topology.genus, 1);
  ASSERT_TRUE(r.labels);
  EXPECT_GE(internal::dice(*r.labels, phantom.truth), 0.95);
  const auto& truth = phantom.truth.u8();
  const double truth_ml = static_cast<double>(std::count(truth.begin(), truth.end(), 1)) *
                          phantom.truth.spacing_mm().prod() / 1000.0;
  EXPECT_NEAR(r.enclosed_volume_ml / truth_ml, 1.0, 0.05);
}

}  // namespace
}  // namespace sonomesh::daemon
