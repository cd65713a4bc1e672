#include "daemon/internal/batch_manifest.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <map>
#include <mutex>
#include <stdexcept>

#include "daemon/internal/journal.h"

namespace sonomesh::daemon {

namespace fs = std::filesystem;

namespace {

// Threads of one process share the descriptor, and flock(2) does not exclude holders of the
// same open file description: the mutex orders them, the lock orders processes.
std::mutex g_append_mutex;

bool safe_id(const std::string& id) {
  if (id.empty() || id.size() > 200 || id.front() == '.') return false;
  for (char c : id) {
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '-' && c != '_' && c != '.') {
      return false;
    }
  }
  return true;
}

std::string default_id(const fs::path& input) {
  std::string name = input.filename().string();
  for (const char* ext : {".nii.gz", ".seg.nrrd"}) {
    const std::string e = ext;
    if (name.size() > e.size() && name.compare(name.size() - e.size(), e.size(), e) == 0) {
      return name.substr(0, name.size() - e.size());
    }
  }
  return input.stem().string();
}

template <typename T>
std::optional<std::array<T, 3>> triple(const nlohmann::json& j) {
  if (!j.is_array() || j.size() != 3) return std::nullopt;
  std::array<T, 3> out{};
  for (int i = 0; i < 3; ++i) {
    if (!j[i].is_number()) return std::nullopt;
    const double v = j[i].get<double>();
    if (!std::isfinite(v)) return std::nullopt;
    if constexpr (std::is_integral_v<T>) {
      if (v != std::floor(v)) return std::nullopt;
    }
    out[i] = static_cast<T>(v);
  }
  return out;
}

// One entry; the error names what is wrong (the caller adds the line number).
std::optional<BatchItem> parse_entry(const std::string& text, const fs::path& base,
                                     std::string& error) {
  const auto j = nlohmann::json::parse(text, nullptr, false);
  if (j.is_discarded() || !j.is_object()) return error = "not a JSON object", std::nullopt;
  for (const auto& [key, value] : j.items()) {
    if (key != "input" && key != "seed_mm" && key != "seed_index" && key != "id" &&
        key != "target") {
      return error = "unknown key '" + key + "'", std::nullopt;
    }
  }
  BatchItem item;
  if (!j.contains("input") || !j["input"].is_string() || j["input"].get<std::string>().empty()) {
    return error = "\"input\" (a path) is missing", std::nullopt;
  }
  item.input = j["input"].get<std::string>();
  if (item.input.is_relative()) item.input = base / item.input;
  if (j.contains("seed_mm") == j.contains("seed_index")) {
    return error = "give exactly one of \"seed_mm\" and \"seed_index\"", std::nullopt;
  }
  if (j.contains("seed_mm") && !(item.seed_mm = triple<float>(j["seed_mm"]))) {
    return error = "\"seed_mm\" must be [x, y, z] in mm", std::nullopt;
  }
  if (j.contains("seed_index") && !(item.seed_index = triple<int>(j["seed_index"]))) {
    return error = "\"seed_index\" must be [i, j, k] (integers)", std::nullopt;
  }
  item.id =
      j.contains("id") && j["id"].is_string() ? j["id"].get<std::string>() : default_id(item.input);
  if (j.contains("id") && !j["id"].is_string())
    return error = "\"id\" must be a string", std::nullopt;
  if (!safe_id(item.id)) {
    return error = "id '" + item.id + "' is not a file name (letters, digits, - _ .)", std::nullopt;
  }
  if (j.contains("target")) {
    if (!j["target"].is_string() || !(item.target = target_from(j["target"]))) {
      return error = "\"target\" must be \"dark\", \"bright\" or \"auto\"", std::nullopt;
    }
  }
  return item;
}

}  // namespace

std::optional<TargetPolarity> target_from(const std::string& text) {
  if (text == "dark") return TargetPolarity::Dark;
  if (text == "bright") return TargetPolarity::Bright;
  if (text == "auto") return TargetPolarity::Auto;
  return std::nullopt;
}

std::optional<std::vector<BatchItem>> read_manifest(const fs::path& path, std::string& error) {
  std::ifstream in(path);
  if (!in) return error = "cannot read manifest " + path.string(), std::nullopt;
  const fs::path base = fs::absolute(path).parent_path();
  std::vector<BatchItem> items;
  std::map<std::string, std::size_t> line_of_id;
  std::string text;
  for (std::size_t line = 1; std::getline(in, text); ++line) {
    if (text.find_first_not_of(" \t\r") == std::string::npos) continue;
    std::string why;
    auto item = parse_entry(text, base, why);
    if (!item) return error = path.string() + ":" + std::to_string(line) + ": " + why, std::nullopt;
    if (const auto seen = line_of_id.find(item->id); seen != line_of_id.end()) {
      error = path.string() + ":" + std::to_string(line) + ": id '" + item->id + "' is also line " +
              std::to_string(seen->second) + "'s (give each an \"id\")";
      return std::nullopt;
    }
    line_of_id[item->id] = line;
    item->index = items.size();
    item->line = line;
    items.push_back(std::move(*item));
  }
  if (items.empty()) return error = "manifest " + path.string() + " has no entries", std::nullopt;
  return items;
}

ResultsFile::ResultsFile(fs::path path) : path_(std::move(path)) {
  fd_ = ::open(path_.c_str(), O_RDWR | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
  if (fd_ < 0) {
    throw std::runtime_error("cannot open " + path_.string() + ": " + std::strerror(errno));
  }
}

ResultsFile::~ResultsFile() {
  if (fd_ >= 0) ::close(fd_);
}

namespace {
// The whole file through `fd` from its start (the caller holds a lock).
std::string read_all(int fd) {
  std::string text;
  char buf[65536];
  for (off_t at = 0;;) {
    const ssize_t n = ::pread(fd, buf, sizeof buf, at);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    text.append(buf, static_cast<std::size_t>(n));
    at += n;
  }
  return text;
}

std::set<std::string> ids_in(const std::string& text) {
  std::set<std::string> ids;
  std::size_t begin = 0;
  for (std::size_t nl; (nl = text.find('\n', begin)) != std::string::npos; begin = nl + 1) {
    const auto j = nlohmann::json::parse(text.substr(begin, nl - begin), nullptr, false);
    if (j.is_object() && j.contains("id") && j["id"].is_string()) ids.insert(j["id"]);
  }
  return ids;  // a last line without its newline was torn by a kill: not a result
}

struct FileLock {
  FileLock(int fd, int op) : fd(fd) {
    while (::flock(fd, op) != 0 && errno == EINTR) {
    }
  }
  ~FileLock() { ::flock(fd, LOCK_UN); }
  int fd;
};
}  // namespace

std::set<std::string> ResultsFile::done_ids() const {
  std::lock_guard guard(g_append_mutex);
  FileLock lock(fd_, LOCK_SH);
  return ids_in(read_all(fd_));
}

bool ResultsFile::append(const nlohmann::json& line, bool unless_done) {
  nlohmann::json out = line;
  if (!out.contains("time")) out["time"] = utc_timestamp();
  std::string text = out.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace) + "\n";
  std::lock_guard guard(g_append_mutex);
  FileLock lock(fd_, LOCK_EX);
  if (unless_done && ids_in(read_all(fd_)).count(line.value("id", std::string()))) return false;
  // Only the last byte is read: a torn line (no newline) gets one, so this line stays whole.
  struct stat st {};
  char last = '\n';
  if (::fstat(fd_, &st) == 0 && st.st_size > 0 && ::pread(fd_, &last, 1, st.st_size - 1) == 1 &&
      last != '\n') {
    text.insert(text.begin(), '\n');
  }
  const char* p = text.data();
  for (std::size_t left = text.size(); left > 0;) {
    const ssize_t n = ::write(fd_, p, left);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0)
      throw std::runtime_error("cannot write " + path_.string() + ": " + std::strerror(errno));
    p += n;
    left -= static_cast<std::size_t>(n);
  }
  if (::fsync(fd_) != 0) {
    throw std::runtime_error("cannot fsync " + path_.string() + ": " + std::strerror(errno));
  }
  return true;
}

}  // namespace sonomesh::daemon
