#pragma once
/// @file
/// @brief The processing worker: a queued volume in, a ProcessedVolume (to the writer) or a
/// `failed` line out. Chooses the seed (SeedPolicy), runs the pipeline, gathers the journal fields.

#include <functional>
#include <mutex>
#include <optional>
#include <stop_token>

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

  /// Processes until the input queue is closed and drained, then closes the output queue.
  void run();
  /// Thread-safe (POST /seed, reload): the next volume starts here; tracking resumes after it.
  void override_seed(const SeedMm& seed_mm);
  /// Called on every turn of run()'s loop, idle or not (the systemd watchdog); before run().
  void set_turn_hook(std::function<void()> hook) { turn_hook_ = std::move(hook); }

 private:
  void process(QueuedVolume item);
  std::optional<SeedCandidate> pick_seed(const volume::Volume& input, const RunConfig& config,
                                         nlohmann::json& line);
  void fail(const QueuedVolume& item, const std::string& reason, nlohmann::json line);
  bool override_waiting();

  RunContext context_;
  VolumeQueue& in_;
  ResultQueue& out_;
  std::optional<SeedMm> phantom_seed_mm_;
  std::stop_token abort_;    // second signal: abort the volume in hand
  PipelineBuffers buffers_;  // smoothing buffers, reused from volume to volume
  SeedPolicy seeds_;         // the worker's own
  std::function<void()> turn_hook_;

  std::mutex override_mutex_;  // the one-slot mailbox from the HTTP and signal threads
  std::optional<SeedMm> override_mm_;
};

}  // namespace sonomesh::daemon
