#pragma once
/// @file
/// @brief `sonomeshd run` composed: Acquisition (its thread: the caller's) -> VolumeQueue ->
/// Worker -> ResultQueue -> Writer -> output sinks, all recording through one Recorder.
///
/// Ownership: the runner owns the parts and the shared configuration; each thread owns the state
/// of its part. Locks: SharedConfig (configuration), Acquisition (its source), Worker (the seed
/// mailbox), Recorder (journal order), and one inside each queue.

#include <array>
#include <atomic>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <stop_token>
#include <string>

#include "acquire/acquire.h"
#include "daemon/internal/acquisition.h"
#include "daemon/internal/output_sink.h"
#include "daemon/internal/recorder.h"
#include "daemon/internal/run_config.h"
#include "daemon/internal/run_stats.h"
#include "daemon/internal/seed_policy.h"
#include "daemon/internal/volume_queue.h"
#include "daemon/internal/worker.h"
#include "daemon/internal/writer.h"

namespace sonomesh::daemon {

class LiveRunner {
 public:
  /// `source` may be null: the acquisition thread then opens one with `factory`, retrying with
  /// backoff (a live probe that is not up yet). `phantom_seed_mm`: the simulator's known seed.
  /// The files sink (OUT/meshes, reports, latest.ply) is always the first sink.
  /// @throws std::runtime_error if OUT cannot be created or the journal cannot be opened.
  LiveRunner(RunConfig config, std::unique_ptr<acquire::Source> source, SourceFactory factory,
             bool live, std::optional<std::array<float, 3>> phantom_seed_mm = std::nullopt);
  ~LiveRunner();

  /// Adds an output (before run()): it sees every journal line and every processed volume.
  void add_sink(std::shared_ptr<OutputSink> sink);
  /// web (issue 18): called on every turn of the worker's loop, idle or not (before run()): the
  /// systemd watchdog must say the worker itself is alive, which no sink can.
  void set_worker_turn_hook(std::function<void()> hook);

  /// Runs until end of stream (after draining) or a stop request (after finishing the volume in
  /// hand). Returns the exit code: 0, or 1 if the journal/outputs could not be written.
  int run();

  /// First call: stop acquiring, finish the volume in hand. Second call: also abort it.
  /// Thread-safe, cheap (called from the signal thread).
  void request_stop();
  /// Applies a new configuration from the next volume on (pipeline, queue capacity, seed, limits;
  /// source/out/http/igtl changes are logged as needing a restart).
  void reload(const RunConfig& config);
  /// POST /seed: the next volume starts from here (tracking resumes after it).
  std::optional<std::string> set_seed(const std::array<float, 3>& seed_mm);

  const RunStats& stats() const { return stats_; }
  RunStats& stats() { return stats_; }
  /// Appends to OUT/events.jsonl (thread-safe; failures are logged, not thrown).
  void event(const std::string& kind, nlohmann::json fields = nlohmann::json::object());

 private:
  void fail_fatal(const std::string& what);
  RunContext context();

  SharedConfig config_;
  bool live_;
  std::filesystem::path out_;
  RunStats stats_;
  std::unique_ptr<EventLog> events_;
  std::unique_ptr<Recorder> recorder_;
  std::unique_ptr<VolumeQueue> queue_;
  std::unique_ptr<ResultQueue> results_;
  std::unique_ptr<Acquisition> acquisition_;
  std::unique_ptr<Worker> worker_;
  std::unique_ptr<Writer> writer_;

  std::atomic<bool> stopping_{false};
  std::atomic<bool> fatal_{false};
  std::stop_source abort_;  // second signal: abort the volume in hand
};

}  // namespace sonomesh::daemon
