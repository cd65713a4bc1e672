// segment::validate: the first problem of a BalloonOptions as one line naming the option; the
// balloon refuses exactly those options.
#include <gtest/gtest.h>

#include <stdexcept>
#include <string>

#include "segment/segment.h"

using namespace sonomesh;

namespace {

segment::BalloonOptions with(void (*change)(segment::BalloonOptions&)) {
  segment::BalloonOptions o;
  change(o);
  return o;
}

}  // namespace

TEST(BalloonOptions, ValidateNamesTheFirstProblem) {
  EXPECT_EQ(segment::validate({}), "");
  const struct {
    segment::BalloonOptions options;
    const char* names;
  } cases[] = {
      {with([](auto& o) { o.tau_curv = 0; }), "tau_curv"},
      {with([](auto& o) { o.initial_radius_vox = 0.5f; }), "initial_radius_vox"},
      {with([](auto& o) { o.snap_back_vox = 4, o.snap_ahead_vox = 5; }), "snap_ahead_vox"},
      {with([](auto& o) { o.time_step = 2; }), "time_step * inflation_vox"},
      {with([](auto& o) { o.umbrella_weight = -1; }), "umbrella_weight"},
      {with([](auto& o) { o.max_iterations = 0; }), "max_iterations"},
      {with([](auto& o) { o.threads = -1; }), "threads"},
  };
  for (const auto& c : cases) {
    const std::string problem = segment::validate(c.options);
    EXPECT_NE(problem.find(c.names), std::string::npos) << problem;
    EXPECT_EQ(problem.find('\n'), std::string::npos) << problem;
  }
}

TEST(BalloonOptions, InflateRefusesWhatValidateRefuses) {
  volume::Volume image(volume::Vec3i(16, 16, 16), volume::Vec3f::Ones(), volume::Vec3f::Zero(),
                       volume::VoxelType::Float32);
  segment::BalloonOptions o;
  o.tau_curv = 0;
  try {
    segment::inflate_balloon(image, volume::Vec3f(8, 8, 8), o);
    FAIL() << "options refused by validate were accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_EQ(std::string(e.what()), "BalloonOptions: " + segment::validate(o));
  }
}
