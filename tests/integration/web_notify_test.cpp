// systemd's notify protocol against a test datagram socket given as NOTIFY_SOCKET: READY once
// HTTP listens and the source is open, STATUS on changes, WATCHDOG from the processing loop
// (and none when the loop stalls), STOPPING at shutdown.
#include <gtest/gtest.h>
#include <sys/socket.h>
#include <sys/un.h>

#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <mutex>

#include "child_process.h"
#include "daemon/internal/notifier.h"

// Last: <httplib.h> pulls in <resolv.h>, whose `_res` macro breaks Eigen headers included after it.
#include <httplib.h>

namespace {

using namespace sonomesh::testing;

// A bound AF_UNIX datagram socket collecting every message with its arrival time.
class NotifySocket {
 public:
  explicit NotifySocket(const fs::path& path) : path_(path) {
    fd_ = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    std::snprintf(addr.sun_path, sizeof addr.sun_path, "%s", path.c_str());
    bound_ = ::bind(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0;
    timeval tv{0, 50000};
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    reader_ = std::thread([this] {
      char buf[4096];
      while (!stop_) {
        const ssize_t n = ::recv(fd_, buf, sizeof buf, 0);
        if (n <= 0) continue;
        std::lock_guard lock(mutex_);
        messages_.push_back({Clock::now(), std::string(buf, static_cast<std::size_t>(n))});
      }
    });
  }
  ~NotifySocket() {
    stop_ = true;
    reader_.join();
    ::close(fd_);
  }
  bool bound() const { return bound_; }
  std::vector<std::pair<Clock::time_point, std::string>> messages() const {
    std::lock_guard lock(mutex_);
    return messages_;
  }
  // Messages starting with `prefix` that arrived in [from, to).
  int count(const std::string& prefix, Clock::time_point from = {},
            Clock::time_point to = Clock::time_point::max()) const {
    int n = 0;
    for (const auto& [t, m] : messages()) {
      if (m.rfind(prefix, 0) == 0 && t >= from && t < to) ++n;
    }
    return n;
  }

 private:
  fs::path path_;
  int fd_ = -1;
  bool bound_ = false;
  std::atomic<bool> stop_{false};
  mutable std::mutex mutex_;
  std::vector<std::pair<Clock::time_point, std::string>> messages_;
  std::thread reader_;
};

TEST(ServiceNotify, ReadyStatusWatchdogAndStoppingFromTheDaemon) {
  ScratchDir dir("notify");
  NotifySocket socket(dir / "notify.sock");
  ASSERT_TRUE(socket.bound());
  Child daemon({SONOMESHD_EXE, "run", "--source", "sim:sphere?rate=4&size=48", "--out",
                (dir / "out").string(), "--http", "127.0.0.1:0"},
               dir / "daemon",
               {"NOTIFY_SOCKET=" + (dir / "notify.sock").string(), "WATCHDOG_USEC=200000"});
  ASSERT_TRUE(wait_until([&] { return socket.count("READY=1") == 1; }, 30s))
      << daemon.stderr_text();
  // READY means usable: the HTTP server answers at once.
  const int port = http_port_of(dir / "out", 1s);
  ASSERT_GT(port, 0);
  httplib::Client client("127.0.0.1", port);
  const auto health = client.Get("/healthz");
  ASSERT_TRUE(health);
  EXPECT_EQ(health->status, 200);

  // The worker's loop pings on every turn (at most every 100 ms here): they keep coming while it
  // runs (how often depends on how long each volume takes on this machine).
  const auto from = Clock::now();
  EXPECT_TRUE(wait_until([&] { return socket.count("WATCHDOG=1", from) >= 5; }, 30s));
  EXPECT_TRUE(wait_until([&] { return socket.count("STATUS=probe connected; ") >= 1; }, 5s));
  EXPECT_TRUE(wait_until(
      [&] {
        for (const auto& [t, m] : socket.messages()) {
          if (m.find("processed") != std::string::npos && m.find("genus 0") != std::string::npos)
            return true;
        }
        return false;
      },
      30s));
  EXPECT_EQ(socket.count("STOPPING=1"), 0);
  daemon.signal(SIGTERM);
  ASSERT_EQ(daemon.wait(30s), 0) << daemon.stderr_text();
  EXPECT_GE(socket.count("STOPPING=1"), 1);
  EXPECT_EQ(socket.count("READY=1"), 1);
}

TEST(ServiceNotify, WithoutWatchdogSecNoPingsAndAStalledLoopStopsThem) {
  ScratchDir dir("wd");
  NotifySocket socket(dir / "notify.sock");
  ASSERT_TRUE(socket.bound());
  ::setenv("NOTIFY_SOCKET", (dir / "notify.sock").c_str(), 1);
  ::unsetenv("WATCHDOG_USEC");
  {
    sonomesh::daemon::Notifier plain;
    EXPECT_TRUE(plain.enabled());
    EXPECT_EQ(plain.watchdog_interval().count(), 0);
    for (int i = 0; i < 20; ++i) plain.watchdog();
  }
  ::setenv("WATCHDOG_USEC", "100000", 1);
  sonomesh::daemon::Notifier notifier;
  EXPECT_EQ(notifier.watchdog_interval().count(), 100000);
  // A loop that turns every 5 ms for 400 ms, then stalls for 400 ms.
  const auto start = Clock::now();
  while (Clock::now() - start < 400ms) {
    notifier.watchdog();
    std::this_thread::sleep_for(5ms);
  }
  const auto stalled = Clock::now();
  std::this_thread::sleep_for(400ms);
  const auto resumed = Clock::now();
  notifier.watchdog();
  std::this_thread::sleep_for(100ms);
  ::unsetenv("NOTIFY_SOCKET");
  ::unsetenv("WATCHDOG_USEC");
  // Half the interval apart: 400 ms of turning gives at most 9 pings (8 when every turn is on
  // time; fewer when this loaded machine delays the loop itself).
  EXPECT_GE(socket.count("WATCHDOG=1", start, stalled + 20ms), 3);
  EXPECT_LE(socket.count("WATCHDOG=1", start, stalled + 20ms), 9);
  EXPECT_EQ(socket.count("WATCHDOG=1", {}, start), 0) << "pings without WatchdogSec";
  EXPECT_EQ(socket.count("WATCHDOG=1", stalled + 20ms, resumed), 0);
  EXPECT_EQ(socket.count("WATCHDOG=1", resumed), 1);
}

}  // namespace
