#pragma once
/// @file
/// @brief A probe volume as an OpenIGTLink IMAGE message, as PlusServer sends one.

#include <cstdint>
#include <string>
#include <vector>

#include "acquire/raw_volume.h"

namespace sonomesh::sim::internal {

/// The whole message (58-byte header + body) for one volume: 1 component, uint8 or uint16 (big
/// endian, the library's default), coordinate system RAS. Geometry as the protocol defines it:
/// matrix column c = the RAS direction of index axis c times its spacing, position = the image's
/// centre, corner + sum_c dir_c * spacing_c * (size_c - 1) / 2 (LPS -> RAS flips x and y).
/// header_version 1: packed by libOpenIGTLink 1.11. 2: the same content inside a version-2 body
/// (extended header with message_id, then the content, then metadata "Source" = "probe-sim"),
/// framed here because that library writes version 1 only. Timestamp from volume.timestamp_ns.
/// @throws std::invalid_argument for another header version or dimensions above 65535.
std::vector<std::uint8_t> encode_igtl_image(const acquire::RawVolume& volume,
                                            const std::string& device, int header_version,
                                            std::uint32_t message_id);

}  // namespace sonomesh::sim::internal
