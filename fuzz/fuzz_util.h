#pragma once
/// @file
/// @brief What the file-format fuzz targets share: a private temporary directory per process,
/// writing the fuzzer's bytes into files there (the readers take paths, not buffers), and the
/// volume readers' checked read of one input as an attached file and as a detached pair.

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string_view>

#include "volume/volume.h"

namespace sonomesh::fuzz {

/// A directory of this process's own under the system temp dir, created on first use. It lives as
/// long as the process; libFuzzer runs one input after the other, so the files are reused.
inline const std::filesystem::path& scratch_dir() {
  static const std::filesystem::path dir = [] {
    auto d = std::filesystem::temp_directory_path() / ("sonomesh-fuzz-" + std::to_string(getpid()));
    std::filesystem::create_directories(d);
    return d;
  }();
  return dir;
}

inline void write_file(const std::filesystem::path& path, std::string_view bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

inline std::string_view as_text(const std::uint8_t* data, std::size_t size) {
  return {reinterpret_cast<const char*>(data), size};
}

/// Reads `path` with read_volume and aborts (a finding) if a volume it accepts has a dimension
/// below 1 or more than max_voxels voxels. 64³: the checks matter here, not big buffers.
inline void read_volume_checked(const std::filesystem::path& path) {
  volume::ReadOptions options;
  options.max_voxels = std::size_t{1} << 18;
  const auto result = volume::read_volume(path, options);
  if (!result) return;
  const auto dims = result.volume.dims();
  const std::size_t n = std::size_t(dims[0]) * dims[1] * dims[2];
  if (dims[0] < 1 || dims[1] < 1 || dims[2] < 1 || n > options.max_voxels) std::abort();
}

/// The input read as one attached file `attached`; then, if `header_end` is inside it, split
/// there into the header `detached` + data.raw (the rest) and read again, so that a header
/// naming data.raw reaches the reader's detached path. The file names carry the format's
/// extension (x.nrrd / x.nhdr, x.mha / x.mhd); the files are rewritten, not created, per input.
inline void read_attached_and_detached(std::string_view bytes, const char* attached,
                                       const char* detached, std::size_t header_end) {
  const auto& dir = scratch_dir();
  write_file(dir / attached, bytes);
  read_volume_checked(dir / attached);
  if (header_end > bytes.size()) return;
  write_file(dir / detached, bytes.substr(0, header_end));
  write_file(dir / "data.raw", bytes.substr(header_end));
  read_volume_checked(dir / detached);
}

}  // namespace sonomesh::fuzz
