#pragma once
/// @file
/// @brief The one parallel-for of segment/ and reconstruct/, on TBB (DESIGN targets two cores).

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cstddef>
#include <thread>
#include <utility>

namespace sonomesh::mesh {

/// Worker count for this machine's job: at most two, as DESIGN targets a two-core box.
inline int default_threads() {
  const unsigned hw = std::thread::hardware_concurrency();
  return hw >= 2 ? 2 : 1;
}

/// A pool of `threads` workers (0 = all hardware threads).
/// parallel_for splits a loop into tasks of at least `grain` items and runs it serially below
/// two of them; parallel_chunks splits it into exactly one contiguous chunk per worker, for loops
/// whose per-chunk results are merged in chunk order (deterministic whatever the scheduling).
class Workers {
 public:
  explicit Workers(int threads) : threads_(resolved(threads)), arena_(threads_) {}

  static int resolved(int requested) {
    return requested > 0 ? requested
                         : std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
  }
  int threads() const { return threads_; }

  /// f(begin, end) over [0, n).
  template <typename F>
  void parallel_for(std::size_t n, std::size_t grain, F&& f) {
    if (threads_ == 1 || n < 2 * grain) {
      f(std::size_t{0}, n);
      return;
    }
    arena_.execute([&] {
      tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, grain),
                        [&](const tbb::blocked_range<std::size_t>& r) { f(r.begin(), r.end()); });
    });
  }

  /// fn(chunk_begin, chunk_end, chunk) for min(threads, end − begin) equal chunks of [begin, end).
  template <class Fn>
  void parallel_chunks(int begin, int end, Fn&& fn) {
    const int n = std::max(0, end - begin);
    const int chunks = std::max(1, std::min(threads_, n));
    if (chunks == 1) {
      fn(begin, end, 0);
      return;
    }
    auto chunk = [&](int t) {
      const int b = begin + static_cast<int>(static_cast<long long>(n) * t / chunks);
      const int e = begin + static_cast<int>(static_cast<long long>(n) * (t + 1) / chunks);
      fn(b, e, t);
    };
    arena_.execute([&] {
      tbb::parallel_for(
          tbb::blocked_range<int>(0, chunks, 1),
          [&](const tbb::blocked_range<int>& r) {
            for (int t = r.begin(); t < r.end(); ++t) chunk(t);
          },
          tbb::simple_partitioner());
    });
  }

 private:
  int threads_;
  tbb::task_arena arena_;
};

/// One-off form of Workers::parallel_chunks.
template <class Fn>
void parallel_chunks(int begin, int end, int threads, Fn&& fn) {
  Workers(std::max(1, threads)).parallel_chunks(begin, end, std::forward<Fn>(fn));
}

}  // namespace sonomesh::mesh
