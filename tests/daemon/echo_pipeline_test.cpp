// The echo realism mode (sim::with_echo_realism) through the pipeline: seeds in blood-pool
// speckle are accepted, the balloon's region term (BalloonOptions::region_fraction) keeps
// vertices moving past speckle grains, and the level stop (level_stop_fraction) stops them on the
// wall instead. Numbers behind the bounds: docs/stopping.md.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <tuple>
#include <utility>

#include "daemon/internal/metrics.h"
#include "daemon/pipeline.h"
#include "echo_phantoms.h"
#include "sim/sim.h"

namespace sonomesh::daemon {
namespace {

using test::echo_phantom;
using test::truth_ml;

// The default pipeline on `phantom` with one of its steps off, then on; both with labels.
std::pair<PipelineResult, PipelineResult> off_and_on(const sim::Phantom& phantom,
                                                     bool PipelineConfig::*step) {
  PipelineConfig config;
  config.*step = false;
  PipelineResult off = run_pipeline(phantom.image, phantom.seed_mm, config);
  config.*step = true;
  PipelineResult on = run_pipeline(phantom.image, phantom.seed_mm, config);
  EXPECT_TRUE(off.ok && on.ok) << off.error << on.error;
  return {std::move(off), std::move(on)};
}

// One stop rule alone, without the pipeline's second opinion.
double pipeline_dice(const sim::Phantom& phantom, float region_fraction, int& genus,
                     float level_stop_fraction = 0.0f) {
  PipelineConfig config;
  config.second_opinion_level_stop = 0.0f;
  config.balloon.region_fraction = region_fraction;
  config.balloon.level_stop_fraction = level_stop_fraction;
  const PipelineResult result = run_pipeline(phantom.image, phantom.seed_mm, config);
  EXPECT_TRUE(result.ok) << result.error;
  genus = result.topology.genus;
  return result.ok && result.labels ? internal::dice(*result.labels, phantom.truth) : 0.0;
}

// The cyst-needle of seed 2 reads 24 grey levels of contrast at a ball sigma of 12.7 (1.9
// sigma): refused at the 2 sigma this test once needed; at 1.8 it gives genus 1 (suspect).
TEST(EchoPipeline, SeedInBloodPoolSpeckleIsAccepted) {
  for (const char* name : {"sphere", "cyst-needle"})
    for (unsigned seed : {1u, 2u}) {
      const sim::Phantom phantom = echo_phantom(name, 0.3f, 64, seed);
      const PipelineResult result = run_pipeline(phantom.image, phantom.seed_mm, PipelineConfig{});
      EXPECT_EQ(result.error.find("hypoechoic"), std::string::npos)
          << name << " seed " << seed << ": " << result.error;
    }
}

TEST(EchoPipeline, RegionTermRecoversTheSphereAtContrastHalf) {
  const sim::Phantom phantom = echo_phantom("sphere", 0.5f);
  int genus_off = -1, genus_on = -1;
  const double off = pipeline_dice(phantom, 0.0f, genus_off);
  const double on = pipeline_dice(phantom, 0.5f, genus_on);
  EXPECT_EQ(genus_on, 0);
  EXPECT_GE(on, 0.88);
  EXPECT_GE(on, off + 0.1) << "without the region term " << off;
}

TEST(EchoPipeline, RegionTermKeepsTheCystNeedleTunnelAtContrastHalf) {
  const sim::Phantom phantom = echo_phantom("cyst-needle", 0.5f);
  int genus = -1;
  EXPECT_GE(pipeline_dice(phantom, 0.5f, genus), 0.83);
  EXPECT_EQ(genus, 1);
}

// Measured at 64³, seed 1 (2026-12-02, the wall level unscaled by the mean behind): sphere 0.70
// off, 0.935 on; lv 0.917; torus 0.845 with its tunnel; double torus 0.880 with both. (The
// cyst-needle leaks along its shadow: not yet.)
TEST(EchoPipeline, LevelStopFindsTheWallBehindSpeckleAtContrastHalf) {
  const sim::Phantom sphere = echo_phantom("sphere", 0.5f);
  int genus = -1;
  const double off = pipeline_dice(sphere, 0.0f, genus);
  const double on = pipeline_dice(sphere, 0.0f, genus, 0.5f);
  EXPECT_EQ(genus, 0);
  EXPECT_GE(on, 0.9);
  EXPECT_GE(on, off + 0.15) << "without the level stop " << off;
  for (const auto& [name, genus_expected, least_dice] :
       {std::tuple{"lv", 0, 0.88}, std::tuple{"torus", 1, 0.83},
        std::tuple{"double-torus", 2, 0.83}}) {
    const double dice = pipeline_dice(echo_phantom(name, 0.5f), 0.0f, genus, 0.5f);
    EXPECT_EQ(genus, genus_expected) << name;
    EXPECT_GE(dice, least_dice) << name;
  }
}

// The quality verdict's wall test: a surface that stopped on the blood pool's speckle (the sphere
// at contrast 0.5 with the paper's stop alone, Dice about 0.7) has the same grey levels on both
// sides over much of it; one on the wall (the level stop, Dice >= 0.9) has a wall beyond it
// (0.91, and 0.89 since the fit on the unsmoothed image: the share reads the smoothed one).
TEST(EchoPipeline, SurfaceStoppedOnSpeckleIsSuspect) {
  const sim::Phantom sphere = echo_phantom("sphere", 0.5f);
  PipelineConfig config;
  config.second_opinion_level_stop = 0.0f;
  const PipelineResult off = run_pipeline(sphere.image, sphere.seed_mm, config);
  ASSERT_TRUE(off.ok) << off.error;
  EXPECT_LT(off.wall_support, 0.75f);
  EXPECT_FALSE(off.quality_ok);
  EXPECT_NE(std::find(off.quality_reasons.begin(), off.quality_reasons.end(),
                      "surface not on the target's wall"),
            off.quality_reasons.end());
  config.balloon.level_stop_fraction = 0.5f;
  const PipelineResult on = run_pipeline(sphere.image, sphere.seed_mm, config);
  ASSERT_TRUE(on.ok) << on.error;
  EXPECT_GE(on.wall_support, 0.85f);
  EXPECT_EQ(std::find(on.quality_reasons.begin(), on.quality_reasons.end(),
                      "surface not on the target's wall"),
            on.quality_reasons.end());
}

// Ψ_cost first (as outside a probe's sector), the pipeline takes the second opinion where the
// paper's stop alone was suspect (the sphere above) and keeps the first result where it was ok
// (the simple simulator's sphere), at no extra cost there.
TEST(EchoPipeline, SecondOpinionReplacesASuspectResultOnly) {
  const sim::Phantom echo = echo_phantom("sphere", 0.5f);
  PipelineConfig cost_first;
  cost_first.level_stop_first_in_sector = false;
  const PipelineResult r = run_pipeline(echo.image, echo.seed_mm, cost_first);
  ASSERT_TRUE(r.ok && r.labels) << r.error;
  EXPECT_TRUE(r.second_opinion);
  EXPECT_EQ(r.stop_rule, "level");
  EXPECT_EQ(r.topology.genus, 0);
  EXPECT_GE(internal::dice(*r.labels, echo.truth), 0.9);
  EXPECT_GE(r.wall_support, 0.85f);
  const sim::Phantom simple = sim::make_phantom({.phantom = "sphere", .size_vox = 64});
  const PipelineResult plain = run_pipeline(simple.image, simple.seed_mm, PipelineConfig{});
  ASSERT_TRUE(plain.ok && plain.quality_ok) << plain.error;
  EXPECT_FALSE(plain.second_opinion);
  EXPECT_EQ(plain.stop_rule, "cost");
}

// In a probe's sector a cold start runs the level stop first: the same echo sphere needs one
// opinion, not two, for a result as good. The simple simulator has no sector: Ψ_cost first.
TEST(EchoPipeline, InAProbesSectorTheLevelStopGoesFirst) {
  const sim::Phantom echo = echo_phantom("sphere", 0.5f);
  const PipelineResult r = run_pipeline(echo.image, echo.seed_mm, PipelineConfig{});
  ASSERT_TRUE(r.ok && r.labels) << r.error;
  EXPECT_TRUE(r.quality_ok);
  EXPECT_EQ(r.stop_rule, "level");
  EXPECT_FALSE(r.second_opinion);
  EXPECT_EQ(r.topology.genus, 0);
  EXPECT_GE(internal::dice(*r.labels, echo.truth), 0.9);
  const sim::Phantom simple = sim::make_phantom({.phantom = "sphere", .size_vox = 64});
  EXPECT_EQ(run_pipeline(simple.image, simple.seed_mm, PipelineConfig{}).stop_rule, "cost");
}

// A balloon stalled in a torus's tube at 64³ (the paper's stop alone: genus 0, Dice about 0.4,
// yet every test of the verdict passed) leaves caps that look down the tube: the open patch asks
// for the second opinion, whose surface lies on the wall. The simple simulator's cyst-needle
// gets no second look: its needle's shadow is darker than the wall but not as dark as the
// inside (a test against the wall's mid level asked, and the level stop leaked for seconds).
TEST(EchoPipeline, OpenPatchAsksForTheSecondOpinion) {
  const sim::Phantom torus = echo_phantom("torus", 0.5f);
  int genus = -1;
  const double alone = pipeline_dice(torus, 0.0f, genus);
  EXPECT_EQ(genus, 0) << "the paper's stop alone found the hole; Dice " << alone;
  PipelineConfig cost_first;  // (Ψ_cost first, as outside a sector)
  cost_first.level_stop_first_in_sector = false;
  const PipelineResult r = run_pipeline(torus.image, torus.seed_mm, cost_first);
  ASSERT_TRUE(r.ok && r.labels) << r.error;
  EXPECT_TRUE(r.second_opinion);
  EXPECT_EQ(r.topology.genus, 1);
  EXPECT_TRUE(r.quality_ok);
  EXPECT_LT(r.open_patch, 0.015f);
  EXPECT_GE(internal::dice(*r.labels, torus.truth), 0.88);
  const sim::Phantom needle = sim::make_phantom({.phantom = "cyst-needle", .size_vox = 64});
  const PipelineResult kept = run_pipeline(needle.image, needle.seed_mm, PipelineConfig{});
  ASSERT_TRUE(kept.ok) << kept.error;
  EXPECT_EQ(kept.topology.genus, 1);
  EXPECT_FALSE(kept.second_opinion) << "open patch " << kept.open_patch;
}

// A thin target (its deepest point under 6 voxels inside) gets the second opinion even where
// the open patch is small: the 64³ echo double torus at contrast 0.7 stalled in a tube with its
// caps on a grain (measured 2026-12-04: genus 0, Dice 0.807, ok) and the level stop's result
// (genus 2, Dice 0.906) is kept.
TEST(EchoPipeline, AThinTargetAsksForTheSecondOpinion) {
  const sim::Phantom dt = echo_phantom("double-torus", 0.7f);
  const PipelineResult r = run_pipeline(dt.image, dt.seed_mm, PipelineConfig{});
  ASSERT_TRUE(r.ok && r.labels) << r.error;
  EXPECT_TRUE(r.second_opinion);
  EXPECT_LT(r.deepest_depth_mm, 6.0f * dt.image.spacing_mm().minCoeff());
  EXPECT_EQ(r.topology.genus, 2);
  EXPECT_GE(internal::dice(*r.labels, dt.truth), 0.88);
}

// A volume after one the level stop segmented (the second opinion) starts warm with the level
// stop too, and needs no second opinion: one balloon, not three.
TEST(EchoPipeline, WarmStartKeepsTheSecondOpinionsRule) {
  const sim::Phantom echo = echo_phantom("sphere", 0.5f);
  PipelineBuffers buffers;
  const PipelineResult first = run_pipeline(echo.image, echo.seed_mm, PipelineConfig{}, buffers);
  ASSERT_TRUE(first.ok && first.quality_ok) << first.error;
  ASSERT_EQ(first.stop_rule, "level");
  const WarmStart warm{first.balloon, first.balloon_stop, 1.5f, first.topology.genus, true,
                       nullptr};
  const PipelineResult next =
      run_pipeline(echo.image, echo.seed_mm, PipelineConfig{}, buffers, &warm);
  ASSERT_TRUE(next.ok && next.labels) << next.error;
  EXPECT_TRUE(next.warm_start) << next.start_reason;
  EXPECT_EQ(next.stop_rule, "level");
  EXPECT_FALSE(next.second_opinion);
  EXPECT_TRUE(next.quality_ok);
  EXPECT_GE(internal::dice(*next.labels, echo.truth), 0.9);
}

// A warm result that is suspect gets no second opinion: the volume before it was ok with the same
// rule, and the next volume starts cold. (A live stream pays for a second opinion only then.)
TEST(EchoPipeline, ASuspectWarmResultGetsNoSecondOpinion) {
  const sim::Phantom echo = echo_phantom("sphere", 0.5f);
  PipelineConfig cost_only;
  cost_only.second_opinion_level_stop = 0.0f;
  PipelineBuffers buffers;
  const PipelineResult first = run_pipeline(echo.image, echo.seed_mm, cost_only, buffers);
  ASSERT_TRUE(first.ok) << first.error;
  const WarmStart warm{first.balloon, first.balloon_stop, 1.5f, {}, false, nullptr};
  const PipelineResult next =
      run_pipeline(echo.image, echo.seed_mm, PipelineConfig{}, buffers, &warm);
  ASSERT_TRUE(next.ok) << next.error;
  ASSERT_TRUE(next.warm_start) << next.start_reason;
  EXPECT_FALSE(next.quality_ok);
  EXPECT_FALSE(next.second_opinion);
  EXPECT_EQ(next.stop_rule, "cost");
}

// At contrast 0.3 both stop rules stall on the blood-pool speckle the grain-sized pre-filter
// leaves; the coarse retry (docs/stopping.md departure 12) finds the target with its topology,
// the fine fit takes its surface back out to the wall (measured 2026-12-04: Dice 0.892-0.911 →
// 0.915-0.936, volume −13.6 to −1.7 % → −5.7 to +5.1 %), and the result is called suspect.
// With the needle's shadow lifted (item 17; 2026-12-05): cyst-needles 0.919 and 0.941, volume
// +4.3 and −1.7 % (before 0.914 and 0.927).
TEST(EchoPipeline, CoarseRetryGetsTheGenusRightAtContrastPointThree) {
  for (const auto& [name, genus] : {std::tuple{"sphere", 0}, std::tuple{"cyst-needle", 1}})
    for (unsigned seed : {1u, 2u}) {
      const sim::Phantom phantom = echo_phantom(name, 0.3f, 96, seed);
      const PipelineResult r = run_pipeline(phantom.image, phantom.seed_mm, PipelineConfig{});
      ASSERT_TRUE(r.ok && r.labels) << name << " seed " << seed << ": " << r.error;
      EXPECT_TRUE(r.coarse_retry) << name << " seed " << seed;
      EXPECT_EQ(r.topology.genus, genus) << name << " seed " << seed;
      EXPECT_GE(internal::dice(*r.labels, phantom.truth), 0.91) << name << " seed " << seed;
      EXPECT_NEAR(r.enclosed_volume_ml / truth_ml(phantom), 1.0, 0.07) << name << " seed " << seed;
      EXPECT_FALSE(r.quality_ok) << name << " seed " << seed;
      EXPECT_NE(std::find(r.quality_reasons.begin(), r.quality_reasons.end(), "coarse pre-filter"),
                r.quality_reasons.end());
    }
}

// At 64³ and contrast 0.3 the level stop's balloon crumples on the blood pool's speckle inside
// the sphere without stalling near the seed (iteration limit, 38-49 % small, speckle handles:
// genus 1): the coarse retry is tried on every low-contrast result and replaces one it encloses
// more than (docs/stopping.md departure 12; measured 2026-12-07: Dice 0.759 / 0.674 → 0.933 /
// 0.927). The torus's retry closes its hole and encloses less: its first result stays.
TEST(EchoPipeline, ALowContrastBalloonCrumpledOnSpeckleIsRetriedCoarse) {
  for (unsigned seed : {4u, 8u}) {
    const sim::Phantom phantom = echo_phantom("sphere", 0.3f, 64, seed);
    const PipelineResult r = run_pipeline(phantom.image, phantom.seed_mm, PipelineConfig{});
    ASSERT_TRUE(r.ok && r.labels) << "seed " << seed << ": " << r.error;
    EXPECT_TRUE(r.coarse_retry) << "seed " << seed;
    EXPECT_EQ(r.topology.genus, 0) << "seed " << seed;
    EXPECT_GE(internal::dice(*r.labels, phantom.truth), 0.9) << "seed " << seed;
    EXPECT_FALSE(r.quality_ok) << "seed " << seed;
  }
  const sim::Phantom torus = echo_phantom("torus", 0.3f, 64, 6);
  const PipelineResult t = run_pipeline(torus.image, torus.seed_mm, PipelineConfig{});
  ASSERT_TRUE(t.ok) << t.error;
  EXPECT_FALSE(t.coarse_retry);
  EXPECT_EQ(t.topology.genus, 1);
}

// The contrast-0.5 case at 96³: every phantom with its genus and the wall found.
// Measured (2026-12-04, docs/results.md): Dice 0.920-0.961, genus right in all eight; the
// cyst-needles suspect for the seal along the needle's shadow, the rest ok. The 0.93 is
// not met by the double tori (0.920, 0.928). With the needle's shadow lifted (docs/stopping.md
// item 17; 2026-12-05) the cyst-needles are ok too, Dice 0.940 and 0.952 (before 0.932, 0.942).
// Since the fit on the unsmoothed image (item 13; 2026-12-06) every phantom meets the issue's
// 0.93: Dice 0.945-0.968, the double tori 0.951 and 0.945.
TEST(EchoPipeline, EveryPhantomKeepsItsGenusAtContrastHalf) {
  for (const auto& [name, genus] : {std::tuple{"lv", 0}, std::tuple{"cyst-needle", 1},
                                    std::tuple{"torus", 1}, std::tuple{"double-torus", 2}})
    for (unsigned seed : {1u, 2u}) {
      const sim::Phantom phantom = echo_phantom(name, 0.5f, 96, seed);
      const PipelineResult r = run_pipeline(phantom.image, phantom.seed_mm, PipelineConfig{});
      ASSERT_TRUE(r.ok && r.labels) << name << " seed " << seed << ": " << r.error;
      EXPECT_EQ(r.topology.genus, genus) << name << " seed " << seed;
      const double dice = internal::dice(*r.labels, phantom.truth);
      EXPECT_GE(dice, 0.93) << name << " seed " << seed;
      EXPECT_GE(r.wall_support, 0.75f) << name << " seed " << seed;
      if (std::string(name) != "cyst-needle") continue;
      EXPECT_LT(r.shadow_factor, 0.5f) << "seed " << seed;  // the needle's shadow was found
      EXPECT_TRUE(r.quality_ok) << "seed " << seed;
    }
}

// The 64³ needle (radius 1.25 voxels, 0.6 mm: a biopsy needle's) was not found until casters were
// judged on the 7-voxel cross rather than the 3×3×3 mean; its shadow left, both contrast-0.7
// cyst-needles came out ok with genus 0 (Dice 0.920, 0.907: the tunnel closed). Lifted
// (2026-12-05): genus 1, 0.936 and 0.929.
TEST(EchoPipeline, AThinNeedlesShadowIsLiftedAndItsTunnelKept) {
  for (unsigned seed : {1u, 2u}) {
    const sim::Phantom phantom = echo_phantom("cyst-needle", 0.7f, 64, seed);
    const PipelineResult r = run_pipeline(phantom.image, phantom.seed_mm, PipelineConfig{});
    ASSERT_TRUE(r.ok && r.labels) << "seed " << seed << ": " << r.error;
    EXPECT_LT(r.shadow_factor, 0.5f) << "seed " << seed;
    EXPECT_EQ(r.topology.genus, 1) << "seed " << seed;
    EXPECT_GE(internal::dice(*r.labels, phantom.truth), 0.92) << "seed " << seed;
  }
}

// The wall fit (docs/stopping.md item 13) moves the pipeline's surface from where the speckle
// stopped it to the wall: on the 64³ echo lv at contrast 0.5 (measured 2026-12-04: Dice 0.917 →
// 0.935, volume −8.5 → −1.2 %) the result is closer to the truth in Dice and in volume, and the
// genus is the same.
TEST(EchoPipeline, WallFitPlacesTheSurfaceOnTheWall) {
  const sim::Phantom lv = echo_phantom("lv", 0.5f);
  const double lv_ml = truth_ml(lv);
  const auto [off, on] = off_and_on(lv, &PipelineConfig::wall_fit);
  ASSERT_TRUE(off.labels && on.labels);
  EXPECT_EQ(on.topology.genus, off.topology.genus);
  EXPECT_GE(internal::dice(*on.labels, lv.truth), internal::dice(*off.labels, lv.truth) + 0.01);
  EXPECT_LT(std::abs(on.enclosed_volume_ml / lv_ml - 1.0),
            std::abs(off.enclosed_volume_ml / lv_ml - 1.0) - 0.03);
}

// The fitted surface reconstructed once more (docs/stopping.md item 19): the fit's scatter about
// the wall averaged away, its genus and its volume kept. The 64³ torus at contrast 0.5 went from
// Dice 0.903 to 0.917 when this was written.
TEST(EchoPipeline, TheFittedSurfaceReconstructedLiesCloserToTheWall) {
  const sim::Phantom torus = echo_phantom("torus", 0.5f);
  const auto [off, on] = off_and_on(torus, &PipelineConfig::resurface);
  ASSERT_TRUE(off.labels && on.labels);
  EXPECT_FALSE(off.resurfaced);
  EXPECT_TRUE(on.resurfaced);
  EXPECT_EQ(on.topology.genus, 1);
  EXPECT_EQ(off.topology.genus, 1);
  EXPECT_GE(internal::dice(*on.labels, torus.truth),
            internal::dice(*off.labels, torus.truth) + 0.007);
  EXPECT_NEAR(on.enclosed_volume_ml / off.enclosed_volume_ml, 1.0, 0.005);
}

// The wall fit once more on the image before its pre-filter (docs/stopping.md item 13): the
// pre-filter blurs the wall along the normal, the fit's rings average the speckle along the
// surface only. The scatter about the wall shrinks, and the walls facing the probe, which the
// pre-filter had drawn inward, come out: the volume nears the truth's. The 64³ torus at contrast
// 0.5 went from a mean surface distance of 0.55 to 0.44 voxel when this was written, and with
// the facing walls' rule from a volume error of −10.2 to −2.9 %.
TEST(EchoPipeline, TheFitOnTheUnsmoothedImageLiesCloserToTheWall) {
  const sim::Phantom torus = echo_phantom("torus", 0.5f);
  const auto [off, on] = off_and_on(torus, &PipelineConfig::fit_unsmoothed);
  ASSERT_TRUE(off.labels && on.labels);
  EXPECT_EQ(on.topology.genus, 1);
  EXPECT_EQ(off.topology.genus, 1);
  const double off_vox = internal::surface_distances(*off.labels, torus.truth).mean_vox;
  const double on_vox = internal::surface_distances(*on.labels, torus.truth).mean_vox;
  EXPECT_LT(on_vox, off_vox - 0.04);
  EXPECT_GE(internal::dice(*on.labels, torus.truth),
            internal::dice(*off.labels, torus.truth) + 0.007);
  const double torus_ml = truth_ml(torus);
  EXPECT_LT(std::abs(on.enclosed_volume_ml / torus_ml - 1.0),
            std::abs(off.enclosed_volume_ml / torus_ml - 1.0) - 0.04);
}

// An ok cyst-needle of genus 1 and Dice 0.94 or more from a stream that crumpled, inflated again
// `restarts` times.
void expect_right_after_crumple(const PipelineResult& r, const sim::Phantom& phantom,
                                int restarts) {
  ASSERT_TRUE(r.ok && r.labels) << r.error;
  EXPECT_EQ(r.balloon_stats.crumple_restarts, restarts);
  EXPECT_TRUE(r.crumpled);
  EXPECT_TRUE(r.quality_ok);
  EXPECT_EQ(r.topology.genus, 1);
  EXPECT_GE(internal::dice(*r.labels, phantom.truth), 0.94);
}

// A balloon whose fronts meet at an angle passes the self-intersection test, crumples and runs
// to the iteration limit (96³ cyst-needle at contrast 0.5, its seed 0.45 of the radius off
// centre: suspect, Dice 0.941). It inflates again with the stricter test (docs/stopping.md item
// 18): ok, genus 1, Dice 0.950; the next volume's balloon starts strict and does not crumple.
// The balloons here inflate from the seed at full resolution: the coarse start's fine pass,
// which begins near the wall, does not crumple on this volume (ok, Dice 0.954).
TEST(EchoPipeline, ACrumpledBalloonInflatesAgainAndIsRight) {
  sim::PhantomSpec spec{.phantom = "cyst-needle", .size_vox = 96, .seed = 1, .time_s = 1.6f};
  spec.contrast = 0.5f;
  const sim::Phantom phantom = sim::make_phantom(sim::with_echo_realism(spec));
  const float radius_mm = static_cast<float>(internal::equivalent_radius_mm(phantom.truth));
  const Vec3f seed_mm = phantom.seed_mm + Vec3f(0.45f * radius_mm, 0.0f, 0.0f);
  PipelineConfig from_seed;
  from_seed.coarse_start = false;
  PipelineConfig off = from_seed;
  off.balloon.crumple_self_intersection_cos = -1.0f;
  const PipelineResult plain = run_pipeline(phantom.image, seed_mm, off);
  ASSERT_TRUE(plain.ok) << plain.error;
  EXPECT_FALSE(plain.quality_ok);
  EXPECT_FALSE(plain.crumpled);

  PipelineBuffers buffers;
  const PipelineResult first = run_pipeline(phantom.image, seed_mm, from_seed, buffers);
  expect_right_after_crumple(first, phantom, 1);
  WarmStart warm = warm_start_from(first, 1.5f);
  warm.previous = nullptr;  // (the balloon, not the tracked surface)
  expect_right_after_crumple(run_pipeline(phantom.image, seed_mm, from_seed, buffers, &warm),
                             phantom, 0);
}

// Below 0.4 of contrast (the seed region's level 60 % of the tissue's or more) the wall test
// passes surfaces stopped on speckle or near-field clutter: the 64³ lv at contrast 0.3 came out
// ok at Dice 0.871, volume −14 % (2026-12-05). It is "low contrast" now; at contrast 0.5 the
// same phantom stays ok.
TEST(EchoPipeline, ALowContrastResultIsNeverOk) {
  const sim::Phantom low = echo_phantom("lv", 0.3f);
  const PipelineResult r = run_pipeline(low.image, low.seed_mm, PipelineConfig{});
  ASSERT_TRUE(r.ok) << r.error;
  EXPECT_FALSE(r.quality_ok);
  EXPECT_NE(std::find(r.quality_reasons.begin(), r.quality_reasons.end(), "low contrast"),
            r.quality_reasons.end());
  const sim::Phantom half = echo_phantom("lv", 0.5f);
  const PipelineResult h = run_pipeline(half.image, half.seed_mm, PipelineConfig{});
  ASSERT_TRUE(h.ok) << h.error;
  EXPECT_TRUE(h.quality_ok);
}

// The 64³ cyst-needles seeded 0.45 of the radius off the centre along +z (contrast 0.7) and +y
// (0.6): the needle crosses the cube the speckle's grain is measured in and read it as 0.88-0.97
// mm, the pre-filter followed it to 1.75 voxels or more, and the needle's tunnel closed into a
// groove (genus 0: "bright structure inside" at +z; ok at +y until the other opinion's needle
// left the doubt, 2026-12-06). Measured without the needle's bright voxels the grain reads
// 0.73-0.82 mm, as from the centre: the pre-filter stays at one voxel and the tunnel opens.
TEST(EchoPipeline, ANeedleAcrossTheGrainsCubeLeavesThePreFilterFine) {
  for (const auto& [contrast, axis] : {std::pair(0.7f, 2), std::pair(0.6f, 1)}) {
    const sim::Phantom phantom = echo_phantom("cyst-needle", contrast);
    Vec3f offset = Vec3f::Zero();
    offset[axis] = 0.45f * static_cast<float>(internal::equivalent_radius_mm(phantom.truth));
    const PipelineResult r =
        run_pipeline(phantom.image, phantom.seed_mm + offset, PipelineConfig{});
    ASSERT_TRUE(r.ok) << contrast << ": " << r.error;
    EXPECT_GT(r.shadow_voxels, 0u) << contrast;
    EXPECT_LE(r.smooth_sigma_mm, phantom.image.spacing_mm().minCoeff()) << contrast;
    EXPECT_EQ(r.topology.genus, 1) << contrast;
  }
}

// The 64³ cyst-needle at contrast 0.3, seed 5: the balloon passes over the needle, its walls are
// added to the samples, and the reconstruction still closes the tunnel: genus 0, flagged.
TEST(EchoPipeline, ANeedleTheReconstructionCouldNotOpenIsFlagged) {
  const sim::Phantom phantom = echo_phantom("cyst-needle", 0.3f, 64, 5);
  const PipelineResult r = run_pipeline(phantom.image, phantom.seed_mm, PipelineConfig{});
  ASSERT_TRUE(r.ok) << r.error;
  ASSERT_EQ(r.topology.genus, 0);  // (the fault this flags; a fix makes this test moot)
  EXPECT_TRUE(r.bright_inside_opened && r.bright_inside_left);
  EXPECT_FALSE(r.quality_ok);
  EXPECT_NE(
      std::find(r.quality_reasons.begin(), r.quality_reasons.end(), "bright structure inside"),
      r.quality_reasons.end());
}

}  // namespace
}  // namespace sonomesh::daemon
