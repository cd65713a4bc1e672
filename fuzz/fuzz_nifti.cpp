/// @file
/// @brief libFuzzer target: the NIfTI-1 reader (volume::read_volume through nifticlib), the input
/// written as x.nii.
///
/// Property beyond "no crash": a volume that is read has dims >= 1 within max_voxels.

#include <cstddef>
#include <cstdint>
#include <cstdlib>

#include "fuzz/fuzz_util.h"
#include "volume/volume.h"

using namespace sonomesh;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const auto path = fuzz::scratch_dir() / "x.nii";
  fuzz::write_file(path, fuzz::as_text(data, size));
  volume::ReadOptions options;
  options.max_voxels = std::size_t{1} << 18;
  const auto result = volume::read_volume(path, options);
  if (!result) return 0;
  const auto dims = result.volume.dims();
  const std::size_t n = std::size_t(dims[0]) * dims[1] * dims[2];
  if (dims[0] < 1 || dims[1] < 1 || dims[2] < 1 || n > options.max_voxels) std::abort();
  return 0;
}
