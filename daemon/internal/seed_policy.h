#pragma once
/// @file
/// @brief Where the next volume's balloon starts (DESIGN.md "Daemon behaviour"): the seed follows
/// the object. Pure: no locks, no I/O; the worker owns one and feeds it.

#include <array>
#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace sonomesh::daemon {

using SeedMm = std::array<float, 3>;

/// Where a seed came from (reported in the journal and /status).
enum class SeedOrigin { Tracked, Configured, Phantom, Centre };
const char* to_string(SeedOrigin origin);

struct SeedCandidate {
  SeedMm mm;
  SeedOrigin origin;
};

/// What the seed for the next volume may be, in order of preference; all in the grid frame the
/// pipeline runs in (the worker maps the operator's world-frame seeds into it first).
struct SeedInputs {
  std::optional<SeedMm> override_mm;    // POST /seed or a reloaded seed: used once
  std::optional<SeedMm> configured_mm;  // the configuration's seed
  std::optional<SeedMm> phantom_mm;     // the simulator's known seed (grid frame already)
  SeedMm centre_mm{};                   // the volume's centre, the last resort
};

class SeedPolicy {
 public:
  /// Candidates for the next volume, best first: an override (which also ends tracking, because
  /// the operator moved the seed), else the tracked point; then configured, phantom, centre.
  std::vector<SeedCandidate> candidates(const SeedInputs& inputs);
  /// After a result: its deepest interior point becomes the tracked seed, unless an override is
  /// already waiting (the operator's seed wins over the object's last position).
  void on_result(const std::optional<SeedMm>& deepest_interior_mm, bool override_waiting);
  const std::optional<SeedMm>& tracked() const { return tracked_mm_; }

 private:
  std::optional<SeedMm> tracked_mm_;
};

/// Why a candidate cannot start a balloon, or nullopt if it can (check_seed on the volume).
using SeedCheck = std::function<std::optional<std::string>(const SeedMm&)>;

struct SeedChoice {
  std::optional<SeedCandidate> chosen;
  std::vector<std::pair<SeedCandidate, std::string>> refused;  // in the order tried, with why
};

/// The first candidate that `check` accepts.
SeedChoice choose_seed(const std::vector<SeedCandidate>& candidates, const SeedCheck& check);

}  // namespace sonomesh::daemon
