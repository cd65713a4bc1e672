#pragma once
// Splits [begin, end) into `threads` contiguous chunks and runs fn(chunk_begin, chunk_end, chunk)
// on std::threads (the calling thread takes the last chunk). Two cores is the target, so a tiny
// fork/join is all that is needed.

#include <algorithm>
#include <thread>
#include <vector>

namespace sonomesh::reconstruct::internal {

template <class Fn>
void parallel_chunks(int begin, int end, int threads, Fn&& fn) {
  const int n = std::max(0, end - begin);
  threads = std::max(1, std::min(threads, n));
  if (threads == 1) {
    fn(begin, end, 0);
    return;
  }
  std::vector<std::thread> workers;
  workers.reserve(threads - 1);
  for (int t = 0; t < threads; ++t) {
    const int b = begin + static_cast<int>(static_cast<long long>(n) * t / threads);
    const int e = begin + static_cast<int>(static_cast<long long>(n) * (t + 1) / threads);
    if (t + 1 == threads) {
      fn(b, e, t);
    } else {
      workers.emplace_back([&fn, b, e, t] { fn(b, e, t); });
    }
  }
  for (auto& w : workers) w.join();
}

/// Worker count for this machine's job: at most two, as DESIGN targets a two-core box.
inline int default_threads() {
  const unsigned hw = std::thread::hardware_concurrency();
  return hw >= 2 ? 2 : 1;
}

}  // namespace sonomesh::reconstruct::internal
