// Socket, replay and recording sources against in-process servers and files.
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <atomic>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <thread>

#include "acquire/acquire.h"
#include "test_util.h"

namespace sonomesh::acquire {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
using test::append;
using test::make_volume;
using test::record;
using OpenResultForTest = tl::expected<std::unique_ptr<Source>, AcquireError>;

fs::path temp_dir() {
  static const fs::path dir = [] {
    fs::path d = fs::temp_directory_path() / ("acquire_test_" + std::to_string(::getpid()));
    fs::create_directories(d);
    return d;
  }();
  return dir;
}

// A listening socket the test writes records to (one client at a time).
class TestServer {
 public:
  explicit TestServer(const fs::path& unix_path) : path_(unix_path) {
    fs::remove(path_);
    fd_ = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    std::strncpy(addr.sun_path, path_.c_str(), sizeof addr.sun_path - 1);
    EXPECT_EQ(::bind(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
    EXPECT_EQ(::listen(fd_, 4), 0);
  }
  explicit TestServer(int /*tcp*/) {
    fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    EXPECT_EQ(::bind(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
    EXPECT_EQ(::listen(fd_, 4), 0);
    socklen_t len = sizeof addr;
    ::getsockname(fd_, reinterpret_cast<sockaddr*>(&addr), &len);
    port_ = ntohs(addr.sin_port);
  }
  ~TestServer() {
    close_client();
    if (fd_ >= 0) ::close(fd_);
    if (!path_.empty()) fs::remove(path_);
  }
  int port() const { return port_; }
  bool accept_client() {
    client_ = ::accept(fd_, nullptr, nullptr);
    return client_ >= 0;
  }
  bool send(const std::vector<std::uint8_t>& bytes) {
    std::size_t off = 0;
    while (off < bytes.size()) {
      const ssize_t n = ::send(client_, bytes.data() + off, bytes.size() - off, MSG_NOSIGNAL);
      if (n <= 0) return false;
      off += static_cast<std::size_t>(n);
    }
    return true;
  }
  void close_client() {
    if (client_ >= 0) ::close(client_);
    client_ = -1;
  }

 private:
  fs::path path_;
  int fd_ = -1;
  int client_ = -1;
  int port_ = 0;
};

// Calls next() until a volume or a non-timeout error arrives (bounded).
tl::expected<RawVolume, AcquireError> next_event(Source& source,
                                                 std::chrono::milliseconds budget = 3s) {
  const auto end = Clock::now() + budget;
  for (;;) {
    auto r = source.next(100ms);
    if (r || r.error().code != AcquireError::Code::Timeout || Clock::now() > end) return r;
  }
}

TEST(SocketSource, UnixReceivesConsecutiveVolumesThenEndOfStream) {
  const fs::path path = temp_dir() / "basic.sock";
  TestServer server(path);
  const int n = 12;
  std::thread writer([&] {
    ASSERT_TRUE(server.accept_client());
    for (int s = 0; s < n; ++s) {
      ASSERT_TRUE(server.send(record(make_volume(100 + s))));
      if (s % 4 == 0) server.send(encode_heartbeat(101 + s, 0));
    }
    server.send(encode_end_of_stream(100 + n, 0));
  });
  auto source = open_source("unix:" + path.string());
  ASSERT_TRUE(source) << to_string(source.error());
  EXPECT_TRUE((*source)->live());
  EXPECT_EQ((*source)->describe(), "unix:" + path.string());
  for (int s = 0; s < n; ++s) {
    auto r = next_event(**source);
    ASSERT_TRUE(r) << to_string(r.error());
    EXPECT_EQ(r->sequence, static_cast<std::uint64_t>(100 + s));
    EXPECT_TRUE(r->voxels == make_volume(100 + s).voxels);
  }
  auto end = next_event(**source);
  ASSERT_FALSE(end);
  EXPECT_EQ(end.error().code, AcquireError::Code::EndOfStream);
  EXPECT_EQ((*source)->next(10ms).error().code, AcquireError::Code::EndOfStream);
  writer.join();
}

TEST(SocketSource, TcpReceivesVolumes) {
  TestServer server(0);
  std::thread writer([&] {
    ASSERT_TRUE(server.accept_client());
    for (int s = 0; s < 5; ++s)
      server.send(record(make_volume(s, {20, 20, 20}, ProbeVoxelType::UInt16)));
  });
  auto source = open_source("tcp:127.0.0.1:" + std::to_string(server.port()));
  ASSERT_TRUE(source) << to_string(source.error());
  for (int s = 0; s < 5; ++s) {
    auto r = next_event(**source);
    ASSERT_TRUE(r) << to_string(r.error());
    EXPECT_EQ(r->sequence, static_cast<std::uint64_t>(s));
    EXPECT_EQ(r->type, ProbeVoxelType::UInt16);
  }
  writer.join();
}

TEST(SocketSource, MissingSocketAndBadUrisAreErrors) {
  auto r = open_source("unix:" + (temp_dir() / "nobody.sock").string());
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code, AcquireError::Code::NotFound);
  EXPECT_EQ(open_source("tcp:localhost").error().code, AcquireError::Code::InvalidArgument);
  EXPECT_EQ(open_source("ftp:x").error().code, AcquireError::Code::InvalidArgument);
  EXPECT_EQ(open_source("nothing").error().code, AcquireError::Code::InvalidArgument);
  EXPECT_EQ(open_source("replay:/nonexistent/x.usv").error().code, AcquireError::Code::NotFound);
}

TEST(SocketSource, ReconnectsAfterServerRestartWithinASecond) {
  const fs::path path = temp_dir() / "restart.sock";
  auto server = std::make_unique<TestServer>(path);
  std::atomic<bool> restarted{false};
  Clock::time_point restart_time;
  std::thread writer([&] {
    ASSERT_TRUE(server->accept_client());
    for (int s = 0; s < 3; ++s) server->send(record(make_volume(s)));
    auto partial = record(make_volume(3));
    partial.resize(partial.size() / 2);
    server->send(partial);  // the link drops mid-record
    std::this_thread::sleep_for(50ms);
    server.reset();  // closes the client and stops listening
    std::this_thread::sleep_for(300ms);
    server = std::make_unique<TestServer>(path);
    restart_time = Clock::now();
    restarted = true;
    ASSERT_TRUE(server->accept_client());
    for (int s = 4; s < 7; ++s) server->send(record(make_volume(s)));
  });
  auto source = open_source("unix:" + path.string());
  ASSERT_TRUE(source) << to_string(source.error());
  for (int s = 0; s < 3; ++s) {
    auto r = next_event(**source);
    ASSERT_TRUE(r) << to_string(r.error());
    EXPECT_EQ(r->sequence, static_cast<std::uint64_t>(s));
  }
  auto incomplete = next_event(**source);
  ASSERT_FALSE(incomplete);
  EXPECT_EQ(incomplete.error().code, AcquireError::Code::Incomplete);
  EXPECT_EQ(incomplete.error().sequence, std::optional<std::uint64_t>(3));
  auto down = next_event(**source);
  ASSERT_FALSE(down);
  EXPECT_EQ(down.error().code, AcquireError::Code::Disconnected);
  for (int s = 4; s < 7; ++s) {
    auto r = next_event(**source);
    ASSERT_TRUE(r) << to_string(r.error());
    EXPECT_EQ(r->sequence, static_cast<std::uint64_t>(s)) << "no Lost: 3 was reported incomplete";
    if (s == 4) {
      ASSERT_TRUE(restarted.load());
      EXPECT_LT(Clock::now() - restart_time, 1s);
    }
  }
  writer.join();
}

TEST(SocketSource, InterruptWakesABlockedNext) {
  const fs::path path = temp_dir() / "interrupt.sock";
  TestServer server(path);
  std::thread acceptor([&] { server.accept_client(); });
  auto source = open_source("unix:" + path.string());
  ASSERT_TRUE(source);
  acceptor.join();
  std::thread waker([&] {
    std::this_thread::sleep_for(50ms);
    (*source)->interrupt();
  });
  const auto start = Clock::now();
  auto r = (*source)->next(10s);
  waker.join();
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code, AcquireError::Code::Timeout);
  EXPECT_LT(Clock::now() - start, 2s);
}

void write_file(const fs::path& path, const std::vector<std::uint8_t>& bytes) {
  std::ofstream out(path, std::ios::binary);
  out.write(reinterpret_cast<const char*>(bytes.data()),
            static_cast<std::streamsize>(bytes.size()));
}

std::vector<std::uint8_t> read_file(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::vector<std::uint8_t>(std::istreambuf_iterator<char>(in), {});
}

TEST(Recording, SocketStreamIsRecordedByteForByteAndReplays) {
  const fs::path path = temp_dir() / "record.sock";
  const fs::path usv = temp_dir() / "record.usv";
  TestServer server(path);
  std::vector<std::uint8_t> sent_volumes;
  for (int s = 0; s < 6; ++s)
    append(sent_volumes,
           record(make_volume(s, {24, 20, 16},
                              s % 2 ? ProbeVoxelType::UInt16 : ProbeVoxelType::UInt8)));
  std::thread writer([&] {
    ASSERT_TRUE(server.accept_client());
    server.send(encode_heartbeat(0, 5));
    server.send(sent_volumes);
    server.send(encode_end_of_stream(6, 0));
  });
  SourceOptions options;
  options.record_path = usv.string();
  auto source = open_source("unix:" + path.string(), options);
  ASSERT_TRUE(source) << to_string(source.error());
  std::vector<RawVolume> received;
  for (;;) {
    auto r = next_event(**source);
    if (!r) {
      ASSERT_EQ(r.error().code, AcquireError::Code::EndOfStream) << to_string(r.error());
      break;
    }
    received.push_back(std::move(*r));
  }
  writer.join();
  ASSERT_EQ(received.size(), 6u);
  const auto file = read_file(usv);
  ASSERT_EQ(file.size(), sent_volumes.size() + 68) << "volumes + end-of-stream record";
  EXPECT_TRUE(std::equal(sent_volumes.begin(), sent_volumes.end(), file.begin()))
      << "the recording holds exactly the volume records the probe sent";

  SourceOptions fast;
  fast.rate_hz = 1000;
  auto replay = open_source("replay:" + usv.string(), fast);
  ASSERT_TRUE(replay) << to_string(replay.error());
  EXPECT_FALSE((*replay)->live());
  for (const RawVolume& want : received) {
    auto r = next_event(**replay);
    ASSERT_TRUE(r) << to_string(r.error());
    EXPECT_EQ(r->sequence, want.sequence);
    EXPECT_TRUE(r->voxels == want.voxels);
    EXPECT_EQ(record(*r), record(want));
  }
  EXPECT_EQ(next_event(**replay).error().code, AcquireError::Code::EndOfStream);
}

TEST(Replay, HonoursRateAndRecordedTimestamps) {
  const fs::path usv = temp_dir() / "paced.usv";
  std::vector<std::uint8_t> bytes;
  const int n = 6;
  for (int s = 0; s < n; ++s) append(bytes, record(make_volume(s, {8, 8, 8})));  // 40 ms apart
  write_file(usv, bytes);
  for (double rate : {0.0, 25.0}) {
    SourceOptions options;
    options.rate_hz = rate;
    auto replay = open_source("replay:" + usv.string(), options);
    ASSERT_TRUE(replay) << to_string(replay.error());
    const auto start = Clock::now();
    for (int s = 0; s < n; ++s) {
      auto r = next_event(**replay);
      ASSERT_TRUE(r) << to_string(r.error());
      EXPECT_EQ(r->sequence, static_cast<std::uint64_t>(s));
    }
    const double elapsed_s = std::chrono::duration<double>(Clock::now() - start).count();
    const double expected_s = rate > 0 ? (n - 1) / rate : (n - 1) * 0.040;
    EXPECT_GE(elapsed_s, expected_s * 0.95) << "rate " << rate;
    EXPECT_LT(elapsed_s, expected_s + 1.0) << "rate " << rate;
    auto end = next_event(**replay);
    EXPECT_EQ(end.error().code, AcquireError::Code::EndOfStream);
  }
  // ?rate= in the URI overrides the option.
  auto replay = open_source("replay:" + usv.string() + "?rate=500");
  ASSERT_TRUE(replay);
  const auto start = Clock::now();
  for (int s = 0; s < n; ++s) ASSERT_TRUE(next_event(**replay));
  EXPECT_LT(Clock::now() - start, 150ms);
  EXPECT_EQ(open_source("replay:" + usv.string() + "?rate=-1").error().code,
            AcquireError::Code::InvalidArgument);
}

TEST(Replay, CorruptRecordingReportsAndContinues) {
  const fs::path usv = temp_dir() / "corrupt.usv";
  std::vector<std::uint8_t> bytes;
  append(bytes, record(make_volume(0, {8, 8, 8})));
  auto bad = record(make_volume(1, {8, 8, 8}));
  bad[100] ^= 0x40;
  append(bytes, bad);
  append(bytes, record(make_volume(2, {8, 8, 8})));
  auto cut = record(make_volume(3, {8, 8, 8}));
  cut.resize(100);
  append(bytes, cut);
  write_file(usv, bytes);
  auto replay = open_source("replay:" + usv.string() + "?rate=1000");
  ASSERT_TRUE(replay);
  EXPECT_EQ(next_event(**replay)->sequence, 0u);
  auto e = next_event(**replay);
  ASSERT_FALSE(e);
  EXPECT_EQ(e.error().code, AcquireError::Code::BadRecord);
  EXPECT_EQ(e.error().sequence, std::optional<std::uint64_t>(1));
  EXPECT_EQ(next_event(**replay)->sequence, 2u);
  e = next_event(**replay);
  EXPECT_EQ(e.error().code, AcquireError::Code::Incomplete);
  EXPECT_EQ(e.error().sequence, std::optional<std::uint64_t>(3));
  EXPECT_EQ(next_event(**replay).error().code, AcquireError::Code::EndOfStream);
}

// The reader's contract only: these files hold .usv records under a volume-file name.
tl::expected<RawVolume, AcquireError> read_record_file(const fs::path& p) {
  StreamParser parser;
  const auto bytes = read_file(p);
  parser.feed(bytes.data(), bytes.size());
  auto e = parser.next_event();
  if (!e || !std::holds_alternative<RawVolume>(*e)) {
    return tl::make_unexpected(AcquireError{AcquireError::Code::BadRecord, 0, "unreadable", {}, 0});
  }
  return std::get<RawVolume>(std::move(*e));
}

TEST(Replay, DirectoryUsesTheRegisteredReaderInNameOrder) {
  const fs::path dir = temp_dir() / "volumes";
  fs::create_directories(dir);
  for (int i : {2, 0, 1}) {
    write_file(dir / ("vol_" + std::to_string(i) + ".nrrd"),
               record(make_volume(50 + i, {8, 8, 8})));
  }
  write_file(dir / "notes.txt", {1, 2, 3});
  // acquire's own replay: knows no volume files.
  EXPECT_EQ(open_source("replay:" + dir.string()).error().code,
            AcquireError::Code::InvalidArgument);
  const SourceOpener opener = replay_opener({{".nrrd"}, read_record_file});
  auto uri = parse_source_uri("replay:" + dir.string());
  ASSERT_TRUE(uri);
  auto replay = opener(*uri, {});
  ASSERT_TRUE(replay) << to_string(replay.error());
  for (int i = 0; i < 3; ++i) {
    auto r = next_event(**replay);
    ASSERT_TRUE(r) << to_string(r.error());
    EXPECT_EQ(r->sequence, static_cast<std::uint64_t>(i)) << "sequence = index in name order";
    EXPECT_TRUE(r->voxels == make_volume(50 + i, {8, 8, 8}).voxels);
  }
  EXPECT_EQ(next_event(**replay).error().code, AcquireError::Code::EndOfStream);
}

TEST(Replay, ExtensionsMatchWholeAndIgnoreCase) {
  const fs::path dir = temp_dir() / "volumes_ext";
  fs::create_directories(dir);
  write_file(dir / "a.NII.GZ", record(make_volume(1, {8, 8, 8})));
  write_file(dir / "b.gz", record(make_volume(2, {8, 8, 8})));
  auto uri = parse_source_uri("replay:" + dir.string() + "?rate=1000");
  ASSERT_TRUE(uri);
  auto replay = replay_opener({{".nii.gz"}, read_record_file})(*uri, {});
  ASSERT_TRUE(replay) << to_string(replay.error());
  EXPECT_TRUE(next_event(**replay).has_value());
  EXPECT_EQ(next_event(**replay).error().code, AcquireError::Code::EndOfStream);
}

TEST(SourceUri, OneParserForEveryScheme) {
  auto uri = parse_source_uri("igtl:localhost:18944?device=Image_Reference&x=");
  ASSERT_TRUE(uri);
  EXPECT_EQ(uri->scheme, "igtl");
  EXPECT_EQ(uri->body, "localhost:18944");
  EXPECT_EQ(uri->query.at("device"), "Image_Reference");
  EXPECT_EQ(uri->query.at("x"), "");
  EXPECT_EQ(parse_source_uri("no-scheme").error().code, AcquireError::Code::InvalidArgument);
  EXPECT_EQ(parse_source_uri("tcp:h:1?a=1&a=2").error().code, AcquireError::Code::InvalidArgument);
  EXPECT_EQ(parse_source_uri("tcp:h:1?=1").error().code, AcquireError::Code::InvalidArgument);
  EXPECT_TRUE(refuse_unknown_keys(*uri, {"device"}).has_value()) << "x is unknown";
  EXPECT_FALSE(refuse_unknown_keys(*parse_source_uri("igtl:h:1?device=a"), {"device"}));
}

TEST(SourceRegistry, SchemesCanBeAddedAndUnknownOnesAreRefused) {
  for (const char* name : {"unix", "tcp", "replay", "usb", "v4l2", "igtl"}) {
    EXPECT_TRUE(find_source_scheme(name).has_value()) << name;
  }
  auto unknown = open_source("nosuch:thing");
  ASSERT_FALSE(unknown);
  EXPECT_EQ(unknown.error().code, AcquireError::Code::InvalidArgument);
  EXPECT_NE(unknown.error().detail.find("igtl:HOST:PORT"), std::string::npos)
      << "the error lists the schemes: " << unknown.error().detail;
  register_source_scheme({"test-one", "test-one:N", false,
                          [](const SourceUri& uri, const SourceOptions&) -> OpenResultForTest {
                            return tl::make_unexpected(AcquireError{
                                AcquireError::Code::NotFound, 0, "body " + uri.body, {}, 0});
                          }});
  auto opened = open_source("test-one:7");
  ASSERT_FALSE(opened);
  EXPECT_EQ(opened.error().detail, "body 7");
  EXPECT_EQ(open_source("tcp:127.0.0.1:1?x=1").error().code, AcquireError::Code::InvalidArgument);
}

}  // namespace
}  // namespace sonomesh::acquire
