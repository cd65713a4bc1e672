#pragma once
/// @file
/// @brief The acquisition thread's job: keep a source open (reconnect with backoff, record the
/// outage), give every sequence its claim (resends dropped, counter restarts as new epochs), turn
/// source errors into `lost`/`rejected` lines, and hand volumes to the worker's queue.

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <tl/expected.hpp>

#include "acquire/acquire.h"
#include "daemon/internal/recorder.h"
#include "daemon/internal/run_config.h"
#include "daemon/internal/run_stats.h"
#include "daemon/internal/volume_queue.h"

namespace sonomesh::daemon {

using SourceFactory =
    std::function<tl::expected<std::unique_ptr<acquire::Source>, acquire::AcquireError>()>;

/// What the parts share; owned by LiveRunner, outliving every thread.
struct RunContext {
  const SharedConfig& config;
  Recorder& recorder;
  RunStats& stats;
  EventLog& events;
  std::function<void(const std::string&)> fatal;  // journal/output failure: stop the daemon
};

/// Journals a volume that will not be processed as `skipped` (shutdown, superseded).
void record_skipped(RunContext& context, const QueuedVolume& item, const std::string& reason,
                    nlohmann::json extra = nlohmann::json::object());

class Acquisition {
 public:
  /// `source` may be null: run() then opens one with `factory`, retrying with backoff. `live`: a
  /// probe (volumes not received while the daemon was down are lost) rather than a replay.
  Acquisition(RunContext context, std::unique_ptr<acquire::Source> source, SourceFactory factory,
              VolumeQueue& queue, bool live);
  ~Acquisition();

  /// Reads until end of stream (closes the queue, which the worker drains) or stop() (journals
  /// what is still queued as skipped).
  void run();
  /// Thread-safe: wakes run() out of a read or a backoff sleep; it returns soon after.
  void stop();
  /// Closes the source (after run() returned).
  void close_source();
  std::optional<std::string> describe_source();

 private:
  bool open_source(std::chrono::milliseconds& backoff);
  void handle_volume(acquire::RawVolume raw, std::chrono::steady_clock::time_point received);
  bool claim_or_restart(std::uint64_t sequence);
  bool done_by_earlier_run(std::uint64_t sequence);
  void handle_error(const acquire::AcquireError& error);
  void handle_bad_record(const acquire::AcquireError& error);
  void handle_lost_source(const acquire::AcquireError& error);
  void sleep_unless_stopped(std::chrono::milliseconds duration);

  RunContext context_;
  SourceFactory factory_;
  VolumeQueue& queue_;

  std::mutex mutex_;  // guards source_ (replaced here, interrupted by stop()) and the wake-up
  std::condition_variable wake_;
  std::unique_ptr<acquire::Source> source_;
  std::atomic<bool> stopping_{false};

  // The acquisition thread's own state.
  acquire::Source* reading_ = nullptr;  // source_ while open; read without the lock
  std::optional<std::uint64_t> highest_sequence_;
  std::optional<std::chrono::steady_clock::time_point> outage_started_;
  std::uint64_t epoch_ = 0;
  bool live_ = false;
  // A restart on an out dir with a journal: its first live volume checks for the gap since.
  bool resume_gap_pending_ = false;
  std::uint64_t earlier_done_ = 0;  // replayed volumes dropped: an earlier run wrote their line
};

}  // namespace sonomesh::daemon
