#pragma once
/// @file
/// @brief systemd's notify protocol through libsystemd (sd_notify): READY=1, STATUS=,
/// WATCHDOG=1, STOPPING=1. Without NOTIFY_SOCKET (not started by systemd) every call is a no-op.

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>

namespace sonomesh::daemon {

class Notifier {
 public:
  /// Reads NOTIFY_SOCKET and the watchdog interval (WATCHDOG_USEC, WATCHDOG_PID) once.
  Notifier();

  bool enabled() const { return enabled_; }
  /// The watchdog interval systemd asked for (WatchdogSec), zero when none.
  std::chrono::microseconds watchdog_interval() const { return watchdog_; }

  void ready();
  void status(const std::string& text);
  /// Called from the processing loop on every turn; sends WATCHDOG=1 at most every half
  /// interval. A loop that stops turning (a hung worker) stops the pings and systemd restarts
  /// the service after WatchdogSec.
  void watchdog();
  void stopping();

  /// Messages sent so far (for logs and tests).
  std::uint64_t sent() const { return sent_; }

 private:
  void send(const std::string& message);

  bool enabled_ = false;
  std::chrono::microseconds watchdog_{0};
  std::atomic<std::int64_t> last_ping_us_{0};
  std::atomic<std::uint64_t> sent_{0};
};

/// READY once the daemon serves (HTTP listens, or is off) and the source is open, and STATUS=
/// whenever the source state or the count of results changes; polls the daemon's status JSON
/// on a thread of its own (never the watchdog: that comes from the worker itself).
class ServiceMonitor {
 public:
  ServiceMonitor(Notifier& notifier, std::function<nlohmann::json()> status);
  ~ServiceMonitor();
  /// `http_ready`: the HTTP server listens (or is off). Starts the polling thread.
  void start(bool http_ready);
  /// Sends STOPPING=1 and stops polling. Idempotent.
  void stop();

  /// The STATUS= text for a status JSON, e.g. "connected; 12 processed, 0 failed; last genus 1".
  static std::string status_text(const nlohmann::json& status);

 private:
  void loop();

  Notifier& notifier_;
  std::function<nlohmann::json()> status_;
  bool http_ready_ = false;
  bool ready_sent_ = false;
  std::string last_status_;
  std::mutex mutex_;
  std::condition_variable cv_;
  bool stopping_ = false;
  std::thread thread_;
};

}  // namespace sonomesh::daemon
