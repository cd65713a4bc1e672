// PLACEHOLDER written by helper "acquire" so the build links before helper "hil" delivers the real
// v4l2 source. "hil" owns this file: replace it entirely with the real implementation of
// open_v4l2_source() declared in acquire/internal/sources.h (use internal::StreamDecoder from
// acquire/internal/stream_decoder.h for the probe stream bytes).
#include "acquire/internal/sources.h"

namespace sonomesh::acquire::internal {

tl::expected<std::unique_ptr<Source>, AcquireError> open_v4l2_source(const std::string& spec,
                                                                    const SourceOptions&) {
  return tl::make_unexpected(AcquireError{AcquireError::Code::InvalidArgument, 0,
                                          "v4l2:" + spec + ": v4l2 sources are not built yet", {}, 0});
}

}  // namespace sonomesh::acquire::internal
