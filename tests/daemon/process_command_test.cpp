// `sonomeshd process` as a user runs it: a child process on a phantom file.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>

#include "reconstruct/reconstruct.h"
#include "sim/sim.h"
#include "volume/volume.h"

namespace sonomesh::daemon {
namespace {

namespace fs = std::filesystem;

struct Outcome {
  int exit_code = -1;
  std::string stderr_text;
  int stderr_lines() const {
    int lines = 0;
    for (char ch : stderr_text) lines += ch == '\n';
    return lines;
  }
};

class ProcessCommand : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = fs::temp_directory_path() / ("sonomesh_daemon_tests_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
    phantom_ = new sim::Phantom(sim::make_phantom({.phantom = "torus", .size_vox = 48}));
    ASSERT_FALSE(volume::write_volume(phantom_->image, dir_ / "torus.nrrd").has_value());
  }
  static void TearDownTestSuite() {
    delete phantom_;
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }

  // Runs sonomeshd with the arguments (already shell-quoted where needed), after `environment`
  // (NAME=value assignments for the command).
  static Outcome run(const std::string& arguments, const std::string& environment = "") {
    const fs::path err = dir_ / "stderr.txt";
    const std::string command = environment + " '" + SONOMESHD_EXE + "' " + arguments +
                                " >/dev/null 2>'" + err.string() + "'";
    const int status = std::system(command.c_str());
    Outcome outcome;
    outcome.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    std::ifstream in(err);
    std::stringstream text;
    text << in.rdbuf();
    outcome.stderr_text = text.str();
    return outcome;
  }

  static std::string path(const std::string& name) { return "'" + (dir_ / name).string() + "'"; }

  static std::string seed_index() {
    const auto& s = phantom_->seed_index;
    return std::to_string(s.x()) + "," + std::to_string(s.y()) + "," + std::to_string(s.z());
  }

  // A bad input: non-zero exit and exactly one line on stderr.
  static void expect_one_line_failure(const std::string& arguments, const std::string& mentions) {
    const Outcome outcome = run(arguments);
    EXPECT_NE(outcome.exit_code, 0) << arguments;
    EXPECT_LT(outcome.exit_code, 128) << "crashed: " << outcome.stderr_text;
    EXPECT_EQ(outcome.stderr_lines(), 1) << outcome.stderr_text;
    EXPECT_NE(outcome.stderr_text.find(mentions), std::string::npos) << outcome.stderr_text;
  }

  static inline fs::path dir_;
  static inline sim::Phantom* phantom_ = nullptr;
};

TEST_F(ProcessCommand, WritesEveryOutputAndTheReport) {
  const Outcome outcome =
      run("process " + path("torus.nrrd") + " --seed-index " + seed_index() + " --mesh " +
          path("mesh.ply") + " --labels " + path("labels.nrrd") + " --report " +
          path("report.json") + " --balloon " + path("balloon.ply") + " --vdb " + path("chi.vdb"));
  ASSERT_EQ(outcome.exit_code, 0) << outcome.stderr_text;
  EXPECT_EQ(outcome.stderr_text, "");

  const auto mesh = reconstruct::read_ply(dir_ / "mesh.ply");
  ASSERT_TRUE(mesh) << mesh.error->message;
  const reconstruct::Topology topology = reconstruct::analyze_topology(mesh.mesh);
  // The topology itself is the pipeline tests' subject; here the file and the report must agree.
  EXPECT_TRUE(topology.watertight);

  const auto balloon = reconstruct::read_ply(dir_ / "balloon.ply");
  ASSERT_TRUE(balloon) << balloon.error->message;
  EXPECT_EQ(balloon.stop.size(), balloon.mesh.vertices.size());
  for (std::uint8_t code : balloon.stop) EXPECT_LE(code, 4);

  const auto labels = volume::read_volume(dir_ / "labels.nrrd");
  ASSERT_TRUE(labels) << labels.error->message;
  EXPECT_EQ(labels.volume.dims(), phantom_->image.dims());
  EXPECT_EQ(labels.volume.type(), volume::VoxelType::UInt8);

  EXPECT_GT(fs::file_size(dir_ / "chi.vdb"), 0u);

  std::ifstream in(dir_ / "report.json");
  const nlohmann::json report = nlohmann::json::parse(in);
  EXPECT_TRUE(report.at("ok").get<bool>());
  EXPECT_TRUE(report.at("input").contains("path"));
  EXPECT_EQ(report.at("seed").at("index").size(), 3u);
  EXPECT_EQ(report.at("seed").at("mm").size(), 3u);
  for (const char* stage : {"smooth", "balloon", "opening", "reconstruct", "mesh", "total"})
    EXPECT_GE(report.at("timings_ms").at(stage).get<double>(), 0.0) << stage;
  EXPECT_GT(report.at("balloon").at("iterations").get<int>(), 0);
  for (const char* reason :
       {"moving", "boundary", "curvature", "self_intersection", "iteration_limit"})
    EXPECT_TRUE(report.at("balloon").at("stop_reasons").contains(reason)) << reason;
  EXPECT_EQ(report.at("reconstruction").at("grid").size(), 3u);
  const auto& m = report.at("mesh");
  EXPECT_EQ(m.at("vertices").get<std::size_t>(), mesh.mesh.vertices.size());
  EXPECT_EQ(m.at("faces").get<std::size_t>(), mesh.mesh.triangles.size());
  EXPECT_EQ(m.at("components").get<int>(), 1);
  EXPECT_EQ(m.at("genus").get<int>(), topology.genus);
  EXPECT_TRUE(m.at("watertight").get<bool>());
  EXPECT_GT(m.at("volume_ml").get<double>(), 0.0);
}

// glibc's MALLOC_PERTURB_ fills every fresh heap block with its byte: a value read before it is
// written then differs between the two runs. This echo phantom's balloon restarts from a mesh with
// stopped vertices, where a face normal was once read unset (tomaat: 4-6 leak seals and 790-1011
// iterations from run to run).
TEST_F(ProcessCommand, TheResultDoesNotDependOnWhatTheHeapHeld) {
  const sim::Phantom echo = sim::make_phantom(
      sim::with_echo_realism({.phantom = "cyst-needle", .size_vox = 64, .contrast = 0.5f}));
  ASSERT_FALSE(volume::write_volume(echo.image, dir_ / "echo.nrrd").has_value());
  const auto& s = echo.seed_index;
  const std::string seed =
      std::to_string(s.x()) + "," + std::to_string(s.y()) + "," + std::to_string(s.z());
  std::string bytes[2];
  for (int run_index = 0; run_index < 2; ++run_index) {
    const std::string mesh = "perturbed" + std::to_string(run_index) + ".ply";
    const Outcome outcome =
        run("process " + path("echo.nrrd") + " --seed-index " + seed + " --mesh " + path(mesh),
            run_index == 0 ? "MALLOC_PERTURB_=90" : "MALLOC_PERTURB_=165");
    ASSERT_LT(outcome.exit_code, 128) << outcome.stderr_text;
    std::ifstream in(dir_ / mesh, std::ios::binary);
    bytes[run_index].assign(std::istreambuf_iterator<char>(in), {});
  }
  EXPECT_FALSE(bytes[0].empty());
  EXPECT_TRUE(bytes[0] == bytes[1]) << "the two runs wrote different meshes";
}

TEST_F(ProcessCommand, AcceptsASeedInMillimetres) {
  const volume::Vec3f& s = phantom_->seed_mm;
  std::ostringstream seed;
  seed << s.x() << "," << s.y() << "," << s.z();
  const Outcome outcome = run("process " + path("torus.nrrd") + " --seed-mm " + seed.str() +
                              " --mesh " + path("mesh_mm.ply"));
  EXPECT_EQ(outcome.exit_code, 0) << outcome.stderr_text;
  EXPECT_TRUE(fs::exists(dir_ / "mesh_mm.ply"));
}

TEST_F(ProcessCommand, MissingFileIsOneLine) {
  expect_one_line_failure(
      "process " + path("nope.nrrd") + " --seed-index 1,2,3 --mesh " + path("m.ply"), "nope.nrrd");
}

TEST_F(ProcessCommand, WrongFormatIsOneLine) {
  std::ofstream(dir_ / "text.nrrd") << "this is not a volume\njust text\n";
  expect_one_line_failure(
      "process " + path("text.nrrd") + " --seed-index 1,2,3 --mesh " + path("m.ply"), "text.nrrd");
}

TEST_F(ProcessCommand, TruncatedDataIsOneLine) {
  fs::copy_file(dir_ / "torus.nrrd", dir_ / "cut.nrrd", fs::copy_options::overwrite_existing);
  fs::resize_file(dir_ / "cut.nrrd", fs::file_size(dir_ / "cut.nrrd") / 2);
  expect_one_line_failure(
      "process " + path("cut.nrrd") + " --seed-index " + seed_index() + " --mesh " + path("m.ply"),
      "cut.nrrd");
}

TEST_F(ProcessCommand, SeedOutsideTheVolumeIsOneLine) {
  expect_one_line_failure(
      "process " + path("torus.nrrd") + " --seed-index 100,5,5 --mesh " + path("m.ply"),
      "outside the volume");
  expect_one_line_failure(
      "process " + path("torus.nrrd") + " --seed-mm -50,0,0 --mesh " + path("m.ply"),
      "outside the volume");
}

TEST_F(ProcessCommand, SeedInBrightTissueIsOneLine) {
  expect_one_line_failure(
      "process " + path("torus.nrrd") + " --seed-index 3,3,3 --mesh " + path("m.ply"),
      "bright tissue");
}

TEST_F(ProcessCommand, UnwritableOutputIsOneLine) {
  expect_one_line_failure("process " + path("torus.nrrd") + " --seed-index " + seed_index() +
                              " --mesh /nonexistent_dir_sonomesh/m.ply",
                          "/nonexistent_dir_sonomesh");
}

TEST_F(ProcessCommand, BadArgumentsAreOneLine) {
  const std::string input = "process " + path("torus.nrrd");
  expect_one_line_failure(input + " --mesh " + path("m.ply"), "seed");
  expect_one_line_failure(input + " --seed-index 1,2,3 --seed-mm 1,2,3 --mesh " + path("m.ply"),
                          "seed");
  expect_one_line_failure(input + " --seed-index 1,2 --mesh " + path("m.ply"), "--seed-index");
  expect_one_line_failure(input + " --seed-index 1,2,3", "--mesh");
  expect_one_line_failure(input + " --seed-index 1,2,3 --mesh " + path("m.ply") + " --bogus",
                          "bogus");
  expect_one_line_failure("", "subcommand");
}

// --config applies the run configuration's pipeline tables; --target overrides its target.
TEST_F(ProcessCommand, ConfigFileSetsThePipeline) {
  {
    std::ofstream toml(dir_ / "few.toml");
    toml << "[pipeline]\ntarget = \"bright\"\n[pipeline.balloon]\nmax_iterations = 3\n";
  }
  run("process " + path("torus.nrrd") + " --seed-index " + seed_index() + " --mesh " +
      path("few.ply") + " --report " + path("few.json") + " --config " + path("few.toml") +
      " --target dark");
  std::ifstream in(dir_ / "few.json");
  const nlohmann::json report = nlohmann::json::parse(in);
  EXPECT_LE(report.at("balloon").at("iterations").get<int>(), 3);
  EXPECT_EQ(report.at("target"), "dark");
  {
    std::ofstream toml(dir_ / "bad.toml");
    toml << "[pipeline.balloon]\nlevel_stop_fraction = 2.0\n";
  }
  expect_one_line_failure("process " + path("torus.nrrd") + " --seed-index " + seed_index() +
                              " --mesh " + path("bad.ply") + " --config " + path("bad.toml"),
                          "level_stop_fraction");
}

TEST_F(ProcessCommand, HelpStillWorks) { EXPECT_EQ(run("process --help").exit_code, 0); }

}  // namespace
}  // namespace sonomesh::daemon
