#pragma once
/// @file
/// @brief A minimal static-partition parallel loop (phantom generation uses both cores).

#include <algorithm>
#include <thread>
#include <vector>

namespace sonomesh::sim::internal {

/// Calls body(lo, hi) on contiguous chunks of [begin, end), one chunk per hardware thread.
/// Results must not depend on the partition (callers seed randomness per index, not per chunk).
template <class Body>
void parallel_chunks(int begin, int end, const Body& body) {
  const int n = end - begin;
  if (n <= 0) return;
  const int threads =
      std::clamp(static_cast<int>(std::thread::hardware_concurrency()), 1, std::min(n, 8));
  if (threads == 1) {
    body(begin, end);
    return;
  }
  std::vector<std::thread> pool;
  pool.reserve(threads - 1);
  const int chunk = (n + threads - 1) / threads;
  for (int t = 1; t < threads; ++t) {
    const int lo = begin + t * chunk, hi = std::min(end, lo + chunk);
    if (lo < hi) pool.emplace_back([&body, lo, hi] { body(lo, hi); });
  }
  body(begin, std::min(end, begin + chunk));
  for (auto& th : pool) th.join();
}

}  // namespace sonomesh::sim::internal
