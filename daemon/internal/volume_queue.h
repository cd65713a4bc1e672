#pragma once
/// @file
/// @brief The bounded queue between the acquisition thread and the processing worker.
///
/// Live sources keep the newest volume (DESIGN.md): a volume still waiting when a newer one
/// arrives is pushed out and handed back to the caller so that it can be journaled as `skipped`.
/// The worker therefore always starts on the freshest volume and the latency never includes
/// waiting behind stale ones. Replay sources are not live: push() blocks while `capacity` volumes
/// wait, so nothing is skipped and the source reads ahead by up to `capacity` volumes.

#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <mutex>
#include <optional>
#include <vector>

#include "acquire/raw_volume.h"

namespace sonomesh::daemon {

/// One volume waiting for the worker.
struct QueuedVolume {
  acquire::RawVolume raw;
  std::chrono::steady_clock::time_point received;  // host clock, when the acquisition got it
  std::uint64_t epoch = 0;                          // journal epoch (probe counter restarts)
};

class VolumeQueue {
 public:
  enum class Mode { KeepNewest, Block };

  /// @throws std::invalid_argument if capacity < 1.
  VolumeQueue(std::size_t capacity, Mode mode);

  /// KeepNewest: never blocks; returns the older volumes it pushed out (oldest first).
  /// Block: waits for room; returns the volume itself (in the vector) if the queue was closed or
  /// aborted while waiting, so the caller can account for it.
  std::vector<QueuedVolume> push(QueuedVolume volume);

  /// Next volume, or nothing after `timeout`, or nothing at once when closed and empty.
  std::optional<QueuedVolume> pop(std::chrono::milliseconds timeout);

  /// No more pushes; pop() drains what is queued, then returns nothing (end of stream).
  void close();
  /// Removes and returns everything still queued and closes the queue (shutdown).
  std::vector<QueuedVolume> abort();

  bool closed() const;
  std::size_t size() const;
  std::size_t capacity() const { return capacity_; }
  Mode mode() const { return mode_; }
  /// Changes the capacity (config reload; Block mode). Volumes above it stay until popped.
  void set_capacity(std::size_t capacity);

 private:
  mutable std::mutex mutex_;
  std::condition_variable not_empty_;
  std::condition_variable not_full_;
  std::deque<QueuedVolume> items_;
  std::size_t capacity_;
  Mode mode_;
  bool closed_ = false;
};

}  // namespace sonomesh::daemon
