/// @file
/// @brief libFuzzer target: the MetaImage reader (volume::read_volume), attached and detached.
/// The input is written as x.mha and read; then, split after its ElementDataFile line, as x.mhd
/// (the header) + data.raw (the rest) and read again, so that "ElementDataFile = data.raw"
/// reaches the detached path.

#include <cstddef>
#include <cstdint>
#include <cstdlib>

#include "fuzz/fuzz_util.h"
#include "volume/volume.h"

using namespace sonomesh;

namespace {

void read_and_check(const std::filesystem::path& path) {
  volume::ReadOptions options;
  options.max_voxels = std::size_t{1} << 18;
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
  fuzz::write_file(dir / "x.mha", bytes);
  read_and_check(dir / "x.mha");

  const auto key = bytes.find("ElementDataFile");
  if (key == std::string_view::npos) return 0;
  const auto eol = bytes.find('\n', key);
  if (eol == std::string_view::npos) return 0;
  fuzz::write_file(dir / "x.mhd", bytes.substr(0, eol + 1));
  fuzz::write_file(dir / "data.raw", bytes.substr(eol + 1));
  read_and_check(dir / "x.mhd");
  return 0;
}
