// NRRD and MetaImage reading/writing: round trips, hand-written headers, malformed files.
#include <gtest/gtest.h>

#include <zlib.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <tuple>

#include "volume/volume.h"

using namespace sonomesh::volume;
namespace fs = std::filesystem;
using Code = VolumeIoError::Code;

namespace {

class TempDir {
 public:
  TempDir() {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    std::string name = std::string(info->test_suite_name()) + "_" + info->name();
    for (char& c : name)
      if (c == '/') c = '_';
    path_ = fs::temp_directory_path() / ("sonomesh_volume_io_" + name + "_" + std::to_string(::getpid()));
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~TempDir() { fs::remove_all(path_); }
  fs::path operator/(const std::string& name) const { return path_ / name; }

 private:
  fs::path path_;
};

Volume random_volume(VoxelType type) {
  Volume v(Vec3i(13, 11, 7), Vec3f(0.5f, 0.75f, 1.25f), Vec3f(-3.0f, 4.5f, 10.25f), type);
  std::mt19937 rng(11);
  for (std::size_t i = 0; i < v.voxel_count(); ++i) {
    switch (type) {
      case VoxelType::UInt8: v.u8()[i] = static_cast<std::uint8_t>(rng()); break;
      case VoxelType::UInt16: v.u16()[i] = static_cast<std::uint16_t>(rng()); break;
      case VoxelType::Float32: v.f32()[i] = static_cast<float>(rng() % 100000) / 7.0f - 5000.0f; break;
    }
  }
  return v;
}

bool same_voxels(const Volume& a, const Volume& b) {
  if (a.type() != b.type() || a.dims() != b.dims()) return false;
  switch (a.type()) {
    case VoxelType::UInt8: return a.u8() == b.u8();
    case VoxelType::UInt16: return a.u16() == b.u16();
    case VoxelType::Float32: return a.f32() == b.f32();
  }
  return false;
}

void write_file(const fs::path& path, const std::string& bytes) {
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

std::string read_file(const fs::path& path) {
  std::ifstream f(path, std::ios::binary);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

std::string zlib_compress(const std::string& raw) {
  uLongf size = compressBound(static_cast<uLong>(raw.size()));
  std::string out(size, '\0');
  compress2(reinterpret_cast<Bytef*>(out.data()), &size, reinterpret_cast<const Bytef*>(raw.data()),
            static_cast<uLong>(raw.size()), 6);
  out.resize(size);
  return out;
}

std::string bytes_0_to(int n) {
  std::string s;
  for (int i = 0; i < n; ++i) s.push_back(static_cast<char>(i));
  return s;
}

// Expects a read to fail with `code` and a one-line message naming the file.
void expect_error(const fs::path& path, Code code, const ReadOptions& options = {}) {
  const auto r = read_volume(path, options);
  ASSERT_FALSE(r) << path << " was read but should fail";
  EXPECT_EQ(static_cast<int>(r.error->code), static_cast<int>(code)) << r.error->message;
  EXPECT_NE(r.error->message.find(path.filename().string()), std::string::npos) << r.error->message;
  EXPECT_EQ(r.error->message.find('\n'), std::string::npos) << r.error->message;
  EXPECT_TRUE(r.volume.empty());
}

const char* ext_name(const std::string& e) { return e.c_str() + 1; }

}  // namespace

// ---------------------------------------------------------------------------------------------
// Round trips: every format x voxel type x compression.

class RoundTrip : public ::testing::TestWithParam<std::tuple<std::string, VoxelType, Compression>> {};

TEST_P(RoundTrip, PreservesVoxelsAndGeometry) {
  const auto& [ext, type, compression] = GetParam();
  TempDir dir;
  const Volume v = random_volume(type);
  const fs::path path = dir / ("vol" + ext);
  const auto err = write_volume(v, path, compression);
  ASSERT_FALSE(err.has_value()) << err->message;
  // Detached formats put the voxels next to the header.
  const bool gz = compression == Compression::Gzip;
  if (ext == ".nhdr") {
    EXPECT_TRUE(fs::exists(dir / (gz ? "vol.raw.gz" : "vol.raw")));
  }
  if (ext == ".mhd") {
    EXPECT_TRUE(fs::exists(dir / (gz ? "vol.zraw" : "vol.raw")));
  }
  const auto r = read_volume(path);
  ASSERT_TRUE(r) << r.error->message;
  EXPECT_TRUE(same_voxels(r.volume, v));
  EXPECT_TRUE(r.volume.spacing_mm().isApprox(v.spacing_mm(), 1e-6f));
  EXPECT_TRUE(r.volume.origin_mm().isApprox(v.origin_mm(), 1e-6f));
  // Compression really compresses: an all-zero volume shrinks more than tenfold.
  if (gz) {
    Volume zeros(Vec3i(40, 40, 40), Vec3f(1, 1, 1), Vec3f(0, 0, 0), type);
    const fs::path zpath = dir / ("zeros" + ext);
    ASSERT_FALSE(write_volume(zeros, zpath, compression).has_value());
    std::uintmax_t total = fs::file_size(zpath);
    if (ext == ".nhdr") total += fs::file_size(dir / "zeros.raw.gz");
    if (ext == ".mhd") total += fs::file_size(dir / "zeros.zraw");
    EXPECT_LT(total, zeros.voxel_count() / 10);
    const auto rz = read_volume(zpath);
    ASSERT_TRUE(rz) << rz.error->message;
    EXPECT_TRUE(same_voxels(rz.volume, zeros));
  }
}

INSTANTIATE_TEST_SUITE_P(
    AllFormats, RoundTrip,
    ::testing::Combine(::testing::Values(std::string(".nrrd"), std::string(".nhdr"), std::string(".mha"),
                                         std::string(".mhd")),
                       ::testing::Values(VoxelType::UInt8, VoxelType::UInt16, VoxelType::Float32),
                       ::testing::Values(Compression::Raw, Compression::Gzip)),
    [](const auto& info) {
      return std::string(ext_name(std::get<0>(info.param))) + "_" + to_string(std::get<1>(info.param)) +
             (std::get<2>(info.param) == Compression::Gzip ? "_gzip" : "_raw");
    });

TEST(NrrdWrite, HeaderCarriesLpsSpaceDirectionsAndOrigin) {
  TempDir dir;
  const Volume v = random_volume(VoxelType::UInt8);
  ASSERT_FALSE(write_volume(v, dir / "h.nhdr").has_value());
  const std::string header = read_file(dir / "h.nhdr");
  EXPECT_NE(header.find("space: left-posterior-superior"), std::string::npos) << header;
  EXPECT_NE(header.find("space directions: (0.5,0,0) (0,0.75,0) (0,0,1.25)"), std::string::npos) << header;
  EXPECT_NE(header.find("space origin: (-3,4.5,10.25)"), std::string::npos) << header;
  EXPECT_NE(header.find("sizes: 13 11 7"), std::string::npos) << header;
}
