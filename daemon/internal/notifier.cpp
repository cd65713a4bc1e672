#include "daemon/internal/notifier.h"

#include <spdlog/spdlog.h>
#include <systemd/sd-daemon.h>

#include <cstdlib>

namespace sonomesh::daemon {

namespace {
constexpr auto kMonitorInterval = std::chrono::milliseconds(250);

std::int64_t now_us() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}
}  // namespace

Notifier::Notifier() {
  const char* socket = std::getenv("NOTIFY_SOCKET");
  enabled_ = socket != nullptr && *socket != '\0';
  std::uint64_t usec = 0;
  // > 0: WATCHDOG_USEC is set and WATCHDOG_PID (if set) is this process.
  if (enabled_ && sd_watchdog_enabled(0, &usec) > 0) watchdog_ = std::chrono::microseconds(usec);
}

void Notifier::send(const std::string& message) {
  if (!enabled_) return;
  const int rc = sd_notify(0, message.c_str());
  if (rc < 0) {
    spdlog::warn("sd_notify({}) failed: {}", message.substr(0, message.find('\n')), rc);
    return;
  }
  ++sent_;
}

void Notifier::ready() { send("READY=1"); }

void Notifier::status(const std::string& text) {
  std::string line = text;
  for (char& c : line) {
    if (c == '\n') c = ' ';  // one status line; a newline would start another assignment
  }
  send("STATUS=" + line);
}

void Notifier::watchdog() {
  if (watchdog_.count() <= 0) return;
  const std::int64_t now = now_us();
  std::int64_t last = last_ping_us_.load();
  // Half the interval, as sd_watchdog_enabled(3) recommends; one thread wins a race.
  if (now - last < watchdog_.count() / 2) return;
  if (!last_ping_us_.compare_exchange_strong(last, now)) return;
  send("WATCHDOG=1");
}

void Notifier::stopping() { send("STOPPING=1"); }

ServiceMonitor::ServiceMonitor(Notifier& notifier, std::function<nlohmann::json()> status)
    : notifier_(notifier), status_(std::move(status)) {}

ServiceMonitor::~ServiceMonitor() { stop(); }

void ServiceMonitor::start(bool http_ready) {
  http_ready_ = http_ready;
  if (!notifier_.enabled()) return;
  thread_ = std::thread([this] { loop(); });
}

void ServiceMonitor::stop() {
  {
    std::lock_guard lock(mutex_);
    if (stopping_) return;
    stopping_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
  notifier_.status("stopping");
  notifier_.stopping();
}

std::string ServiceMonitor::status_text(const nlohmann::json& status) {
  const std::string state = status.value("/source/state"_json_pointer, std::string("unknown"));
  std::string text = state == "connected"      ? "probe connected"
                     : state == "connecting"   ? "waiting for the probe"
                     : state == "reconnecting" ? "probe lost, reconnecting"
                                               : "source " + state;
  const nlohmann::json volumes = status.value("volumes", nlohmann::json::object());
  text += "; " + std::to_string(volumes.value("processed", 0)) + " processed, " +
          std::to_string(volumes.value("failed", 0)) + " failed";
  const nlohmann::json last = status.value("last_processed", nlohmann::json());
  if (last.is_object()) {
    text += "; last sequence " + std::to_string(last.value("sequence", 0)) + " genus " +
            std::to_string(last.value("genus", -1));
  }
  return text;
}

void ServiceMonitor::loop() {
  while (true) {
    const nlohmann::json status = status_ ? status_() : nlohmann::json::object();
    const std::string state = status.value("/source/state"_json_pointer, std::string());
    const std::string text = status_text(status);
    if (text != last_status_) {
      notifier_.status(text);
      last_status_ = text;
    }
    // READY=1 once the daemon can be used: its HTTP listens and the source has been opened
    // (a probe that is not up yet keeps the unit "activating", with STATUS saying why).
    if (!ready_sent_ && http_ready_ && state != "connecting" && !state.empty()) {
      notifier_.ready();
      ready_sent_ = true;
    }
    std::unique_lock lock(mutex_);
    if (cv_.wait_for(lock, kMonitorInterval, [&] { return stopping_; })) return;
  }
}

}  // namespace sonomesh::daemon
