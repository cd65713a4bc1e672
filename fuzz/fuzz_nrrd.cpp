/// @file
/// @brief libFuzzer target: the NRRD reader (volume::read_volume through Teem), attached and
/// detached. The input is written as x.nrrd and read; then, split after its first blank line, as
/// a detached pair x.nhdr (the header) + data.raw (the rest) and read again, so that a header
/// naming "data file: data.raw" reaches the detached path.
///
/// Property beyond "no crash": a volume that is read has dims >= 1 within max_voxels and one
/// value per voxel.

#include <cstddef>
#include <cstdint>
#include <cstdlib>

#include "fuzz/fuzz_util.h"
#include "volume/volume.h"

using namespace sonomesh;

namespace {

void read_and_check(const std::filesystem::path& path) {
  volume::ReadOptions options;
  options.max_voxels = std::size_t{1} << 18;  // 64³: the checks matter here, not big buffers
  const auto result = volume::read_volume(path, options);
  if (!result) return;
  const auto dims = result.volume.dims();
  const std::size_t n = std::size_t(dims[0]) * dims[1] * dims[2];
  if (dims[0] < 1 || dims[1] < 1 || dims[2] < 1 || n > options.max_voxels) std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const auto bytes = fuzz::as_text(data, size);
  const auto& dir = fuzz::scratch_dir();
  fuzz::write_file(dir / "x.nrrd", bytes);
  read_and_check(dir / "x.nrrd");

  const auto end = bytes.find("\n\n");
  if (end == std::string_view::npos) return 0;
  fuzz::write_file(dir / "x.nhdr", bytes.substr(0, end + 2));
  fuzz::write_file(dir / "data.raw", bytes.substr(end + 2));
  read_and_check(dir / "x.nhdr");
  return 0;
}
