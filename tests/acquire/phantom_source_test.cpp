// sim::PhantomSource: the daemon's sim: source - URI parsing, pacing, sequences, motion.
#include "sim/phantom_source.h"

#include <gtest/gtest.h>

#include <thread>

#include "acquire/protocol.h"

namespace sonomesh::sim {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
using acquire::AcquireError;

TEST(PhantomSource, ParsesSimUris) {
  auto o = parse_sim_uri("sim:torus?rate=25&size=40&count=3&seed=9");
  ASSERT_TRUE(o) << o.error().detail;
  EXPECT_EQ(o->spec.phantom, "torus");
  EXPECT_EQ(o->rate_hz, 25.0);
  EXPECT_EQ(o->spec.size_vox, 40);
  EXPECT_EQ(o->count, 3u);
  EXPECT_EQ(o->spec.seed, 9u);
  EXPECT_TRUE(parse_sim_uri("sim:sphere"));
  for (const char* bad : {"sim:banana", "sim:sphere?rate=0", "sim:sphere?size=8",
                          "sim:sphere?rate=fast", "sim:sphere?colour=red", "sim:sphere?count=-1"}) {
    auto r = parse_sim_uri(bad);
    ASSERT_FALSE(r) << bad;
    EXPECT_EQ(r.error().code, AcquireError::Code::InvalidArgument);
    EXPECT_EQ(r.error().detail.find('\n'), std::string::npos);
  }
  EXPECT_FALSE(open_phantom_source("sim:banana"));
}

TEST(PhantomSource, PacedConsecutiveMovingVolumesThenEnd) {
  auto source = open_phantom_source("sim:sphere?rate=40&size=24&count=5");
  ASSERT_TRUE(source) << source.error().detail;
  EXPECT_TRUE((*source)->live());
  std::vector<acquire::RawVolume> got;
  const auto start = Clock::now();
  while (got.size() < 5) {
    auto r = (*source)->next(1s);
    ASSERT_TRUE(r) << acquire::to_string(r.error());
    got.push_back(std::move(*r));
  }
  EXPECT_GE(Clock::now() - start, 4 * 25ms * 95 / 100) << "paced at 40 Hz";
  for (std::size_t i = 0; i < got.size(); ++i) {
    EXPECT_EQ(got[i].sequence, i);
    EXPECT_EQ(got[i].dims, (std::array<int, 3>{24, 24, 24}));
    EXPECT_EQ(got[i].timestamp_ns, i * 25'000'000ull);
    EXPECT_TRUE(acquire::encode_volume_record(got[i])) << "a valid probe record";
  }
  EXPECT_NE(got[0].voxels, got[4].voxels) << "the target breathes";
  EXPECT_EQ((*source)->next(10ms).error().code, AcquireError::Code::EndOfStream);
}

TEST(PhantomSource, TimeoutBeforeDueAndInterrupt) {
  auto source = open_phantom_source("sim:sphere?rate=1&size=16");
  ASSERT_TRUE(source);
  ASSERT_TRUE((*source)->next(100ms));  // volume 0 is due at once
  auto early = (*source)->next(20ms);   // volume 1 is due after 1 s
  ASSERT_FALSE(early);
  EXPECT_EQ(early.error().code, AcquireError::Code::Timeout);
  std::thread waker([&] {
    std::this_thread::sleep_for(30ms);
    (*source)->interrupt();
  });
  const auto start = Clock::now();
  auto r = (*source)->next(5s);
  waker.join();
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code, AcquireError::Code::Timeout);
  EXPECT_LT(Clock::now() - start, 900ms);
}

}  // namespace
}  // namespace sonomesh::sim
