#pragma once
/// @file
/// @brief The processing worker: a queued volume in, a ProcessedVolume (to the writer) or a
/// `failed` line out. Chooses the seed (SeedPolicy), runs the pipeline, gathers the journal fields.

#include <functional>
#include <mutex>
#include <optional>
#include <stop_token>
#include <string>

#include "daemon/internal/acquisition.h"
#include "daemon/internal/bounded_queue.h"
#include "daemon/internal/output_sink.h"
#include "daemon/internal/seed_policy.h"
#include "daemon/internal/volume_queue.h"
#include "daemon/pipeline.h"

namespace sonomesh::daemon {

/// A processed volume with the journal fields the worker gathered, for the writer.
struct WorkerResult {
  ProcessedVolume volume;
  nlohmann::json line;
};

using ResultQueue = BoundedQueue<WorkerResult>;

class Worker {
 public:
  Worker(RunContext context, VolumeQueue& in, ResultQueue& out,
         std::optional<SeedMm> phantom_seed_mm, std::stop_token abort);

  /// Processes until the input queue is closed and drained. `lanes` threads may run it at once,
  /// each lane `lane` of them with its own buffers and one core: a live stream's next volume
  /// is then segmented while the last one still is (issue 17), warm-started from the newest
  /// result there is. The caller closes the output queue once every lane returned.
  void run(int lane = 0, int lanes = 1);
  /// Thread-safe (POST /seed, reload): the next volume starts here; tracking resumes after it.
  void override_seed(const SeedMm& seed_mm);
  /// Called on every turn of run()'s loop, idle or not (the systemd watchdog); before run().
  void set_turn_hook(std::function<void()> hook) { turn_hook_ = std::move(hook); }

 private:
  // What a volume starts from, taken under state_mutex_.
  struct Start {
    RunConfig config;
    SeedCandidate seed;
    StartDecision decision;
    std::optional<WarmStart> warm;
    std::uint64_t anchor = 0;  // anchor_ when the warm start was taken
    std::string anchor_note;   // Previous::note of that warm start
    int chain_length = 0;      // the configured track_max_chain (config's is doubled while busy)
  };
  void process(QueuedVolume item, PipelineBuffers& buffers, int lanes);
  std::optional<Start> begin_volume(const volume::Volume& input, int lanes, nlohmann::json& line);
  void refresh_anchor(std::uint64_t sequence, const volume::Volume& input, const Start& start,
                      const Vec3f& seed_mm, const WarmStart& tracked, PipelineBuffers& buffers);
  // The state the next volumes start from, advanced by a result newer than the one it holds.
  std::optional<WarmStart> end_volume(std::uint64_t sequence, const volume::Volume& input,
                                      const Start& start, PipelineResult& result);
  std::optional<SeedCandidate> pick_seed(const volume::Volume& input, const RunConfig& config,
                                         nlohmann::json& line);
  void fail(const QueuedVolume& item, const std::string& reason, nlohmann::json line);
  bool override_waiting();
  bool claim_cold_start();
  // How this volume's balloon starts (issue 17), and what the next one needs from this result.
  StartDecision choose_start(const volume::Volume& input, const SeedCandidate& seed) const;
  void keep_for_warm_start(const volume::Volume& input, const PipelineResult& result);
  std::optional<WarmStart> take_warm_start(const volume::Volume& input, const StartDecision& start);
  void flag_genus_change(const SeedCandidate& seed, PipelineResult& result, bool newest);

  // What the next volume's warm start needs from the last result; empty after a failure.
  struct Previous {
    WarmStart warm;  // its inset set when it is taken
    Vec3f centroid_mm = Vec3f::Zero();
    double volume_ml = 0.0;
    Vec3i dims = Vec3i::Zero();
    Vec3f spacing_mm = Vec3f::Zero(), origin_mm = Vec3f::Zero();
    bool quality_ok = false;
    float motion_vox = 0.0f;     // centroid motion from the result before
    float volume_change = 0.0f;  // |ΔV| / V from the result before
    std::string note;  // a refreshed anchor: said in the start_reason of the volume tracked from it
  };

  RunContext context_;
  VolumeQueue& in_;
  ResultQueue& out_;
  std::optional<SeedMm> phantom_seed_mm_;
  std::stop_token abort_;  // second signal: abort the volume in hand
  // Everything below up to turn_hook_ is the lanes' shared state, under state_mutex_.
  std::mutex state_mutex_;
  std::optional<std::uint64_t> state_sequence_;  // of the newest volume that set it
  SeedPolicy seeds_;                             // the worker's own
  std::optional<Previous> previous_;
  std::string previous_dropped_;  // why previous_ was last reset (the next cold start says it)
  bool seed_overridden_ = false;  // the last pick_seed used an override
  std::optional<Vec3f> last_centroid_mm_;  // of the last result (its motion, for the next)
  double last_volume_ml_ = 0.0;
  int since_refused_ = 1 << 30;    // volumes since the pipeline last refused a warm start
  std::optional<int> last_genus_;  // of the last result with a surface
  bool cold_lane_busy_ = false;    // a lane started cold with nothing warm (claim_cold_start)
  bool refresh_busy_ = false;      // a lane runs refresh_anchor
  std::uint64_t anchor_ = 0;  // refreshes and new objects so far: a result begun before is not kept
  std::function<void()> turn_hook_;

  std::mutex override_mutex_;  // the one-slot mailbox from the HTTP and signal threads
  std::optional<SeedMm> override_mm_;
};

}  // namespace sonomesh::daemon
