// The igtl: source against an OpenIGTLink server written in the test (igtl_test_server.h).
#include "acquire/igtl.h"

#include <gtest/gtest.h>

#include <cmath>

#include "acquire/acquire.h"
#include "igtl_test_server.h"

namespace sonomesh::acquire {
namespace {

using namespace std::chrono_literals;
using test::Bytes;
using test::IgtlTestServer;
using test::ImageSpec;
using test::MessageSpec;
using Result = tl::expected<RawVolume, AcquireError>;

Bytes operator+(Bytes a, const Bytes& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
}

Bytes image(const ImageSpec& spec = {}, const MessageSpec& m = {}) {
  return test::message(m, test::image_content(spec));
}

// The next result that is not a Timeout (within 5 s).
Result next_event(Source& source) {
  const auto until = std::chrono::steady_clock::now() + 5s;
  for (;;) {
    auto r = source.next(100ms);
    if (r || r.error().code != AcquireError::Code::Timeout) return r;
    if (std::chrono::steady_clock::now() > until) return r;
  }
}

std::unique_ptr<Source> open(const IgtlTestServer& server, const std::string& query = "") {
  EXPECT_TRUE(server.ok());
  auto source = open_source(server.uri(query));
  EXPECT_TRUE(source) << to_string(source.error());
  return source ? std::move(*source) : nullptr;
}

void expect_voxels(const RawVolume& v, bool wide) {
  const std::size_t n = static_cast<std::size_t>(v.dims[0]) * v.dims[1] * v.dims[2];
  ASSERT_EQ(v.voxels.size(), n * (wide ? 2 : 1));
  for (std::size_t i = 0; i < n; i += 97) {
    const std::uint16_t got =
        wide ? static_cast<std::uint16_t>(v.voxels[2 * i] | (v.voxels[2 * i + 1] << 8))
             : v.voxels[i];
    ASSERT_EQ(got, test::voxel_value(i, wide)) << "voxel " << i;
  }
}

TEST(IgtlCodec, Crc64IsEcma182AsOpenIgtlinkComputesIt) {
  const std::string check = "123456789";
  const Bytes bytes(check.begin(), check.end());
  EXPECT_EQ(igtl::crc64(bytes.data(), bytes.size()), 0x6C40DF5F0B497347ull);  // CRC-64/ECMA-182
  EXPECT_EQ(igtl::crc64(bytes.data(), bytes.size()), test::crc64_bitwise(bytes));
  Bytes random(1000);
  for (std::size_t i = 0; i < random.size(); ++i)
    random[i] = static_cast<std::uint8_t>(i * 131 + 7);
  for (std::size_t n : {0u, 1u, 7u, 8u, 9u, 63u, 1000u}) {
    const Bytes part(random.begin(), random.begin() + static_cast<std::ptrdiff_t>(n));
    EXPECT_EQ(igtl::crc64(part.data(), part.size()), test::crc64_bitwise(part)) << n << " bytes";
  }
  EXPECT_EQ(igtl::timestamp_ns((std::uint64_t{3} << 32) | 0x40000000u), 3'250'000'000ull);
}

TEST(IgtlSource, Version1Uint8AndUint16InBothEndiannesses) {
  ImageSpec big16;
  big16.scalar = 5;
  big16.endian = 1;
  ImageSpec little16 = big16;
  little16.endian = 2;
  IgtlTestServer server(image() + image(big16) + image(little16));
  auto source = open(server);
  ASSERT_TRUE(source);
  for (int k = 0; k < 3; ++k) {
    auto v = next_event(*source);
    ASSERT_TRUE(v) << to_string(v.error());
    EXPECT_EQ(v->sequence, static_cast<std::uint64_t>(k)) << "arrival order";
    EXPECT_EQ(v->dims, (std::array<int, 3>{12, 10, 8}));
    EXPECT_EQ(v->type, k == 0 ? ProbeVoxelType::UInt8 : ProbeVoxelType::UInt16);
    EXPECT_EQ(v->timestamp_ns, 1700000000ull * 1'000'000'000ull + 500'000'000ull);
    expect_voxels(*v, k > 0);
  }
}

// Geometry of an oblique image: the test computes the corner from the centre itself.
void expect_geometry(const RawVolume& v, const ImageSpec& s) {
  const double flip = s.coordinate == 1 ? -1.0 : 1.0;  // RAS -> LPS on x and y
  std::array<double, 3> corner{};
  for (int a = 0; a < 3; ++a) corner[a] = s.centre[a] * (a < 2 ? flip : 1.0);
  for (int c = 0; c < 3; ++c) {
    const auto& col = s.columns[c];
    const double norm = std::sqrt(col[0] * col[0] + col[1] * col[1] + col[2] * col[2]);
    EXPECT_NEAR(v.spacing_mm[c], norm, 1e-5);
    for (int a = 0; a < 3; ++a) {
      const double dir = col[a] / norm * (a < 2 ? flip : 1.0);
      EXPECT_NEAR(v.direction[3 * c + a], dir, 1e-5) << "column " << c << " row " << a;
      corner[a] -= col[a] * (a < 2 ? flip : 1.0) * (s.size[c] - 1) / 2.0;
    }
  }
  for (int a = 0; a < 3; ++a) EXPECT_NEAR(v.origin_mm[a], corner[a], 1e-4) << "axis " << a;
}

ImageSpec oblique(int coordinate) {
  ImageSpec s;
  s.coordinate = coordinate;
  const float c30 = std::cos(0.5235988f), s30 = std::sin(0.5235988f);
  // Rotation by 30 degrees about z, then tilted about x by 90: columns stay orthogonal.
  s.columns = {{{0.5f * c30, 0.5f * s30, 0.0f}, {0.0f, 0.0f, 0.6f}, {0.7f * s30, -0.7f * c30, 0}}};
  s.centre = {-10.0f, 25.0f, 40.0f};
  return s;
}

TEST(IgtlSource, ObliqueMatrixInRasAndLpsGivesDirectionAndCornerOrigin) {
  const ImageSpec ras = oblique(1), lps = oblique(2);
  IgtlTestServer server(image(ras) + image(lps));
  auto source = open(server);
  ASSERT_TRUE(source);
  for (const ImageSpec* spec : {&ras, &lps}) {
    auto v = next_event(*source);
    ASSERT_TRUE(v) << to_string(v.error());
    expect_geometry(*v, *spec);
  }
}

TEST(IgtlSource, Version2HeadersMetadataAndMessageIdGapsMakeLost) {
  MessageSpec v2;
  v2.version = 2;
  Bytes script;
  for (std::uint32_t id : {1u, 2u, 5u}) {
    v2.message_id = id;
    script = script + image({}, v2);
  }
  IgtlTestServer server(script);
  auto source = open(server);
  ASSERT_TRUE(source);
  EXPECT_EQ(next_event(*source)->sequence, 0u);
  EXPECT_EQ(next_event(*source)->sequence, 1u);
  auto lost = next_event(*source);
  ASSERT_FALSE(lost);
  EXPECT_EQ(lost.error().code, AcquireError::Code::Lost);
  EXPECT_EQ(lost.error().sequence, std::optional<std::uint64_t>(2));
  EXPECT_EQ(lost.error().count, 2u);
  auto v = next_event(*source);
  ASSERT_TRUE(v) << to_string(v.error());
  EXPECT_EQ(v->sequence, 4u);
  expect_voxels(*v, false);
}

TEST(IgtlSource, OtherTypesAndDevicesAreReadAndSkipped) {
  MessageSpec transform{.type = "TRANSFORM", .device = "ProbeToTracker"};
  MessageSpec status{.version = 2, .type = "STATUS", .device = "", .message_id = 9};
  MessageSpec other{.device = "Image_Other"};
  const Bytes script = test::message(transform, Bytes(48, 0)) + image() +
                       test::message(status, Bytes(30, 0)) + image({}, other) +
                       test::message({.type = "STRING"}, Bytes{0, 3, 0, 2, 'o', 'k'}) + image();
  IgtlTestServer server(script);
  auto source = open(server, "?device=Image_Reference");
  ASSERT_TRUE(source);
  EXPECT_EQ(next_event(*source)->sequence, 0u);
  EXPECT_EQ(next_event(*source)->sequence, 1u) << "Image_Other and the rest are not volumes";
  EXPECT_EQ(source->next(300ms).error().code, AcquireError::Code::Timeout);
}

// Every unusable IMAGE is one BadRecord with its own sequence, and the stream goes on.
TEST(IgtlSource, UnusableImagesAreRejectedWithTheReason) {
  ImageSpec int16, rgb, sub, short_data, huge;
  int16.scalar = 4;
  rgb.components = 3;
  sub.sub_size = {12, 10, 4};
  short_data.data_bytes_delta = -5;
  huge.size = {60000, 60000, 60000};
  huge.no_data = true;
  const std::vector<std::pair<Bytes, std::string>> bad = {
      {image(int16), "int16"},
      {image(rgb), "3 components"},
      {image(sub), "not the whole image"},
      {image(short_data), "image data is"},
      {image({}, {.corrupt_crc = true}), "CRC-64 mismatch"},
      {image(huge), "outside 1..1024"},
  };
  Bytes script;
  for (const auto& [bytes, why] : bad) script = script + bytes;
  IgtlTestServer server(script + image());
  auto source = open(server);
  ASSERT_TRUE(source);
  for (std::size_t k = 0; k < bad.size(); ++k) {
    auto r = next_event(*source);
    ASSERT_FALSE(r) << "message " << k << " should be rejected";
    EXPECT_EQ(r.error().code, AcquireError::Code::BadRecord);
    EXPECT_EQ(r.error().sequence, std::optional<std::uint64_t>(k));
    EXPECT_NE(r.error().detail.find(bad[k].second), std::string::npos) << r.error().detail;
  }
  auto good = next_event(*source);
  ASSERT_TRUE(good) << to_string(good.error());
  EXPECT_EQ(good->sequence, bad.size());
}

TEST(IgtlSource, AbsurdBodySizeIsRefusedBeforeAllocating) {
  MessageSpec claims{.body_bytes_override = 1ull << 50};
  IgtlTestServer server(image({}, claims), /*close_after_script=*/true);
  auto source = open(server);
  ASSERT_TRUE(source);
  auto r = next_event(*source);
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code, AcquireError::Code::BadRecord);
  EXPECT_NE(r.error().detail.find("exceeds the limit"), std::string::npos) << r.error().detail;
  EXPECT_EQ(next_event(*source).error().code, AcquireError::Code::Disconnected)
      << "the truncation of the skipped body is not reported twice";
}

TEST(IgtlSource, TruncatedBodyIsIncompleteThenDisconnected) {
  Bytes cut = image();
  cut.resize(cut.size() - 100);
  IgtlTestServer server(image() + cut, /*close_after_script=*/true);
  auto source = open(server);
  ASSERT_TRUE(source);
  EXPECT_EQ(next_event(*source)->sequence, 0u);
  auto r = next_event(*source);
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code, AcquireError::Code::Incomplete);
  EXPECT_EQ(r.error().sequence, std::optional<std::uint64_t>(1));
  EXPECT_EQ(next_event(*source).error().code, AcquireError::Code::Disconnected);
}

TEST(IgtlSource, GarbageHeaderLosesFramingAndReconnects) {
  Bytes garbage(58, 0xff);
  IgtlTestServer server(image() + garbage + image());
  auto source = open(server);
  ASSERT_TRUE(source);
  EXPECT_EQ(next_event(*source)->sequence, 0u);
  auto r = next_event(*source);
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code, AcquireError::Code::BadRecord);
  EXPECT_NE(r.error().detail.find("framing lost"), std::string::npos);
  EXPECT_EQ(next_event(*source).error().code, AcquireError::Code::Disconnected);
  auto again = next_event(*source);
  ASSERT_TRUE(again) << to_string(again.error());
  EXPECT_EQ(again->sequence, 1u) << "the new connection's first image";
  EXPECT_EQ(server.accepted(), 2);
}

TEST(IgtlSource, ServerRestartIsReconnectedWithBackoff) {
  auto server = std::make_unique<IgtlTestServer>(image(), /*close_after_script=*/true);
  const int port = server->port();
  auto source = open(*server);
  ASSERT_TRUE(source);
  EXPECT_EQ(next_event(*source)->sequence, 0u);
  EXPECT_EQ(next_event(*source).error().code, AcquireError::Code::Disconnected);
  server.reset();  // the server is gone; the source keeps trying
  EXPECT_EQ(source->next(200ms).error().code, AcquireError::Code::Timeout);
  server = std::make_unique<IgtlTestServer>(image(), /*close_after_script=*/false, port);
  ASSERT_TRUE(server->ok());
  auto v = next_event(*source);
  ASSERT_TRUE(v) << to_string(v.error());
  EXPECT_EQ(v->sequence, 1u);
}

TEST(IgtlSource, BadUrisAreRefused) {
  EXPECT_EQ(open_source("igtl:localhost").error().code, AcquireError::Code::InvalidArgument);
  EXPECT_EQ(open_source("igtl:localhost:1?devise=x").error().code,
            AcquireError::Code::InvalidArgument);
  EXPECT_EQ(open_source("igtl:localhost:1?device=").error().code,
            AcquireError::Code::InvalidArgument);
  EXPECT_EQ(open_source("igtl:127.0.0.1:1").error().code, AcquireError::Code::NotFound)
      << "nobody listens on port 1";
}

}  // namespace
}  // namespace sonomesh::acquire
