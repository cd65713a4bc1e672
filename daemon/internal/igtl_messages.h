#pragma once
/// @file
/// @brief The OpenIGTLink messages sonomesh sends to 3D Slicer, packed by libOpenIGTLink (header
/// version 1): POLYDATA `sonomesh-mesh`, IMAGE `sonomesh-labels`, STRING `sonomesh-status`.
/// Geometry is RAS millimetres, Slicer's frame: LPS with x and y negated.

#include <cstdint>
#include <string>

#include "segment/mesh.h"
#include "volume/volume.h"

namespace sonomesh::daemon {

inline constexpr const char* kIgtlMeshDevice = "sonomesh-mesh";
inline constexpr const char* kIgtlLabelsDevice = "sonomesh-labels";
inline constexpr const char* kIgtlStatusDevice = "sonomesh-status";

/// Seconds since the epoch, the header's timestamp.
struct IgtlTime {
  std::uint32_t seconds = 0;
  std::uint32_t fraction = 0;  // 2^-32 s
  static IgtlTime now();
};

/// The surface (points in LPS mm) as POLYDATA with its triangles as polygons, points in RAS.
std::string pack_igtl_mesh(const segment::Mesh& mesh_lps, IgtlTime time);
/// A UInt8 label volume as IMAGE: its grid's directions and spacing, centre in RAS.
/// @throws std::invalid_argument for a volume that is not UInt8.
std::string pack_igtl_labels(const volume::Volume& labels, IgtlTime time);
/// UTF-8 text as STRING (MIBenum 106).
std::string pack_igtl_string(const std::string& device, const std::string& text, IgtlTime time);

}  // namespace sonomesh::daemon
