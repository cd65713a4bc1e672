// The daemon's parts in isolation: the seed policy, the option table, the bounded queue's modes,
// the recorder's hand-over to sinks, and the quality verdict in /status and /metrics.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <set>

#include "daemon/internal/bounded_queue.h"
#include "daemon/internal/recorder.h"
#include "daemon/internal/run_config.h"
#include "daemon/internal/run_options.h"
#include "daemon/internal/run_stats.h"
#include "daemon/internal/seed_policy.h"
#include "prometheus_parse.h"

namespace fs = std::filesystem;
using namespace sonomesh::daemon;

namespace {

SeedInputs inputs_with(std::optional<SeedMm> override_mm, std::optional<SeedMm> configured,
                       std::optional<SeedMm> phantom) {
  SeedInputs in;
  in.override_mm = override_mm;
  in.configured_mm = configured;
  in.phantom_mm = phantom;
  in.centre_mm = {9, 9, 9};
  return in;
}

std::vector<SeedOrigin> origins(const std::vector<SeedCandidate>& c) {
  std::vector<SeedOrigin> out;
  for (const auto& x : c) out.push_back(x.origin);
  return out;
}

}  // namespace

TEST(SeedPolicy, PrefersTrackedThenConfiguredPhantomCentre) {
  SeedPolicy p;
  auto c = p.candidates(inputs_with(std::nullopt, SeedMm{1, 1, 1}, SeedMm{2, 2, 2}));
  EXPECT_EQ(origins(c), (std::vector<SeedOrigin>{SeedOrigin::Configured, SeedOrigin::Phantom,
                                                 SeedOrigin::Centre}));
  p.on_result(SeedMm{5, 5, 5}, false);
  c = p.candidates(inputs_with(std::nullopt, std::nullopt, std::nullopt));
  ASSERT_EQ(c.size(), 2u);
  EXPECT_EQ(c[0].origin, SeedOrigin::Tracked);
  EXPECT_EQ(c[0].mm, (SeedMm{5, 5, 5}));
  EXPECT_EQ(c[1].origin, SeedOrigin::Centre);
}

TEST(SeedPolicy, AnOverrideEndsTrackingAndWinsOverTheNextResult) {
  SeedPolicy p;
  p.on_result(SeedMm{5, 5, 5}, false);
  auto c = p.candidates(inputs_with(SeedMm{7, 7, 7}, std::nullopt, std::nullopt));
  EXPECT_EQ(c[0].mm, (SeedMm{7, 7, 7}));
  EXPECT_EQ(c[0].origin, SeedOrigin::Configured);
  EXPECT_FALSE(p.tracked().has_value());
  // A result that finishes while another override waits does not become the tracked seed.
  p.on_result(SeedMm{6, 6, 6}, true);
  EXPECT_FALSE(p.tracked().has_value());
  p.on_result(SeedMm{6, 6, 6}, false);
  EXPECT_EQ(*p.tracked(), (SeedMm{6, 6, 6}));
}

TEST(SeedPolicy, ChooseTakesTheFirstAcceptedAndListsTheRefused) {
  const std::vector<SeedCandidate> c{{{1, 1, 1}, SeedOrigin::Tracked},
                                     {{2, 2, 2}, SeedOrigin::Configured},
                                     {{3, 3, 3}, SeedOrigin::Centre}};
  const SeedChoice choice = choose_seed(c, [](const SeedMm& mm) -> std::optional<std::string> {
    if (mm[0] < 2.5f) return "bright tissue";
    return std::nullopt;
  });
  ASSERT_TRUE(choice.chosen);
  EXPECT_EQ(choice.chosen->origin, SeedOrigin::Centre);
  ASSERT_EQ(choice.refused.size(), 2u);
  EXPECT_EQ(choice.refused[0].second, "bright tissue");
  const SeedChoice none =
      choose_seed(c, [](const SeedMm&) { return std::optional<std::string>("outside"); });
  EXPECT_FALSE(none.chosen);
  EXPECT_EQ(none.refused.size(), 3u);
}

TEST(BoundedQueue, DropOldestKeepsTheNewestCapacityItems) {
  BoundedQueue<int> q(2, QueueMode::DropOldest);
  EXPECT_TRUE(q.push(1).empty());
  EXPECT_TRUE(q.push(2).empty());
  EXPECT_EQ(q.push(3), std::vector<int>{1});
  EXPECT_EQ(q.size(), 2u);
  EXPECT_EQ(*q.pop(std::chrono::milliseconds(0)), 2);
  EXPECT_EQ(*q.pop(std::chrono::milliseconds(0)), 3);
}

// ---------------------------------------------------------------------------------------------
// The option table: a configuration that loads always runs.

TEST(RunOptions, ValuesTheLibraryRefusesAreRefusedAtLoadNamingTheOption) {
  struct Case {
    const char* text;
    const char* option;
  };
  const Case cases[] = {
      {"[pipeline.balloon]\ninitial_radius_vox = 0.5\n", "pipeline.balloon.initial_radius_vox"},
      {"[pipeline.balloon]\ntau_curv = 0\n", "pipeline.balloon.tau_curv"},
      {"[pipeline.balloon]\nsnap_back_vox = 4\nsnap_ahead_vox = 5\n", "snap_ahead_vox"},
      {"[pipeline.balloon]\ntau_cost_fraction = 1\n", "pipeline.balloon.tau_cost_fraction"},
      {"[pipeline]\ntarget = \"grey\"\n", "pipeline.target"},
  };
  for (const Case& c : cases) {
    RunConfig config;
    const auto err = load_config_text(c.text, "f.toml", config);
    ASSERT_TRUE(err.has_value()) << c.text;
    EXPECT_NE(err->find(c.option), std::string::npos) << *err;
    EXPECT_EQ(err->find('\n'), std::string::npos) << *err;  // one line
    EXPECT_EQ(err->rfind("f.toml: ", 0), 0u) << *err;
  }
}

TEST(RunOptions, EveryOptionHasDocAndItsDefaultPassesItsOwnCheck) {
  const RunConfig defaults;
  std::set<std::string> names;
  for (const OptionSpec& spec : run_options()) {
    EXPECT_TRUE(names.insert(spec.name()).second) << spec.name() << " declared twice";
    EXPECT_GT(std::string(spec.doc).size(), 3u) << spec.name();
    EXPECT_FALSE(check_value(spec, spec.get(defaults)).has_value()) << spec.name();
  }
  EXPECT_FALSE(check_cross_rules(defaults).has_value());
  // The daemon's own check sees values that came from flags, not only from the file.
  RunConfig c;
  c.source = "sim:sphere";
  c.out = "/tmp/x";
  c.pipeline.balloon.initial_radius_vox = 0.5f;
  ASSERT_TRUE(validate(c).has_value());
  EXPECT_NE(validate(c)->find("initial_radius_vox"), std::string::npos);
}

// Each balloon option at the edges of its range and just inside them: a value the loader takes is
// one the balloon's own check (segment::validate) takes, so a configuration that loads runs.
TEST(RunOptions, WhatLoadsTheBalloonAccepts) {
  int loaded = 0;
  for (const OptionSpec& spec : run_options()) {
    const bool number = spec.kind == OptionKind::Number || spec.kind == OptionKind::Integer;
    if (std::string(spec.table) != "pipeline.balloon" || !number) continue;
    const OptionRange& r = spec.range;
    std::vector<double> values{r.lo, r.hi};
    if (spec.kind == OptionKind::Number)
      for (double f : {1e-3, 0.5, 1.0 - 1e-3}) values.push_back(r.lo + f * (r.hi - r.lo));
    for (const double v : values) {
      RunConfig c;
      const std::string text =
          "[pipeline.balloon]\n" + std::string(spec.key) + " = " + option_toml(v) + "\n";
      if (const auto err = load_config_text(text, "f.toml", c)) {
        EXPECT_NE(err->find(spec.key), std::string::npos) << *err;
        continue;
      }
      ++loaded;
      EXPECT_EQ(sonomesh::segment::validate(c.pipeline.balloon), "") << text;
    }
  }
  EXPECT_GT(loaded, 40);
  // Each in range alone, not together: refused at load with the balloon's own words.
  RunConfig c;
  const auto err = load_config_text("[pipeline.balloon]\ntime_step = 2\n", "f.toml", c);
  ASSERT_TRUE(err.has_value());
  EXPECT_NE(err->find("pipeline.balloon: time_step * inflation_vox"), std::string::npos) << *err;
}

// A float field's default prints as written (0.45, not 0.449999988), and any value prints as
// text that loads back as the same value.
TEST(RunOptions, NumbersPrintShortAndLoadBackTheSame) {
  EXPECT_EQ(option_toml(static_cast<double>(0.45f)), "0.45");
  EXPECT_EQ(option_toml(static_cast<double>(0.3f)), "0.3");
  EXPECT_EQ(option_toml(0.1), "0.1");
  EXPECT_EQ(option_toml(2.0), "2");
  const RunConfig defaults;
  for (const OptionSpec& spec : run_options()) {
    if (spec.kind != OptionKind::Number) continue;
    const std::string text = "[" + std::string(spec.table) + "]\n" + spec.key + " = " +
                             option_toml(spec.get(defaults)) + "\n";
    RunConfig c;
    ASSERT_FALSE(load_config_text(text, "f.toml", c).has_value()) << text;
    EXPECT_EQ(spec.get(c), spec.get(defaults)) << text;
  }
}

TEST(RunOptions, TargetAndIgtlLoadAndPrint) {
  RunConfig c;
  ASSERT_FALSE(
      load_config_text("[pipeline]\ntarget = \"bright\"\n[outputs]\n"
                       "igtl_listen = \"127.0.0.1:18945\"\n",
                       "f.toml", c));
  EXPECT_EQ(c.pipeline.target, TargetPolarity::Bright);
  EXPECT_EQ(c.igtl_listen, "127.0.0.1:18945");
  const std::string text = to_toml(c);
  EXPECT_NE(text.find("target = 'bright'"), std::string::npos) << text;
  RunConfig back;
  ASSERT_FALSE(load_config_text(text, "printed", back));
  EXPECT_EQ(back.pipeline.target, TargetPolarity::Bright);
  c.source = "sim:sphere";
  c.out = "/tmp/x";
  c.igtl_listen = "0.0.0.0:18945";
  ASSERT_TRUE(validate(c).has_value());
  EXPECT_NE(validate(c)->find("--igtl-any-address"), std::string::npos);
  c.igtl_any_address = true;
  EXPECT_FALSE(validate(c).has_value());
}

// ---------------------------------------------------------------------------------------------
// The recorder shows every line to the sinks, in journal order, with the journal's keys.

namespace {
class CollectingSink : public OutputSink {
 public:
  const char* name() const override { return "collect"; }
  void on_line(const nlohmann::json& line, const ProcessedVolume* volume) override {
    lines.push_back(line);
    with_volume.push_back(volume != nullptr);
  }
  std::vector<nlohmann::json> lines;
  std::vector<bool> with_volume;
};
}  // namespace

TEST(Recorder, SinksSeeEveryLineAsTheJournalHasIt) {
  const fs::path dir = fs::temp_directory_path() / ("sonomesh_parts_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  RunStats stats;
  auto sink = std::make_shared<CollectingSink>();
  {
    Recorder recorder(dir / "journal.jsonl", stats);
    recorder.add_sink(sink);
    ASSERT_TRUE(recorder.claim(1));
    recorder.record(1, JournalStatus::Skipped, {{"reason", "superseded"}}, 0);
    EXPECT_EQ(recorder.record_lost(2, 3, "sequence gap"), 3u);
    ProcessedVolume v;
    v.sequence = 5;
    ASSERT_TRUE(recorder.claim(5));
    recorder.record(5, JournalStatus::Processed, {{"quality", "suspect"}}, 0, &v);
  }
  ASSERT_EQ(sink->lines.size(), 5u);
  std::ifstream in(dir / "journal.jsonl");
  std::string text;
  for (std::size_t i = 0; std::getline(in, text); ++i) {
    const auto line = nlohmann::json::parse(text);
    EXPECT_EQ(line["sequence"], sink->lines[i]["sequence"]);
    EXPECT_EQ(line["status"], sink->lines[i]["status"]);
  }
  EXPECT_EQ(sink->with_volume, (std::vector<bool>{false, false, false, false, true}));
  EXPECT_EQ(stats.counter(JournalStatus::Lost), 3u);
  fs::remove_all(dir);
}

TEST(RunStats, QualityVerdictInStatusAndMetrics) {
  RunStats stats;
  stats.count_quality(true, {});
  stats.count_quality(false, {"touches the volume edge", "leak bound"});
  stats.count_quality(false, {"leak bound"});
  stats.set_last_processed(3, 0);
  const auto status = stats.status_json();
  EXPECT_EQ(status["quality"]["ok"], 1);
  EXPECT_EQ(status["quality"]["suspect"], 2);
  EXPECT_EQ(status["quality"]["suspect_reasons"]["leak bound"], 2);
  EXPECT_EQ(status["last_processed"]["quality"], "suspect");
  const auto metrics = sonomesh::testing::parse_prometheus(stats.prometheus_text());
  ASSERT_TRUE(metrics.error.empty()) << metrics.error;
  EXPECT_EQ(metrics.value("sonomesh_results_total", {{"quality", "ok"}}), 1);
  EXPECT_EQ(metrics.value("sonomesh_results_total", {{"quality", "suspect"}}), 2);
  EXPECT_EQ(metrics.value("sonomesh_suspect_reasons_total", {{"reason", "leak bound"}}), 2);
}

namespace sonomesh::daemon {
namespace {

// The warm/cold decision (issue 17): warm only when every condition holds.
StartInputs warm_inputs() {
  return {.have_previous = true,
          .previous_quality_ok = true,
          .seed_overridden = false,
          .seed_tracked = true,
          .same_grid = true,
          .motion_vox = 0.5f,
          .volume_change = 0.02f};
}

TEST(SeedPolicy, DecideStartWarmWhenEverythingHolds) {
  const StartDecision d = decide_start(warm_inputs());
  EXPECT_TRUE(d.warm);
  EXPECT_EQ(d.reason, "previous balloon");
}

TEST(SeedPolicy, DecideStartColdForEachFailedCondition) {
  auto cold_reason = [](auto change) {
    StartInputs in = warm_inputs();
    change(in);
    const StartDecision d = decide_start(in);
    EXPECT_FALSE(d.warm);
    return d.reason;
  };
  EXPECT_EQ(cold_reason([](StartInputs& in) { in.have_previous = false; }), "no previous balloon");
  EXPECT_EQ(cold_reason([](StartInputs& in) {
              in.have_previous = false;
              in.previous_dropped = "sequence 3 failed";
            }),
            "no previous balloon (sequence 3 failed)");
  EXPECT_EQ(cold_reason([](StartInputs& in) { in.seed_overridden = true; }), "seed override");
  EXPECT_EQ(cold_reason([](StartInputs& in) { in.previous_quality_ok = false; }),
            "previous result suspect");
  EXPECT_EQ(cold_reason([](StartInputs& in) { in.seed_tracked = false; }), "seed not tracked");
  EXPECT_EQ(cold_reason([](StartInputs& in) { in.same_grid = false; }), "grid changed");
  EXPECT_EQ(cold_reason([](StartInputs& in) { in.motion_vox = 7.0f; }).rfind("moved", 0), 0u);
  EXPECT_EQ(cold_reason([](StartInputs& in) { in.volume_change = 0.4f; }), "volume changed 40 %");
  EXPECT_EQ(cold_reason([](StartInputs& in) { in.since_refused = 0; }),
            "warm start refused recently");
  StartInputs after_backoff = warm_inputs();
  after_backoff.since_refused = StartLimits{}.refused_backoff_volumes;
  EXPECT_TRUE(decide_start(after_backoff).warm);
  // NaN motion (a degenerate centroid) is not "small".
  EXPECT_FALSE(decide_start({.have_previous = true,
                             .previous_quality_ok = true,
                             .seed_tracked = true,
                             .same_grid = true,
                             .motion_vox = std::numeric_limits<float>::quiet_NaN()})
                   .warm);
}

TEST(SeedPolicy, DecideStartOverrideWinsOverEverything) {
  StartInputs in = warm_inputs();
  in.seed_overridden = true;
  in.have_previous = false;
  EXPECT_EQ(decide_start(in).reason, "seed override");
}

}  // namespace
}  // namespace sonomesh::daemon
