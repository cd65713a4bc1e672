/// @file
/// @brief libFuzzer target: OpenIGTLink framing and IMAGE bodies (acquire::igtl). The bytes after
/// the first go through MessageReader in chunks whose size is the first byte (so that message
/// boundaries fall anywhere); every Message's content (message_content) and, for IMAGE, its
/// volume (decode_image) are decoded; end_of_input() closes the stream.
///
/// Properties beyond "no crash": a message body has the header's size, at most max_body_bytes;
/// a content lies inside its body; a decoded volume has dims within the limits, one value per
/// voxel of its type, positive finite spacing, finite origin and unit direction columns; after
/// FramingLost no further event comes; after end_of_input() the reader is empty.

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <variant>

#include "acquire/igtl.h"

using namespace sonomesh::acquire;

namespace {

constexpr std::uint64_t kMaxBodyBytes = 1u << 20;

void check(bool ok) {
  if (!ok) std::abort();
}

void check_volume(const RawVolume& v, const igtl::ImageLimits& limits) {
  std::size_t voxels = 1;
  for (int a = 0; a < 3; ++a) {
    check(v.dims[a] >= 1 && v.dims[a] <= limits.max_dims[a]);
    voxels *= static_cast<std::size_t>(v.dims[a]);
    check(std::isfinite(v.spacing_mm[a]) && v.spacing_mm[a] > 0.0f);
    check(std::isfinite(v.origin_mm[a]));
    double norm2 = 0.0;
    for (int r = 0; r < 3; ++r) norm2 += double(v.direction[3 * a + r]) * v.direction[3 * a + r];
    check(std::abs(norm2 - 1.0) < 1e-3);
  }
  check(v.voxels.size() <= limits.max_payload_bytes);
  check(v.voxels.size() == voxels * std::size_t(bytes_per_voxel(v.type)));
}

void check_message(const igtl::MessageReader::Message& m, const igtl::ImageLimits& limits) {
  check(m.body.size() == m.header.body_bytes && m.body.size() <= kMaxBodyBytes);
  const auto content = igtl::message_content(m.header, m.body);
  if (!content) return;
  const auto* body_end = m.body.data() + m.body.size();
  check(content->data >= m.body.data() && content->data + content->size <= body_end);
  if (m.header.type != "IMAGE") return;
  const auto volume = igtl::decode_image(content->data, content->size, limits);
  if (volume) check_volume(*volume, limits);
}

// Returns false once the framing is lost (the reader must then stay silent).
bool drain(igtl::MessageReader& reader, const igtl::ImageLimits& limits) {
  while (auto event = reader.next()) {
    if (const auto* m = std::get_if<igtl::MessageReader::Message>(&*event))
      check_message(*m, limits);
    if (const auto* o = std::get_if<igtl::MessageReader::Oversize>(&*event))
      check(o->header.body_bytes > kMaxBodyBytes);
    if (std::holds_alternative<igtl::MessageReader::FramingLost>(*event)) {
      check(!reader.next());
      return false;
    }
  }
  return true;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  igtl::ImageLimits limits;  // small: the checks matter here, not big buffers
  limits.max_dims = {96, 96, 96};
  limits.max_payload_bytes = kMaxBodyBytes;
  igtl::MessageReader reader(kMaxBodyBytes);
  const std::size_t chunk = std::size_t{data[0]} + 1;  // 1..256 bytes per feed
  bool framed = true;
  for (std::size_t pos = 1; pos < size && framed; pos += chunk) {
    reader.feed(data + pos, pos + chunk <= size ? chunk : size - pos);
    framed = drain(reader, limits);
  }
  if (const auto last = reader.end_of_input()) {
    if (const auto* t = std::get_if<igtl::MessageReader::Truncated>(&*last))
      check(t->got_bytes < t->header.body_bytes);
  }
  check(!reader.next());  // empty after end_of_input()
  return 0;
}
