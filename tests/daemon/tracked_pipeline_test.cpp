// Streams and seeds as the daemon sees them: a breathing echo-mode cyst-needle with the seed
// tracked from volume to volume, and the same target from different seeds.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <string>
#include <utility>
#include <vector>

#include "daemon/internal/metrics.h"
#include "daemon/pipeline.h"
#include "sim/sim.h"

namespace sonomesh::daemon {
namespace {

using volume::Vec3f;

// 60 volumes at 10 volumes/s (six seconds of breathing), 96³; each seed is the deepest interior
// point of the previous result, as the daemon's worker tracks it. Every volume must be processed
// with genus 1; returns on how many it was not.
int wrong_genus_volumes(bool echo) {
  constexpr int kVolumes = 60;
  PipelineBuffers buffers;
  std::optional<Vec3f> seed_mm;
  int wrong = 0;
  for (int i = 0; i < kVolumes; ++i) {
    sim::PhantomSpec spec{.phantom = "cyst-needle", .size_vox = 96};
    spec.time_s = static_cast<float>(i) / 10.0f;
    const sim::Phantom phantom = sim::make_phantom(echo ? sim::with_echo_realism(spec) : spec);
    const Vec3f seed = seed_mm.value_or(phantom.seed_mm);
    const PipelineResult r = run_pipeline(phantom.image, seed, PipelineConfig{}, buffers);
    EXPECT_TRUE(r.ok) << "volume " << i << ": " << r.error;
    if (!r.ok || !r.deepest_interior_mm) return kVolumes;
    if (r.topology.genus != 1) {
      ++wrong;
      std::printf("volume %d: genus %d\n", i, r.topology.genus);
    }
    seed_mm = r.deepest_interior_mm;
  }
  return wrong;
}

// Every volume genus 1, in the simple and in the echo realism, each volume segmented cold at the
// tracked seed (the daemon's warm starts are tested through it, DaemonRun in tests/integration).
TEST(TrackedPipeline, BreathingCystNeedleKeepsGenusOneOnEveryVolume) {
  EXPECT_EQ(wrong_genus_volumes(false), 0);
}

TEST(TrackedPipeline, BreathingEchoCystNeedleKeepsGenusOneOnEveryVolume) {
  EXPECT_EQ(wrong_genus_volumes(true), 0);
}

// Seeds anywhere in the inner half of the target give the same surface.
TEST(TrackedPipeline, SeedsInTheInnerHalfGiveTheSameResult) {
  const sim::Phantom phantom = sim::make_phantom({.phantom = "sphere", .size_vox = 64});
  const float r_mm =
      0.45f *
      static_cast<float>(internal::equivalent_radius_mm(phantom.truth));  // inside the inner half
  const std::array<Vec3f, 5> offsets = {Vec3f::Zero(), Vec3f(r_mm, 0, 0), Vec3f(0, -r_mm, 0),
                                        Vec3f(0, 0, r_mm),
                                        Vec3f(-r_mm, r_mm, -r_mm) / std::sqrt(3.0f)};
  std::vector<volume::Volume> labels;
  for (const Vec3f& offset : offsets) {
    const PipelineResult r =
        run_pipeline(phantom.image, phantom.seed_mm + offset, PipelineConfig{});
    ASSERT_TRUE(r.ok && r.labels) << r.error;
    EXPECT_EQ(r.topology.genus, 0);
    labels.push_back(*r.labels);
  }
  for (std::size_t a = 0; a < labels.size(); ++a)
    for (std::size_t b = a + 1; b < labels.size(); ++b)
      EXPECT_GE(internal::dice(labels[a], labels[b]), 0.98) << "seeds " << a << " and " << b;
}

// In the echo realism speckle and the needle's shadow can make a seed of the inner half fail:
// each result is right or flagged, and the ok ones are the same surface, to the Dice of
// 0.98 between any two. (Measured 2026-12-05: 7 of 7 ok; before the shadow was lifted,
// docs/stopping.md item 17, 4 of 7, three sealed leaks along the shadow. 2026-12-06: the ok
// results' Dice between any two 0.987 or more.)
// The phantom's seed and the six 0.45 of the target's equivalent radius away along ±x, ±y, ±z.
std::array<Vec3f, 7> inner_half_offsets(const sim::Phantom& p) {
  const float r_mm = 0.45f * static_cast<float>(internal::equivalent_radius_mm(p.truth));
  return {Vec3f::Zero(),      Vec3f(r_mm, 0, 0), Vec3f(-r_mm, 0, 0), Vec3f(0, r_mm, 0),
          Vec3f(0, -r_mm, 0), Vec3f(0, 0, r_mm), Vec3f(0, 0, -r_mm)};
}

// The pipeline with the default options from the phantom's seed moved by `offset_mm`.
PipelineResult run_from(const sim::Phantom& p, const Vec3f& offset_mm = Vec3f::Zero()) {
  return run_pipeline(p.image, p.seed_mm + offset_mm, PipelineConfig{});
}

sim::Phantom echo_phantom(const std::string& name, int size_vox, unsigned seed, float contrast,
                          float time_s = 0.0f) {
  sim::PhantomSpec spec{.phantom = name, .size_vox = size_vox, .seed = seed, .time_s = time_s};
  spec.contrast = contrast;
  return sim::make_phantom(sim::with_echo_realism(spec));
}

TEST(TrackedPipeline, EchoSeedsInTheInnerHalfAreRightOrFlagged) {
  const sim::Phantom p = sim::make_phantom(sim::with_echo_realism(
      {.phantom = "cyst-needle", .size_vox = 96, .seed = 1, .time_s = 1.6f}));
  ASSERT_EQ(p.genus, 1);
  std::vector<volume::Volume> ok_labels;
  for (const Vec3f& offset : inner_half_offsets(p)) {
    const PipelineResult r = run_from(p, offset);
    if (!r.ok || !r.quality_ok) continue;
    ASSERT_TRUE(r.labels);
    EXPECT_EQ(r.topology.genus, 1) << offset.transpose();
    EXPECT_GE(internal::dice(*r.labels, p.truth), 0.93) << offset.transpose();
    ok_labels.push_back(*r.labels);
  }
  EXPECT_GE(ok_labels.size(), 6u);
  for (std::size_t a = 0; a < ok_labels.size(); ++a)
    for (std::size_t b = a + 1; b < ok_labels.size(); ++b)
      EXPECT_GE(internal::dice(ok_labels[a], ok_labels[b]), 0.98)
          << "ok results " << a << ", " << b;
}

// At contrast 0.5 the blood pool's bright grains inside a surface that passed over a short
// stretch of needle outnumber the needle's voxels (1 361 against 463 from the seed 0.45 of the
// radius along −x), so the needle was not opened and the result came out ok with genus 0. Where
// a needle cast a shadow and the surface has no tunnel, the needle is opened however many grains
// lie beside it (docs/stopping.md item 14): no seed's result is ok without the tunnel.
TEST(TrackedPipeline, EchoSeedsAtContrastHalfAreNeverOkWithoutTheTunnel) {
  const sim::Phantom p = echo_phantom("cyst-needle", 96, 1, 0.5f);
  ASSERT_EQ(p.genus, 1);
  const std::array<Vec3f, 7> offsets = inner_half_offsets(p);
  for (const Vec3f& offset : offsets) {
    const PipelineResult r = run_from(p, offset);
    ASSERT_TRUE(r.ok) << r.error;
    if (r.quality_ok) {
      EXPECT_EQ(r.topology.genus, 1) << offset.transpose();
    }
    if (offset == offsets[2]) {
      EXPECT_TRUE(r.bright_inside_opened);
    }
  }
}

// At 64³ the needle is 2.5 voxels across: the opened balloon wraps it half-way, the first
// reconstruction's χ holds 47 of its bright voxels, none deep, and the surface came out genus 0,
// ok, from five of the twelve contrast-0.7 seeds 0.45 of the radius off the centre. The fitted
// surface covers the needle whole; its walls open the tunnel there (docs/stopping.md item 14).
TEST(TrackedPipeline, A64CystsNeedleIsOpenedOnTheFittedSurface) {
  const sim::Phantom p = echo_phantom("cyst-needle", 64, 1, 0.7f);
  ASSERT_EQ(p.genus, 1);
  const std::array<Vec3f, 7> offsets = inner_half_offsets(p);
  for (const Vec3f& offset : {offsets[1], offsets[3], offsets[4]}) {
    const PipelineResult r = run_from(p, offset);
    ASSERT_TRUE(r.ok) << r.error;
    EXPECT_TRUE(r.topology.genus == 1 || !r.quality_ok) << offset.transpose();
    ASSERT_TRUE(r.labels);
    EXPECT_GE(internal::dice(*r.labels, p.truth), 0.92) << offset.transpose();
  }
}

// A double torus's tube seeded 0.45 of its radius along −x: Ψ_cost stalls in the tube (genus 0,
// Dice 0.38, 13 % of its surface open onto the tube), and the level stop, asked for the second
// opinion, stalls near the seed. The stall passed every test of its own; the second opinion that
// could not confirm it is said (docs/stopping.md item 9).
TEST(TrackedPipeline, AStallTheOtherStopRuleCannotConfirmIsSuspect) {
  const sim::Phantom p = echo_phantom("double-torus", 64, 2, 0.5f);
  ASSERT_EQ(p.genus, 2);
  const PipelineResult r = run_from(p, inner_half_offsets(p)[2]);
  ASSERT_TRUE(r.ok) << r.error;
  ASSERT_NE(r.topology.genus, 2) << "the case this test pins down has changed";
  EXPECT_FALSE(r.quality_ok);
  EXPECT_TRUE(r.unconfirmed);
}

// The 96³ torus seeded 0.45 of its radius along −x: Ψ_cost's balloon is suspect, and the level
// stop's result, taken in its place, stalled in the tube (Dice 0.89, 5 % of its surface open
// onto the tube). Nothing confirms it, and the verdict says so.
TEST(TrackedPipeline, AnOpenResultWhoseOtherOpinionWasSuspectIsSuspect) {
  const sim::Phantom p = echo_phantom("torus", 96, 2, 0.5f);
  const PipelineResult r = run_from(p, inner_half_offsets(p)[2]);
  ASSERT_TRUE(r.ok) << r.error;
  ASSERT_TRUE(r.labels);
  ASSERT_LT(internal::dice(*r.labels, p.truth), 0.92) << "the case this test pins down has changed";
  EXPECT_FALSE(r.quality_ok);
  EXPECT_TRUE(r.unconfirmed);
}

// The 96³ double torus at contrast 0.5, seed 4, 3 s: Ψ_cost stalled in one tube (genus 0, Dice
// 0.42, open 4.4 %); the level stop, asked, ran through both loops and its surface missed the
// seed, enclosing less than twice the first. Its balloon's reach says what its surface cannot.
TEST(TrackedPipeline, AnOtherBalloonThatReachedFarLeavesDoubt) {
  const sim::Phantom p = echo_phantom("double-torus", 96, 4, 0.5f, 3.0f);
  const PipelineResult r = run_from(p);
  ASSERT_TRUE(r.ok) << r.error;
  ASSERT_NE(r.topology.genus, 2) << "the case this test pins down has changed";
  EXPECT_FALSE(r.quality_ok);
  EXPECT_TRUE(r.unconfirmed);
}

// The 64³ double torus at contrast 0.4, seed 3: Ψ_cost's balloon is suspect and the level
// stop's result, taken in its place, stalled in a tube with its caps on grains (genus 0, Dice
// 0.59, open 0.3 %). Thin and closed, nothing confirms it.
// The same where the first opinion's surface was made and called suspect: the 64³ ventricle of
// seed 2 at contrast 0.4 (Ψ_cost "surface not on the target's wall"; the level stop's surface
// genus 0, Dice 0.74, volume −38 %, 7.7 voxels deep).
TEST(TrackedPipeline, AThinClosedResultWhoseOtherOpinionWasSuspectIsSuspect) {
  for (const auto& [name, seed] : {std::pair("double-torus", 3u), std::pair("lv", 2u)}) {
    const sim::Phantom p = echo_phantom(name, 64, seed, 0.4f);
    const PipelineResult r = run_from(p);
    ASSERT_TRUE(r.ok && r.labels) << name << ": " << r.error;
    ASSERT_LT(internal::dice(*r.labels, p.truth), 0.9) << name << ": the case has changed";
    EXPECT_FALSE(r.quality_ok) << name;
    EXPECT_TRUE(r.unconfirmed) << name;
  }
}

// A genus-0 result 6-8 voxels deep may be a stall in a tube whose caps sit on grains: the 96³
// double torus at contrast 0.5 and 0.8 s (Dice 0.33, open 1.15 %), and the 64³ ventricle of
// phantom seed 4 (Dice 0.91, the level stop's 0.95). The second opinion is asked of them
// (docs/stopping.md item 9). (Ψ_cost first, as outside a sector: in one the level stop goes
// first, and the ventricle's is ok.)
TEST(TrackedPipeline, AThinGenusZeroResultIsAskedAgain) {
  PipelineConfig cost_first;
  cost_first.level_stop_first_in_sector = false;
  const auto run_from = [&](const sim::Phantom& p) {
    return run_pipeline(p.image, p.seed_mm, cost_first);
  };
  const sim::Phantom torus = echo_phantom("double-torus", 96, 1, 0.5f, 0.8f);
  const PipelineResult t = run_from(torus);
  ASSERT_TRUE(t.ok) << t.error;
  EXPECT_TRUE(t.second_opinion);
  EXPECT_TRUE(t.topology.genus == 2 || !t.quality_ok);
  const sim::Phantom lv = echo_phantom("lv", 64, 4, 0.5f);
  const PipelineResult v = run_from(lv);
  ASSERT_TRUE(v.ok && v.labels) << v.error;
  EXPECT_TRUE(v.second_opinion);
  EXPECT_TRUE(internal::dice(*v.labels, lv.truth) >= 0.93 || !v.quality_ok);
}

// Seeds a voxel or two from the needle, where the balloon wrapped it without meeting itself
// behind it, so the reconstruction passed over it (genus 0 from 11 of 27 seeds round the cyst's
// centre before): the needle's walls inside the surface opened it again (docs/stopping.md item
// 14). Since the grain is measured without the needle (departure 1, session 37) the pre-filter
// stays at one voxel from these seeds and the balloon's sheets meet behind the needle themselves.
TEST(TrackedPipeline, SeedsBesideTheNeedleGetItsTunnel) {
  const sim::Phantom p = sim::make_phantom({.phantom = "cyst-needle",
                                            .size_vox = 96,
                                            .spacing_mm = Vec3f::Constant(0.5f),
                                            .time_s = 0.3f});
  ASSERT_EQ(p.genus, 1);
  for (const Vec3f& seed_mm :
       {Vec3f(23.5f, 23.5f, 23.5f), Vec3f(24.0f, 23.5f, 24.5f), Vec3f(24.5f, 23.5f, 23.5f)}) {
    const PipelineResult r = run_pipeline(p.image, seed_mm, PipelineConfig{});
    ASSERT_TRUE(r.ok && r.labels) << r.error;
    EXPECT_EQ(r.topology.genus, 1) << seed_mm.transpose();
    EXPECT_GE(internal::dice(*r.labels, p.truth), 0.96) << seed_mm.transpose();
  }
}

}  // namespace
}  // namespace sonomesh::daemon
