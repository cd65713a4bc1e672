// The wall fit in a probe's sector: a wall the beam runs along is placed where its dropout
// begins, not half way up the rise beyond it (segment::WallFitOptions::along_beam_fraction;
// docs/stopping.md item 13).
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "daemon/internal/metrics.h"
#include "daemon/pipeline.h"
#include "echo_phantoms.h"
#include "sim/sim.h"

namespace sonomesh::daemon {
namespace {

using test::echo_phantom;
using test::truth_ml;

struct Outcome {
  double volume_error = 0.0, dice = 0.0;
};

Outcome run(const sim::Phantom& phantom, float along_beam_fraction) {
  PipelineConfig config;
  config.wall_fit_options.along_beam_fraction = along_beam_fraction;
  const PipelineResult r = run_pipeline(phantom.image, phantom.seed_mm, config);
  EXPECT_TRUE(r.ok && r.labels) << r.error;
  if (!r.ok || !r.labels) return {};
  return {r.enclosed_volume_ml / truth_ml(phantom) - 1.0, internal::dice(*r.labels, phantom.truth)};
}

// 96³ echo phantoms whose result came out over 3 % large while the walls were crossed half way
// all round (+3.1 to +3.9 %, 2026-12-07): within 3 % now, and no less overlap.
TEST(WallFitPipeline, AWallAlongTheBeamIsPlacedWhereItsDropoutBegins) {
  struct Case {
    const char* phantom;
    float contrast;
    unsigned seed;
  };
  for (const Case c : {Case{"lv", 0.7f, 1}, Case{"lv", 0.7f, 2}, Case{"cyst-needle", 0.5f, 2}}) {
    const sim::Phantom phantom = echo_phantom(c.phantom, c.contrast, 96, c.seed);
    const Outcome lower = run(phantom, segment::WallFitOptions{}.along_beam_fraction);
    const Outcome half = run(phantom, 0.5f);
    const std::string name = std::string(c.phantom) + " seed " + std::to_string(c.seed);
    EXPECT_LE(std::abs(lower.volume_error), 0.03) << name;
    EXPECT_LT(lower.volume_error, half.volume_error - 0.01) << name;
    EXPECT_GE(lower.dice, half.dice - 0.002) << name;
  }
}

}  // namespace
}  // namespace sonomesh::daemon
