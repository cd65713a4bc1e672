#include "daemon/internal/outputs.h"

#include <functional>
#include <stdexcept>

#include "daemon/internal/atomic_file.h"
#include "reconstruct/reconstruct.h"

namespace sonomesh::daemon::internal {
namespace {

namespace fs = std::filesystem;

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

std::optional<std::string> write_mesh_ply(const segment::Mesh& mesh, const fs::path& path) {
  return atomically(path, [&](const fs::path& temporary) -> std::optional<std::string> {
    if (auto error = reconstruct::write_ply(mesh, temporary))
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

std::optional<std::string> write_labels(const volume::Volume& labels, const fs::path& path) {
  auto write = [&](const fs::path& target) -> std::optional<std::string> {
    if (auto error = volume::write_volume(labels, target, volume::Compression::Gzip))
      return "cannot write " + path.string() + ": " + error->message;
    return std::nullopt;
  };
  const std::string extension = path.extension().string();
  if (extension == ".nhdr" || extension == ".mhd") return write(path);
  return atomically(path, write);
}

std::optional<std::string> write_indicator_vdb(const volume::Volume& field, const fs::path& path) {
  return atomically(path, [&](const fs::path& temporary) -> std::optional<std::string> {
    if (auto error = volume::write_vdb(field, temporary, "indicator"))
      return "cannot write " + path.string() + ": " + error->message;
    return std::nullopt;
  });
}

}  // namespace sonomesh::daemon::internal
