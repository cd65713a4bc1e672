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

/// The pipeline runs in the input's grid frame (origin + spacing ⊙ ijk); files are in its world
/// frame (LPS mm, DESIGN.md "Geometry and files"). Vertices are mapped with grid_to_world_mm; a
/// reflecting direction (determinant -1) reverses the triangles' winding so they stay
/// counter-clockwise seen from outside.
segment::Mesh mesh_to_world(const segment::Mesh& grid_mesh, const volume::Volume& frame);
/// A seed given in world mm (`process --seed-mm`, HTTP POST /seed, TOML) in the grid frame the
/// pipeline runs in.
volume::Vec3f seed_world_to_grid_mm(const volume::Volume& frame,
                                    const volume::Vec3f& seed_world_mm);

/// Binary little-endian PLY (`float x y z`, `list uchar int vertex_indices`, `comment SPACE=LPS`)
/// of a grid-frame mesh, written in the world frame of `frame`.
std::optional<std::string> write_mesh_ply(const segment::Mesh& grid_mesh,
                                          const volume::Volume& frame,
                                          const std::filesystem::path& path);
/// PLY, STL or OBJ by extension, in the world frame of `frame` (each says SPACE=LPS).
std::optional<std::string> write_mesh_file(const segment::Mesh& grid_mesh,
                                           const volume::Volume& frame,
                                           const std::filesystem::path& path);
/// The balloon PLY with the per-vertex `uchar stop` property, in the world frame of `frame`.
std::optional<std::string> write_balloon_ply(const segment::Mesh& grid_mesh,
                                             const std::vector<segment::StopReason>& stop,
                                             const volume::Volume& frame,
                                             const std::filesystem::path& path);
/// As above for a mesh already in the world frame (identity direction: grid and world agree).
std::optional<std::string> write_mesh_ply(const segment::Mesh& mesh,
                                          const std::filesystem::path& path);
std::optional<std::string> write_balloon_ply(const segment::Mesh& mesh,
                                             const std::vector<segment::StopReason>& stop,
                                             const std::filesystem::path& path);

struct LabelFileOptions {
  /// Also write an ITK-SNAP label description beside the labels (label_description_path).
  bool itksnap_description = false;
};
/// Label volume (UInt8) with the geometry of `frame` (origin, direction), by extension: NRRD
/// (.nrrd, .nhdr), MetaImage (.mha, .mhd), NIfTI-1 (.nii, .nii.gz), or a 3D Slicer segmentation
/// (.seg.nrrd). Detached formats (.nhdr, .mhd) are written in place: their data file name is tied
/// to the header name.
std::optional<std::string> write_labels(const volume::Volume& labels, const volume::Volume& frame,
                                        const std::filesystem::path& path,
                                        const LabelFileOptions& options = {});
/// As above with the labels' own geometry.
std::optional<std::string> write_labels(const volume::Volume& labels,
                                        const std::filesystem::path& path);
/// Where the ITK-SNAP label description of `labels_path` goes: X.nii.gz -> X.label.txt.
std::filesystem::path label_description_path(const std::filesystem::path& labels_path);
/// Float32 field as an OpenVDB float grid named "indicator".
std::optional<std::string> write_indicator_vdb(const volume::Volume& field,
                                               const std::filesystem::path& path);

}  // namespace sonomesh::daemon::internal
