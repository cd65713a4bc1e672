#pragma once
/// @file
/// @brief What the NRRD reader checks before Teem sees a file, and the short path Teem opens.
///
/// Teem formats its error messages into a fixed 1 KiB stack buffer (_biffMsgAddVL) without a
/// bound: a header line or a file path of ~1000 bytes that ends up in a message aborts the process.
/// So Teem is only given headers whose field lines are short (comments and key:=value lines, which
/// Teem never quotes, may be long) and a path of bounded length.

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>

#include "volume/internal/io.h"

namespace sonomesh::volume::internal {

/// Longest NRRD field line handed to Teem (a 3D "space directions" line with 17 digits per
/// number is ~220 bytes; Teem's messages quote the line with up to ~300 bytes of context).
constexpr std::size_t kMaxNrrdFieldLine = 400;

// What a bounded look at the header text tells before Teem parses it.
struct HeaderScan {
  std::uintmax_t header_bytes = 0;  // offset of the attached data (after the blank line)
  bool has_end = false;             // saw the blank line that ends the header
  std::string data_file;            // "data file:" value, if any
};

/// Reads the header line by line: the magic must be exactly NRRD0001..NRRD0005 (anything else would
/// send Teem to its plain-text reader, whose error path leaks), no NUL bytes, field lines of at
/// most kMaxNrrdFieldLine bytes, the whole header within
/// HeaderLines::kMaxHeader (1 MiB).
std::optional<VolumeIoError> scan_nrrd_header(const std::filesystem::path& path, HeaderScan& scan);

/// A path to `file` short enough for Teem's messages: /proc/self/fd/<dir fd>/<file name>, through
/// a descriptor of the file's directory held open for the object's lifetime (relative detached
/// data files resolve against it as against the real directory).
class ShortPath {
 public:
  explicit ShortPath(const std::filesystem::path& file);
  ~ShortPath();
  ShortPath(const ShortPath&) = delete;
  ShortPath& operator=(const ShortPath&) = delete;
  /// Empty if the directory cannot be opened or the path would still be too long.
  const std::string& path() const { return short_; }
  /// `text` with the /proc/self/fd/<n> prefix put back to the real directory.
  std::string restore(std::string text) const;

 private:
  int dir_fd_ = -1;
  std::string short_, prefix_, real_dir_;
};

}  // namespace sonomesh::volume::internal
