/// @file
/// @brief libFuzzer target: the NRRD reader (volume::read_volume through Teem), attached and
/// detached. The input is written as x.nrrd and read; then, split after its first blank line, as
/// a detached pair x.nhdr (the header) + data.raw (the rest) and read again, so that a header
/// naming "data file: data.raw" reaches the detached path.
///
/// Property beyond "no crash": a volume that is read has dims >= 1 within max_voxels.

#include <cstddef>
#include <cstdint>

#include "fuzz/fuzz_util.h"

using namespace sonomesh;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const auto bytes = fuzz::as_text(data, size);
  const auto end = bytes.find("\n\n");  // npos: no detached read
  fuzz::read_attached_and_detached(bytes, "x.nrrd", "x.nhdr",
                                   end == std::string_view::npos ? end : end + 2);
  return 0;
}
