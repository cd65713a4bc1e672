#pragma once
/// @file
/// @brief Byte stream -> Source::next() results: the protocol parser plus sequence-gap tracking.
/// Shared by every source that receives probe stream bytes (socket, .usv replay, USB bulk IN).

#include <cstddef>
#include <cstdint>
#include <deque>
#include <optional>
#include <tl/expected.hpp>

#include "acquire/acquire.h"
#include "acquire/protocol.h"

namespace sonomesh::acquire::internal {

using NextResult = tl::expected<RawVolume, AcquireError>;

class StreamDecoder {
 public:
  explicit StreamDecoder(const SourceOptions& options);
  void feed(const std::uint8_t* data, std::size_t size);
  /// The next result for Source::next(), or nullopt when more bytes are needed. Heartbeats are
  /// consumed here (they only produce Lost when they reveal a gap). Mapping: good volume -> value;
  /// gap -> Lost (before the volume that revealed it); dropped record -> BadRecord (Truncated ->
  /// Incomplete); end-of-stream record -> EndOfStream (after any Lost it reveals).
  std::optional<NextResult> next();
  /// The input ended (link dropped, file ended): a partial record becomes an Incomplete / BadRecord
  /// result; the parser starts empty for the next connection. The gap tracker is kept, so volumes
  /// lost during an outage are reported as Lost when the stream resumes.
  void end_of_input();
  /// True once an end-of-stream record was decoded.
  bool end_of_stream_seen() const { return end_of_stream_seen_; }

 private:
  StreamParser parser_;
  SequenceTracker tracker_;
  std::deque<NextResult> ready_;
  bool end_of_stream_seen_ = false;
};

/// Maps a parser drop to the error a source returns.
AcquireError to_error(const DroppedRecord& dropped);

}  // namespace sonomesh::acquire::internal
