#include "daemon/internal/recorder.h"

#include <spdlog/spdlog.h>

namespace sonomesh::daemon {

void EventLog::event(const std::string& kind, nlohmann::json fields) {
  if (!fields.is_object()) fields = nlohmann::json::object();
  fields["event"] = kind;
  try {
    file_.append(std::move(fields));
  } catch (const std::exception& e) {
    spdlog::error("{}", e.what());
  }
}

Recorder::Recorder(const std::filesystem::path& journal_path, RunStats& stats)
    : journal_(journal_path), stats_(stats) {}

void Recorder::add_sink(std::shared_ptr<OutputSink> sink) { sinks_.push_back(std::move(sink)); }

void Recorder::record(std::optional<std::uint64_t> sequence, JournalStatus status,
                      nlohmann::json fields, std::uint64_t epoch, const ProcessedVolume* volume) {
  if (!fields.is_object()) fields = nlohmann::json::object();
  std::lock_guard lock(mutex_);
  // The sinks get the line as the journal writes it (Journal::write adds the same keys).
  nlohmann::json line = fields;
  line["sequence"] = sequence ? nlohmann::json(*sequence) : nlohmann::json(nullptr);
  line["status"] = to_string(status);
  if (epoch > 0) line["epoch"] = epoch;
  line["time"] = utc_timestamp();
  journal_.write(sequence, status, std::move(fields), epoch);
  stats_.count(status);
  for (const auto& sink : sinks_) {
    try {
      sink->on_line(line, volume);
    } catch (const std::exception& e) {
      spdlog::error("output {}: {}", sink->name(), e.what());
    }
  }
}

std::uint64_t Recorder::record_lost(std::uint64_t first, std::uint64_t count,
                                    const std::string& reason) {
  std::uint64_t written = 0;
  const std::uint64_t epoch = journal_.epoch();
  for (std::uint64_t i = 0; i < count; ++i) {
    const std::uint64_t seq = first + i;
    if (seq < first) break;  // wrapped
    if (!journal_.claim(seq)) continue;
    record(seq, JournalStatus::Lost, {{"reason", reason}}, epoch);
    ++written;
  }
  return written;
}

}  // namespace sonomesh::daemon
