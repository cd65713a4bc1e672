#include "daemon/internal/outputs.h"

#include <Eigen/LU>
#include <cctype>
#include <cstring>
#include <functional>
#include <stdexcept>

#include "daemon/internal/atomic_file.h"
#include "reconstruct/reconstruct.h"

namespace sonomesh::daemon::internal {
namespace {

namespace fs = std::filesystem;

bool ends_with_lower(const std::string& name, const std::string& suffix) {
  if (name.size() < suffix.size()) return false;
  for (std::size_t i = 0; i < suffix.size(); ++i)
    if (std::tolower(static_cast<unsigned char>(name[name.size() - suffix.size() + i])) !=
        suffix[i])
      return false;
  return true;
}

// Runs write_atomically (temporary name, fsync, rename) with a writer that reports errors as a
// line, and turns every failure into that one line.
std::optional<std::string> atomically(
    const fs::path& path, const std::function<std::optional<std::string>(const fs::path&)>& write) {
  std::optional<std::string> problem;
  try {
    write_atomically(path, [&](const fs::path& temporary) {
      problem = write(temporary);
      if (problem) throw std::runtime_error(*problem);
    });
  } catch (const std::exception& e) {
    if (!problem) problem = e.what();
  }
  return problem;
}

}  // namespace

std::optional<std::string> write_text_atomically(const fs::path& path, const std::string& text) {
  try {
    write_file_atomically(path, text);
  } catch (const std::exception& e) {
    return std::string(e.what());
  }
  return std::nullopt;
}

segment::Mesh mesh_to_world(const segment::Mesh& grid_mesh, const volume::Volume& frame) {
  segment::Mesh world = grid_mesh;
  for (auto& v : world.vertices) v = frame.grid_to_world_mm(v);
  if (frame.direction().determinant() < 0.0f)
    for (auto& t : world.triangles) std::swap(t[1], t[2]);
  return world;
}

volume::Vec3f seed_world_to_grid_mm(const volume::Volume& frame,
                                    const volume::Vec3f& seed_world_mm) {
  return frame.world_to_grid_mm(seed_world_mm);
}

std::optional<std::string> write_mesh_ply(const segment::Mesh& mesh, const fs::path& path) {
  return atomically(path, [&](const fs::path& temporary) -> std::optional<std::string> {
    if (auto error = reconstruct::write_ply(mesh, temporary))
      return "cannot write " + path.string() + ": " + error->message;
    return std::nullopt;
  });
}

std::optional<std::string> write_mesh_ply(const segment::Mesh& grid_mesh,
                                          const volume::Volume& frame, const fs::path& path) {
  return internal::write_mesh_ply(mesh_to_world(grid_mesh, frame), path);
}

std::optional<std::string> write_mesh_file(const segment::Mesh& grid_mesh,
                                           const volume::Volume& frame, const fs::path& path) {
  const segment::Mesh world = mesh_to_world(grid_mesh, frame);
  return atomically(path, [&](const fs::path& temporary) -> std::optional<std::string> {
    // The temporary keeps the extension, so write_mesh picks the format of `path`.
    if (auto error = reconstruct::write_mesh(world, temporary))
      return "cannot write " + path.string() + ": " + error->message;
    return std::nullopt;
  });
}

std::optional<std::string> write_balloon_ply(const segment::Mesh& mesh,
                                             const std::vector<segment::StopReason>& stop,
                                             const fs::path& path) {
  return atomically(path, [&](const fs::path& temporary) -> std::optional<std::string> {
    if (auto error = reconstruct::write_balloon_ply(mesh, stop, temporary))
      return "cannot write " + path.string() + ": " + error->message;
    return std::nullopt;
  });
}

std::optional<std::string> write_balloon_ply(const segment::Mesh& grid_mesh,
                                             const std::vector<segment::StopReason>& stop,
                                             const volume::Volume& frame, const fs::path& path) {
  return internal::write_balloon_ply(mesh_to_world(grid_mesh, frame), stop, path);
}

fs::path label_description_path(const fs::path& labels_path) {
  std::string name = labels_path.filename().string();
  for (const char* ext : {".seg.nrrd", ".nii.gz", ".nrrd", ".nhdr", ".mha", ".mhd", ".nii"})
    if (ends_with_lower(name, ext)) {
      name.resize(name.size() - std::strlen(ext));
      break;
    }
  return labels_path.parent_path() / (name + ".label.txt");
}

std::optional<std::string> write_labels(const volume::Volume& labels, const volume::Volume& frame,
                                        const fs::path& path, const LabelFileOptions& options) {
  if (labels.dims() != frame.dims())
    return "cannot write " + path.string() + ": labels and input grids differ";
  volume::Volume placed = labels;  // uint8, small next to the input; gets the input's geometry
  placed.set_origin_mm(frame.origin_mm());
  placed.set_direction(frame.direction());
  const bool segmentation = ends_with_lower(path.filename().string(), ".seg.nrrd");
  const bool nifti_gz = ends_with_lower(path.filename().string(), ".nii.gz");
  auto write = [&](const fs::path& target) -> std::optional<std::string> {
    std::optional<volume::VolumeIoError> error;
    if (segmentation) {
      error = volume::write_segmentation(placed, target);
    } else if (nifti_gz && target != path) {
      // nifticlib compresses by the name, which must end in .nii.gz: stage under such a name.
      fs::path staged = target;
      staged += ".nii.gz";
      error = volume::write_volume(placed, staged);
      std::error_code ec;
      if (!error) fs::rename(staged, target, ec);
      if (ec) return "cannot write " + path.string() + ": " + ec.message();
    } else {
      error = volume::write_volume(placed, target, volume::Compression::Gzip);
    }
    if (error) return "cannot write " + path.string() + ": " + error->message;
    return std::nullopt;
  };
  const std::string extension = path.extension().string();
  auto problem =
      extension == ".nhdr" || extension == ".mhd" ? write(path) : atomically(path, write);
  if (problem || !options.itksnap_description) return problem;
  const fs::path description = label_description_path(path);
  return atomically(description, [&](const fs::path& temporary) -> std::optional<std::string> {
    if (auto error = volume::write_label_description(temporary))
      return "cannot write " + description.string() + ": " + error->message;
    return std::nullopt;
  });
}

std::optional<std::string> write_labels(const volume::Volume& labels, const fs::path& path) {
  return write_labels(labels, labels, path);
}

std::optional<std::string> write_indicator_vdb(const volume::Volume& field, const fs::path& path) {
  return atomically(path, [&](const fs::path& temporary) -> std::optional<std::string> {
    if (auto error = volume::write_vdb(field, temporary, "indicator"))
      return "cannot write " + path.string() + ": " + error->message;
    return std::nullopt;
  });
}

}  // namespace sonomesh::daemon::internal
