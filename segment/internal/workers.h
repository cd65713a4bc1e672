#pragma once
/// @file
/// @brief The balloon's threads: a TBB arena of BalloonOptions::threads workers.

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cstddef>
#include <thread>

namespace sonomesh::segment::internal {

/// A loop is split into tasks of at least `grain` items and runs serially below two of them.
/// kHeavy suits the per-vertex evolution and A_t lookups (1-2 thousand instructions per vertex),
/// kLight the light loops (face normals, copies): one grain of 512 for all left the fronts of a
/// few hundred vertices on one core.
struct Workers {
  tbb::task_arena arena;
  bool serial = false;
  static constexpr std::size_t kHeavy = 128, kLight = 512;

  /// `requested` as BalloonOptions::threads has it: 0 = all hardware threads.
  explicit Workers(int requested)
      : arena(resolved(requested)), serial(resolved(requested) == 1) {}

  static int resolved(int requested) {
    return requested > 0 ? requested
                         : std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
  }

  template <typename F>
  void parallel_for(std::size_t n, std::size_t grain, F&& f) {
    if (serial || n < 2 * grain) {
      f(std::size_t{0}, n);
      return;
    }
    arena.execute([&] {
      tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, grain),
                        [&](const tbb::blocked_range<std::size_t>& r) { f(r.begin(), r.end()); });
    });
  }
};

}  // namespace sonomesh::segment::internal
