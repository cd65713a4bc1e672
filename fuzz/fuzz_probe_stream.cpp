/// @file
/// @brief libFuzzer target: the probe-stream decoder (acquire::StreamParser) on arbitrary bytes,
/// fed in chunks whose sizes come from the input itself so that record boundaries fall anywhere.
///
/// Properties checked beyond "no crash": every volume it returns has a payload matching its dims
/// and type and within the limits, and after finish() the parser holds no bytes.

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <variant>

#include "acquire/protocol.h"

using namespace sonomesh::acquire;

namespace {

void check(bool ok) {
  if (!ok) std::abort();
}

void drain(StreamParser& parser, const ParserLimits& limits) {
  while (auto event = parser.next_event()) {
    if (const auto* v = std::get_if<RawVolume>(&*event)) {
      for (int a = 0; a < 3; ++a) check(v->dims[a] >= 1 && v->dims[a] <= limits.max_dims[a]);
      check(v->voxels.size() <= limits.max_payload_bytes);
      const std::size_t voxels = std::size_t(v->dims[0]) * v->dims[1] * v->dims[2];
      check(v->voxels.size() == voxels * std::size_t(bytes_per_voxel(v->type)));
    }
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  // Small limits: the interesting paths are the checks, not allocating a gigabyte.
  ParserLimits limits;
  limits.max_dims = {96, 96, 96};
  limits.max_payload_bytes = 1u << 20;
  StreamParser parser(limits);
  // First byte: chunk size (1..256) for feeding the rest.
  const std::size_t chunk = std::size_t{data[0]} + 1;
  for (std::size_t pos = 1; pos < size; pos += chunk) {
    const std::size_t n = pos + chunk <= size ? chunk : size - pos;
    parser.feed(data + pos, n);
    drain(parser, limits);
  }
  parser.finish();
  drain(parser, limits);
  check(parser.buffered_bytes() == 0);
  return 0;
}
