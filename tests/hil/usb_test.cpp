// USB probe source against emulated probes: the real libusb path (udev enumeration, descriptors,
// string descriptors, claim, async bulk IN URBs) with the device side answered by FakeUsbProbe.
#include <gtest/gtest.h>

#include <chrono>
#include <memory>
#include <thread>

#include "acquire/acquire.h"
#include "acquire/protocol.h"
#include "tests/hil/fake_usb_probe.h"
#include "tests/hil/test_volumes.h"

namespace sonomesh::hil {
namespace {

using acquire::AcquireError;
using acquire::RawVolume;
using namespace std::chrono_literals;

constexpr int kSize = 48;

std::vector<std::uint8_t> record(const RawVolume& v) {
  auto r = acquire::encode_volume_record(v);
  if (!r) throw std::runtime_error(acquire::to_string(r.error()));
  return *r;
}

void expect_same_volume(const RawVolume& got, const RawVolume& sent) {
  EXPECT_EQ(got.sequence, sent.sequence);
  EXPECT_EQ(got.timestamp_ns, sent.timestamp_ns);
  EXPECT_EQ(got.dims, sent.dims);
  EXPECT_EQ(got.type, sent.type);
  EXPECT_EQ(got.spacing_mm, sent.spacing_mm);
  ASSERT_EQ(got.voxels.size(), sent.voxels.size());
  EXPECT_TRUE(got.voxels == sent.voxels) << "voxels differ from what the probe sent";
}

std::unique_ptr<acquire::Source> open_or_fail(const std::string& uri) {
  auto source = acquire::open_source(uri);
  if (!source) {
    ADD_FAILURE() << uri << ": " << acquire::to_string(source.error());
    return nullptr;
  }
  return std::move(*source);
}

/// next() until something other than Timeout arrives (or `budget` runs out).
tl::expected<RawVolume, AcquireError> next_non_timeout(acquire::Source& source,
                                                       std::chrono::milliseconds budget) {
  const auto until = std::chrono::steady_clock::now() + budget;
  for (;;) {
    auto r = source.next(100ms);
    if (r || r.error().code != AcquireError::Code::Timeout ||
        std::chrono::steady_clock::now() >= until)
      return r;
  }
}

TEST(UsbHil, VolumesArriveBitExact) {
  FakeUsbBus bus;
  FakeUsbProbe& probe = bus.add_probe({});
  std::vector<RawVolume> sent;
  for (std::uint64_t seq = 100; seq < 104; ++seq) {
    sent.push_back(probe_volume(
        seq, kSize, seq % 2 ? acquire::ProbeVoxelType::UInt16 : acquire::ProbeVoxelType::UInt8));
    probe.push(record(sent.back()));
  }
  // A heartbeat between volumes is consumed silently.
  probe.push(acquire::encode_heartbeat(104, 0));
  sent.push_back(probe_volume(104, kSize));
  probe.push(record(sent.back()));

  auto source = open_or_fail("usb:1209:0001");
  ASSERT_TRUE(source);
  EXPECT_EQ(source->describe(), "usb:1209:0001");
  EXPECT_TRUE(source->live());
  for (const auto& s : sent) {
    auto got = source->next(2s);
    ASSERT_TRUE(got) << acquire::to_string(got.error());
    expect_same_volume(*got, s);
  }
  EXPECT_EQ(probe.bytes_queued(), 0u);
  EXPECT_GT(probe.pending_in_urbs(), 1u) << "several bulk IN transfers should be kept in flight";
}

TEST(UsbHil, RecordLargerThanOneTransferIsReassembled) {
  FakeUsbBus bus;
  FakeUsbProbe& probe = bus.add_probe({});
  const RawVolume big = probe_volume(7, 96, acquire::ProbeVoxelType::UInt16);  // 1.7 MiB > one URB
  const auto bytes = record(big);
  auto source = open_or_fail("usb:1209:0001");
  ASSERT_TRUE(source);
  // Trickle the record in uneven pieces while the host is reading.
  std::thread feeder([&] {
    std::size_t at = 0, piece = 1000;
    while (at < bytes.size()) {
      const std::size_t n = std::min(piece, bytes.size() - at);
      probe.push(std::vector<std::uint8_t>(bytes.begin() + static_cast<long>(at),
                                           bytes.begin() + static_cast<long>(at + n)));
      at += n;
      piece = piece * 3 + 17;
      std::this_thread::sleep_for(2ms);
    }
  });
  auto got = next_non_timeout(*source, 5s);
  feeder.join();
  ASSERT_TRUE(got) << acquire::to_string(got.error());
  expect_same_volume(*got, big);
}

TEST(UsbHil, IdleProbeGivesTimeoutAndInterruptWakes) {
  FakeUsbBus bus;
  bus.add_probe({});
  auto source = open_or_fail("usb:1209:0001");
  ASSERT_TRUE(source);
  auto t0 = std::chrono::steady_clock::now();
  auto r = source->next(150ms);
  auto waited = std::chrono::steady_clock::now() - t0;
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code, AcquireError::Code::Timeout);
  EXPECT_GE(waited, 140ms);

  std::thread waker([&] {
    std::this_thread::sleep_for(50ms);
    source->interrupt();
  });
  t0 = std::chrono::steady_clock::now();
  r = source->next(10s);
  waited = std::chrono::steady_clock::now() - t0;
  waker.join();
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code, AcquireError::Code::Timeout);
  EXPECT_LT(waited, 5s) << "interrupt() must wake a blocked next()";
}

TEST(UsbHil, SerialSelectsTheProbe) {
  FakeUsbBus bus;
  FakeUsbProbe& a = bus.add_probe({.serial = "PROBE-A"});
  FakeUsbProbe& b = bus.add_probe({.serial = "PROBE-B"});
  const RawVolume va = probe_volume(1, kSize);
  const RawVolume vb = probe_volume(2, kSize);
  a.push(record(va));
  b.push(record(vb));

  auto source_b = open_or_fail("usb:1209:0001/PROBE-B");
  ASSERT_TRUE(source_b);
  auto got = source_b->next(2s);
  ASSERT_TRUE(got) << acquire::to_string(got.error());
  expect_same_volume(*got, vb);
  EXPECT_EQ(a.bytes_sent(), 0u) << "the other probe must not be read";
  source_b.reset();

  auto missing = acquire::open_source("usb:1209:0001/PROBE-C");
  ASSERT_FALSE(missing);
  EXPECT_EQ(missing.error().code, AcquireError::Code::NotFound)
      << acquire::to_string(missing.error());
  auto other_pid = acquire::open_source("usb:1209:0002");
  ASSERT_FALSE(other_pid);
  EXPECT_EQ(other_pid.error().code, AcquireError::Code::NotFound);
  auto bad = acquire::open_source("usb:12345:0001");
  ASSERT_FALSE(bad);
  EXPECT_EQ(bad.error().code, AcquireError::Code::InvalidArgument);
}

TEST(UsbHil, UnplugMidVolumeGivesDisconnectedThenRecovers) {
  FakeUsbBus bus;
  FakeUsbProbe& probe = bus.add_probe({});
  const RawVolume v1 = probe_volume(1, kSize);
  const RawVolume v2 = probe_volume(2, kSize);
  const RawVolume v4 = probe_volume(4, kSize);
  probe.push(record(v1));
  const auto r2 = record(v2);
  probe.push(std::vector<std::uint8_t>(r2.begin(), r2.begin() + static_cast<long>(r2.size() / 2)));

  auto source = open_or_fail("usb:1209:0001");
  ASSERT_TRUE(source);
  auto got = source->next(2s);
  ASSERT_TRUE(got) << acquire::to_string(got.error());
  expect_same_volume(*got, v1);
  // Let the host take the first half of volume 2, then pull the cable.
  auto idle = source->next(100ms);
  ASSERT_FALSE(idle);
  EXPECT_EQ(idle.error().code, AcquireError::Code::Timeout);
  EXPECT_EQ(probe.bytes_queued(), 0u);
  probe.unplug();

  auto cut = source->next(2s);
  ASSERT_FALSE(cut);
  EXPECT_EQ(cut.error().code, AcquireError::Code::Incomplete) << acquire::to_string(cut.error());
  EXPECT_EQ(cut.error().sequence.value_or(0), 2u);
  auto down = source->next(2s);
  ASSERT_FALSE(down);
  EXPECT_EQ(down.error().code, AcquireError::Code::Disconnected)
      << acquire::to_string(down.error());
  // While the probe is away: Timeout, not Disconnected again.
  for (int i = 0; i < 3; ++i) {
    auto r = source->next(120ms);
    ASSERT_FALSE(r);
    EXPECT_EQ(r.error().code, AcquireError::Code::Timeout) << acquire::to_string(r.error());
  }

  probe.replug();
  probe.push(record(v4));  // volume 3 was never sent: lost during the outage
  const auto t0 = std::chrono::steady_clock::now();
  auto lost = next_non_timeout(*source, 3s);
  ASSERT_FALSE(lost);
  EXPECT_EQ(lost.error().code, AcquireError::Code::Lost) << acquire::to_string(lost.error());
  EXPECT_EQ(lost.error().sequence.value_or(0), 3u);
  EXPECT_EQ(lost.error().count, 1u);
  EXPECT_LT(std::chrono::steady_clock::now() - t0, 1500ms) << "backoff is capped at 500 ms";
  auto back = source->next(2s);
  ASSERT_TRUE(back) << acquire::to_string(back.error());
  expect_same_volume(*back, v4);
}

TEST(UsbHil, CorruptRecordIsReportedAndStreamResynchronises) {
  FakeUsbBus bus;
  FakeUsbProbe& probe = bus.add_probe({});
  const RawVolume v1 = probe_volume(1, kSize);
  const RawVolume v2 = probe_volume(2, kSize);
  auto bad = record(v1);
  bad[64 + 1000] ^= 0xFF;  // payload bit flip: payload CRC fails
  probe.push(bad);
  probe.push(record(v2));
  auto source = open_or_fail("usb:1209:0001");
  ASSERT_TRUE(source);
  auto a = source->next(2s);
  ASSERT_FALSE(a);
  EXPECT_EQ(a.error().code, AcquireError::Code::BadRecord);
  EXPECT_EQ(a.error().sequence.value_or(0), 1u);
  auto b = source->next(2s);
  ASSERT_TRUE(b) << acquire::to_string(b.error());
  expect_same_volume(*b, v2);
}

}  // namespace
}  // namespace sonomesh::hil
