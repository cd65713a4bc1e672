#include <gtest/gtest.h>

#include <string>

#include "daemon/pipeline.h"
#include "sim/sim.h"

namespace sonomesh::daemon {
namespace {

TEST(SeedCheck, AcceptsThePhantomSeed) {
  const sim::Phantom phantom = sim::make_phantom({.phantom = "sphere", .size_vox = 48});
  EXPECT_EQ(check_seed(phantom.image, phantom.seed_mm), std::nullopt);
}

TEST(SeedCheck, RefusesASeedOutsideTheVolume) {
  const sim::Phantom phantom = sim::make_phantom({.phantom = "sphere", .size_vox = 48});
  const auto problem = check_seed(phantom.image, phantom.image.max_mm() + Vec3f(1, 0, 0));
  ASSERT_TRUE(problem.has_value());
  EXPECT_NE(problem->find("outside the volume"), std::string::npos) << *problem;
}

TEST(SeedCheck, RefusesASeedInBrightTissue) {
  const sim::Phantom phantom = sim::make_phantom({.phantom = "sphere", .size_vox = 48});
  // A corner region, well away from the centred target: tissue.
  const Vec3f corner = phantom.image.index_to_mm(Vec3f(4, 4, 4));
  ASSERT_EQ(phantom.truth.value(4, 4, 4), 0.0f);
  const auto problem = check_seed(phantom.image, corner);
  ASSERT_TRUE(problem.has_value());
  EXPECT_NE(problem->find("bright tissue"), std::string::npos) << *problem;
}

sim::Phantom low_contrast_echo(const std::string& name, unsigned seed) {
  sim::PhantomSpec spec{.phantom = name, .size_vox = 64, .seed = seed};
  spec.contrast = 0.3f;
  return sim::make_phantom(sim::with_echo_realism(spec));
}

// The echo phantoms' zeros outside the sector are left out of the target/tissue split; with them
// in, it fell at 64-68 grey levels, under the targets' own level at contrast 0.3, and 9 of these
// 10 seeds were refused as lying in bright tissue (2026-12-05).
TEST(SeedCheck, AcceptsEchoPhantomSeedsAtLowContrast) {
  for (const char* name : {"sphere", "lv", "cyst-needle", "torus", "double-torus"})
    for (const unsigned seed : {1u, 2u}) {
      const sim::Phantom phantom = low_contrast_echo(name, seed);
      EXPECT_EQ(check_seed(phantom.image, phantom.seed_mm), std::nullopt) << name << " " << seed;
    }
}

TEST(SeedCheck, RefusesASeedWhereTheProbeHasNoData) {
  const sim::Phantom phantom = low_contrast_echo("sphere", 1);
  ASSERT_EQ(phantom.image.value(1, 1, 1), 0.0f);  // (the sector's apex is at the top centre)
  const auto problem = check_seed(phantom.image, phantom.image.index_to_mm(Vec3f(1, 1, 1)));
  ASSERT_TRUE(problem.has_value());
  EXPECT_NE(problem->find("no data"), std::string::npos) << *problem;
}

TEST(SeedCheck, MessagesAreOneLine) {
  const sim::Phantom phantom = sim::make_phantom({.phantom = "torus", .size_vox = 48});
  for (const Vec3f& p : {Vec3f(-100, 0, 0), phantom.image.index_to_mm(Vec3f(2, 2, 2))}) {
    const auto problem = check_seed(phantom.image, p);
    ASSERT_TRUE(problem.has_value());
    EXPECT_EQ(problem->find('\n'), std::string::npos);
  }
}

}  // namespace
}  // namespace sonomesh::daemon
