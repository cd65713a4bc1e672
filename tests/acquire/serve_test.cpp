// probe-sim serve in a child process, read by the socket source: clean streams, every injected
// fault accounted for, and a served replay of a recording.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "acquire/acquire.h"

namespace sonomesh::acquire {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

fs::path temp_dir() {
  static const fs::path dir = [] {
    fs::path d = fs::temp_directory_path() / ("acquire_serve_test_" + std::to_string(::getpid()));
    fs::create_directories(d);
    return d;
  }();
  return dir;
}

// probe-sim as a child process, its stderr captured to a file.
class ProbeSim {
 public:
  ProbeSim(std::vector<std::string> args, const fs::path& log) : log_(log) {
    args.insert(args.begin(), {PROBE_SIM_PATH, "serve"});
    pid_ = ::fork();
    if (pid_ == 0) {
      const int fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      ::dup2(fd, 2);
      std::vector<char*> argv;
      for (auto& a : args) argv.push_back(a.data());
      argv.push_back(nullptr);
      ::execv(argv[0], argv.data());
      ::_exit(127);
    }
  }
  ~ProbeSim() {
    if (pid_ > 0 && !reaped_) {
      ::kill(pid_, SIGTERM);
      ::waitpid(pid_, nullptr, 0);
    }
  }
  int wait() {
    int status = 0;
    ::waitpid(pid_, &status, 0);
    reaped_ = true;
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  }
  std::string log() const {
    std::ifstream in(log_);
    return std::string(std::istreambuf_iterator<char>(in), {});
  }

 private:
  fs::path log_;
  pid_t pid_ = -1;
  bool reaped_ = false;
};

// open_source with retries while the child starts listening.
std::unique_ptr<Source> connect(const std::string& uri, const SourceOptions& options = {}) {
  const auto end = Clock::now() + 10s;
  for (;;) {
    auto source = open_source(uri, options);
    if (source) return std::move(*source);
    if (Clock::now() > end) {
      ADD_FAILURE() << to_string(source.error());
      return nullptr;
    }
    std::this_thread::sleep_for(20ms);
  }
}

struct Tally {
  std::vector<RawVolume> volumes;
  std::map<std::uint64_t, int> accounted;  // sequence -> times reported
  int bad_records = 0, incomplete = 0, lost_events = 0, disconnects = 0, unsequenced_bad = 0;
  bool ended = false;
};

Tally drain(Source& source, std::chrono::seconds budget = 20s) {
  Tally t;
  const auto end = Clock::now() + budget;
  while (Clock::now() < end) {
    auto r = source.next(200ms);
    if (r) {
      ++t.accounted[r->sequence];
      t.volumes.push_back(std::move(*r));
      continue;
    }
    const AcquireError& e = r.error();
    switch (e.code) {
      case AcquireError::Code::Timeout:
        break;
      case AcquireError::Code::EndOfStream:
        t.ended = true;
        return t;
      case AcquireError::Code::Disconnected:
        ++t.disconnects;
        break;
      case AcquireError::Code::Lost:
        ++t.lost_events;
        for (std::uint64_t s = 0; s < e.count; ++s) ++t.accounted[*e.sequence + s];
        break;
      case AcquireError::Code::BadRecord:
      case AcquireError::Code::Incomplete:
        (e.code == AcquireError::Code::BadRecord ? t.bad_records : t.incomplete)++;
        if (e.sequence)
          ++t.accounted[*e.sequence];
        else
          ++t.unsequenced_bad;
        break;
      default:
        ADD_FAILURE() << "unexpected " << to_string(e);
        return t;
    }
  }
  ADD_FAILURE() << "stream did not end within the budget";
  return t;
}

int count_lines(const std::string& log, const std::string& what) {
  int n = 0;
  for (std::size_t p = log.find(what); p != std::string::npos; p = log.find(what, p + 1)) ++n;
  return n;
}

TEST(ProbeSimServe, StreamsConsecutiveVolumes) {
  const fs::path sock = temp_dir() / "clean.sock";
  ProbeSim sim({"--phantom", "sphere", "--size", "32", "--rate", "100", "--count", "25", "--listen",
                "unix:" + sock.string()},
               temp_dir() / "clean.log");
  auto source = connect("unix:" + sock.string());
  ASSERT_TRUE(source);
  const Tally t = drain(*source);
  EXPECT_TRUE(t.ended);
  ASSERT_EQ(t.volumes.size(), 25u);
  for (std::size_t i = 0; i < t.volumes.size(); ++i) {
    EXPECT_EQ(t.volumes[i].sequence, i);
    EXPECT_EQ(t.volumes[i].dims, (std::array<int, 3>{32, 32, 32}));
  }
  EXPECT_NE(t.volumes.front().voxels, t.volumes.back().voxels) << "the target moves";
  EXPECT_EQ(sim.wait(), 0);
}

TEST(ProbeSimServe, EveryInjectedFaultIsAccountedAndNoGoodVolumeLost) {
  const fs::path sock = temp_dir() / "faults.sock";
  const int count = 60;
  ProbeSim sim({"--phantom",
                "torus",
                "--size",
                "32",
                "--rate",
                "200",
                "--count",
                std::to_string(count),
                "--listen",
                "unix:" + sock.string(),
                "--corrupt-every",
                "7",
                "--drop-every",
                "11",
                "--truncate-every",
                "17",
                "--disconnect-every",
                "23",
                "--down-ms",
                "200",
                "--fault-seed",
                "3"},
               temp_dir() / "faults.log");
  auto source = connect("unix:" + sock.string());
  ASSERT_TRUE(source);
  const Tally t = drain(*source);
  EXPECT_EQ(sim.wait(), 0);
  const std::string log = sim.log();
  const int corrupt = count_lines(log, "fault corrupt");
  const int drop = count_lines(log, "fault drop");
  const int truncate = count_lines(log, "fault truncate");
  const int disconnect = count_lines(log, "fault disconnect");
  ASSERT_GT(corrupt, 0);
  ASSERT_GT(drop, 0);
  ASSERT_GT(truncate, 0);
  ASSERT_GT(disconnect, 0);
  EXPECT_TRUE(t.ended);
  // Every sequence sent is accounted for exactly once: a good volume, a bad record, an
  // incomplete record or a lost one.
  for (int s = 0; s < count; ++s) {
    EXPECT_EQ(t.accounted.count(s) ? t.accounted.at(s) : 0, 1) << "sequence " << s << "\n" << log;
  }
  EXPECT_EQ(t.accounted.size(), static_cast<std::size_t>(count));
  EXPECT_EQ(t.volumes.size() + static_cast<std::size_t>(corrupt + drop + truncate),
            static_cast<std::size_t>(count))
      << "good volumes received + faults accounted == records sent\n"
      << log;
  EXPECT_EQ(t.incomplete, truncate);
  EXPECT_EQ(t.disconnects, truncate + disconnect);
  // No good volume lost: every sequence the log names as faulty is missing, every other arrived.
  std::set<std::uint64_t> faulty;
  const std::regex fault_re("fault (corrupt|drop|truncate) seq=([0-9]+)");
  for (auto it = std::sregex_iterator(log.begin(), log.end(), fault_re);
       it != std::sregex_iterator(); ++it) {
    faulty.insert(std::stoull((*it)[2]));
  }
  std::set<std::uint64_t> received;
  for (const auto& v : t.volumes) received.insert(v.sequence);
  for (int s = 0; s < count; ++s) {
    EXPECT_NE(faulty.count(s) > 0, received.count(s) > 0) << "sequence " << s;
  }
}

TEST(ProbeSimServe, ServesARecordingItWasRecordedFrom) {
  const fs::path sock = temp_dir() / "rec.sock";
  const fs::path usv = temp_dir() / "rec.usv";
  std::vector<RawVolume> first;
  {
    ProbeSim sim({"--phantom", "ellipsoid", "--size", "24", "--rate", "100", "--count", "8",
                  "--listen", "unix:" + sock.string()},
                 temp_dir() / "rec1.log");
    SourceOptions options;
    options.record_path = usv.string();
    auto source = connect("unix:" + sock.string(), options);
    ASSERT_TRUE(source);
    Tally t = drain(*source);
    ASSERT_EQ(t.volumes.size(), 8u);
    first = std::move(t.volumes);
    EXPECT_EQ(sim.wait(), 0);
  }
  ProbeSim sim({"--replay", usv.string(), "--rate", "0", "--listen", "unix:" + sock.string()},
               temp_dir() / "rec2.log");
  auto source = connect("unix:" + sock.string());
  ASSERT_TRUE(source);
  const Tally t = drain(*source);
  EXPECT_TRUE(t.ended);
  ASSERT_EQ(t.volumes.size(), first.size());
  for (std::size_t i = 0; i < first.size(); ++i) {
    EXPECT_EQ(t.volumes[i].sequence, first[i].sequence);
    EXPECT_EQ(t.volumes[i].timestamp_ns, first[i].timestamp_ns);
    EXPECT_TRUE(t.volumes[i].voxels == first[i].voxels);
  }
  EXPECT_EQ(sim.wait(), 0);
}

TEST(ProbeSimServe, BadArgumentsGiveOneLineAndNonZeroExit) {
  ProbeSim sim({"--phantom", "banana", "--listen", "unix:" + (temp_dir() / "x.sock").string()},
               temp_dir() / "bad.log");
  EXPECT_NE(sim.wait(), 0);
  const std::string log = sim.log();
  EXPECT_NE(log.find("banana"), std::string::npos) << log;
  EXPECT_EQ(std::count(log.begin(), log.end(), '\n'), 1) << log;
}

}  // namespace
}  // namespace sonomesh::acquire
