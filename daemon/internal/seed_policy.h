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

/// What the worker knows when it chooses how the next volume's balloon starts (issue 17): from
/// the previous volume's balloon (warm) or from the small sphere at the seed (cold).
struct StartInputs {
  bool have_previous = false;        // a balloon is kept from the last volume (it succeeded)
  bool previous_quality_ok = false;  // and its verdict was "ok"
  bool seed_overridden = false;      // POST /seed or a reload moved the seed for this volume
  bool seed_tracked = false;         // the seed chosen is the tracked point
  bool same_grid = false;            // the new volume's grid (dims, spacing, origin) is the last's
  float motion_vox = 0.0f;           // how far the result's centroid moved between the last two
  float volume_change = 0.0f;        // |ΔV| / V of the enclosed volume between the last two
  int since_refused = 1 << 30;       // volumes since the pipeline's check last refused a warm start
  std::string previous_dropped = {};  // why the last balloon kept was dropped (empty: none was)
};

/// Beyond these the previous balloon says too little about the new volume.
struct StartLimits {
  float max_motion_vox = 6.0f;      // a probe moved, not a breath (breathing: < 1 voxel a volume)
  float max_volume_change = 0.25f;  // the target changed shape, or the result did
  // After a refused warm start, this many volumes start cold without trying: a refused attempt
  // costs its checks and start mesh on top of the cold start. Since the start mesh comes from
  // the eroded interior it costs a few ms at 128³, and the seam behind a needle is no longer
  // refused, so one volume is enough (it was 8 when the normal-offset inset was refused there).
  int refused_backoff_volumes = 1;
};

struct StartDecision {
  bool warm = false;
  std::string reason;  // why (the journal's "start_reason")
};

/// Warm only when every condition holds; otherwise cold with the first reason that failed.
StartDecision decide_start(const StartInputs& in, const StartLimits& limits = {});

}  // namespace sonomesh::daemon
