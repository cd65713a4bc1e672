// `sonomeshd batch`: a manifest of 30 small volumes with two bad inputs (28 results, 2 recorded
// failures, exit 0); killed half-way and rerun without redoing finished lines; --index runs one
// line; parallel --index runs on one out dir keep results.jsonl whole; a bad manifest exits 2.
#include <gtest/gtest.h>

#include <map>
#include <set>

#include "child_process.h"

namespace {

using namespace sonomesh::testing;

// Three distinct 48³ phantoms from probe-sim, each copied under many names (the batch does not
// care that inputs repeat; their ids differ).
void make_manifest(const fs::path& dir, int good, const fs::path& manifest) {
  const std::vector<std::pair<std::string, int>> kinds = {
      {"sphere", 1}, {"sphere", 2}, {"ellipsoid", 3}};
  std::vector<fs::path> sources;
  for (const auto& [phantom, seed] : kinds) {
    const fs::path vol = dir / (phantom + std::to_string(seed) + ".nrrd");
    Child gen({PROBE_SIM_EXE, "generate", "--phantom", phantom, "--size", "48", "--seed",
               std::to_string(seed), "--out", vol.string(), "--truth",
               (dir / ("truth" + std::to_string(seed) + ".nrrd")).string()},
              dir / "gen");
    ASSERT_EQ(gen.wait(60s), 0) << gen.stderr_text();
    sources.push_back(vol);
  }
  std::ofstream m(manifest);
  for (int i = 0; i < good; ++i) {
    const fs::path input = dir / ("vol" + std::to_string(i) + ".nrrd");
    fs::copy_file(sources[i % sources.size()], input, fs::copy_options::overwrite_existing);
    m << nlohmann::json{{"input", input.filename().string()}, {"seed_index", {24, 24, 24}}}.dump()
      << "\n";
    if (i == good / 2) m << "\n";  // a blank line is not an entry
  }
  std::ofstream(dir / "garbage.nrrd") << "this is not a volume\n";
  m << nlohmann::json{{"input", "garbage.nrrd"}, {"seed_mm", {1, 2, 3}}}.dump() << "\n";
  m << nlohmann::json{{"input", "missing.nrrd"}, {"seed_mm", {1, 2, 3}}, {"id", "missing"}}.dump()
    << "\n";
}

std::vector<std::string> raw_lines(const fs::path& path) {
  std::vector<std::string> lines;
  std::ifstream in(path);
  for (std::string line; std::getline(in, line);) lines.push_back(line);
  return lines;
}

// Every line parses, and each id appears once. Returns id -> line.
std::map<std::string, nlohmann::json> results_by_id(const fs::path& path) {
  std::map<std::string, nlohmann::json> by_id;
  for (const std::string& text : raw_lines(path)) {
    const auto j = nlohmann::json::parse(text, nullptr, false);
    EXPECT_FALSE(j.is_discarded()) << "torn line: " << text;
    if (j.is_discarded()) continue;
    EXPECT_EQ(by_id.count(j["id"]), 0u) << "id twice: " << j["id"];
    by_id[j["id"]] = j;
  }
  return by_id;
}

Child batch(const ScratchDir& dir, const std::vector<std::string>& extra, const std::string& log) {
  std::vector<std::string> argv = {SONOMESHD_EXE, "batch",
                                   "--manifest",  (dir / "manifest.jsonl").string(),
                                   "--out",       (dir / "out").string()};
  argv.insert(argv.end(), extra.begin(), extra.end());
  return Child(argv, dir / log);
}

TEST(Batch, ThirtyInputsTwoBadGiveTwentyEightResultsAndTwoFailures) {
  ScratchDir dir("batch30");
  make_manifest(dir.path(), 28, dir / "manifest.jsonl");
  Child run = batch(dir, {"--jobs", "2"}, "run");
  ASSERT_EQ(run.wait(300s), 0) << run.stderr_text();
  const auto results = results_by_id(dir / "out" / "results.jsonl");
  ASSERT_EQ(results.size(), 30u);
  int processed = 0, failed = 0;
  for (const auto& [id, line] : results) {
    if (line["status"] == "processed") {
      ++processed;
      EXPECT_TRUE(fs::exists(dir / "out" / (id + ".ply"))) << id;
      EXPECT_TRUE(fs::exists(dir / "out" / (id + ".json"))) << id;
      EXPECT_EQ(line["genus"], 0) << id;
      EXPECT_TRUE(line["watertight"].get<bool>()) << id;
    } else {
      ++failed;
      EXPECT_EQ(line["status"], "failed");
      EXPECT_FALSE(line.value("reason", "").empty());
    }
  }
  EXPECT_EQ(processed, 28);
  EXPECT_EQ(failed, 2);
  EXPECT_EQ(results.at("garbage")["status"], "failed");
  EXPECT_EQ(results.at("missing")["status"], "failed");
  EXPECT_EQ(results.at("vol15")["index"], 15);  // the blank line after vol14 is not an entry
}

TEST(Batch, KilledHalfWayResumesWithoutRedoingFinishedLines) {
  ScratchDir dir("batchkill");
  make_manifest(dir.path(), 28, dir / "manifest.jsonl");
  const fs::path results_path = dir / "out" / "results.jsonl";
  {
    Child run = batch(dir, {"--jobs", "1"}, "first");
    ASSERT_TRUE(wait_until([&] { return raw_lines(results_path).size() >= 6; }, 300s));
    run.signal(SIGKILL);
    run.wait(10s);
  }
  const auto before = results_by_id(results_path);
  ASSERT_GE(before.size(), 6u);
  ASSERT_LT(before.size(), 30u) << "finished before the kill; nothing to resume";
  std::map<std::string, fs::file_time_type> written;
  for (const auto& [id, line] : before) {
    if (line["status"] == "processed")
      written[id] = fs::last_write_time(dir / "out" / (id + ".ply"));
  }
  Child rerun = batch(dir, {"--jobs", "2"}, "rerun");
  ASSERT_EQ(rerun.wait(300s), 0) << rerun.stderr_text();
  EXPECT_NE(rerun.stderr_text().find(std::to_string(before.size()) + " already done"),
            std::string::npos)
      << rerun.stderr_text();
  const auto after = results_by_id(results_path);
  EXPECT_EQ(after.size(), 30u);
  for (const auto& [id, time] : written) {
    EXPECT_EQ(fs::last_write_time(dir / "out" / (id + ".ply")), time) << id << " was redone";
    EXPECT_EQ(after.at(id)["time"], before.at(id)["time"]) << id;
  }
}

TEST(Batch, IndexRunsOneLineAndParallelIndexRunsKeepResultsWhole) {
  ScratchDir dir("batchidx");
  make_manifest(dir.path(), 6, dir / "manifest.jsonl");
  {
    Child one = batch(dir, {"--index", "3"}, "one");
    ASSERT_EQ(one.wait(120s), 0) << one.stderr_text();
    const auto results = results_by_id(dir / "out" / "results.jsonl");
    ASSERT_EQ(results.size(), 1u);
    EXPECT_EQ(results.begin()->second["index"], 3);
    EXPECT_EQ(results.begin()->second["id"], "vol3");
  }
  // Indices 0-2, 4-7 two at a time, and index 5 twice at once: one line per id, none torn.
  for (const auto& [a, b] : std::vector<std::pair<int, int>>{{0, 1}, {2, 4}, {5, 5}, {6, 7}}) {
    Child pa = batch(dir, {"--index", std::to_string(a)}, "p" + std::to_string(a));
    Child pb = batch(dir, {"--index", std::to_string(b)}, "q" + std::to_string(b));
    ASSERT_EQ(pa.wait(120s), 0) << pa.stderr_text();
    ASSERT_EQ(pb.wait(120s), 0) << pb.stderr_text();
  }
  const auto results = results_by_id(dir / "out" / "results.jsonl");
  EXPECT_EQ(results.size(), 8u);  // 6 good + garbage + missing
  for (const std::string& text : raw_lines(dir / "out" / "results.jsonl")) {
    EXPECT_FALSE(text.empty());
  }
  Child out_of_range = batch(dir, {"--index", "8"}, "range");
  EXPECT_EQ(out_of_range.wait(30s), 2);
}

TEST(Batch, BadManifestExitsTwoNamingTheLine) {
  ScratchDir dir("batchbad");
  std::ofstream(dir / "manifest.jsonl") << "{\"input\": \"a.nrrd\", \"seed_mm\": [1, 2, 3]}\n"
                                        << "{\"input\": \"b.nrrd\"}\n";
  Child run = batch(dir, {}, "run");
  EXPECT_EQ(run.wait(30s), 2);
  EXPECT_NE(run.stderr_text().find("manifest.jsonl:2:"), std::string::npos) << run.stderr_text();
  EXPECT_FALSE(fs::exists(dir / "out" / "results.jsonl"));
}

}  // namespace
