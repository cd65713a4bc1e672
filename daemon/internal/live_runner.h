#pragma once
/// @file
/// @brief `sonomeshd run`: acquisition thread -> bounded queue -> processing worker -> writer
/// thread, with the journal, the outputs, seed tracking, reconnects and clean shutdown.

#include <array>
#include <atomic>
#include <condition_variable>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <stop_token>
#include <string>

#include <tl/expected.hpp>

#include "acquire/acquire.h"
#include "daemon/internal/journal.h"
#include "daemon/internal/live_hooks.h"  // web: issue 18
#include "daemon/internal/run_config.h"
#include "daemon/internal/run_stats.h"
#include "daemon/internal/volume_queue.h"
#include "daemon/pipeline.h"

namespace sonomesh::daemon {

using SourceFactory =
    std::function<tl::expected<std::unique_ptr<acquire::Source>, acquire::AcquireError>()>;

/// Where a seed came from (reported in the journal and /status).
enum class SeedOrigin { Tracked, Configured, Phantom, Centre };
const char* to_string(SeedOrigin origin);

class LiveRunner {
 public:
  /// `source` may be null: the acquisition thread then opens one with `factory`, retrying with
  /// backoff (a live probe that is not up yet). `phantom_seed_mm`: the simulator's known seed.
  /// @throws std::runtime_error if OUT cannot be created or the journal cannot be opened.
  LiveRunner(RunConfig config, std::unique_ptr<acquire::Source> source, SourceFactory factory,
             bool live, std::optional<std::array<float, 3>> phantom_seed_mm = std::nullopt);
  ~LiveRunner();

  /// Runs until end of stream (after draining) or a stop request (after finishing the volume in
  /// hand). Returns the exit code: 0, or 1 if the journal/outputs could not be written.
  int run();

  /// First call: stop acquiring, finish the volume in hand. Second call: also abort it.
  /// Thread-safe, cheap (called from the signal thread).
  void request_stop();
  /// Applies a new configuration from the next volume on (pipeline, queue capacity, seed, limits;
  /// source/out/http changes are logged as needing a restart).
  void reload(const RunConfig& config);
  /// POST /seed: the next volume starts from here (tracking resumes after it).
  std::optional<std::string> set_seed(const std::array<float, 3>& seed_mm);

  const RunStats& stats() const { return stats_; }
  /// web (issue 18): the live page's and systemd's callbacks; set before run().
  void set_hooks(LiveHooks hooks) { hooks_ = std::move(hooks); }
  /// Appends to OUT/events.jsonl (thread-safe; failures are logged, not thrown).
  void event(const std::string& kind, nlohmann::json fields = nlohmann::json::object());

 private:
  struct WriteJob;
  class WriteQueue;

  void acquisition_loop();
  void worker_loop();
  void writer_loop();
  void handle_volume(acquire::RawVolume raw, std::chrono::steady_clock::time_point received);
  void handle_error(const acquire::AcquireError& error);
  bool done_by_earlier_run(std::uint64_t sequence);
  void process_one(QueuedVolume item);
  void write_one(WriteJob& job);
  void journal_skipped(const QueuedVolume& item, const std::string& reason,
                       nlohmann::json extra = nlohmann::json::object());
  void prune_outputs();
  void fail_fatal(const std::string& what);
  RunConfig config_snapshot() const;

  mutable std::mutex config_mutex_;
  RunConfig config_;
  std::unique_ptr<acquire::Source> source_;
  SourceFactory factory_;
  bool live_;
  std::optional<std::array<float, 3>> phantom_seed_mm_;

  std::filesystem::path out_;
  std::unique_ptr<Journal> journal_;
  std::unique_ptr<JsonlFile> events_;
  RunStats stats_;
  std::unique_ptr<VolumeQueue> queue_;
  std::unique_ptr<WriteQueue> write_queue_;

  std::mutex source_mutex_;  // guards source_ replacement against interrupt() from other threads
  std::atomic<bool> source_ready_{false};
  std::mutex stop_mutex_;
  std::condition_variable stop_cv_;  // interruptible backoff sleeps

  std::atomic<bool> stopping_{false};
  std::atomic<bool> fatal_{false};
  std::stop_source abort_;  // second signal: abort the volume in hand
  PipelineBuffers buffers_;  // the worker's smoothing buffers, reused from volume to volume
  LiveHooks hooks_;          // web (issue 18)

  std::mutex seed_mutex_;
  std::optional<std::array<float, 3>> tracked_seed_mm_;
  std::optional<std::array<float, 3>> override_seed_mm_;  // POST /seed, used once

  // Acquisition state (acquisition thread only).
  std::optional<std::uint64_t> highest_sequence_;
  std::optional<std::chrono::steady_clock::time_point> outage_started_;
  std::uint64_t epoch_ = 0;
  // A restart on an out dir with a journal: its first live volume checks for the gap since.
  bool resume_gap_pending_ = false;
  std::uint64_t earlier_done_ = 0;  // replayed volumes dropped: an earlier run wrote their line

  std::mutex written_mutex_;
  std::vector<std::string> written_stems_;  // for keep_meshes pruning, oldest first
};

}  // namespace sonomesh::daemon
