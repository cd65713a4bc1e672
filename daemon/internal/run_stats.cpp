#include "daemon/internal/run_stats.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <vector>

#ifndef SONOMESH_VERSION
#define SONOMESH_VERSION "unknown"
#endif

namespace sonomesh::daemon {

namespace {
constexpr std::array<JournalStatus, 5> kStatuses{JournalStatus::Processed, JournalStatus::Skipped,
                                                 JournalStatus::Failed, JournalStatus::Rejected,
                                                 JournalStatus::Lost};

// Prometheus float formatting: plain decimal, "+Inf" for infinity.
std::string prom_number(double v) {
  if (std::isinf(v)) return v > 0 ? "+Inf" : "-Inf";
  if (std::isnan(v)) return "NaN";
  std::ostringstream out;
  out.precision(9);
  out << v;
  return out.str();
}

// Prometheus label value: backslash, double quote and newline escaped.
std::string prom_label(const std::string& v) {
  std::string out;
  for (char c : v) {
    if (c == '\\' || c == '"') out.push_back('\\');
    if (c == '\n') {
      out += "\\n";
      continue;
    }
    out.push_back(c);
  }
  return out;
}

double quantile_of(std::vector<double> values, double q) {
  std::sort(values.begin(), values.end());
  // Nearest rank: the smallest value with at least q of the samples at or below it.
  const double rank = std::ceil(q * static_cast<double>(values.size()));
  const std::size_t index =
      static_cast<std::size_t>(std::clamp(rank, 1.0, static_cast<double>(values.size()))) - 1;
  return values[index];
}
}  // namespace

const char* to_string(SourceState state) {
  switch (state) {
    case SourceState::Connecting:
      return "connecting";
    case SourceState::Connected:
      return "connected";
    case SourceState::Reconnecting:
      return "reconnecting";
    case SourceState::Ended:
      return "ended";
  }
  return "unknown";
}

RunStats::RunStats() : started_(std::chrono::steady_clock::now()) {}

void RunStats::set_source(std::string describe, bool live) {
  std::lock_guard lock(mutex_);
  source_ = std::move(describe);
  live_ = live;
}

void RunStats::count(JournalStatus status, std::uint64_t n) {
  std::lock_guard lock(mutex_);
  counters_[status] += n;
}

void RunStats::add_latency(double latency_ms) {
  std::lock_guard lock(mutex_);
  recent_latency_ms_.push_back(latency_ms);
  while (recent_latency_ms_.size() > kLatencyWindow) recent_latency_ms_.pop_front();
  const double s = latency_ms / 1000.0;
  for (std::size_t i = 0; i < kLatencyBuckets.size(); ++i) {
    if (s <= kLatencyBuckets[i]) ++bucket_counts_[i];
  }
  ++latency_count_;
  latency_sum_s_ += s;
}

void RunStats::add_stage_time(const std::string& stage, double ms) {
  std::lock_guard lock(mutex_);
  stage_sum_ms_[stage] += ms;
  ++stage_count_[stage];
}

void RunStats::set_source_state(SourceState state) {
  std::lock_guard lock(mutex_);
  source_state_ = state;
}

void RunStats::set_last_error(std::string error) {
  std::lock_guard lock(mutex_);
  last_error_ = std::move(error);
  last_error_time_ = utc_timestamp();
}

void RunStats::set_queue_depth(std::size_t depth, std::size_t capacity) {
  std::lock_guard lock(mutex_);
  queue_depth_ = depth;
  queue_capacity_ = capacity;
}

void RunStats::set_seed(std::optional<std::array<float, 3>> seed_mm, std::string origin) {
  std::lock_guard lock(mutex_);
  seed_mm_ = seed_mm;
  seed_origin_ = std::move(origin);
}

void RunStats::set_last_processed(std::uint64_t sequence, int genus) {
  std::lock_guard lock(mutex_);
  last_sequence_ = sequence;
  last_genus_ = genus;
}

void RunStats::count_quality(bool ok, const std::vector<std::string>& reasons) {
  std::lock_guard lock(mutex_);
  ++(ok ? quality_ok_ : quality_suspect_);
  if (!ok) {
    for (const std::string& reason : reasons) ++suspect_reasons_[reason];
  }
  last_quality_ok_ = ok;
  last_quality_reasons_ = reasons;
}

void RunStats::count_start(bool warm) {
  std::lock_guard lock(mutex_);
  ++(warm ? warm_starts_ : cold_starts_);
}

void RunStats::set_igtl(std::size_t clients, std::uint64_t sent, std::uint64_t dropped) {
  std::lock_guard lock(mutex_);
  igtl_enabled_ = true;
  igtl_clients_ = clients;
  igtl_sent_ = sent;
  igtl_dropped_ = dropped;
}

void RunStats::count_outage() {
  std::lock_guard lock(mutex_);
  ++outages_;
}

SourceState RunStats::source_state() const {
  std::lock_guard lock(mutex_);
  return source_state_;
}

std::uint64_t RunStats::counter(JournalStatus status) const {
  std::lock_guard lock(mutex_);
  const auto it = counters_.find(status);
  return it == counters_.end() ? 0 : it->second;
}

std::optional<double> RunStats::latency_quantile_ms(double q) const {
  std::lock_guard lock(mutex_);
  if (recent_latency_ms_.empty()) return std::nullopt;
  return quantile_of({recent_latency_ms_.begin(), recent_latency_ms_.end()}, q);
}

nlohmann::json RunStats::status_json() const {
  std::lock_guard lock(mutex_);
  nlohmann::json j;
  nlohmann::json counts = nlohmann::json::object();
  std::uint64_t total = 0;
  for (JournalStatus s : kStatuses) {
    const auto it = counters_.find(s);
    const std::uint64_t n = it == counters_.end() ? 0 : it->second;
    counts[to_string(s)] = n;
    total += n;
  }
  j["volumes"] = counts;
  j["volumes_total"] = total;
  nlohmann::json latency = {{"window", recent_latency_ms_.size()}};
  if (recent_latency_ms_.empty()) {
    latency["p50"] = nullptr;
    latency["p95"] = nullptr;
  } else {
    std::vector<double> v(recent_latency_ms_.begin(), recent_latency_ms_.end());
    latency["p50"] = quantile_of(v, 0.5);
    latency["p95"] = quantile_of(v, 0.95);
    latency["max"] = *std::max_element(v.begin(), v.end());
  }
  j["latency_ms"] = latency;
  j["source"] = {{"uri", source_},
                 {"live", live_},
                 {"state", to_string(source_state_)},
                 {"outages", outages_}};
  j["last_error"] = last_error_.empty()
                        ? nlohmann::json(nullptr)
                        : nlohmann::json{{"message", last_error_}, {"time", last_error_time_}};
  j["queue"] = {{"depth", queue_depth_}, {"capacity", queue_capacity_}};
  j["seed"] = {{"mm", seed_mm_ ? nlohmann::json(*seed_mm_) : nlohmann::json(nullptr)},
               {"origin", seed_origin_}};
  j["last_processed"] = nlohmann::json(nullptr);
  if (last_sequence_) {
    j["last_processed"] = {{"sequence", *last_sequence_}, {"genus", last_genus_}};
    if (last_quality_ok_) {
      j["last_processed"]["quality"] = *last_quality_ok_ ? "ok" : "suspect";
      j["last_processed"]["quality_reasons"] = last_quality_reasons_;
    }
  }
  j["quality"] = {
      {"ok", quality_ok_}, {"suspect", quality_suspect_}, {"suspect_reasons", suspect_reasons_}};
  j["starts"] = {{"warm", warm_starts_}, {"cold", cold_starts_}};
  if (igtl_enabled_) {
    j["igtl"] = {{"clients", igtl_clients_}, {"sent", igtl_sent_}, {"dropped", igtl_dropped_}};
  }
  j["uptime_s"] =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - started_).count();
  return j;
}

namespace {
// The "# HELP" and "# TYPE" lines of one metric.
void describe(std::ostream& out, const std::string& name, const char* type,
              const std::string& help) {
  out << "# HELP " << name << ' ' << help << "\n# TYPE " << name << ' ' << type << "\n";
}
}  // namespace

std::string RunStats::prometheus_text() const {
  std::lock_guard lock(mutex_);
  std::ostringstream out;
  prom_counts(out);
  prom_latency(out);
  prom_state(out);
  return out.str();
}

void RunStats::prom_counts(std::ostream& out) const {
  // *_info: constant 1 with the facts as labels (Prometheus naming conventions).
  describe(out, "sonomesh_build_info", "gauge", "The running sonomeshd's version.");
  out << "sonomesh_build_info{version=\"" << prom_label(SONOMESH_VERSION) << "\"} 1\n";
  describe(out, "sonomesh_source_info", "gauge", "The probe source this daemon reads.");
  out << "sonomesh_source_info{uri=\"" << prom_label(source_) << "\",live=\""
      << (live_ ? "true" : "false") << "\"} 1\n";
  describe(out, "sonomesh_volumes_total", "counter",
           "Volumes by journal status (one per sequence number).");
  for (JournalStatus s : kStatuses) {
    const auto it = counters_.find(s);
    out << "sonomesh_volumes_total{status=\"" << to_string(s) << "\"} "
        << (it == counters_.end() ? 0 : it->second) << "\n";
  }
  describe(out, "sonomesh_results_total", "counter", "Processed volumes by quality verdict.");
  out << "sonomesh_results_total{quality=\"ok\"} " << quality_ok_ << "\n"
      << "sonomesh_results_total{quality=\"suspect\"} " << quality_suspect_ << "\n";
  describe(out, "sonomesh_suspect_reasons_total", "counter",
           "Suspect results by reason (one may have several).");
  for (const auto& [reason, n] : suspect_reasons_)
    out << "sonomesh_suspect_reasons_total{reason=\"" << prom_label(reason) << "\"} " << n << "\n";
  describe(out, "sonomesh_starts_total", "counter",
           "Processed volumes by how the balloon started.");
  out << "sonomesh_starts_total{start=\"warm\"} " << warm_starts_ << "\n"
      << "sonomesh_starts_total{start=\"cold\"} " << cold_starts_ << "\n";
}

void RunStats::prom_latency(std::ostream& out) const {
  describe(out, "sonomesh_latency_seconds", "summary",
           "Received-to-mesh-written latency over the last " + std::to_string(kLatencyWindow) +
               " meshes.");
  if (!recent_latency_ms_.empty()) {
    std::vector<double> v(recent_latency_ms_.begin(), recent_latency_ms_.end());
    for (double q : {0.5, 0.95, 0.99})
      out << "sonomesh_latency_seconds{quantile=\"" << prom_number(q) << "\"} "
          << prom_number(quantile_of(v, q) / 1000.0) << "\n";
  }
  out << "sonomesh_latency_seconds_sum " << prom_number(latency_sum_s_) << "\n"
      << "sonomesh_latency_seconds_count " << latency_count_ << "\n";
  describe(out, "sonomesh_latency_histogram_seconds", "histogram",
           "Received-to-mesh-written latency.");
  for (std::size_t i = 0; i < kLatencyBuckets.size(); ++i)
    out << "sonomesh_latency_histogram_seconds_bucket{le=\"" << prom_number(kLatencyBuckets[i])
        << "\"} " << bucket_counts_[i] << "\n";
  out << "sonomesh_latency_histogram_seconds_bucket{le=\"+Inf\"} " << latency_count_ << "\n"
      << "sonomesh_latency_histogram_seconds_sum " << prom_number(latency_sum_s_) << "\n"
      << "sonomesh_latency_histogram_seconds_count " << latency_count_ << "\n";
}

void RunStats::prom_state(std::ostream& out) const {
  describe(out, "sonomesh_stage_seconds_total", "counter", "Time spent per pipeline stage.");
  for (const auto& [stage, ms] : stage_sum_ms_)
    out << "sonomesh_stage_seconds_total{stage=\"" << stage << "\"} " << prom_number(ms / 1000.0)
        << "\n";
  describe(out, "sonomesh_queue_depth", "gauge", "Volumes waiting for the worker.");
  out << "sonomesh_queue_depth " << queue_depth_ << "\n";
  describe(out, "sonomesh_queue_capacity", "gauge", "Capacity of the queue.");
  out << "sonomesh_queue_capacity " << queue_capacity_ << "\n";
  describe(out, "sonomesh_source_connected", "gauge", "1 while the probe source is connected.");
  out << "sonomesh_source_connected " << (source_state_ == SourceState::Connected ? 1 : 0) << "\n";
  describe(out, "sonomesh_source_outages_total", "counter", "Times the source was lost.");
  out << "sonomesh_source_outages_total " << outages_ << "\n";
  if (igtl_enabled_) {
    describe(out, "sonomesh_igtl_clients", "gauge", "OpenIGTLink clients connected.");
    out << "sonomesh_igtl_clients " << igtl_clients_ << "\n";
    describe(out, "sonomesh_igtl_results_total", "counter",
             "OpenIGTLink result sets by outcome (dropped: a slow client had newer ones "
             "waiting).");
    out << "sonomesh_igtl_results_total{outcome=\"sent\"} " << igtl_sent_ << "\n"
        << "sonomesh_igtl_results_total{outcome=\"dropped\"} " << igtl_dropped_ << "\n";
  }
  describe(out, "sonomesh_uptime_seconds", "gauge", "Seconds since the daemon started.");
  out << "sonomesh_uptime_seconds "
      << prom_number(
             std::chrono::duration<double>(std::chrono::steady_clock::now() - started_).count())
      << "\n";
}

}  // namespace sonomesh::daemon
