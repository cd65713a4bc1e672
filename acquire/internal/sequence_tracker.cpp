// SequenceTracker: gaps in probe sequence numbers (acquire/protocol.h).
#include "acquire/protocol.h"

namespace sonomesh::acquire {

std::optional<SequenceTracker::Gap> SequenceTracker::observe_volume(std::uint64_t sequence) {
  std::optional<Gap> gap;
  if (expected_ && sequence > *expected_) gap = Gap{*expected_, sequence - *expected_};
  expected_ = sequence + 1;
  return gap;
}

std::optional<SequenceTracker::Gap> SequenceTracker::observe_next(std::uint64_t next_sequence) {
  std::optional<Gap> gap;
  if (expected_ && next_sequence > *expected_) gap = Gap{*expected_, next_sequence - *expected_};
  expected_ = next_sequence;
  return gap;
}

}  // namespace sonomesh::acquire
