// probe-sim serve: a probe on a socket - phantom volumes or a .usv replay, with fault injection.
#include <netdb.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>
#include <random>
#include <stdexcept>
#include <string>
#include <thread>
#include <variant>
#include <vector>

#include "acquire/protocol.h"
#include "sim/internal/commands.h"
#include "sim/internal/igtl_serve.h"
#include "sim/phantom_source.h"

namespace sonomesh::sim::internal {
namespace {

using Clock = std::chrono::steady_clock;
namespace fs = std::filesystem;

struct ServeArgs {
  std::string phantom;
  std::string replay;
  std::string listen;
  double rate_hz = 10.0;
  int size = 64;
  std::uint64_t count = 0;
  std::uint32_t seed = 1;
  std::string igtl;  // HOST:PORT: an OpenIGTLink server instead of the probe stream
  int igtl_header = 1;
  std::string igtl_device = "Image_Reference";
  bool oblique = false;
  std::string realism;     // empty: as the --phantom URI says (default simple)
  float contrast = -1.0f;  // < 0: as the --phantom URI says
  std::uint64_t corrupt_every = 0;
  std::uint64_t drop_every = 0;
  std::uint64_t truncate_every = 0;
  std::uint64_t disconnect_every = 0;
  int down_ms = 500;
  int heartbeat_ms = 500;
  std::uint32_t fault_seed = 1;
};

void log_line(const std::string& text) { std::cerr << "probe-sim: " + text + "\n" << std::flush; }

// The listening side of unix:PATH / tcp:HOST:PORT.
class Listener {
 public:
  explicit Listener(const std::string& spec) {
    if (spec.rfind("unix:", 0) == 0) {
      path_ = spec.substr(5);
      if (path_.empty() || path_.size() >= sizeof(sockaddr_un{}.sun_path))
        throw std::invalid_argument("--listen " + spec + ": bad socket path");
    } else if (spec.rfind("tcp:", 0) == 0) {
      const std::string rest = spec.substr(4);
      const auto colon = rest.rfind(':');
      if (colon == std::string::npos)
        throw std::invalid_argument("--listen " + spec + ": expected tcp:HOST:PORT");
      host_ = rest.substr(0, colon);
      port_ = rest.substr(colon + 1);
    } else {
      throw std::invalid_argument("--listen " + spec + ": expected unix:PATH or tcp:HOST:PORT");
    }
    spec_ = spec;
  }
  ~Listener() { stop(); }

  void start() {
    if (!path_.empty()) {
      ::unlink(path_.c_str());
      fd_ = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
      sockaddr_un addr{};
      addr.sun_family = AF_UNIX;
      std::memcpy(addr.sun_path, path_.data(), path_.size());
      if (::bind(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0)
        throw std::runtime_error("bind " + spec_ + ": " + std::strerror(errno));
    } else {
      addrinfo hints{};
      hints.ai_family = AF_UNSPEC;
      hints.ai_socktype = SOCK_STREAM;
      hints.ai_flags = AI_PASSIVE;
      addrinfo* list = nullptr;
      if (const int rc = ::getaddrinfo(host_.c_str(), port_.c_str(), &hints, &list); rc != 0)
        throw std::runtime_error(spec_ + ": " + ::gai_strerror(rc));
      fd_ = ::socket(list->ai_family, SOCK_STREAM | SOCK_CLOEXEC, 0);
      const int one = 1;
      ::setsockopt(fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
      const int rc = ::bind(fd_, list->ai_addr, list->ai_addrlen);
      ::freeaddrinfo(list);
      if (rc != 0) throw std::runtime_error("bind " + spec_ + ": " + std::strerror(errno));
    }
    if (::listen(fd_, 1) != 0)
      throw std::runtime_error("listen " + spec_ + ": " + std::strerror(errno));
    log_line("listening on " + spec_);
  }
  void stop() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
    if (!path_.empty()) ::unlink(path_.c_str());
  }
  int accept_client() {
    for (;;) {
      const int c = ::accept4(fd_, nullptr, nullptr, SOCK_CLOEXEC);
      if (c >= 0) return c;
      if (errno != EINTR && errno != ECONNABORTED)
        throw std::runtime_error(std::string("accept: ") + std::strerror(errno));
    }
  }

 private:
  std::string spec_, path_, host_, port_;
  int fd_ = -1;
};

bool send_all(int fd, const std::uint8_t* data, std::size_t size) {
  while (size > 0) {
    const ssize_t n = ::send(fd, data, size, MSG_NOSIGNAL);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    data += n;
    size -= static_cast<std::size_t>(n);
  }
  return true;
}

// Where the volumes come from: phantoms generated on demand or the volumes of a recording.
class VolumeFeed {
 public:
  explicit VolumeFeed(const ServeArgs& args) : args_(args) {
    if (!args.replay.empty()) {
      file_.open(args.replay, std::ios::binary);
      if (!file_) throw std::invalid_argument("--replay " + args.replay + ": cannot open");
    } else {
      auto parsed = parse_sim_uri(args.phantom);
      if (!parsed) throw std::invalid_argument("--phantom: " + parsed.error().detail);
      phantom_ = *parsed;
      phantom_.spec.size_vox = args.size;
      phantom_.spec.seed = args.seed;
      if (args.realism == "echo") phantom_.spec = with_echo_realism(phantom_.spec);
      if (args.contrast >= 0.0f) phantom_.spec.contrast = args.contrast;
      phantom_.spec.oblique = phantom_.spec.oblique || args.oblique;
      phantom_.rate_hz = args.rate_hz > 0 ? args.rate_hz : 10.0;
    }
  }

  /// The next volume to send, or nullopt at the end of a recording.
  std::optional<acquire::RawVolume> next(std::uint64_t sequence) {
    if (args_.replay.empty()) return make_stream_volume(phantom_, sequence);
    for (;;) {
      while (auto event = parser_.next_event()) {
        if (auto* v = std::get_if<acquire::RawVolume>(&*event)) return std::move(*v);
        if (auto* d = std::get_if<acquire::DroppedRecord>(&*event))
          log_line(std::string("replay: skipping a bad record in the recording: ") +
                   acquire::to_string(d->reason));
      }
      if (eof_) return std::nullopt;
      std::vector<std::uint8_t> chunk(1 << 20);
      file_.read(reinterpret_cast<char*>(chunk.data()), static_cast<std::streamsize>(chunk.size()));
      const auto got = static_cast<std::size_t>(file_.gcount());
      parser_.feed(chunk.data(), got);
      if (got < chunk.size()) {
        eof_ = true;
        parser_.finish();
      }
    }
  }

 private:
  const ServeArgs& args_;
  PhantomSourceOptions phantom_;
  std::ifstream file_;
  acquire::StreamParser parser_;
  bool eof_ = false;
};

std::uint64_t now_ns() {
  return static_cast<std::uint64_t>(
      std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch())
          .count());
}

bool due(std::uint64_t n, std::uint64_t every) { return every > 0 && n % every == 0; }

void check_serve_args(const ServeArgs& args) {
  if (args.phantom.empty() == args.replay.empty())
    throw std::invalid_argument("give exactly one of --phantom NAME or --replay PATH");
  if (args.rate_hz < 0 || !std::isfinite(args.rate_hz) ||
      (args.replay.empty() && args.rate_hz == 0))
    throw std::invalid_argument("--rate must be > 0 (or 0 with --replay: recorded timestamps)");
  if (args.size < 16) throw std::invalid_argument("--size must be at least 16");
  if (args.listen.empty() == args.igtl.empty())
    throw std::invalid_argument("give exactly one of --listen (probe stream) or --igtl HOST:PORT");
}

// What became of a volume record handed to the client.
enum class Sent { Ok, Dropped, ClientClosed };

// The probe stream on --listen: one client at a time, paced volumes with heartbeats between them,
// and the fault schedule (1-based over the volume records produced).
class StreamServer {
 public:
  StreamServer(const ServeArgs& args, VolumeFeed& feed)
      : args_(args), feed_(feed), listener_(args.listen), fault_rng_(args.fault_seed) {}

  void run() {
    listener_.start();
    while (!finished_) {
      const int client = listener_.accept_client();
      log_line("client connected");
      // Finished, truncated or the client went away; a disconnect fault closed it already.
      if (!serve_client(client)) ::close(client);
    }
  }

 private:
  // Streams to one client until the stream ends or the connection does; true when a disconnect
  // fault closed the client.
  bool serve_client(int client) {
    const auto start = Clock::now();
    const std::uint64_t start_records = records_;
    first_ts_.reset();  // recorded-timestamp pacing restarts with each client
    last_send_ = Clock::now();
    for (;;) {
      if (end_of_stream(client)) {
        finished_ = true;
        return false;
      }
      const Clock::time_point when = send_time(start, records_ - start_records);
      if (!heartbeat_until(client, when)) return false;
      std::this_thread::sleep_until(when);
      acquire::RawVolume volume = std::move(*pending_);
      pending_.reset();
      const std::uint64_t n = ++records_;
      sequence_ = volume.sequence + 1;
      const Sent sent = send_volume(client, n, volume);
      if (sent == Sent::Dropped) continue;
      if (sent == Sent::ClientClosed) return false;
      last_send_ = Clock::now();
      if (due(n, args_.disconnect_every) && !count_reached()) {
        disconnect(client, volume.sequence);
        return true;
      }
    }
  }

  bool count_reached() const { return args_.count > 0 && records_ >= args_.count; }

  // At the --count limit or the end of the recording: sends end of stream. Else the next volume
  // is pending.
  bool end_of_stream(int client) {
    std::string why;
    if (count_reached()) {
      why = "end of stream after " + std::to_string(records_) + " volumes";
    } else if (!pending_ && !(pending_ = feed_.next(sequence_))) {
      why = "end of stream: recording finished after " + std::to_string(records_) + " volumes";
    } else {
      return false;
    }
    const auto eos = acquire::encode_end_of_stream(sequence_, now_ns());
    send_all(client, eos.data(), eos.size());
    log_line(why);
    return true;
  }

  // Pacing: the k-th volume of this client at a fixed rate, or at the recording's own timestamps.
  Clock::time_point send_time(Clock::time_point start, std::uint64_t k) {
    if (args_.rate_hz > 0)
      return start + std::chrono::nanoseconds(static_cast<std::int64_t>(
                         std::llround(static_cast<double>(k) * 1e9 / args_.rate_hz)));
    if (!first_ts_) first_ts_ = pending_->timestamp_ns;
    return pending_->timestamp_ns < *first_ts_
               ? Clock::now()
               : start + std::chrono::nanoseconds(pending_->timestamp_ns - *first_ts_);
  }

  // Idle until `when`: heartbeats, which also reveal a client that went away (false).
  bool heartbeat_until(int client, Clock::time_point when) {
    const auto period = std::chrono::milliseconds(args_.heartbeat_ms);
    while (Clock::now() + period < when) {
      std::this_thread::sleep_until(std::max(Clock::now(), last_send_ + period));
      if (Clock::now() >= last_send_ + period) {
        const auto hb = acquire::encode_heartbeat(pending_->sequence, now_ns());
        if (!send_all(client, hb.data(), hb.size())) return false;
        last_send_ = Clock::now();
      }
    }
    return true;
  }

  // Record n with its faults: dropped, truncated (then the connection ends), or a flipped bit.
  Sent send_volume(int client, std::uint64_t n, const acquire::RawVolume& volume) {
    const std::uint64_t seq = volume.sequence;
    if (due(n, args_.drop_every)) {
      log_line("fault drop seq=" + std::to_string(seq));
      return Sent::Dropped;
    }
    auto bytes = acquire::encode_volume_record(volume);
    if (!bytes) throw std::runtime_error(bytes.error().detail);
    if (due(n, args_.truncate_every)) {
      log_line("fault truncate seq=" + std::to_string(seq));
      send_all(client, bytes->data(), bytes->size() / 2);
      return Sent::ClientClosed;
    }
    if (due(n, args_.corrupt_every)) corrupt(*bytes, seq);
    if (!send_all(client, bytes->data(), bytes->size())) {
      log_line("client gone at seq=" + std::to_string(seq));
      return Sent::ClientClosed;
    }
    return Sent::Ok;
  }

  // Flips one bit of the header or of the payload.
  void corrupt(std::vector<std::uint8_t>& bytes, std::uint64_t seq) {
    const bool header = fault_rng_() % 2 == 0;
    const std::size_t payload = bytes.size() - acquire::kHeaderBytes - acquire::kPayloadCrcBytes;
    const std::size_t offset = header ? fault_rng_() % acquire::kHeaderBytes
                                      : acquire::kHeaderBytes + fault_rng_() % payload;
    bytes[offset] ^= static_cast<std::uint8_t>(1u << (fault_rng_() % 8));
    log_line("fault corrupt seq=" + std::to_string(seq) +
             " where=" + (header ? "header" : "payload") + " offset=" + std::to_string(offset));
  }

  // Closes the client and stops listening for --down-ms.
  void disconnect(int client, std::uint64_t seq) {
    log_line("fault disconnect seq=" + std::to_string(seq) +
             " down_ms=" + std::to_string(args_.down_ms));
    ::close(client);
    listener_.stop();
    std::this_thread::sleep_for(std::chrono::milliseconds(args_.down_ms));
    listener_.start();
  }

  const ServeArgs& args_;
  VolumeFeed& feed_;
  Listener listener_;
  std::mt19937 fault_rng_;
  std::uint64_t sequence_ = 0;  // next volume's sequence as the probe numbers them
  std::uint64_t records_ = 0;   // volume records produced
  std::optional<acquire::RawVolume> pending_;
  bool finished_ = false;
  std::optional<std::uint64_t> first_ts_;
  Clock::time_point last_send_;
};

int run_serve(const ServeArgs& args) {
  check_serve_args(args);
  ::signal(SIGPIPE, SIG_IGN);
  VolumeFeed feed(args);
  if (!args.igtl.empty()) {
    if (args.corrupt_every || args.drop_every || args.truncate_every || args.disconnect_every)
      throw std::invalid_argument("the fault options apply to --listen only, not --igtl");
    IgtlServeOptions options{args.igtl, args.rate_hz, args.count, args.igtl_header,
                             args.igtl_device};
    return run_igtl_serve(options, [&feed](std::uint64_t sequence) { return feed.next(sequence); });
  }
  if (args.oblique)  // the probe stream's header has no direction: it would be lost silently
    throw std::invalid_argument("--oblique needs --igtl (the probe stream carries no direction)");
  StreamServer server(args, feed);
  server.run();
  return 0;
}

}  // namespace

void add_serve_command(CLI::App& app, int& exit_code) {
  auto args = std::make_shared<ServeArgs>();
  CLI::App* cmd =
      app.add_subcommand("serve", "stream phantom volumes or a .usv recording over a socket");
  auto* phantom = cmd->add_option("--phantom", args->phantom, "phantom name (sphere, torus, ...)");
  auto* replay = cmd->add_option("--replay", args->replay, "a .usv recording to stream");
  phantom->excludes(replay);
  auto* listen =
      cmd->add_option("--listen", args->listen, "unix:PATH or tcp:HOST:PORT (probe stream)");
  cmd->add_option("--igtl", args->igtl,
                  "HOST:PORT: act as a PlusServer, OpenIGTLink IMAGE messages")
      ->excludes(listen);
  cmd->add_option("--igtl-header", args->igtl_header,
                  "OpenIGTLink header version, 1 or 2 (MESSAGE_ID)")
      ->check(CLI::IsMember({1, 2}));
  cmd->add_option("--igtl-device", args->igtl_device, "IMAGE device name");
  cmd->add_flag("--oblique", args->oblique,
                "the grid lies obliquely in the world (sim::oblique_direction)");
  cmd->add_option("--rate", args->rate_hz, "volumes per second (replay: 0 = recorded timestamps)");
  cmd->add_option("--size", args->size, "phantom edge in voxels");
  cmd->add_option("--count", args->count, "volumes before end of stream (0 = endless)");
  cmd->add_option("--seed", args->seed, "phantom random seed");
  cmd->add_option("--realism", args->realism, "image model: simple or echo (a probe's sector view)")
      ->check(CLI::IsMember({"simple", "echo"}));
  cmd->add_option("--contrast", args->contrast, "phantom contrast, 0..1")
      ->check(CLI::Range(0.0, 1.0));
  cmd->add_option("--corrupt-every", args->corrupt_every,
                  "flip a bit in every Nth record (header or payload)");
  cmd->add_option("--drop-every", args->drop_every, "skip every Nth record (a sequence gap)");
  cmd->add_option("--truncate-every", args->truncate_every,
                  "send half of every Nth record, then close");
  cmd->add_option("--disconnect-every", args->disconnect_every,
                  "after every Nth record close and stop listening");
  cmd->add_option("--down-ms", args->down_ms, "how long a --disconnect-every outage lasts");
  cmd->add_option("--heartbeat-ms", args->heartbeat_ms, "heartbeat interval when idle");
  cmd->add_option("--fault-seed", args->fault_seed, "seed of the fault injection choices");
  cmd->callback([args, &exit_code] {
    try {
      exit_code = run_serve(*args);
    } catch (const std::exception& e) {
      std::cerr << "probe-sim serve: " << e.what() << '\n';
      exit_code = 2;
    }
  });
}

}  // namespace sonomesh::sim::internal
