#pragma once
/// @file
/// @brief What the file-format fuzz targets share: a private temporary directory per process and
/// writing the fuzzer's bytes into files there (the readers take paths, not buffers).

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string_view>

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

}  // namespace sonomesh::fuzz
