// PLACEHOLDER written by helper "acquire" so the build links before helper "hil" delivers the real
// usb source. "hil" owns this file: replace it entirely with the real implementation of
// open_usb_source() declared in acquire/internal/sources.h (use internal::StreamDecoder from
// acquire/internal/stream_decoder.h for the probe stream bytes).
#include "acquire/internal/sources.h"

namespace sonomesh::acquire::internal {

tl::expected<std::unique_ptr<Source>, AcquireError> open_usb_source(const std::string& spec,
                                                                    const SourceOptions&) {
  return tl::make_unexpected(AcquireError{AcquireError::Code::InvalidArgument, 0,
                                          "usb:" + spec + ": usb sources are not built yet", {}, 0});
}

}  // namespace sonomesh::acquire::internal
