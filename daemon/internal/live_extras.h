#pragma once
/// @file
/// @brief The live page's and systemd's parts of `sonomeshd run`, composed in one place: the
/// event hub (/events), the slice renderer (/slices, fed by an output sink), the notifier (READY,
/// STATUS, WATCHDOG, STOPPING) and the watchdog hook the worker calls on every turn.

#include <filesystem>
#include <functional>
#include <memory>

#include "daemon/internal/event_hub.h"
#include "daemon/internal/notifier.h"
#include "daemon/internal/output_sink.h"
#include "daemon/internal/run_stats.h"
#include "daemon/internal/slice_renderer.h"
#include "daemon/internal/web_routes.h"

namespace sonomesh::daemon {

class LiveExtras {
 public:
  /// `out`: the run's output directory (its journal.jsonl is what /events streams).
  LiveExtras(const std::filesystem::path& out, const RunStats& stats);
  ~LiveExtras();

  /// Starts following the journal; call before the runner writes its first line.
  void start();
  /// The daemon serves: HTTP listens (or is off). READY=1 follows once the source is open.
  void serving(bool http_ready);
  /// A stop was requested (signal): STOPPING=1 at once.
  void stop_requested();
  /// After the runner returned, before the HTTP server stops: ends the event streams, the
  /// monitor, and sends STOPPING=1 if not sent yet. Idempotent.
  void stop();

  WebContext web();
  /// For LiveRunner::set_worker_turn_hook: a systemd watchdog ping (rate-limited by Notifier).
  std::function<void()> worker_turn_hook();
  /// For LiveRunner::add_sink: hands every processed volume to the slice renderer before its
  /// journal line goes out (so /slices has it when /events says so).
  std::shared_ptr<OutputSink> slice_sink();
  Notifier& notifier() { return notifier_; }

 private:
  const RunStats& stats_;
  Notifier notifier_;
  EventHub hub_;
  SliceRenderer slices_;
  ServiceMonitor monitor_;
  bool stop_sent_ = false;
};

}  // namespace sonomesh::daemon
