#include <gtest/gtest.h>

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
