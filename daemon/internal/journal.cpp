#include "daemon/internal/journal.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <ctime>
#include <stdexcept>

namespace sonomesh::daemon {

namespace {
// Claims further back than this below the highest claim are folded into the floor. A sequence
// that old arriving late would be treated as already claimed, which is the safe side (no
// duplicate line); volumes never legitimately arrive 65536 sequences late.
constexpr std::uint64_t kClaimWindow = 65536;
}  // namespace

std::string utc_timestamp() {
  const auto now = std::chrono::system_clock::now();
  const auto ms = std::chrono::duration_cast<std::chrono::milliseconds>(now.time_since_epoch());
  const std::time_t secs = static_cast<std::time_t>(ms.count() / 1000);
  std::tm tm{};
  gmtime_r(&secs, &tm);
  char buf[40];
  const std::size_t n = std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%S", &tm);
  std::snprintf(buf + n, sizeof buf - n, ".%03dZ", static_cast<int>(ms.count() % 1000));
  return buf;
}

JsonlFile::JsonlFile(const std::filesystem::path& path) : path_(path) {
  fd_ = ::open(path.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
  if (fd_ < 0) {
    throw std::runtime_error("cannot open " + path.string() + ": " + std::strerror(errno));
  }
}

JsonlFile::~JsonlFile() {
  if (fd_ >= 0) ::close(fd_);
}

void JsonlFile::append(nlohmann::json line) {
  if (!line.contains("time")) line["time"] = utc_timestamp();
  // Invalid UTF-8 in a detail string must not throw halfway through a line: replace it.
  std::string text = line.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  text.push_back('\n');
  std::lock_guard lock(mutex_);
  const char* p = text.data();
  std::size_t left = text.size();
  while (left > 0) {
    const ssize_t n = ::write(fd_, p, left);
    if (n < 0) {
      if (errno == EINTR) continue;
      throw std::runtime_error("cannot write " + path_.string() + ": " + std::strerror(errno));
    }
    p += n;
    left -= static_cast<std::size_t>(n);
  }
  if (::fsync(fd_) != 0 && errno != EINVAL) {
    throw std::runtime_error("cannot fsync " + path_.string() + ": " + std::strerror(errno));
  }
}

const char* to_string(JournalStatus status) {
  switch (status) {
    case JournalStatus::Processed: return "processed";
    case JournalStatus::Skipped: return "skipped";
    case JournalStatus::Failed: return "failed";
    case JournalStatus::Rejected: return "rejected";
    case JournalStatus::Lost: return "lost";
  }
  return "unknown";
}

Journal::Journal(const std::filesystem::path& path) : file_(path) {}

bool Journal::claim_locked(std::uint64_t sequence) {
  if (sequence < floor_) return false;
  if (!claimed_.insert(sequence).second) return false;
  const std::uint64_t highest = *claimed_.rbegin();
  if (highest > kClaimWindow && highest - kClaimWindow > floor_) {
    // Fold old claims into the floor, but only a contiguous prefix: an unclaimed hole below the
    // new floor would otherwise be silently treated as claimed. Holes that old are reported by
    // the source as lost long before, so in practice the prefix is contiguous.
    const std::uint64_t target = highest - kClaimWindow;
    auto it = claimed_.begin();
    while (it != claimed_.end() && *it < target && *it == floor_) {
      ++floor_;
      it = claimed_.erase(it);
    }
  }
  return true;
}

bool Journal::claim(std::uint64_t sequence) {
  std::lock_guard lock(mutex_);
  return claim_locked(sequence);
}

std::uint64_t Journal::new_epoch() {
  std::lock_guard lock(mutex_);
  claimed_.clear();
  floor_ = 0;
  return ++epoch_;
}

std::uint64_t Journal::epoch() const {
  std::lock_guard lock(mutex_);
  return epoch_;
}

void Journal::write(std::optional<std::uint64_t> sequence, JournalStatus status,
                    nlohmann::json fields, std::optional<std::uint64_t> epoch) {
  nlohmann::json line = nlohmann::json::object();
  line["sequence"] = sequence ? nlohmann::json(*sequence) : nlohmann::json(nullptr);
  line["status"] = to_string(status);
  const std::uint64_t e = epoch ? *epoch : this->epoch();
  if (e > 0) line["epoch"] = e;
  if (fields.is_object()) {
    for (auto& [key, value] : fields.items()) {
      if (key != "sequence" && key != "status") line[key] = std::move(value);
    }
  }
  line["time"] = utc_timestamp();
  file_.append(std::move(line));
  std::lock_guard lock(mutex_);
  ++lines_;
}

std::uint64_t Journal::write_lost(std::uint64_t first, std::uint64_t count,
                                  const std::string& reason) {
  std::uint64_t written = 0;
  for (std::uint64_t i = 0; i < count; ++i) {
    const std::uint64_t seq = first + i;
    if (seq < first) break;  // wrapped
    if (!claim(seq)) continue;
    write(seq, JournalStatus::Lost, {{"reason", reason}});
    ++written;
  }
  return written;
}

std::uint64_t Journal::lines_written() const {
  std::lock_guard lock(mutex_);
  return lines_;
}

}  // namespace sonomesh::daemon
