#pragma once
/// @file
/// @brief What the daemon reports over HTTP: counters, latency, source state, seed. Thread-safe.

#include <array>
#include <chrono>
#include <cstdint>
#include <deque>
#include <iosfwd>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "daemon/internal/journal.h"

namespace sonomesh::daemon {

enum class SourceState { Connecting, Connected, Reconnecting, Ended };
const char* to_string(SourceState state);

class RunStats {
 public:
  /// Upper bounds (seconds) of the latency histogram buckets (+Inf is implicit).
  static constexpr std::array<double, 10> kLatencyBuckets{0.025, 0.05, 0.075, 0.1, 0.15,
                                                          0.25,  0.5,  1.0,   2.5, 5.0};
  /// Number of recent latencies the quantiles are computed over.
  static constexpr std::size_t kLatencyWindow = 1024;

  RunStats();

  void set_source(std::string describe, bool live);
  void count(JournalStatus status, std::uint64_t n = 1);
  /// A mesh was written `latency_ms` after its volume was received.
  void add_latency(double latency_ms);
  /// Per-stage time of a processed volume (accumulated for /metrics).
  void add_stage_time(const std::string& stage, double ms);
  void set_source_state(SourceState state);
  void set_last_error(std::string error);
  void set_queue_depth(std::size_t depth, std::size_t capacity);
  void set_seed(std::optional<std::array<float, 3>> seed_mm, std::string origin);
  void set_last_processed(std::uint64_t sequence, int genus);
  /// The quality verdict of a processed volume (DESIGN.md): counted per verdict and per reason,
  /// and shown as the latest one.
  void count_quality(bool ok, const std::vector<std::string>& reasons);
  void count_outage();
  /// How a processed volume's balloon started (issue 17): warm or cold.
  void count_start(bool warm);
  /// The OpenIGTLink server's clients and result sets sent or dropped (slow clients).
  void set_igtl(std::size_t clients, std::uint64_t sent, std::uint64_t dropped);

  SourceState source_state() const;
  std::uint64_t counter(JournalStatus status) const;
  /// Quantile q in [0, 1] of the recent latencies in ms, or nothing before the first mesh.
  std::optional<double> latency_quantile_ms(double q) const;

  /// GET /status body.
  nlohmann::json status_json() const;
  /// GET /metrics body (Prometheus text exposition format 0.0.4).
  std::string prometheus_text() const;

 private:
  // prometheus_text's parts, called with mutex_ held.
  void prom_counts(std::ostream& out) const;
  void prom_latency(std::ostream& out) const;
  void prom_state(std::ostream& out) const;

  mutable std::mutex mutex_;
  std::chrono::steady_clock::time_point started_;
  std::string source_;
  bool live_ = true;
  std::map<JournalStatus, std::uint64_t> counters_;
  std::deque<double> recent_latency_ms_;
  std::array<std::uint64_t, kLatencyBuckets.size()> bucket_counts_{};
  std::uint64_t latency_count_ = 0;
  double latency_sum_s_ = 0;
  std::map<std::string, double> stage_sum_ms_;
  std::map<std::string, std::uint64_t> stage_count_;
  SourceState source_state_ = SourceState::Connecting;
  std::string last_error_;
  std::string last_error_time_;
  std::size_t queue_depth_ = 0;
  std::size_t queue_capacity_ = 0;
  std::optional<std::array<float, 3>> seed_mm_;
  std::string seed_origin_;
  std::optional<std::uint64_t> last_sequence_;
  int last_genus_ = -1;
  std::uint64_t quality_ok_ = 0;
  std::uint64_t quality_suspect_ = 0;
  std::uint64_t warm_starts_ = 0;
  std::uint64_t cold_starts_ = 0;
  std::map<std::string, std::uint64_t> suspect_reasons_;
  std::optional<bool> last_quality_ok_;
  std::vector<std::string> last_quality_reasons_;
  std::uint64_t outages_ = 0;
  bool igtl_enabled_ = false;
  std::size_t igtl_clients_ = 0;
  std::uint64_t igtl_sent_ = 0;
  std::uint64_t igtl_dropped_ = 0;
};

}  // namespace sonomesh::daemon
