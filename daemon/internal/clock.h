#pragma once
/// @file
/// @brief The daemon's clock for durations, and the milliseconds since a point on it.

#include <chrono>

namespace sonomesh::daemon::internal {

using Clock = std::chrono::steady_clock;

inline double ms_since(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

}  // namespace sonomesh::daemon::internal
