// GET /events: one Server-Sent Event per journal line, in journal order, `id:` the sequence,
// resumed after Last-Event-ID; and the EventHub's own framing and resume rules.
#include <gtest/gtest.h>

#include <map>

#include "child_process.h"
#include "daemon/internal/event_hub.h"

// Last: <httplib.h> pulls in <resolv.h>, whose `_res` macro breaks Eigen headers included after it.
#include <httplib.h>

namespace {

using namespace sonomesh::testing;
using sonomesh::daemon::EventHub;
using sonomesh::daemon::EventStream;

struct SseEvent {
  std::string name, id, data;
};

// Parses complete events out of `buffer` (removing them).
std::vector<SseEvent> parse_sse(std::string& buffer) {
  std::vector<SseEvent> out;
  for (std::size_t end; (end = buffer.find("\n\n")) != std::string::npos;) {
    const std::string block = buffer.substr(0, end);
    buffer.erase(0, end + 2);
    SseEvent e;
    std::size_t begin = 0;
    while (begin <= block.size()) {
      std::size_t nl = block.find('\n', begin);
      if (nl == std::string::npos) nl = block.size();
      const std::string line = block.substr(begin, nl - begin);
      begin = nl + 1;
      if (line.rfind("id: ", 0) == 0) e.id = line.substr(4);
      if (line.rfind("event: ", 0) == 0) e.name = line.substr(7);
      if (line.rfind("data: ", 0) == 0) e.data += (e.data.empty() ? "" : "\n") + line.substr(6);
    }
    if (!e.data.empty()) out.push_back(e);  // comments (keep-alives) have no data
  }
  return out;
}

// Journal events (unnamed) from /events until `count` arrived.
std::vector<SseEvent> read_events(int port, std::size_t count, const std::string& last_id = {}) {
  httplib::Client client("127.0.0.1", port);
  client.set_read_timeout(30, 0);
  httplib::Headers headers;
  if (!last_id.empty()) headers.emplace("Last-Event-ID", last_id);
  std::string buffer;
  std::vector<SseEvent> events;
  client.Get("/events", headers, [&](const char* data, std::size_t len) {
    buffer.append(data, len);
    for (auto& e : parse_sse(buffer)) {
      if (e.name.empty()) events.push_back(std::move(e));
    }
    return events.size() < count;  // false: close the stream
  });
  if (events.size() > count) events.resize(count);  // one chunk may carry several events
  return events;
}

std::vector<std::string> journal_lines(const fs::path& path) {
  std::vector<std::string> lines;
  std::ifstream in(path);
  for (std::string line; std::getline(in, line);) lines.push_back(line);
  return lines;
}

TEST(LiveEvents, OneEventPerJournalLineInOrderAndResumesAfterLastEventId) {
  ScratchDir dir("sse");
  Child daemon({SONOMESHD_EXE, "run", "--source", "sim:sphere?rate=10&size=48", "--out",
                (dir / "out").string(), "--http", "127.0.0.1:0"},
               dir / "daemon");
  const int port = http_port_of(dir / "out");
  ASSERT_GT(port, 0) << daemon.stderr_text();

  const std::vector<SseEvent> first = read_events(port, 4);
  ASSERT_EQ(first.size(), 4u);
  // Reconnect after a pause in which more lines were written, resuming after the second event.
  ASSERT_TRUE(
      wait_until([&] { return journal_lines(dir / "out" / "journal.jsonl").size() >= 8; }, 60s));
  const std::vector<SseEvent> resumed = read_events(port, 5, first[1].id);
  ASSERT_EQ(resumed.size(), 5u);
  // The *_info metrics (Prometheus naming conventions) carry the version and the source.
  httplib::Client client("127.0.0.1", port);
  const auto metrics = client.Get("/metrics");
  ASSERT_TRUE(metrics);
  EXPECT_NE(metrics->body.find("sonomesh_build_info{version=\""), std::string::npos);
  EXPECT_NE(metrics->body.find(
                "sonomesh_source_info{uri=\"sim:sphere?rate=10&size=48\",live=\"true\"} 1"),
            std::string::npos);
  daemon.signal(SIGINT);
  ASSERT_EQ(daemon.wait(30s), 0) << daemon.stderr_text();

  const std::vector<std::string> journal = journal_lines(dir / "out" / "journal.jsonl");
  ASSERT_GE(journal.size(), 7u);
  for (std::size_t i = 0; i < first.size(); ++i) {
    EXPECT_EQ(first[i].data, journal[i]) << "event " << i;
    const auto line = nlohmann::json::parse(journal[i]);
    EXPECT_EQ(first[i].id, std::to_string(line["sequence"].get<std::uint64_t>()));
  }
  // After Last-Event-ID = the second line's id: the third line onwards, none repeated or missed.
  for (std::size_t i = 0; i < resumed.size(); ++i) {
    EXPECT_EQ(resumed[i].data, journal[i + 2]) << "resumed event " << i;
  }
}

TEST(LiveEvents, HubFramesResumesAndEndsStreams) {
  EXPECT_EQ(sonomesh::daemon::sse_message("7", "{\"a\":1}"), "id: 7\ndata: {\"a\":1}\n\n");
  EXPECT_EQ(sonomesh::daemon::sse_message("", "x\ny", "state"),
            "event: state\ndata: x\ndata: y\n\n");
  EXPECT_EQ(sonomesh::daemon::event_id_of(nlohmann::json{{"sequence", 5}, {"epoch", 2}}, 9),
            "e2-5");
  EXPECT_EQ(sonomesh::daemon::event_id_of(nlohmann::json{{"sequence", nullptr}}, 9), "r9");

  ScratchDir dir("hub");
  EventHub hub(
      dir / "journal.jsonl",
      [] {
        return nlohmann::json{{"source", {{"state", "connected"}}}};
      },
      /*capacity=*/3);
  for (int s = 0; s < 5; ++s) hub.publish(nlohmann::json{{"sequence", s}}.dump());
  // Kept: sequences 2, 3, 4 (positions 3-5). Resuming after "3" gives 4; an unknown id gives all.
  EXPECT_EQ(hub.resume_position("3"), 4u);
  auto after = hub.wait_after(hub.resume_position("3"), 10ms);
  ASSERT_EQ(after.size(), 1u);
  EXPECT_EQ(after[0].id, "4");
  EXPECT_EQ(hub.wait_after(hub.resume_position("0"), 10ms).size(), 3u);

  EventStream stream(hub, "2");
  auto chunk = stream.next(10ms);  // the state event comes first
  ASSERT_TRUE(chunk);
  EXPECT_EQ(chunk->rfind("event: state\n", 0), 0u);
  chunk = stream.next(10ms);
  ASSERT_TRUE(chunk);
  EXPECT_EQ(*chunk, "id: 3\ndata: {\"sequence\":3}\n\nid: 4\ndata: {\"sequence\":4}\n\n");
  EXPECT_EQ(*stream.next(10ms), ": keep-alive\n\n");
  hub.stop();
  EXPECT_FALSE(stream.next(10ms));
}

}  // namespace
