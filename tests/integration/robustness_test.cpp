// `sonomeshd run` when things go wrong on disk: bad files in a replay directory, SIGKILL (power
// loss) in the middle of a run followed by a restart on the same out dir, a torn journal line.
#include <gtest/gtest.h>

#include <map>
#include <set>
#include <string>

#include "child_process.h"
#include "daemon/internal/atomic_file.h"
#include "sim/sim.h"
#include "volume/volume.h"

using namespace sonomesh::testing;

namespace {

// Every journal line is a whole JSON object (read_jsonl throws otherwise) and no (epoch,
// sequence) has two lines. Returns sequence -> line for epoch 0.
std::map<std::uint64_t, nlohmann::json> journal_by_sequence(const fs::path& out) {
  std::map<std::uint64_t, nlohmann::json> by_seq;
  std::set<std::pair<std::uint64_t, std::uint64_t>> seen;
  for (const auto& line : read_jsonl(out / "journal.jsonl")) {
    EXPECT_TRUE(line.is_object());
    if (line["sequence"].is_null()) continue;
    const std::uint64_t epoch = line.value("epoch", std::uint64_t{0});
    const auto seq = line["sequence"].get<std::uint64_t>();
    EXPECT_TRUE(seen.insert({epoch, seq}).second) << "twice: " << line.dump();
    if (epoch == 0) by_seq[seq] = line;
  }
  return by_seq;
}

void expect_no_temporaries(const fs::path& out) {
  for (const auto& e : fs::recursive_directory_iterator(out)) {
    EXPECT_FALSE(sonomesh::daemon::is_temporary_name(e.path())) << "left behind: " << e.path();
  }
}

void write_sphere(const fs::path& path, int seed) {
  sonomesh::sim::PhantomSpec spec;
  spec.phantom = "sphere";
  spec.size_vox = 48;
  spec.seed = static_cast<std::uint32_t>(seed);
  const auto phantom = sonomesh::sim::make_phantom(spec);
  ASSERT_FALSE(sonomesh::volume::write_volume(phantom.image, path).has_value()) << path;
}

void write_text(const fs::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
}

std::unique_ptr<Child> start_daemon(const fs::path& dir, const std::string& source,
                                    const std::string& log_name) {
  return std::make_unique<Child>(
      std::vector<std::string>{SONOMESHD_EXE, "run", "--source", source, "--out",
                               (dir / "out").string(), "--http", "off"},
      dir / log_name);
}

}  // namespace

// One bad file is one `rejected` line naming it; the files after it are still processed.
TEST(DaemonRobustness, BadFilesInAReplayDirectoryAreRejectedAndTheRunGoesOn) {
  const ScratchDir dir("badfiles");
  const fs::path vols = dir / "volumes";
  fs::create_directories(vols);
  write_sphere(vols / "v0.nrrd", 1);
  write_text(vols / "v1.nrrd", "this is not a NRRD file\n");
  write_text(vols / "v2.nrrd",  // a good header whose data is cut short
             "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 48 48 48\nencoding: raw\n\nshort");
  write_text(vols / "v3.mha", "ObjectType = Image\nNDims = 3\nDimSize = 4 4\n");
  write_text(vols / "v4.nrrd",  // an image, not a volume
             "NRRD0004\ntype: uint8\ndimension: 2\nsizes: 2 2\nencoding: ascii\n\n1 2 3 4\n");
  write_text(vols / "v5.nrrd", "NRRD0004\n" + std::string(3000, '0') + "\n\n");  // issue 19
  write_sphere(vols / "v6.nrrd", 2);
  auto daemon = start_daemon(dir, "replay:" + vols.string(), "daemon");
  const auto code = daemon->wait(60000ms);
  ASSERT_TRUE(code.has_value()) << "no exit at the end of the replay";
  ASSERT_EQ(*code, 0) << daemon->stderr_text();
  const auto by_seq = journal_by_sequence(dir / "out");
  ASSERT_EQ(by_seq.size(), 7u) << daemon->stderr_text();
  EXPECT_EQ(by_seq.at(0)["status"], "processed") << by_seq.at(0).dump();
  EXPECT_EQ(by_seq.at(6)["status"], "processed") << by_seq.at(6).dump();
  for (std::uint64_t s = 1; s <= 5; ++s) {
    const auto& line = by_seq.at(s);
    EXPECT_EQ(line["status"], "rejected") << line.dump();
    EXPECT_NE(line.value("reason", "").find("v" + std::to_string(s)), std::string::npos)
        << "the reason names the file: " << line.dump();
  }
}

// SIGKILL mid-run, a torn last journal line (what power loss mid-write leaves) and a stale
// temporary; the restart repairs the journal, says so, cleans up and processes every remaining
// volume exactly once.
TEST(DaemonRobustness, SigkillThenRestartGoesOnWithoutProcessingAnythingTwice) {
  const ScratchDir dir("sigkill");
  const fs::path vols = dir / "volumes", out = dir / "out";
  fs::create_directories(vols);
  constexpr int kVolumes = 6;
  for (int i = 0; i < kVolumes; ++i)
    write_sphere(vols / ("v" + std::to_string(i) + ".nrrd"), i + 1);
  auto first = start_daemon(dir, "replay:" + vols.string() + "?rate=4", "first");
  ASSERT_TRUE(wait_until(
      [&] {
        for (const auto& l : read_jsonl(out / "journal.jsonl")) {
          if (l["status"] == "processed") return true;
        }
        return false;
      },
      30000ms))
      << first->stderr_text();
  first->signal(SIGKILL);
  ASSERT_EQ(first->wait(5000ms), -SIGKILL);
  const auto before = journal_by_sequence(out);
  ASSERT_LT(before.size(), static_cast<std::size_t>(kVolumes)) << "killed too late to test";
  const std::string torn = R"({"sequence":5,"status":"proc)";
  {
    std::ofstream j(out / "journal.jsonl", std::ios::app | std::ios::binary);
    j << torn;
  }
  write_text(out / "meshes" / ".9.tmp-99999.ply", "half a mesh");

  auto second = start_daemon(dir, "replay:" + vols.string(), "second");
  const auto code = second->wait(60000ms);
  ASSERT_TRUE(code.has_value());
  ASSERT_EQ(*code, 0) << second->stderr_text();
  const std::string log = second->stderr_text();
  EXPECT_NE(log.find("set aside"), std::string::npos) << log;
  EXPECT_NE(log.find("earlier run"), std::string::npos) << log;
  std::ifstream aside(out / "journal.jsonl.torn");
  std::string aside_text((std::istreambuf_iterator<char>(aside)), {});
  EXPECT_NE(aside_text.find(torn), std::string::npos) << aside_text;

  const auto after = journal_by_sequence(out);
  ASSERT_EQ(after.size(), static_cast<std::size_t>(kVolumes)) << log;
  for (const auto& [seq, line] : before) {
    EXPECT_EQ(after.at(seq), line) << "an earlier line changed or was redone";
  }
  for (const auto& [seq, line] : after) {
    EXPECT_EQ(line["status"], "processed") << line.dump();
    EXPECT_TRUE(fs::exists(out / line["mesh"].get<std::string>())) << line.dump();
  }
  expect_no_temporaries(out);
}

// A live probe goes on while the daemon is down: after the restart the sequences it missed get
// `lost` lines, the ones it had keep theirs, and nothing is journaled twice.
TEST(DaemonRobustness, RestartAgainstALiveProbeAccountsForTheDowntime) {
  const ScratchDir dir("livekill");
  const fs::path out = dir / "out";
  const std::string sock = (dir / "probe.sock").string();
  Child probe({PROBE_SIM_EXE, "serve", "--phantom", "sphere", "--size", "48", "--rate", "8",
               "--listen", "unix:" + sock},
              dir / "probe");
  ASSERT_TRUE(wait_until([&] { return fs::exists(sock); }, 5000ms)) << probe.stderr_text();
  auto processed = [&](std::size_t n) {
    return wait_until(
        [&] {
          std::size_t k = 0;
          for (const auto& l : read_jsonl(out / "journal.jsonl")) k += l["status"] == "processed";
          return k >= n;
        },
        30000ms);
  };
  auto first = start_daemon(dir, "unix:" + sock, "first");
  ASSERT_TRUE(processed(2)) << first->stderr_text();
  first->signal(SIGKILL);
  first->wait(5000ms);
  const auto before = journal_by_sequence(out);
  // Two more processed after the restart, counted against the processed lines (not all lines:
  // how many were skipped before depends on the machine's speed, under ASan most of them).
  std::size_t processed_before = 0;
  for (const auto& [seq, line] : before) processed_before += line["status"] == "processed";
  std::this_thread::sleep_for(600ms);
  auto second = start_daemon(dir, "unix:" + sock, "second");
  ASSERT_TRUE(processed(processed_before + 2)) << second->stderr_text();
  second->signal(SIGTERM);
  ASSERT_EQ(second->wait(15000ms), 0) << second->stderr_text();
  probe.signal(SIGTERM);
  const auto after = journal_by_sequence(out);
  ASSERT_FALSE(after.empty());
  for (std::uint64_t s = 0; s <= after.rbegin()->first; ++s) {
    EXPECT_TRUE(after.count(s)) << "sequence " << s << " has no line";
  }
  for (const auto& [seq, line] : before) EXPECT_EQ(after.at(seq), line);
  expect_no_temporaries(out);
}
