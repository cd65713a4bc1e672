#pragma once
/// @file
/// @brief Output files that appear whole or not at all: write a temporary name, fsync, rename.

#include <filesystem>
#include <functional>
#include <string_view>

namespace sonomesh::daemon {

/// The temporary name used for `target`: ".<stem>.tmp-<pid>.<ext>" in the same directory (same
/// file system, so rename(2) is atomic; the original extension is kept for writers that choose
/// the format by extension; the leading dot hides it from globs like meshes/*.ply).
std::filesystem::path temporary_name(const std::filesystem::path& target);

/// True for names temporary_name() produces (any pid).
bool is_temporary_name(const std::filesystem::path& path);

/// Calls write(tmp) to produce the file under its temporary name, fsyncs it, renames it over
/// `target` and fsyncs the directory. On any failure the temporary is removed.
/// @throws std::runtime_error naming the file (or whatever `write` throws).
void write_atomically(const std::filesystem::path& target,
                      const std::function<void(const std::filesystem::path& tmp)>& write);

/// write_atomically() with a byte string.
void write_file_atomically(const std::filesystem::path& target, std::string_view bytes);

/// Publishes an existing file under another name in the same file system atomically (hard link
/// to a temporary name, then rename; a copy where hard links are not supported). No fsync: the
/// source is already durable and the new name is a convenience (latest.ply) that a crash may
/// leave pointing at the previous mesh, which is still a whole file.
void publish_copy_atomically(const std::filesystem::path& source,
                             const std::filesystem::path& target);

/// Removes temporary files left in `dir` by a process that was killed. Returns how many.
int remove_stale_temporaries(const std::filesystem::path& dir);

}  // namespace sonomesh::daemon
