// The daemon's infrastructure pieces in isolation: queue, journal, atomic outputs, statistics,
// HTTP server, configuration.
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <thread>

#include "daemon/internal/atomic_file.h"
#include "daemon/internal/http_status.h"
#include "daemon/internal/journal.h"
#include "daemon/internal/run_config.h"
#include "daemon/internal/run_stats.h"
#include "daemon/internal/volume_queue.h"
#include "prometheus_parse.h"

// Last: <httplib.h> pulls in <resolv.h>, whose `_res` macro breaks Eigen headers included after it.
#include <httplib.h>

namespace fs = std::filesystem;
using namespace sonomesh::daemon;
using namespace std::chrono_literals;

namespace {

fs::path fresh_dir(const std::string& name) {
  const fs::path dir =
      fs::temp_directory_path() / ("sonomesh_infra_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

QueuedVolume volume_with(std::uint64_t seq) {
  QueuedVolume v;
  v.raw.sequence = seq;
  v.raw.dims = {2, 2, 2};
  v.raw.voxels.assign(8, 0);
  v.received = std::chrono::steady_clock::now();
  return v;
}

std::vector<nlohmann::json> read_jsonl(const fs::path& path) {
  std::vector<nlohmann::json> lines;
  std::ifstream in(path);
  std::string line;
  while (std::getline(in, line)) lines.push_back(nlohmann::json::parse(line));
  return lines;
}

}  // namespace

// ---------------------------------------------------------------------------------------------

TEST(VolumeQueue, KeepNewestPushesOutEveryOlderVolume) {
  VolumeQueue q(2, VolumeQueue::Mode::KeepNewest);
  EXPECT_TRUE(q.push(volume_with(1)).empty());
  auto out = q.push(volume_with(2));
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].raw.sequence, 1u);
  EXPECT_EQ(q.size(), 1u);
  EXPECT_EQ(q.pop(10ms)->raw.sequence, 2u);
  EXPECT_TRUE(q.push(volume_with(3)).empty());  // nothing waiting: nothing skipped
  EXPECT_EQ(q.pop(10ms)->raw.sequence, 3u);
  EXPECT_FALSE(q.pop(10ms).has_value());
}

TEST(VolumeQueue, BlockModeWaitsForRoom) {
  VolumeQueue q(1, VolumeQueue::Mode::Block);
  q.push(volume_with(1));
  std::atomic<bool> pushed{false};
  std::thread producer([&] {
    EXPECT_TRUE(q.push(volume_with(2)).empty());
    pushed = true;
  });
  std::this_thread::sleep_for(50ms);
  EXPECT_FALSE(pushed.load());
  EXPECT_EQ(q.pop(100ms)->raw.sequence, 1u);
  producer.join();
  EXPECT_TRUE(pushed.load());
  EXPECT_EQ(q.pop(100ms)->raw.sequence, 2u);
}

TEST(VolumeQueue, AbortReturnsEverythingAndUnblocksProducers) {
  VolumeQueue q(1, VolumeQueue::Mode::Block);
  q.push(volume_with(1));
  std::vector<QueuedVolume> returned;
  std::thread producer([&] { returned = q.push(volume_with(2)); });
  std::this_thread::sleep_for(30ms);
  auto left = q.abort();
  producer.join();
  ASSERT_EQ(left.size(), 1u);
  EXPECT_EQ(left[0].raw.sequence, 1u);
  ASSERT_EQ(returned.size(), 1u);  // the blocked volume comes back to be accounted for
  EXPECT_EQ(returned[0].raw.sequence, 2u);
  EXPECT_FALSE(q.pop(10ms).has_value());
  EXPECT_EQ(q.push(volume_with(3)).size(), 1u);  // closed: handed straight back
}

TEST(VolumeQueue, CloseDrainsBeforeEnding) {
  VolumeQueue q(3, VolumeQueue::Mode::Block);
  q.push(volume_with(1));
  q.push(volume_with(2));
  q.close();
  EXPECT_EQ(q.pop(10ms)->raw.sequence, 1u);
  EXPECT_EQ(q.pop(10ms)->raw.sequence, 2u);
  const auto t0 = std::chrono::steady_clock::now();
  EXPECT_FALSE(q.pop(1000ms).has_value());
  EXPECT_LT(std::chrono::steady_clock::now() - t0, 500ms);  // no wait once closed and empty
}

TEST(VolumeQueue, GrowingCapacityReleasesABlockedProducer) {
  VolumeQueue q(1, VolumeQueue::Mode::Block);
  q.push(volume_with(1));
  std::atomic<bool> pushed{false};
  std::thread producer([&] {
    q.push(volume_with(2));
    pushed = true;
  });
  std::this_thread::sleep_for(30ms);
  EXPECT_FALSE(pushed.load());
  q.set_capacity(2);
  producer.join();
  EXPECT_EQ(q.size(), 2u);
  EXPECT_THROW(VolumeQueue(0, VolumeQueue::Mode::Block), std::invalid_argument);
  EXPECT_THROW(q.set_capacity(0), std::invalid_argument);
}

// ---------------------------------------------------------------------------------------------

TEST(Journal, OneLinePerSequenceWithTimestamps) {
  const fs::path dir = fresh_dir("journal");
  {
    Journal j(dir / "journal.jsonl");
    ASSERT_TRUE(j.claim(0));
    j.write(0, JournalStatus::Processed, {{"mesh", "meshes/0.ply"}, {"genus", 1}});
    ASSERT_TRUE(j.claim(3));  // a rejected record with an intact header
    j.write(3, JournalStatus::Rejected, {{"reason", "payload crc"}});
    // The source then reports 1..4 as a gap: 3 already has its line.
    EXPECT_EQ(j.write_lost(1, 4, "sequence gap"), 3u);
    EXPECT_FALSE(j.claim(2));
    j.write(std::nullopt, JournalStatus::Rejected, {{"reason", "header crc"}});
    EXPECT_EQ(j.lines_written(), 6u);
  }
  const auto lines = read_jsonl(dir / "journal.jsonl");
  ASSERT_EQ(lines.size(), 6u);
  std::multiset<std::uint64_t> seqs;
  int null_seq = 0;
  for (const auto& l : lines) {
    ASSERT_TRUE(l.contains("status"));
    ASSERT_TRUE(l.contains("time"));
    EXPECT_EQ(l["time"].get<std::string>().back(), 'Z');
    if (l["sequence"].is_null()) {
      ++null_seq;
      EXPECT_EQ(l["status"], "rejected");
    } else {
      seqs.insert(l["sequence"].get<std::uint64_t>());
    }
    if (l["status"] != "processed") {
      EXPECT_TRUE(l.contains("reason")) << l.dump();
    }
  }
  EXPECT_EQ(null_seq, 1);
  EXPECT_EQ(seqs, (std::multiset<std::uint64_t>{0, 1, 2, 3, 4}));
}

TEST(Journal, EpochsSeparateRestartedCounters) {
  const fs::path dir = fresh_dir("epoch");
  Journal j(dir / "journal.jsonl");
  ASSERT_TRUE(j.claim(5));
  j.write(5, JournalStatus::Processed, {});
  EXPECT_FALSE(j.claim(5));
  EXPECT_EQ(j.new_epoch(), 1u);
  EXPECT_TRUE(j.claim(5));
  j.write(5, JournalStatus::Processed, {});
  const auto lines = read_jsonl(dir / "journal.jsonl");
  ASSERT_EQ(lines.size(), 2u);
  EXPECT_FALSE(lines[0].contains("epoch"));
  EXPECT_EQ(lines[1]["epoch"], 1);
}

TEST(Journal, LongRunsKeepTheClaimSetBounded) {
  const fs::path dir = fresh_dir("bounded");
  Journal j(dir / "journal.jsonl");
  for (std::uint64_t s = 0; s < 200000; ++s) ASSERT_TRUE(j.claim(s));
  EXPECT_FALSE(j.claim(10));      // folded into the floor: still refused
  EXPECT_FALSE(j.claim(199999));  // recent: refused
  EXPECT_TRUE(j.claim(200000));
}

TEST(Journal, UnwritableFileIsAClearError) {
  EXPECT_THROW(Journal("/nonexistent-dir/journal.jsonl"), std::runtime_error);
}

// ---------------------------------------------------------------------------------------------

TEST(AtomicFile, RenamesIntoPlaceAndLeavesNoTemporary) {
  const fs::path dir = fresh_dir("atomic");
  write_file_atomically(dir / "a.json", "{\"x\":1}\n");
  std::ifstream in(dir / "a.json");
  std::string text((std::istreambuf_iterator<char>(in)), {});
  EXPECT_EQ(text, "{\"x\":1}\n");
  publish_copy_atomically(dir / "a.json", dir / "latest.json");
  EXPECT_TRUE(fs::exists(dir / "latest.json"));
  // A writer that fails leaves neither the target nor the temporary.
  EXPECT_THROW(write_atomically(dir / "b.ply",
                                [](const fs::path& tmp) {
                                  std::ofstream(tmp) << "half";
                                  throw std::runtime_error("disk full");
                                }),
               std::runtime_error);
  EXPECT_FALSE(fs::exists(dir / "b.ply"));
  for (const auto& e : fs::directory_iterator(dir)) {
    EXPECT_FALSE(is_temporary_name(e.path())) << e.path();
  }
  // The temporary keeps the extension (writers choose the format by it) and is hidden.
  const fs::path tmp = temporary_name(dir / "12.ply");
  EXPECT_EQ(tmp.extension(), ".ply");
  EXPECT_EQ(tmp.filename().string()[0], '.');
  EXPECT_TRUE(is_temporary_name(tmp));
  EXPECT_FALSE(is_temporary_name(dir / "12.ply"));
  std::ofstream(tmp) << "stale";
  EXPECT_EQ(remove_stale_temporaries(dir), 1);
}

// ---------------------------------------------------------------------------------------------

TEST(RunStats, QuantilesAndPrometheusText) {
  RunStats stats;
  EXPECT_FALSE(stats.latency_quantile_ms(0.5).has_value());
  for (int i = 1; i <= 100; ++i) stats.add_latency(i);
  EXPECT_NEAR(*stats.latency_quantile_ms(0.5), 50, 1);
  EXPECT_NEAR(*stats.latency_quantile_ms(0.95), 95, 1);
  stats.count(JournalStatus::Processed, 7);
  stats.count(JournalStatus::Lost, 2);
  stats.set_source_state(SourceState::Connected);
  stats.set_queue_depth(1, 2);
  const auto prom = sonomesh::testing::parse_prometheus(stats.prometheus_text());
  ASSERT_TRUE(prom.error.empty()) << prom.error << "\n" << stats.prometheus_text();
  EXPECT_EQ(prom.value("sonomesh_volumes_total", {{"status", "processed"}}), 7.0);
  EXPECT_EQ(prom.value("sonomesh_volumes_total", {{"status", "lost"}}), 2.0);
  EXPECT_EQ(prom.value("sonomesh_volumes_total", {{"status", "skipped"}}), 0.0);
  EXPECT_EQ(prom.value("sonomesh_source_connected"), 1.0);
  EXPECT_EQ(prom.value("sonomesh_queue_depth"), 1.0);
  EXPECT_EQ(prom.value("sonomesh_latency_histogram_seconds_count"), 100.0);
  EXPECT_EQ(prom.value("sonomesh_latency_histogram_seconds_bucket", {{"le", "0.05"}}), 50.0);
  EXPECT_EQ(prom.types.at("sonomesh_latency_seconds"), "summary");
  EXPECT_EQ(prom.types.at("sonomesh_latency_histogram_seconds"), "histogram");
  const auto status = stats.status_json();
  EXPECT_EQ(status["volumes"]["processed"], 7);
  EXPECT_EQ(status["source"]["state"], "connected");
  EXPECT_NEAR(status["latency_ms"]["p95"].get<double>(), 95, 1);
}

// ---------------------------------------------------------------------------------------------

TEST(HttpAddress, ParsesAndRefusesRemoteByDefault) {
  EXPECT_EQ(parse_http_address("127.0.0.1:8080")->port, 8080);
  EXPECT_EQ(parse_http_address("[::1]:9")->host, "::1");
  EXPECT_EQ(parse_http_address(":7")->host, "127.0.0.1");
  EXPECT_FALSE(parse_http_address("127.0.0.1:http").has_value());
  EXPECT_FALSE(parse_http_address("127.0.0.1:70000").has_value());
  EXPECT_TRUE(is_loopback_host("127.0.0.1"));
  EXPECT_TRUE(is_loopback_host("127.3.2.1"));
  EXPECT_TRUE(is_loopback_host("::1"));
  EXPECT_FALSE(is_loopback_host("0.0.0.0"));
  EXPECT_FALSE(is_loopback_host("192.168.1.5"));
  RunConfig c;
  c.source = "sim:sphere";
  c.out = "/tmp/x";
  c.http_address = "0.0.0.0:8080";
  ASSERT_TRUE(validate(c).has_value());
  EXPECT_NE(validate(c)->find("--allow-remote-http"), std::string::npos);
  c.allow_remote_http = true;
  EXPECT_FALSE(validate(c).has_value());
}

TEST(HttpAddress, SeedBodies) {
  EXPECT_EQ(*parse_seed_text("1,2.5,-3"), (std::array<float, 3>{1, 2.5f, -3}));
  EXPECT_EQ(*parse_seed_text(" 1, 2, 3\n"), (std::array<float, 3>{1, 2, 3}));
  EXPECT_EQ(*parse_seed_text("{\"seed_mm\":[4,5,6]}"), (std::array<float, 3>{4, 5, 6}));
  EXPECT_FALSE(parse_seed_text("1,2").has_value());
  EXPECT_FALSE(parse_seed_text("1,2,3,4").has_value());
  EXPECT_FALSE(parse_seed_text("{\"seed\":[1,2,3]}").has_value());
  EXPECT_FALSE(parse_seed_text("nan,1,2").has_value());
  EXPECT_FALSE(parse_seed_text("").has_value());
}

TEST(HttpStatusServer, ServesStatusMetricsLatestAndSeed) {
  const fs::path dir = fresh_dir("http");
  RunStats stats;
  stats.count(JournalStatus::Processed, 3);
  std::optional<std::array<float, 3>> got_seed;
  HttpStatusServer server(stats, dir / "latest.ply", [&](const std::array<float, 3>& s) {
    got_seed = s;
    return std::optional<std::string>{};
  });
  const int port = server.start({"127.0.0.1", 0});
  ASSERT_GT(port, 0);
  httplib::Client client("127.0.0.1", port);
  auto health = client.Get("/healthz");
  ASSERT_TRUE(health);
  EXPECT_EQ(health->status, 200);
  EXPECT_EQ(nlohmann::json::parse(health->body)["status"], "ok");
  auto status = client.Get("/status");
  ASSERT_TRUE(status);
  EXPECT_EQ(nlohmann::json::parse(status->body)["volumes"]["processed"], 3);
  auto metrics = client.Get("/metrics");
  ASSERT_TRUE(metrics);
  EXPECT_NE(metrics->get_header_value("Content-Type").find("text/plain"), std::string::npos);
  const auto prom = sonomesh::testing::parse_prometheus(metrics->body);
  EXPECT_TRUE(prom.error.empty()) << prom.error;
  EXPECT_EQ(client.Get("/latest.ply")->status, 404);
  std::ofstream(dir / "latest.ply") << "ply\n";
  EXPECT_EQ(client.Get("/latest.ply")->body, "ply\n");
  auto bad = client.Post("/seed", "1,2", "text/plain");
  ASSERT_TRUE(bad);
  EXPECT_EQ(bad->status, 400);
  EXPECT_FALSE(got_seed.has_value());
  auto good = client.Post("/seed", "{\"seed_mm\":[1,2,3]}", "application/json");
  ASSERT_TRUE(good);
  EXPECT_EQ(good->status, 200);
  ASSERT_TRUE(got_seed.has_value());
  EXPECT_EQ((*got_seed)[2], 3.0f);
  EXPECT_EQ(client.Get("/nothing")->status, 404);
  server.stop();
}

TEST(HttpStatusServer, BusyPortIsAnError) {
  RunStats stats;
  HttpStatusServer first(stats, "/nonexistent", {});
  const int port = first.start({"127.0.0.1", 0});
  HttpStatusServer second(stats, "/nonexistent", {});
  EXPECT_THROW(second.start({"127.0.0.1", port}), std::runtime_error);
}

// ---------------------------------------------------------------------------------------------

TEST(RunConfig, PrintedConfigurationRoundTrips) {
  RunConfig c;
  c.source = "unix:/tmp/probe.sock";
  c.out = "/tmp/out dir";
  c.seed_mm = std::array<float, 3>{1.5f, -2.0f, 3.25f};
  c.queue_capacity = 3;
  c.pipeline.smooth_sigma_mm = 0.75f;
  c.pipeline.balloon.max_iterations = 321;
  c.pipeline.poisson.divergence = sonomesh::reconstruct::DivergenceMode::CentralDifference;
  c.pipeline.poisson.cell_mm = 0.6f;
  c.keep_meshes = 10;
  const std::string text = to_toml(c);
  RunConfig back;
  ASSERT_FALSE(load_config_text(text, "printed", back).has_value()) << text;
  EXPECT_EQ(back.source, c.source);
  EXPECT_EQ(back.out, c.out);
  EXPECT_EQ(back.seed_mm, c.seed_mm);
  EXPECT_EQ(back.queue_capacity, 3u);
  EXPECT_EQ(back.pipeline.smooth_sigma_mm, 0.75f);
  EXPECT_EQ(back.pipeline.balloon.max_iterations, 321);
  EXPECT_EQ(back.pipeline.poisson.divergence,
            sonomesh::reconstruct::DivergenceMode::CentralDifference);
  EXPECT_FLOAT_EQ(back.pipeline.poisson.cell_mm, 0.6f);
  EXPECT_EQ(back.keep_meshes, 10u);
  EXPECT_EQ(to_toml(back), text);
  // Unset sigma prints as "auto" and reads back unset.
  RunConfig autos;
  ASSERT_FALSE(load_config_text(to_toml(RunConfig{}), "defaults", autos).has_value());
  EXPECT_FALSE(autos.pipeline.smooth_sigma_mm.has_value());
}

TEST(RunConfig, ErrorsNameTheKey) {
  RunConfig c;
  auto err = load_config_text("[pipeline.balloon]\nmax_iteration = 5\n", "f.toml", c);
  ASSERT_TRUE(err.has_value());
  EXPECT_NE(err->find("pipeline.balloon.max_iteration"), std::string::npos) << *err;
  err = load_config_text("[daemon]\nqueue_capacity = 0\n", "f.toml", c);
  ASSERT_TRUE(err.has_value());
  EXPECT_NE(err->find("queue_capacity"), std::string::npos) << *err;
  err = load_config_text("[daemon]\nqueue_capacity = \"two\"\n", "f.toml", c);
  ASSERT_TRUE(err.has_value());
  err = load_config_text("[daemon\n", "f.toml", c);
  ASSERT_TRUE(err.has_value());
  EXPECT_NE(err->find("f.toml:1"), std::string::npos) << *err;
  err = load_config_text("[pipeline.poisson]\ndivergence = \"fast\"\n", "f.toml", c);
  ASSERT_TRUE(err.has_value());
  err = load_config_text("[nonsense]\n", "f.toml", c);
  ASSERT_TRUE(err.has_value());
  EXPECT_EQ(c.queue_capacity, 2u);  // a failed load leaves the configuration alone
  RunConfig ok;
  ASSERT_FALSE(load_config_text("[http]\naddress = \"127.0.0.1:0\"\n", "f.toml", ok));
  EXPECT_TRUE(ok.http_explicit);
}
