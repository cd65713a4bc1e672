// The bounded NRRD header scan and the short path handed to Teem (see nrrd_scan.h).
#include "volume/internal/nrrd_scan.h"

#include <fcntl.h>
#include <teem/nrrd.h>
#include <unistd.h>

#include <cstring>
#include <fstream>

#include "volume/internal/header_lines.h"

namespace sonomesh::volume::internal {
namespace {

std::string trimmed_value(const std::string& line, std::size_t key_length) {
  std::string value = line.substr(key_length);
  value.erase(0, value.find_first_not_of(' '));
  while (!value.empty() && value.back() == ' ') value.pop_back();
  return value;
}

bool valid_magic(const std::string& line) {
  return line.size() == 8 && line.rfind("NRRD000", 0) == 0 && line[7] >= '1' && line[7] <= '5';
}

// One header line (without its newline): the checks that keep Teem's messages bounded.
std::optional<VolumeIoError> check_line(const std::filesystem::path& path, const std::string& line,
                                        int line_no, HeaderScan& scan) {
  if (line.find('\0') != std::string::npos)
    return io_error(Code::BadHeader, path, "binary bytes inside the header");
  const bool comment = !line.empty() && line[0] == '#';
  const bool key_value = line.find(":=") != std::string::npos;
  if (!comment && !key_value && line.size() > kMaxNrrdFieldLine)
    return io_error(Code::BadHeader, path,
                    "header line " + std::to_string(line_no) + " is " +
                        std::to_string(line.size()) + " bytes long (at most " +
                        std::to_string(kMaxNrrdFieldLine) + ")");
  if (comment || key_value) return std::nullopt;
  if (line.rfind("type:", 0) == 0) {
    const std::string value = trimmed_value(line, 5);
    if (airEnumVal(nrrdType, value.c_str()) == nrrdTypeUnknown)
      return io_error(Code::UnsupportedType, path, "unknown voxel type '" + value + "'");
  }
  for (const char* key : {"data file:", "datafile:"})
    if (line.rfind(key, 0) == 0) scan.data_file = trimmed_value(line, std::strlen(key));
  return std::nullopt;
}

}  // namespace

std::optional<VolumeIoError> scan_nrrd_header(const std::filesystem::path& path, HeaderScan& scan) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return io_error(Code::IoError, path, "cannot open for reading");
  HeaderLines lines(in);
  std::string line;
  const auto bad_magic = [&] {
    return io_error(Code::UnknownFormat, path,
                    "not a NRRD file (no NRRD0001..NRRD0005 magic line)");
  };
  if (!lines.next(line)) return bad_magic();
  for (int line_no = 1;; ++line_no) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line_no == 1 && !valid_magic(line.substr(0, 16))) return bad_magic();
    // A detached header may end at EOF without a newline; an attached one never does.
    if (!lines.terminated() && lines.at_limit())
      return io_error(Code::BadHeader, path, "header longer than 1 MiB");
    if (line.empty() && lines.terminated()) {
      scan.has_end = true;
      scan.header_bytes = lines.consumed();
      return std::nullopt;
    }
    // Teem's reader ends a line at a '\r' too: each part is a line to it (found by fuzz_nrrd: a
    // key:=value line, exempt from the length bound, ran on after a '\r' into a long field line
    // whose error message overflowed Teem's buffer).
    for (std::size_t from = 0;;) {
      const std::size_t cr = line.find('\r', from);
      if (auto err = check_line(path, line.substr(from, cr - from), line_no, scan)) return err;
      if (cr == std::string::npos) break;
      from = cr + 1;
    }
    if (!lines.next(line)) break;
  }
  scan.header_bytes = lines.consumed();
  return std::nullopt;
}

ShortPath::ShortPath(const std::filesystem::path& file) {
  const std::filesystem::path dir = file.has_parent_path() ? file.parent_path() : ".";
  dir_fd_ = ::open(dir.c_str(), O_PATH | O_DIRECTORY | O_CLOEXEC);
  if (dir_fd_ < 0) return;
  prefix_ = "/proc/self/fd/" + std::to_string(dir_fd_);
  real_dir_ = dir.string();
  const std::string name = file.filename().string();
  if (name.size() <= 255) short_ = prefix_ + "/" + name;
}

ShortPath::~ShortPath() {
  if (dir_fd_ >= 0) ::close(dir_fd_);
}

std::string ShortPath::restore(std::string text) const {
  if (prefix_.empty()) return text;
  for (std::size_t at = text.find(prefix_); at != std::string::npos;
       at = text.find(prefix_, at + real_dir_.size()))
    text.replace(at, prefix_.size(), real_dir_);
  return text;
}

}  // namespace sonomesh::volume::internal
