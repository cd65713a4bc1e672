#pragma once
/// @file
/// @brief PNG encoding for the live page's slices (libpng directly: OpenCV's imgcodecs drags in
/// GDAL and ~100 more shared libraries that every `sonomeshd` start had to load and relocate).

#include <cstddef>
#include <cstdint>
#include <string>

namespace sonomesh::daemon::internal {

/// An 8-bit colour image, rows of `width` blue-green-red pixels (OpenCV's order) `stride` bytes
/// apart, as PNG bytes; empty if libpng refuses it.
std::string encode_png_bgr(const std::uint8_t* pixels, int width, int height, std::size_t stride);

}  // namespace sonomesh::daemon::internal
