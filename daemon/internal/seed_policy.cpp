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

}  // namespace sonomesh::daemon
