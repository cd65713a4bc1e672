#pragma once
/// @file
/// @brief The queue between the acquisition thread and the processing worker.
///
/// Live sources keep the newest volume (DESIGN.md): the worker always starts on the freshest
/// volume, and one pushed out is journaled as `skipped`. Replay sources block instead, so the
/// source reads ahead by up to `capacity` volumes and nothing is skipped.

#include <chrono>
#include <cstdint>

#include "acquire/raw_volume.h"
#include "daemon/internal/bounded_queue.h"

namespace sonomesh::daemon {

/// One volume waiting for the worker.
struct QueuedVolume {
  acquire::RawVolume raw;
  std::chrono::steady_clock::time_point received;  // host clock, when the acquisition got it
  std::uint64_t epoch = 0;                         // journal epoch (probe counter restarts)
};

using VolumeQueue = BoundedQueue<QueuedVolume>;

}  // namespace sonomesh::daemon
