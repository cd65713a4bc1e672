#include "daemon/internal/event_hub.h"

#include <fcntl.h>
#include <spdlog/spdlog.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>

namespace sonomesh::daemon {

namespace {
// The journal is polled, not watched: a line reaches clients at most this late, and at 5-10
// volumes/s a poll finds one or two lines.
constexpr auto kFollowInterval = std::chrono::milliseconds(100);
// A state event goes out at least this often even when nothing changed (the page shows its age).
constexpr auto kStateEvery = std::chrono::seconds(5);
}  // namespace

std::string sse_message(const std::string& id, const std::string& data,
                        const std::string& event_name) {
  std::string out;
  out.reserve(data.size() + id.size() + 24);
  if (!event_name.empty()) out += "event: " + event_name + "\n";
  if (!id.empty()) out += "id: " + id + "\n";
  // A data field ends at a newline: a journal line has none, but a multi-line payload must be
  // sent as several data fields or it would end the event early.
  std::size_t begin = 0;
  while (true) {
    const std::size_t end = data.find('\n', begin);
    out += "data: " + data.substr(begin, end == std::string::npos ? end : end - begin) + "\n";
    if (end == std::string::npos) break;
    begin = end + 1;
  }
  out += "\n";
  return out;
}

std::string event_id_of(const nlohmann::json& line, std::uint64_t position) {
  auto count_at = [&](const char* key) -> std::optional<std::uint64_t> {
    if (!line.is_object()) return std::nullopt;
    const auto it = line.find(key);
    if (it == line.end() || !it->is_number_integer() || it->get<std::int64_t>() < 0) {
      return std::nullopt;
    }
    return it->get<std::uint64_t>();
  };
  const auto seq = count_at("sequence");
  if (!seq) return "r" + std::to_string(position);
  const auto epoch = count_at("epoch");
  if (epoch && *epoch > 0) return "e" + std::to_string(*epoch) + "-" + std::to_string(*seq);
  return std::to_string(*seq);
}

EventHub::EventHub(std::filesystem::path journal, std::function<nlohmann::json()> status,
                   std::size_t capacity)
    : journal_(std::move(journal)), status_(std::move(status)), capacity_(capacity) {}

EventHub::~EventHub() { stop(); }

void EventHub::start() {
  std::error_code ec;
  const auto size = std::filesystem::file_size(journal_, ec);
  start_offset_ = ec ? 0 : size;
  follower_ = std::thread([this] { follow_loop(); });
}

void EventHub::stop() {
  {
    std::lock_guard lock(mutex_);
    stopping_ = true;
  }
  changed_.notify_all();
  if (follower_.joinable()) follower_.join();
}

bool EventHub::stopped() const {
  std::lock_guard lock(mutex_);
  return stopping_;
}

void EventHub::publish(const std::string& line) {
  {
    std::lock_guard lock(mutex_);
    const auto parsed = nlohmann::json::parse(line, nullptr, false);
    JournalEvent event{next_position_, event_id_of(parsed, next_position_), line};
    ++next_position_;
    ring_.push_back(std::move(event));
    while (ring_.size() > capacity_) ring_.pop_front();
  }
  changed_.notify_all();
}

std::uint64_t EventHub::resume_position(const std::string& last_event_id) const {
  if (last_event_id.empty()) return 0;
  std::lock_guard lock(mutex_);
  // Newest first: an id repeats only after a counter restart without an epoch (not possible
  // within one journal run), and then the latest is the one the client saw.
  for (auto it = ring_.rbegin(); it != ring_.rend(); ++it) {
    if (it->id == last_event_id) return it->position;
  }
  return 0;
}

std::vector<JournalEvent> EventHub::wait_after(std::uint64_t position,
                                               std::chrono::milliseconds timeout) {
  std::unique_lock lock(mutex_);
  changed_.wait_for(lock, timeout, [&] { return stopping_ || next_position_ > position + 1; });
  std::vector<JournalEvent> out;
  if (stopping_) return out;
  for (const JournalEvent& e : ring_) {
    if (e.position > position) out.push_back(e);
  }
  return out;
}

nlohmann::json EventHub::state() const {
  nlohmann::json s = status_ ? status_() : nlohmann::json::object();
  nlohmann::json out = nlohmann::json::object();
  for (const char* key : {"source", "last_processed", "last_error", "volumes"}) {
    if (s.contains(key)) out[key] = s[key];
  }
  return out;
}

bool EventHub::try_open_stream() {
  std::lock_guard lock(mutex_);
  if (stopping_ || streams_ >= kMaxStreams) return false;
  ++streams_;
  return true;
}

void EventHub::close_stream() {
  std::lock_guard lock(mutex_);
  --streams_;
}

void EventHub::read_new_lines(int fd, std::string& partial) {
  char buf[65536];
  while (true) {
    const ssize_t n = ::read(fd, buf, sizeof buf);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return;
    partial.append(buf, static_cast<std::size_t>(n));
    std::size_t begin = 0;
    for (std::size_t nl; (nl = partial.find('\n', begin)) != std::string::npos; begin = nl + 1) {
      if (nl > begin) publish(partial.substr(begin, nl - begin));
    }
    partial.erase(0, begin);  // a line still being written waits for its newline
  }
}

void EventHub::follow_loop() {
  int fd = -1;
  std::string partial;
  std::uint64_t offset = start_offset_;
  while (true) {
    {
      std::unique_lock lock(mutex_);
      if (changed_.wait_for(lock, kFollowInterval, [&] { return stopping_; })) break;
    }
    if (fd < 0) {
      fd = ::open(journal_.c_str(), O_RDONLY | O_CLOEXEC);
      if (fd < 0) continue;  // not created yet
      if (::lseek(fd, static_cast<off_t>(offset), SEEK_SET) < 0) offset = 0;
    }
    struct stat st {};
    if (::fstat(fd, &st) == 0 && static_cast<std::uint64_t>(st.st_size) < offset) {
      // Truncated or replaced under us: follow the new content from its start.
      spdlog::warn("{} shrank; following it from the start", journal_.string());
      ::lseek(fd, 0, SEEK_SET);
      partial.clear();
    }
    read_new_lines(fd, partial);
    const off_t now = ::lseek(fd, 0, SEEK_CUR);
    offset = now < 0 ? 0 : static_cast<std::uint64_t>(now);
  }
  if (fd >= 0) ::close(fd);
}

EventStream::EventStream(EventHub& hub, const std::string& last_event_id)
    : hub_(hub), position_(hub.resume_position(last_event_id)) {}

std::optional<std::string> EventStream::next(std::chrono::milliseconds wait) {
  if (hub_.stopped()) return std::nullopt;
  std::string chunk;
  const auto now = std::chrono::steady_clock::now();
  const nlohmann::json state = hub_.state();
  const std::string state_text = state.dump();
  const std::string source_state = state.value("/source/state"_json_pointer, std::string());
  if (source_state != last_state_ || now - last_state_sent_ >= kStateEvery) {
    chunk += sse_message({}, state_text, "state");
    last_state_ = source_state;
    last_state_sent_ = now;
  }
  if (chunk.empty()) {
    for (const JournalEvent& e : hub_.wait_after(position_, wait)) {
      chunk += sse_message(e.id, e.data);
      position_ = e.position;
    }
  }
  if (hub_.stopped()) return std::nullopt;
  if (chunk.empty()) chunk = ": keep-alive\n\n";
  return chunk;
}

}  // namespace sonomesh::daemon
