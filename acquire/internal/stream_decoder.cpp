#include "acquire/internal/stream_decoder.h"

#include <string>
#include <type_traits>
#include <variant>

namespace sonomesh::acquire::internal {
namespace {

ParserLimits limits_of(const SourceOptions& options) {
  return ParserLimits{options.max_dims, options.max_payload_bytes};
}

AcquireError lost(const SequenceTracker::Gap& gap) {
  return AcquireError{AcquireError::Code::Lost, 0,
                      std::to_string(gap.count) + " volume(s) missing from sequence " +
                          std::to_string(gap.first_missing),
                      gap.first_missing, gap.count};
}

}  // namespace

AcquireError to_error(const DroppedRecord& dropped) {
  const auto code = dropped.reason == DropReason::Truncated ? AcquireError::Code::Incomplete
                                                            : AcquireError::Code::BadRecord;
  return AcquireError{code, 0, std::string(to_string(dropped.reason)) + ": " + dropped.detail,
                      dropped.sequence, 0};
}

StreamDecoder::StreamDecoder(const SourceOptions& options) : parser_(limits_of(options)) {}

void StreamDecoder::feed(const std::uint8_t* data, std::size_t size) { parser_.feed(data, size); }

std::optional<NextResult> StreamDecoder::next() {
  while (ready_.empty()) {
    std::optional<ParserEvent> event = parser_.next_event();
    if (!event) return std::nullopt;
    std::visit(
        [this](auto&& e) {
          using T = std::decay_t<decltype(e)>;
          if constexpr (std::is_same_v<T, RawVolume>) {
            if (auto gap = tracker_.observe_volume(e.sequence)) {
              ready_.push_back(tl::make_unexpected(lost(*gap)));
            }
            ready_.push_back(std::move(e));
          } else if constexpr (std::is_same_v<T, Heartbeat>) {
            if (auto gap = tracker_.observe_next(e.next_sequence)) {
              ready_.push_back(tl::make_unexpected(lost(*gap)));
            }
          } else if constexpr (std::is_same_v<T, EndOfStream>) {
            if (auto gap = tracker_.observe_next(e.next_sequence)) {
              ready_.push_back(tl::make_unexpected(lost(*gap)));
            }
            end_of_stream_seen_ = true;
            ready_.push_back(tl::make_unexpected(AcquireError{
                AcquireError::Code::EndOfStream, 0, "end-of-stream record", e.next_sequence, 0}));
          } else {
            // A refused volume record with an intact header accounts for its sequence: it is
            // reported as BadRecord, not again as Lost.
            if (e.sequence && e.kind == static_cast<std::uint16_t>(RecordKind::Volume)) {
              if (auto gap = tracker_.observe_volume(*e.sequence)) {
                ready_.push_back(tl::make_unexpected(lost(*gap)));
              }
            }
            ready_.push_back(tl::make_unexpected(to_error(e)));
          }
        },
        std::move(*event));
  }
  NextResult result = std::move(ready_.front());
  ready_.pop_front();
  return result;
}

void StreamDecoder::end_of_input() { parser_.finish(); }

}  // namespace sonomesh::acquire::internal
