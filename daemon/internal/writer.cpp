#include "daemon/internal/writer.h"

#include <spdlog/spdlog.h>

namespace sonomesh::daemon {

using Clock = std::chrono::steady_clock;

namespace {
double ms_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}
}  // namespace

void Writer::run() {
  while (auto result = in_.pop()) {
    try {
      write_one(*result);
    } catch (const std::exception& e) {
      context_.fatal(e.what());  // the journal cannot be written
    }
  }
}

void Writer::write_one(WorkerResult& result) {
  const ProcessedVolume& v = result.volume;
  nlohmann::json& line = result.line;
  const Clock::time_point started = Clock::now();
  for (const auto& sink : context_.recorder.sinks()) {
    try {
      sink->write(v, line);
    } catch (const std::exception& e) {
      // An output that cannot be written is this volume's failure; its line still goes out.
      line["reason"] = std::string("write: ") + e.what();
      context_.recorder.record(v.sequence, JournalStatus::Failed, std::move(line), v.epoch);
      context_.stats.set_last_error(e.what());
      spdlog::error("sequence {}: {}", v.sequence, e.what());
      return;
    }
  }
  const Clock::time_point done = Clock::now();
  line["timings_ms"]["write"] = ms_between(started, done);
  // The latency ends where readers look: a sink that publishes the mesh says when (files).
  if (!line.contains("latency_ms")) line["latency_ms"] = ms_between(v.received, done);
  const double latency_ms = line["latency_ms"].get<double>();
  const int genus = line.value("genus", -1);
  const bool quality_ok = line.value("quality", std::string("ok")) == "ok";
  context_.recorder.record(v.sequence, JournalStatus::Processed, line, v.epoch, &v);
  RunStats& stats = context_.stats;
  stats.add_latency(latency_ms);
  stats.set_last_processed(v.sequence, genus);
  stats.count_quality(quality_ok, line.value("quality_reasons", std::vector<std::string>{}));
  for (const auto& [stage, ms] : v.timings.stages()) stats.add_stage_time(stage, ms);
  spdlog::info("sequence {} processed: genus {}, {:.0f} ms after it arrived", v.sequence, genus,
               latency_ms);
}

}  // namespace sonomesh::daemon
