#pragma once
/// @file
/// @brief eventfd-based wake-up for Source::interrupt() and interruptible sleeps (internal).

#include <poll.h>
#include <sys/eventfd.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdint>

namespace sonomesh::acquire::internal {

class Waker {
 public:
  Waker() : fd_(::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC)) {}
  ~Waker() {
    if (fd_ >= 0) ::close(fd_);
  }
  Waker(const Waker&) = delete;
  Waker& operator=(const Waker&) = delete;

  int fd() const { return fd_; }
  void wake() {
    const std::uint64_t one = 1;
    [[maybe_unused]] const auto n = ::write(fd_, &one, sizeof one);
  }
  /// Clears a pending wake; true if there was one.
  bool drain() {
    std::uint64_t value = 0;
    return ::read(fd_, &value, sizeof value) == static_cast<ssize_t>(sizeof value);
  }
  /// Sleeps until `until` or a wake (consumed); true if woken.
  bool sleep_until(std::chrono::steady_clock::time_point until) {
    for (;;) {
      const int ms = poll_ms(until);
      pollfd p{fd_, POLLIN, 0};
      const int r = ::poll(&p, 1, ms);
      if (r > 0) {
        drain();
        return true;
      }
      if (std::chrono::steady_clock::now() >= until) return false;
    }
  }

  /// Milliseconds from now to `until`, rounded up, >= 0, capped at one minute (for poll()).
  static int poll_ms(std::chrono::steady_clock::time_point until) {
    const auto left = until - std::chrono::steady_clock::now();
    if (left <= std::chrono::steady_clock::duration::zero()) return 0;
    const auto ms = std::chrono::ceil<std::chrono::milliseconds>(left).count();
    return static_cast<int>(std::min<std::int64_t>(ms, 60000));
  }

 private:
  int fd_;
};

}  // namespace sonomesh::acquire::internal
