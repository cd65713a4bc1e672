#pragma once
/// @file
/// @brief Reconnect pacing shared by the sources that reconnect (internal).

#include <algorithm>
#include <chrono>

namespace sonomesh::acquire::internal {

/// Backoff between reconnect attempts: 50 ms doubling to 500 ms, so a returning probe is
/// picked up within a second without hammering an absent one.
class Backoff {
 public:
  using Clock = std::chrono::steady_clock;
  bool due() const { return Clock::now() >= next_attempt_; }
  Clock::time_point next_attempt() const { return next_attempt_; }
  void failed() {
    next_attempt_ = Clock::now() + delay_;
    delay_ = std::min(delay_ * 2, kMax);
  }
  void succeeded() { delay_ = kFirst; }
  /// The link dropped: the first attempt waits kFirst.
  void dropped() {
    delay_ = kFirst;
    failed();
  }

 private:
  static constexpr std::chrono::milliseconds kFirst{50};
  static constexpr std::chrono::milliseconds kMax{500};
  std::chrono::milliseconds delay_ = kFirst;
  Clock::time_point next_attempt_{};
};

}  // namespace sonomesh::acquire::internal
