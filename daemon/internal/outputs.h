#pragma once
/// @file
/// @brief Output files of the daemon, each written to a temporary name in the same directory and
/// renamed, so a reader never sees half a file (DESIGN.md "Daemon behaviour"). Every function
/// returns nullopt on success or one line naming the file and the problem.

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "segment/mesh.h"
#include "volume/volume.h"

namespace sonomesh::daemon::internal {

std::optional<std::string> write_text_atomically(const std::filesystem::path& path,
                                                 const std::string& text);
/// Binary little-endian PLY (`float x y z`, `list uchar int vertex_indices`), mm.
std::optional<std::string> write_mesh_ply(const segment::Mesh& mesh,
                                          const std::filesystem::path& path);
/// The balloon PLY with the per-vertex `uchar stop` property.
std::optional<std::string> write_balloon_ply(const segment::Mesh& mesh,
                                             const std::vector<segment::StopReason>& stop,
                                             const std::filesystem::path& path);
/// Label volume (UInt8) as NRRD/MetaImage by extension. Detached formats (.nhdr, .mhd) are
/// written in place: their data file name is tied to the header name.
std::optional<std::string> write_labels(const volume::Volume& labels,
                                        const std::filesystem::path& path);
/// Float32 field as an OpenVDB float grid named "indicator".
std::optional<std::string> write_indicator_vdb(const volume::Volume& field,
                                               const std::filesystem::path& path);

}  // namespace sonomesh::daemon::internal
