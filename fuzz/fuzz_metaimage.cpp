/// @file
/// @brief libFuzzer target: the MetaImage reader (volume::read_volume), attached and detached.
/// The input is written as x.mha and read; then, split after its ElementDataFile line, as x.mhd
/// (the header) + data.raw (the rest) and read again, so that "ElementDataFile = data.raw"
/// reaches the detached path.
///
/// Property beyond "no crash": a volume that is read has dims >= 1 within max_voxels.

#include <cstddef>
#include <cstdint>

#include "fuzz/fuzz_util.h"

using namespace sonomesh;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const auto bytes = fuzz::as_text(data, size);
  const auto key = bytes.find("ElementDataFile");
  const auto eol = key == std::string_view::npos ? key : bytes.find('\n', key);
  fuzz::read_attached_and_detached(bytes, "x.mha", "x.mhd",
                                   eol == std::string_view::npos ? eol : eol + 1);
  return 0;
}
