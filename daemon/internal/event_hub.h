#pragma once
/// @file
/// @brief GET /events: the journal as a Server-Sent Events stream, one event per journal line.
///
/// The hub follows OUT/journal.jsonl itself (from where it was at start), so every line the
/// journal gets becomes exactly one event, whoever wrote it, without hooks in the writers. Each
/// event's `id:` is the line's sequence (`eN-SEQ` in a later epoch; `rPOS` for a record without
/// a sequence). A client that reconnects with Last-Event-ID gets the lines after that one, in
/// journal order (not sequence order: journal lines are not sorted), from a ring of recent lines.

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <thread>
#include <vector>

namespace sonomesh::daemon {

/// One journal line as an event: `position` counts lines from the hub's start (1, 2, ...).
struct JournalEvent {
  std::uint64_t position = 0;
  std::string id;
  std::string data;  // the journal line, one line of JSON
};

/// The SSE wire form of an event: "id: ID\ndata: LINE\n\n" (`event:` NAME first if not empty).
std::string sse_message(const std::string& id, const std::string& data,
                        const std::string& event_name = {});

/// The `id:` of a journal line (see the file comment).
std::string event_id_of(const nlohmann::json& line, std::uint64_t position);

class EventHub {
 public:
  /// `status`: the daemon's /status JSON, sent as `event: state` when the source state changes
  /// and every few seconds (the page's "probe disconnected" banner). `capacity`: lines kept for
  /// new clients and resumes (a few minutes at the probe's rate).
  EventHub(std::filesystem::path journal, std::function<nlohmann::json()> status,
           std::size_t capacity = 4096);
  ~EventHub();
  EventHub(const EventHub&) = delete;
  EventHub& operator=(const EventHub&) = delete;

  /// Starts following the journal from its current end (lines of earlier runs are not events).
  void start();
  /// Stops following and wakes every waiting client (their streams end). Idempotent.
  void stop();
  bool stopped() const;

  /// Adds one journal line (the follower calls this; tests may too). Unparsable lines are
  /// published as they are, with a positional id.
  void publish(const std::string& line);

  /// Position after which a client with this Last-Event-ID resumes: the position of that id in
  /// the ring; 0 (everything kept) for an empty or unknown id.
  std::uint64_t resume_position(const std::string& last_event_id) const;
  /// Events after `position`, waiting up to `timeout` for one; empty on timeout or stop.
  std::vector<JournalEvent> wait_after(std::uint64_t position, std::chrono::milliseconds timeout);

  /// The current state event body (the status JSON's source and last_processed parts).
  nlohmann::json state() const;

  /// Streams open now / the cap (a stream holds one HTTP worker thread while it is open).
  bool try_open_stream();
  void close_stream();
  static constexpr int kMaxStreams = 8;

 private:
  void follow_loop();
  void read_new_lines(int fd, std::string& partial);

  std::filesystem::path journal_;
  std::function<nlohmann::json()> status_;
  std::size_t capacity_;

  mutable std::mutex mutex_;
  std::condition_variable changed_;
  std::deque<JournalEvent> ring_;
  std::uint64_t next_position_ = 1;
  bool stopping_ = false;
  int streams_ = 0;

  std::uint64_t start_offset_ = 0;
  std::thread follower_;
};

/// One client's stream: what to send next. Used by the HTTP route; blocks up to `wait`.
class EventStream {
 public:
  EventStream(EventHub& hub, const std::string& last_event_id);
  /// The next chunk to send: events, a state event when the source state changed or a few
  /// seconds passed, or a comment to keep the connection alive. Nothing when the hub stopped.
  std::optional<std::string> next(std::chrono::milliseconds wait);

 private:
  EventHub& hub_;
  std::uint64_t position_;
  std::string last_state_;
  std::chrono::steady_clock::time_point last_state_sent_{};
};

}  // namespace sonomesh::daemon
