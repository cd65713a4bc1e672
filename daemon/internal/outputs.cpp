#include "daemon/internal/outputs.h"

#include <unistd.h>

#include <cstdio>
#include <fstream>
#include <functional>

#include "reconstruct/reconstruct.h"

namespace sonomesh::daemon::internal {
namespace {

namespace fs = std::filesystem;

// A temporary name in the target's directory (rename is only atomic within one file system) that
// keeps the extension, because the writers pick the format from it.
fs::path temporary_for(const fs::path& path) {
  const fs::path name = path.filename();
  return path.parent_path() /
         ("." + name.stem().string() + ".partial-" + std::to_string(::getpid()) +
          name.extension().string());
}

// Writes through `write` to a temporary name, then renames over `path`.
std::optional<std::string> atomically(
    const fs::path& path, const std::function<std::optional<std::string>(const fs::path&)>& write) {
  const fs::path temporary = temporary_for(path);
  if (auto problem = write(temporary)) {
    std::error_code ignored;
    fs::remove(temporary, ignored);
    return problem;
  }
  std::error_code ec;
  fs::rename(temporary, path, ec);
  if (ec) {
    fs::remove(temporary, ec);
    return "cannot write " + path.string() + ": " + ec.message();
  }
  return std::nullopt;
}

}  // namespace

std::optional<std::string> write_text_atomically(const fs::path& path, const std::string& text) {
  return atomically(path, [&](const fs::path& temporary) -> std::optional<std::string> {
    std::ofstream out(temporary, std::ios::binary);
    out << text;
    out.close();
    if (!out) return "cannot write " + path.string();
    return std::nullopt;
  });
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
