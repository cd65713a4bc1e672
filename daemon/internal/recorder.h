#pragma once
/// @file
/// @brief The one way a journal line goes out: written (journal.h), counted (RunStats), and shown
/// to every output sink in journal order. Also OUT/events.jsonl.

#include <filesystem>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "daemon/internal/journal.h"
#include "daemon/internal/output_sink.h"
#include "daemon/internal/run_stats.h"

namespace sonomesh::daemon {

/// OUT/events.jsonl: outages, reloads, signals. A failed append is logged, never thrown: events
/// are diagnostics, the journal is the record.
class EventLog {
 public:
  explicit EventLog(const std::filesystem::path& path) : file_(path) {}
  void event(const std::string& kind, nlohmann::json fields = nlohmann::json::object());

 private:
  JsonlFile file_;
};

class Recorder {
 public:
  /// @throws std::runtime_error if the journal cannot be opened.
  Recorder(const std::filesystem::path& journal_path, RunStats& stats);

  /// Before the threads start.
  void add_sink(std::shared_ptr<OutputSink> sink);
  const std::vector<std::shared_ptr<OutputSink>>& sinks() const { return sinks_; }

  bool claim(std::uint64_t sequence) { return journal_.claim(sequence); }
  /// What the journal says, including what an earlier run on the same out dir left.
  const Journal& journal() const { return journal_; }
  std::uint64_t new_epoch() { return journal_.new_epoch(); }

  /// Writes one line (sequence, status, epoch and time are set here), counts it, shows it to the
  /// sinks. @throws std::runtime_error if the journal cannot be written.
  void record(std::optional<std::uint64_t> sequence, JournalStatus status, nlohmann::json fields,
              std::uint64_t epoch, const ProcessedVolume* volume = nullptr);
  /// `lost` lines for [first, first + count) not claimed yet, in the journal's current epoch.
  /// Returns how many were written.
  std::uint64_t record_lost(std::uint64_t first, std::uint64_t count, const std::string& reason);

 private:
  Journal journal_;
  RunStats& stats_;
  std::vector<std::shared_ptr<OutputSink>> sinks_;
  std::mutex mutex_;  // one line at a time, so that sinks see the journal's order
};

}  // namespace sonomesh::daemon
