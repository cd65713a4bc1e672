#include "daemon/internal/journal.h"

#include <fcntl.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <ctime>
#include <fstream>
#include <stdexcept>

#include "daemon/internal/atomic_file.h"

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

namespace {

// A line is whole if it is a JSON object: every line this file type writes is one.
std::optional<nlohmann::json> whole_line(const std::string& text) {
  auto j = nlohmann::json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded() || !j.is_object()) return std::nullopt;
  return j;
}

// Copies the kept lines to a temporary, renames it over `path`; bad ones go to `torn`.
void rewrite_without_bad_lines(const std::filesystem::path& path,
                               const std::filesystem::path& torn) {
  std::ifstream in(path, std::ios::binary);
  std::ofstream aside(torn, std::ios::binary | std::ios::app);
  write_atomically(path, [&](const std::filesystem::path& tmp) {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    std::string text;
    while (std::getline(in, text)) {
      (whole_line(text) ? out : aside) << text << '\n';
    }
    out.flush();
    if (!out) throw std::runtime_error("cannot write " + tmp.string());
  });
  aside.flush();
  if (!aside) throw std::runtime_error("cannot write " + torn.string());
}

}  // namespace

JsonlRepair repair_jsonl(const std::filesystem::path& path,
                         const std::function<void(const nlohmann::json&)>& on_line) {
  JsonlRepair repair;
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) return repair;
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("cannot read " + path.string() + ": " + std::strerror(errno));
  // A torn write is always the last line, but a crash of the file system can leave garbage (NUL
  // blocks) anywhere: check every line, and rewrite only when something is wrong.
  bool newline_missing = false;
  std::string text;
  while (std::getline(in, text)) {
    newline_missing = in.eof();
    if (auto line = whole_line(text)) {
      ++repair.whole_lines;
      if (on_line) on_line(*line);
    } else {
      ++repair.set_aside;
    }
  }
  if (in.bad()) throw std::runtime_error("cannot read " + path.string());
  in.close();
  if (repair.set_aside > 0 || newline_missing) {
    if (repair.set_aside > 0) repair.set_aside_path = path.string() + ".torn";
    rewrite_without_bad_lines(path, path.string() + ".torn");
  }
  return repair;
}

JsonlFile::JsonlFile(const std::filesystem::path& path,
                     const std::function<void(const nlohmann::json&)>& on_line)
    : path_(path), repair_(repair_jsonl(path, on_line)) {
  if (repair_.set_aside > 0) {
    spdlog::warn(
        "{}: {} torn or unreadable line(s) set aside in {} (a crash or power loss "
        "mid-write); {} whole line(s) kept",
        path.string(), repair_.set_aside, repair_.set_aside_path.string(), repair_.whole_lines);
  }
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
    case JournalStatus::Processed:
      return "processed";
    case JournalStatus::Skipped:
      return "skipped";
    case JournalStatus::Failed:
      return "failed";
    case JournalStatus::Rejected:
      return "rejected";
    case JournalStatus::Lost:
      return "lost";
  }
  return "unknown";
}

std::vector<std::pair<std::uint64_t, std::uint64_t>> Journal::holes_before() const {
  std::vector<std::pair<std::uint64_t, std::uint64_t>> holes;
  std::optional<std::uint64_t> end;  // one past the previous range
  for (const auto& [first, last] : earlier_.ranges) {
    if (end && first > *end) holes.emplace_back(*end, first - *end);
    end = last + 1;
  }
  return holes;
}

void Journal::Earlier::add(const nlohmann::json& line) {
  const auto e = line.find("epoch");
  const std::uint64_t line_epoch =
      e != line.end() && e->is_number_unsigned() ? e->get<std::uint64_t>() : 0;
  if (line_epoch > epoch) ranges.clear();
  if (line_epoch < epoch) return;
  epoch = line_epoch;
  const auto s = line.find("sequence");
  if (s == line.end() || !s->is_number_unsigned()) return;  // a rejected record without one
  const std::uint64_t seq = s->get<std::uint64_t>();
  // Merge [seq, seq] into the ranges: join the one ending at seq - 1 and the one starting at
  // seq + 1.
  auto next = ranges.upper_bound(seq);
  if (next != ranges.begin()) {
    auto prev = std::prev(next);
    if (prev->second >= seq) return;  // already in
    if (prev->second + 1 == seq) {
      prev->second = seq;
      if (next != ranges.end() && next->first == seq + 1) {
        prev->second = next->second;
        ranges.erase(next);
      }
      return;
    }
  }
  if (next != ranges.end() && next->first == seq + 1) {
    const std::uint64_t last = next->second;
    ranges.erase(next);
    ranges.emplace(seq, last);
    return;
  }
  ranges.emplace(seq, seq);
}

Journal::Journal(const std::filesystem::path& path)
    : file_(path, [this](const nlohmann::json& line) { earlier_.add(line); }) {
  epoch_ = earlier_.epoch;
  if (!earlier_.ranges.empty()) {
    // The newest kClaimWindow sequences become claims; everything further down is below the
    // floor, as claim_locked would have folded it in the earlier run.
    const std::uint64_t top = earlier_.ranges.rbegin()->second;
    floor_ = top > kClaimWindow ? top - kClaimWindow : 0;
    for (const auto& [first, last] : earlier_.ranges) {
      for (std::uint64_t s = std::max(first, floor_); s <= last && s >= first; ++s) {
        claimed_.insert(s);
      }
    }
  }
  if (file_.repair().whole_lines > 0) {
    spdlog::info(
        "{}: continuing after {} line(s) of an earlier run (epoch {}, {} sequence "
        "range(s))",
        path.string(), file_.repair().whole_lines, epoch_, earlier_.ranges.size());
  }
}

bool Journal::written_before(std::uint64_t sequence) const {
  std::lock_guard lock(mutex_);
  auto next = earlier_.ranges.upper_bound(sequence);
  if (next == earlier_.ranges.begin()) return false;
  return std::prev(next)->second >= sequence;
}

std::optional<std::uint64_t> Journal::highest_before() const {
  std::lock_guard lock(mutex_);
  if (earlier_.ranges.empty()) return std::nullopt;
  return earlier_.ranges.rbegin()->second;
}

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
