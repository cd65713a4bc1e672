#include "daemon/internal/seed_policy.h"

namespace sonomesh::daemon {

const char* to_string(SeedOrigin origin) {
  switch (origin) {
    case SeedOrigin::Tracked:
      return "tracked";
    case SeedOrigin::Configured:
      return "configured";
    case SeedOrigin::Phantom:
      return "phantom";
    case SeedOrigin::Centre:
      return "centre";
  }
  return "unknown";
}

std::vector<SeedCandidate> SeedPolicy::candidates(const SeedInputs& inputs) {
  std::vector<SeedCandidate> out;
  if (inputs.override_mm) {
    out.push_back({*inputs.override_mm, SeedOrigin::Configured});
    tracked_mm_.reset();
  } else if (tracked_mm_) {
    out.push_back({*tracked_mm_, SeedOrigin::Tracked});
  }
  if (inputs.configured_mm) out.push_back({*inputs.configured_mm, SeedOrigin::Configured});
  if (inputs.phantom_mm) out.push_back({*inputs.phantom_mm, SeedOrigin::Phantom});
  out.push_back({inputs.centre_mm, SeedOrigin::Centre});
  return out;
}

void SeedPolicy::on_result(const std::optional<SeedMm>& deepest_interior_mm,
                           bool override_waiting) {
  if (deepest_interior_mm && !override_waiting) tracked_mm_ = deepest_interior_mm;
}

SeedChoice choose_seed(const std::vector<SeedCandidate>& candidates, const SeedCheck& check) {
  SeedChoice choice;
  for (const SeedCandidate& c : candidates) {
    if (auto why = check(c.mm)) {
      choice.refused.emplace_back(c, std::move(*why));
      continue;
    }
    choice.chosen = c;
    break;
  }
  return choice;
}

StartDecision decide_start(const StartInputs& in, const StartLimits& limits) {
  auto cold = [](std::string why) { return StartDecision{false, std::move(why)}; };
  if (in.seed_overridden) return cold("seed override");
  if (!in.have_previous)
    return cold(in.previous_dropped.empty() ? "no previous balloon"
                                            : "no previous balloon (" + in.previous_dropped + ")");
  if (!in.previous_quality_ok) return cold("previous result suspect");
  if (!in.seed_tracked) return cold("seed not tracked");
  if (!in.same_grid) return cold("grid changed");
  if (!(in.motion_vox <= limits.max_motion_vox))
    return cold("moved " + std::to_string(in.motion_vox) + " vox");
  if (!(in.volume_change <= limits.max_volume_change))
    return cold("volume changed " + std::to_string(static_cast<int>(100.0f * in.volume_change)) +
                " %");
  if (in.since_refused < limits.refused_backoff_volumes) return cold("warm start refused recently");
  return {true, "previous balloon"};
}

}  // namespace sonomesh::daemon
