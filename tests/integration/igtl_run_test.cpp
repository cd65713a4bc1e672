// `sonomeshd run --source igtl:...` end to end: a hand-written OpenIGTLink server in the test
// sends a phantom as IMAGE messages (and a bad one); the daemon's journal is read back.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <thread>

#include "../acquire/igtl_test_server.h"
#include "sim/sim.h"

extern char** environ;

namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using sonomesh::acquire::test::Bytes;
using sonomesh::acquire::test::IgtlTestServer;
using sonomesh::acquire::test::ImageSpec;
using sonomesh::acquire::test::MessageSpec;

std::vector<nlohmann::json> journal(const fs::path& out) {
  std::vector<nlohmann::json> lines;
  std::ifstream in(out / "journal.jsonl");
  std::string line;
  while (std::getline(in, line)) {
    if (!line.empty()) lines.push_back(nlohmann::json::parse(line));
  }
  return lines;
}

// A phantom as an IMAGE message in LPS (identity directions): the centre is the grid's middle.
Bytes phantom_image(const sonomesh::sim::Phantom& phantom, const MessageSpec& m) {
  const auto& v = phantom.image;
  ImageSpec s;
  for (int a = 0; a < 3; ++a) {
    s.size[a] = v.dims()[a];
    s.columns[a] = {0, 0, 0};
    s.columns[a][a] = v.spacing_mm()[a];
    s.centre[a] = v.origin_mm()[a] + v.spacing_mm()[a] * (v.dims()[a] - 1) / 2.0f;
  }
  const Bytes voxels(v.u8().begin(), v.u8().end());
  return sonomesh::acquire::test::message(m, sonomesh::acquire::test::image_content(s, &voxels));
}

TEST(DaemonRunIgtl, ImagesAreProcessedAndUnusableOnesRejected) {
  const fs::path dir = fs::path("/tmp") / ("smi_igtl_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  sonomesh::sim::PhantomSpec spec;
  spec.phantom = "sphere";
  spec.size_vox = 48;
  const auto phantom = sonomesh::sim::make_phantom(spec);
  ImageSpec int16;
  int16.scalar = 4;
  MessageSpec v2{.version = 2, .message_id = 1};
  Bytes script = phantom_image(phantom, v2);
  MessageSpec bad{.version = 2, .message_id = 2};
  const Bytes rejected = sonomesh::acquire::test::message(bad, image_content(int16));
  script.insert(script.end(), rejected.begin(), rejected.end());
  v2.message_id = 4;  // id 3 never arrives: one lost line
  const Bytes last = phantom_image(phantom, v2);
  script.insert(script.end(), last.begin(), last.end());
  IgtlTestServer server(script);
  ASSERT_TRUE(server.ok());

  const auto& seed = phantom.seed_mm;
  const std::string seed_text =
      std::to_string(seed.x()) + "," + std::to_string(seed.y()) + "," + std::to_string(seed.z());
  std::vector<std::string> argv{SONOMESHD_EXE, "run",
                                "--source",    server.uri("?device=Image_Reference"),
                                "--out",       (dir / "out").string(),
                                "--http",      "off",
                                "--seed-mm",   seed_text};
  std::vector<char*> args;
  for (auto& a : argv) args.push_back(a.data());
  args.push_back(nullptr);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  const std::string err_path = (dir / "daemon.err").string();
  posix_spawn_file_actions_addopen(&actions, 2, err_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC,
                                   0644);
  pid_t pid = -1;
  ASSERT_EQ(posix_spawn(&pid, args[0], &actions, nullptr, args.data(), environ), 0);
  posix_spawn_file_actions_destroy(&actions);

  // Four lines: 0 processed (or superseded), 1 rejected, 2 lost, 3 processed.
  const auto until = std::chrono::steady_clock::now() + 60s;
  while (journal(dir / "out").size() < 4 && std::chrono::steady_clock::now() < until) {
    std::this_thread::sleep_for(50ms);
  }
  ::kill(pid, SIGTERM);
  int status = 0;
  ::waitpid(pid, &status, 0);
  std::ifstream err_in(err_path);
  const std::string err((std::istreambuf_iterator<char>(err_in)), {});
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << err;

  std::map<std::uint64_t, nlohmann::json> by_seq;
  for (const auto& line : journal(dir / "out"))
    by_seq[line["sequence"].get<std::uint64_t>()] = line;
  ASSERT_EQ(by_seq.size(), 4u) << err;
  // A live source keeps the newest volume: the first image is superseded by the last when the
  // worker has not taken it yet (the script arrives at once; seen on a loaded machine), and is
  // accounted for either way.
  if (by_seq[0]["status"] == "skipped") {
    EXPECT_EQ(by_seq[0]["reason"], "superseded") << by_seq[0].dump();
  } else {
    EXPECT_EQ(by_seq[0]["status"], "processed") << by_seq[0].dump();
    EXPECT_EQ(by_seq[0]["genus"], 0) << by_seq[0].dump();
  }
  EXPECT_EQ(by_seq[1]["status"], "rejected") << by_seq[1].dump();
  EXPECT_NE(by_seq[1]["reason"].get<std::string>().find("int16"), std::string::npos);
  EXPECT_EQ(by_seq[2]["status"], "lost") << by_seq[2].dump();
  EXPECT_EQ(by_seq[3]["status"], "processed") << by_seq[3].dump();
  EXPECT_EQ(by_seq[3]["genus"], 0) << by_seq[3].dump();
  if (!::testing::Test::HasFailure()) fs::remove_all(dir);
}

}  // namespace
