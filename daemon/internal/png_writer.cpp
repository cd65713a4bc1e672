#include "daemon/internal/png_writer.h"

#include <png.h>

#include <csetjmp>

namespace sonomesh::daemon::internal {
namespace {

void append(png_structp png, png_bytep data, png_size_t length) {
  static_cast<std::string*>(png_get_io_ptr(png))
      ->append(reinterpret_cast<const char*>(data), length);
}

void no_flush(png_structp) {}

// libpng reports errors by longjmp to the setjmp below: nothing in this frame has a destructor,
// so the jump skips none (the caller's string outlives it).
bool write_png(std::string* out, const std::uint8_t* pixels, int width, int height,
               std::size_t stride) {
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  if (!png) return false;
  png_infop info = png_create_info_struct(png);
  if (!info || setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    return false;
  }
  png_set_write_fn(png, out, append, no_flush);
  // Fastest zlib level: the page asks for each slice once per result, over loopback.
  png_set_compression_level(png, 1);
  png_set_IHDR(png, info, static_cast<png_uint_32>(width), static_cast<png_uint_32>(height), 8,
               PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
               PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  png_set_bgr(png);
  for (int y = 0; y < height; ++y)
    png_write_row(png, const_cast<png_bytep>(pixels + static_cast<std::size_t>(y) * stride));
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  return true;
}

}  // namespace

std::string encode_png_bgr(const std::uint8_t* pixels, int width, int height, std::size_t stride) {
  std::string out;
  if (width <= 0 || height <= 0 || !write_png(&out, pixels, width, height, stride)) return {};
  return out;
}

}  // namespace sonomesh::daemon::internal
