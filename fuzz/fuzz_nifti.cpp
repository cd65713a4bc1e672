/// @file
/// @brief libFuzzer target: the NIfTI-1 reader (volume::read_volume through nifticlib), the input
/// written as x.nii.
///
/// Property beyond "no crash": a volume that is read has dims >= 1 within max_voxels.

#include <cstddef>
#include <cstdint>

#include "fuzz/fuzz_util.h"

using namespace sonomesh;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const auto path = fuzz::scratch_dir() / "x.nii";
  fuzz::write_file(path, fuzz::as_text(data, size));
  fuzz::read_volume_checked(path);
  return 0;
}
