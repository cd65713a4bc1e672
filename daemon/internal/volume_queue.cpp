#include "daemon/internal/volume_queue.h"

namespace sonomesh::daemon {

// Compiled once here rather than in every file that includes the header.
template class BoundedQueue<QueuedVolume>;

}  // namespace sonomesh::daemon
