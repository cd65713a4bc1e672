// NRRD and MetaImage reading/writing: round trips, hand-written headers, malformed files.
#include <gtest/gtest.h>
#include <unistd.h>
#include <zlib.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <thread>
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
    path_ = fs::temp_directory_path() /
            ("sonomesh_volume_io_" + name + "_" + std::to_string(::getpid()));
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
      case VoxelType::UInt8:
        v.u8()[i] = static_cast<std::uint8_t>(rng());
        break;
      case VoxelType::UInt16:
        v.u16()[i] = static_cast<std::uint16_t>(rng());
        break;
      case VoxelType::Float32:
        v.f32()[i] = static_cast<float>(rng() % 100000) / 7.0f - 5000.0f;
        break;
    }
  }
  return v;
}

bool same_voxels(const Volume& a, const Volume& b) {
  if (a.type() != b.type() || a.dims() != b.dims()) return false;
  switch (a.type()) {
    case VoxelType::UInt8:
      return a.u8() == b.u8();
    case VoxelType::UInt16:
      return a.u16() == b.u16();
    case VoxelType::Float32:
      return a.f32() == b.f32();
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

class RoundTrip : public ::testing::TestWithParam<std::tuple<std::string, VoxelType, Compression>> {
};

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
    ::testing::Combine(::testing::Values(std::string(".nrrd"), std::string(".nhdr"),
                                         std::string(".mha"), std::string(".mhd")),
                       ::testing::Values(VoxelType::UInt8, VoxelType::UInt16, VoxelType::Float32),
                       ::testing::Values(Compression::Raw, Compression::Gzip)),
    [](const auto& info) {
      return std::string(ext_name(std::get<0>(info.param))) + "_" +
             to_string(std::get<1>(info.param)) +
             (std::get<2>(info.param) == Compression::Gzip ? "_gzip" : "_raw");
    });

TEST(NrrdWrite, HeaderCarriesLpsSpaceDirectionsAndOrigin) {
  TempDir dir;
  const Volume v = random_volume(VoxelType::UInt8);
  ASSERT_FALSE(write_volume(v, dir / "h.nhdr").has_value());
  const std::string header = read_file(dir / "h.nhdr");
  EXPECT_NE(header.find("space: left-posterior-superior"), std::string::npos) << header;
  EXPECT_NE(header.find("space directions: (0.5,0,0) (0,0.75,0) (0,0,1.25)"), std::string::npos)
      << header;
  EXPECT_NE(header.find("space origin: (-3,4.5,10.25)"), std::string::npos) << header;
  EXPECT_NE(header.find("sizes: 13 11 7"), std::string::npos) << header;
}

// ---------------------------------------------------------------------------------------------
// Hand-written headers: orientation handling.

namespace {

// A 3x2x2 volume whose file voxel (i, j, k) holds i + 3j + 6k.
constexpr int kNx = 3, kNy = 2, kNz = 2;
int file_value(int i, int j, int k) { return i + kNx * j + kNx * kNy * k; }

std::string mha_header(const std::string& matrix, const std::string& extra = "",
                       const std::string& type = "MET_UCHAR", const std::string& dims = "3 2 2",
                       const std::string& data_file = "LOCAL") {
  return "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n" +
         extra + "TransformMatrix = " + matrix +
         "\nOffset = 10 20 30\nElementSpacing = 1 2 3\nDimSize = " + dims +
         "\nElementType = " + type + "\nElementDataFile = " + data_file + "\n";
}

std::string nrrd_header(const std::string& directions, const std::string& extra = "",
                        const std::string& type = "uint8", const std::string& sizes = "3 2 2") {
  return "NRRD0004\ntype: " + type +
         "\ndimension: 3\nspace: left-posterior-superior\nsizes: " + sizes +
         "\nspace directions: " + directions + "\nkinds: domain domain domain\nendian: little\n" +
         extra + "space origin: (10,20,30)\n";
}

// Every file voxel must be found at its physical position in the loaded volume.
void expect_matches_file_geometry(const Volume& v, const Vec3f& file_origin,
                                  const Vec3f& axis_sign) {
  ASSERT_EQ(v.dims(), Vec3i(kNx, kNy, kNz));
  EXPECT_TRUE(v.spacing_mm().isApprox(Vec3f(1, 2, 3)));
  for (int k = 0; k < kNz; ++k)
    for (int j = 0; j < kNy; ++j)
      for (int i = 0; i < kNx; ++i) {
        const Vec3f p =
            file_origin + axis_sign.cwiseProduct(Vec3f(1, 2, 3)).cwiseProduct(Vec3f(i, j, k));
        EXPECT_FLOAT_EQ(sample_mm(v, p), static_cast<float>(file_value(i, j, k))) << i << j << k;
      }
}

}  // namespace

TEST(MetaImageOrientation, FlippedAxesAreResolvedIntoData) {
  TempDir dir;
  const auto path = dir / "flip.mha";
  write_file(path, mha_header("1 0 0 0 -1 0 0 0 -1") + bytes_0_to(12));
  const auto r = read_volume(path);
  ASSERT_TRUE(r) << r.error->message;
  EXPECT_TRUE(r.volume.origin_mm().isApprox(Vec3f(10, 18, 27))) << r.volume.origin_mm().transpose();
  // Data order: new (i, j, k) is file (i, 1 - j, 1 - k).
  EXPECT_EQ(r.volume.value(0, 0, 0), file_value(0, 1, 1));
  EXPECT_EQ(r.volume.value(2, 1, 1), file_value(2, 0, 0));
  EXPECT_EQ(r.volume.value(1, 0, 1), file_value(1, 1, 0));
  expect_matches_file_geometry(r.volume, Vec3f(10, 20, 30), Vec3f(1, -1, -1));

  // Identity keeps the order; a flip along x alone works as well.
  write_file(path, mha_header("1 0 0 0 1 0 0 0 1") + bytes_0_to(12));
  const auto id = read_volume(path);
  ASSERT_TRUE(id) << id.error->message;
  EXPECT_TRUE(id.volume.origin_mm().isApprox(Vec3f(10, 20, 30)));
  expect_matches_file_geometry(id.volume, Vec3f(10, 20, 30), Vec3f(1, 1, 1));
  write_file(path, mha_header("-1 0 0 0 1 0 0 0 1") + bytes_0_to(12));
  const auto fx = read_volume(path);
  ASSERT_TRUE(fx) << fx.error->message;
  expect_matches_file_geometry(fx.volume, Vec3f(10, 20, 30), Vec3f(-1, 1, 1));
}

// Oblique and permuted axes are kept as the volume's direction; the voxels stay in file order and
// grid_to_world_mm puts each one where the file says.
void expect_world_positions(const Volume& v, const Vec3f& origin, const Mat3f& axes_times_spacing) {
  for (int k = 0; k < 2; ++k)
    for (int j = 0; j < 2; ++j)
      for (int i = 0; i < 3; ++i) {
        EXPECT_EQ(v.value(i, j, k), file_value(i, j, k));
        const Vec3f world = v.grid_to_world_mm(v.index_to_mm(Vec3f(i, j, k)));
        const Vec3f expected = origin + axes_times_spacing * Vec3f(i, j, k);
        EXPECT_LT((world - expected).norm(), 1e-4f)
            << world.transpose() << " vs " << expected.transpose();
      }
}

TEST(MetaImageOrientation, ObliqueAndPermutedMatricesAreKeptAsDirection) {
  TempDir dir;
  const auto path = dir / "oblique.mha";
  const float h = 0.70710678f;
  write_file(path,
             mha_header("0.70710678 0.70710678 0 -0.70710678 0.70710678 0 0 0 1") + bytes_0_to(12));
  auto r = read_volume(path);
  ASSERT_TRUE(r) << r.error->message;
  Mat3f axes;  // columns: axis directions times ElementSpacing (1 2 3)
  axes << h, -2 * h, 0, h, 2 * h, 0, 0, 0, 3;
  expect_world_positions(r.volume, Vec3f(10, 20, 30), axes);
  EXPECT_TRUE(r.volume.spacing_mm().isApprox(Vec3f(1, 2, 3)));
  write_file(path, mha_header("0 1 0 1 0 0 0 0 1") + bytes_0_to(12));
  r = read_volume(path);
  ASSERT_TRUE(r) << r.error->message;
  axes << 0, 2, 0, 1, 0, 0, 0, 0, 3;
  expect_world_positions(r.volume, Vec3f(10, 20, 30), axes);
}

TEST(MetaImageOrientation, NonOrthogonalAndDegenerateMatricesAreRefused) {
  TempDir dir;
  const auto path = dir / "sheared.mha";
  write_file(path, mha_header("1 0 0 0.6 0.8 0 0 0 1") + bytes_0_to(12));
  expect_error(path, Code::UnsupportedOrientation);
  write_file(path, mha_header("1 0 0 1 0 0 0 0 1") + bytes_0_to(12));
  expect_error(path, Code::UnsupportedOrientation);
}

TEST(NrrdOrientation, NegativeSpaceDirectionFlipsData) {
  TempDir dir;
  const auto path = dir / "flip.nrrd";
  write_file(path, nrrd_header("(1,0,0) (0,-2,0) (0,0,3)") + "encoding: raw\n\n" + bytes_0_to(12));
  const auto r = read_volume(path);
  ASSERT_TRUE(r) << r.error->message;
  EXPECT_TRUE(r.volume.origin_mm().isApprox(Vec3f(10, 18, 30))) << r.volume.origin_mm().transpose();
  EXPECT_EQ(r.volume.value(0, 0, 0), file_value(0, 1, 0));
  expect_matches_file_geometry(r.volume, Vec3f(10, 20, 30), Vec3f(1, -1, 1));
}

TEST(NrrdOrientation, RasSpaceIsConvertedToLps) {
  TempDir dir;
  const auto path = dir / "ras.nrrd";
  std::string h = nrrd_header("(1,0,0) (0,2,0) (0,0,3)") + "encoding: raw\n\n" + bytes_0_to(12);
  h.replace(h.find("left-posterior-superior"), 23, "right-anterior-superior");
  write_file(path, h);
  const auto r = read_volume(path);
  ASSERT_TRUE(r) << r.error->message;
  // RAS (x, y, z) is LPS (-x, -y, z): both in-plane axes now point the other way.
  expect_matches_file_geometry(r.volume, Vec3f(-10, -20, 30), Vec3f(-1, -1, 1));
}

TEST(NrrdOrientation, ObliqueDirectionsAreKeptAndShearIsRefused) {
  TempDir dir;
  const auto path = dir / "oblique.nrrd";
  write_file(
      path, nrrd_header("(0.8,0.6,0) (-1.2,1.6,0) (0,0,3)") + "encoding: raw\n\n" + bytes_0_to(12));
  const auto r = read_volume(path);
  ASSERT_TRUE(r) << r.error->message;
  Mat3f axes;
  axes << 0.8f, -1.2f, 0, 0.6f, 1.6f, 0, 0, 0, 3;
  expect_world_positions(r.volume, Vec3f(10, 20, 30), axes);
  EXPECT_TRUE(r.volume.spacing_mm().isApprox(Vec3f(1, 2, 3)));
  write_file(path,
             nrrd_header("(0.8,0.6,0) (1.2,1.6,0) (0,0,3)") + "encoding: raw\n\n" + bytes_0_to(12));
  expect_error(path, Code::UnsupportedOrientation);
  write_file(path, nrrd_header("(1,0,0) (2,0,0) (0,0,3)") + "encoding: raw\n\n" + bytes_0_to(12));
  expect_error(path, Code::UnsupportedOrientation);
}

TEST(NrrdRead, DetachedHeaderWithGzipDataAndPlainSpacings) {
  TempDir dir;
  // gzip file written by zlib's gz* API, referenced from a hand-written detached header.
  const std::string data = bytes_0_to(12);
  gzFile gz = gzopen((dir / "d.raw.gz").c_str(), "wb");
  gzwrite(gz, data.data(), static_cast<unsigned>(data.size()));
  gzclose(gz);
  write_file(dir / "d.nhdr",
             "NRRD0004\ntype: unsigned char\ndimension: 3\nsizes: 3 2 2\n"
             "spacings: 1 2 3\nencoding: gzip\ndata file: d.raw.gz\n");
  const auto r = read_volume(dir / "d.nhdr");
  ASSERT_TRUE(r) << r.error->message;
  EXPECT_TRUE(r.volume.origin_mm().isApprox(Vec3f(0, 0, 0)));
  expect_matches_file_geometry(r.volume, Vec3f(0, 0, 0), Vec3f(1, 1, 1));
}

TEST(MetaImageRead, DetachedRawAndZlibAttachedAndBigEndianAndShortConversion) {
  TempDir dir;
  write_file(dir / "d.raw", bytes_0_to(12));
  write_file(dir / "d.mhd", mha_header("1 0 0 0 1 0 0 0 1", "", "MET_UCHAR", "3 2 2", "d.raw"));
  const auto r = read_volume(dir / "d.mhd");
  ASSERT_TRUE(r) << r.error->message;
  expect_matches_file_geometry(r.volume, Vec3f(10, 20, 30), Vec3f(1, 1, 1));

  const std::string z = zlib_compress(bytes_0_to(12));
  write_file(dir / "z.mha",
             mha_header("1 0 0 0 1 0 0 0 1", "CompressedData = True\nCompressedDataSize = " +
                                                 std::to_string(z.size()) + "\n") +
                 z);
  const auto rz = read_volume(dir / "z.mha");
  ASSERT_TRUE(rz) << rz.error->message;
  expect_matches_file_geometry(rz.volume, Vec3f(10, 20, 30), Vec3f(1, 1, 1));

  // Big-endian uint16: bytes (0, v) per voxel.
  std::string be;
  for (int n = 0; n < 12; ++n) be += std::string{'\0', static_cast<char>(n)};
  std::string h = mha_header("1 0 0 0 1 0 0 0 1", "", "MET_USHORT");
  h.replace(h.find("BinaryDataByteOrderMSB = False"), 30, "BinaryDataByteOrderMSB = True");
  write_file(dir / "be.mha", h + be);
  const auto rbe = read_volume(dir / "be.mha");
  ASSERT_TRUE(rbe) << rbe.error->message;
  ASSERT_EQ(rbe.volume.type(), VoxelType::UInt16);
  expect_matches_file_geometry(rbe.volume, Vec3f(10, 20, 30), Vec3f(1, 1, 1));

  // Signed shorts are converted to float, negative values kept.
  std::string le;
  for (int n = 0; n < 12; ++n) {
    const std::int16_t v = static_cast<std::int16_t>(-n);
    le.append(reinterpret_cast<const char*>(&v), 2);
  }
  write_file(dir / "s.mha", mha_header("1 0 0 0 1 0 0 0 1", "", "MET_SHORT") + le);
  const auto rs = read_volume(dir / "s.mha");
  ASSERT_TRUE(rs) << rs.error->message;
  ASSERT_EQ(rs.volume.type(), VoxelType::Float32);
  EXPECT_EQ(rs.volume.value(2, 1, 1), -11.0f);
}

// The header is read a block at a time (not as one 1 MiB buffer per file): a header whose lines
// cross block boundaries reads as before, and the 1 MiB limit still holds.
TEST(MetaImageRead, HeaderAcrossReadBlocksAndHeaderLimit) {
  TempDir dir;
  const std::string pad = "Comment = " + std::string(5000, 'x') + "\n";  // > one 4 KiB block
  write_file(dir / "long.mha", mha_header("1 0 0 0 1 0 0 0 1", pad) + bytes_0_to(12));
  const auto r = read_volume(dir / "long.mha");
  ASSERT_TRUE(r) << r.error->message;
  expect_matches_file_geometry(r.volume, Vec3f(10, 20, 30), Vec3f(1, 1, 1));

  std::string lines;  // many short lines, ElementDataFile at ~9 KiB into the file
  for (int i = 0; i < 900; ++i) lines += "Comment = c\n";
  write_file(dir / "lines.mha", mha_header("1 0 0 0 1 0 0 0 1", lines) + bytes_0_to(12));
  const auto rl = read_volume(dir / "lines.mha");
  ASSERT_TRUE(rl) << rl.error->message;
  EXPECT_EQ(rl.volume.value(2, 1, 1), 11);

  const std::string huge = "Comment = " + std::string(std::size_t{1} << 20, 'x') + "\n";
  write_file(dir / "huge.mha", mha_header("1 0 0 0 1 0 0 0 1", huge) + bytes_0_to(12));
  const auto rh = read_volume(dir / "huge.mha");
  ASSERT_FALSE(rh);
  EXPECT_EQ(rh.error->code, Code::BadHeader);
  EXPECT_NE(rh.error->message.find("longer than 1 MiB"), std::string::npos) << rh.error->message;
}

// ---------------------------------------------------------------------------------------------
// Malformed files: each gets its own code and a one-line message; nothing crashes.

TEST(Malformed, MissingFileAndUnknownExtension) {
  TempDir dir;
  expect_error(dir / "nothing.nrrd", Code::NotFound);
  expect_error(dir / "nothing.mha", Code::NotFound);
  write_file(dir / "vol.tiff", "II*");
  expect_error(dir / "vol.tiff", Code::UnknownFormat);
}

TEST(Malformed, RandomBytesAreUnknownFormat) {
  TempDir dir;
  std::mt19937 rng(5);
  std::string junk(4096, '\0');
  for (char& c : junk) c = static_cast<char>(rng());
  write_file(dir / "junk.nrrd", junk);
  write_file(dir / "junk.mha", junk);
  write_file(dir / "junk.nhdr", junk);
  write_file(dir / "junk.mhd", junk);
  expect_error(dir / "junk.nrrd", Code::UnknownFormat);
  expect_error(dir / "junk.nhdr", Code::UnknownFormat);
  expect_error(dir / "junk.mha", Code::UnknownFormat);
  expect_error(dir / "junk.mhd", Code::UnknownFormat);
  write_file(dir / "empty.nrrd", "");
  write_file(dir / "empty.mha", "");
  expect_error(dir / "empty.nrrd", Code::UnknownFormat);
  expect_error(dir / "empty.mha", Code::UnknownFormat);
}

TEST(Malformed, TruncatedData) {
  TempDir dir;
  const Volume v = random_volume(VoxelType::UInt16);
  for (const std::string name : {"t.nrrd", "t.mha"}) {
    ASSERT_FALSE(write_volume(v, dir / name).has_value());
    fs::resize_file(dir / name, fs::file_size(dir / name) - 100);
    expect_error(dir / name, Code::TruncatedData);
  }
  ASSERT_FALSE(write_volume(v, dir / "t.mhd").has_value());
  fs::resize_file(dir / "t.raw", 10);
  expect_error(dir / "t.mhd", Code::TruncatedData);
  ASSERT_FALSE(write_volume(v, dir / "t2.nhdr").has_value());
  fs::resize_file(dir / "t2.raw", 10);
  expect_error(dir / "t2.nhdr", Code::TruncatedData);
  // Compressed payload cut in half: CompressedDataSize promises more than is there.
  ASSERT_FALSE(write_volume(v, dir / "tz.mha", Compression::Gzip).has_value());
  fs::resize_file(dir / "tz.mha", fs::file_size(dir / "tz.mha") - 200);
  expect_error(dir / "tz.mha", Code::TruncatedData);
  // A zlib stream that decodes to fewer voxels than the header announces.
  const std::string z = zlib_compress(bytes_0_to(6));
  write_file(dir / "short.mha", mha_header("1 0 0 0 1 0 0 0 1", "CompressedData = True\n") + z);
  expect_error(dir / "short.mha", Code::TruncatedData);
}

TEST(Malformed, SizesThatDoNotMatch) {
  TempDir dir;
  // Detached data larger than the header's dimensions.
  write_file(dir / "big.raw", bytes_0_to(20));
  write_file(dir / "big.mhd", mha_header("1 0 0 0 1 0 0 0 1", "", "MET_UCHAR", "3 2 2", "big.raw"));
  expect_error(dir / "big.mhd", Code::SizeMismatch);
  write_file(dir / "big.nhdr",
             nrrd_header("(1,0,0) (0,2,0) (0,0,3)") + "encoding: raw\ndata file: big.raw\n");
  expect_error(dir / "big.nhdr", Code::SizeMismatch);
  // Attached data with trailing bytes.
  write_file(dir / "big.mha", mha_header("1 0 0 0 1 0 0 0 1") + bytes_0_to(13));
  expect_error(dir / "big.mha", Code::SizeMismatch);
  // DimSize with two values for NDims 3.
  write_file(dir / "dims.mha",
             mha_header("1 0 0 0 1 0 0 0 1", "", "MET_UCHAR", "3 4") + bytes_0_to(12));
  expect_error(dir / "dims.mha", Code::SizeMismatch);
  // A zlib stream holding more voxels than announced.
  const std::string z = zlib_compress(bytes_0_to(24));
  write_file(dir / "zbig.mha", mha_header("1 0 0 0 1 0 0 0 1", "CompressedData = True\n") + z);
  expect_error(dir / "zbig.mha", Code::SizeMismatch);
}

TEST(Malformed, UnknownVoxelTypes) {
  TempDir dir;
  write_file(dir / "t.mha", mha_header("1 0 0 0 1 0 0 0 1", "", "MET_FOO") + bytes_0_to(12));
  expect_error(dir / "t.mha", Code::UnsupportedType);
  write_file(dir / "t.nrrd", nrrd_header("(1,0,0) (0,2,0) (0,0,3)", "", "quaternion") +
                                 "encoding: raw\n\n" + bytes_0_to(12));
  expect_error(dir / "t.nrrd", Code::UnsupportedType);
  write_file(dir / "rgb.mha",
             mha_header("1 0 0 0 1 0 0 0 1", "ElementNumberOfChannels = 3\n") + bytes_0_to(36));
  expect_error(dir / "rgb.mha", Code::UnsupportedType);
}

TEST(Malformed, AbsurdDimensionsFailBeforeAllocating) {
  TempDir dir;
  // 10^15 voxels: over the voxel limit.
  write_file(
      dir / "huge.mha",
      mha_header("1 0 0 0 1 0 0 0 1", "", "MET_FLOAT", "100000 100000 100000") + bytes_0_to(12));
  write_file(dir / "huge.nrrd",
             nrrd_header("(1,0,0) (0,2,0) (0,0,3)", "", "float", "100000 100000 100000") +
                 "encoding: raw\n\n" + bytes_0_to(12));
  const auto t0 = std::chrono::steady_clock::now();
  expect_error(dir / "huge.mha", Code::BadDimensions);
  expect_error(dir / "huge.nrrd", Code::BadDimensions);
  // 10^9 voxels is within the default limit, but the file holds 12 bytes: refused from the file
  // size, again before any allocation.
  write_file(dir / "big.mha",
             mha_header("1 0 0 0 1 0 0 0 1", "", "MET_UCHAR", "1000 1000 1000") + bytes_0_to(12));
  write_file(dir / "big.nrrd",
             nrrd_header("(1,0,0) (0,2,0) (0,0,3)", "", "uint8", "1000 1000 1000") +
                 "encoding: raw\n\n" + bytes_0_to(12));
  write_file(dir / "bigz.mha", mha_header("1 0 0 0 1 0 0 0 1", "CompressedData = True\n",
                                          "MET_UCHAR", "1000 1000 1000") +
                                   zlib_compress(bytes_0_to(12)));
  expect_error(dir / "big.mha", Code::TruncatedData);
  expect_error(dir / "big.nrrd", Code::TruncatedData);
  expect_error(dir / "bigz.mha", Code::TruncatedData);
  // Allocating and filling gigabytes would take far longer than this.
  EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::seconds(2));
  // Non-positive and overflowing sizes; a custom lower limit.
  write_file(dir / "neg.mha",
             mha_header("1 0 0 0 1 0 0 0 1", "", "MET_UCHAR", "3 -2 2") + bytes_0_to(12));
  expect_error(dir / "neg.mha", Code::BadDimensions);
  write_file(dir / "zero.nrrd",
             nrrd_header("(1,0,0) (0,2,0) (0,0,3)", "", "uint8", "3 0 2") + "encoding: raw\n\n");
  const auto rz = read_volume(dir / "zero.nrrd");
  EXPECT_FALSE(rz);
  write_file(dir / "ovf.mha",
             mha_header("1 0 0 0 1 0 0 0 1", "", "MET_UCHAR", "4294967296 4294967296 4294967296") +
                 bytes_0_to(12));
  expect_error(dir / "ovf.mha", Code::BadDimensions);
  write_file(dir / "ok.mha", mha_header("1 0 0 0 1 0 0 0 1") + bytes_0_to(12));
  ReadOptions tight;
  tight.max_voxels = 11;
  expect_error(dir / "ok.mha", Code::BadDimensions, tight);
  write_file(dir / "twod.mha",
             "ObjectType = Image\nNDims = 2\nDimSize = 3 4\nElementType = MET_UCHAR\n"
             "ElementDataFile = LOCAL\n" +
                 bytes_0_to(12));
  expect_error(dir / "twod.mha", Code::BadDimensions);
}

TEST(Malformed, MissingDetachedDataFile) {
  TempDir dir;
  write_file(dir / "m.mhd", mha_header("1 0 0 0 1 0 0 0 1", "", "MET_UCHAR", "3 2 2", "gone.raw"));
  expect_error(dir / "m.mhd", Code::NotFound);
  write_file(dir / "m.nhdr",
             nrrd_header("(1,0,0) (0,2,0) (0,0,3)") + "encoding: raw\ndata file: gone.raw\n");
  expect_error(dir / "m.nhdr", Code::NotFound);
}

TEST(Malformed, CorruptCompressedData) {
  TempDir dir;
  std::string junk(64, '\0');
  std::mt19937 rng(9);
  for (char& c : junk) c = static_cast<char>(rng());
  write_file(dir / "bad.mha", mha_header("1 0 0 0 1 0 0 0 1", "CompressedData = True\n") + junk);
  expect_error(dir / "bad.mha", Code::Compression);
  write_file(dir / "bad.nrrd",
             nrrd_header("(1,0,0) (0,2,0) (0,0,3)") + "encoding: gzip\n\n" + junk);
  expect_error(dir / "bad.nrrd", Code::Compression);
  // A valid gzip header followed by garbage.
  std::string gz_head = "\x1f\x8b\x08\x00\x00\x00\x00\x00\x00\x03";
  write_file(dir / "bad2.nrrd",
             nrrd_header("(1,0,0) (0,2,0) (0,0,3)") + "encoding: gzip\n\n" + gz_head + junk);
  expect_error(dir / "bad2.nrrd", Code::Compression);
}

TEST(Malformed, BadHeaders) {
  TempDir dir;
  write_file(dir / "nodims.mha",
             "ObjectType = Image\nNDims = 3\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n");
  expect_error(dir / "nodims.mha", Code::BadHeader);
  write_file(dir / "noend.mha", "ObjectType = Image\nNDims = 3\nDimSize = 3 2 2\n");
  expect_error(dir / "noend.mha", Code::BadHeader);
  write_file(dir / "text.mha",
             mha_header("1 0 0 0 1 0 0 0 1", "", "MET_UCHAR", "3 x 2") + bytes_0_to(12));
  expect_error(dir / "text.mha", Code::BadHeader);
  write_file(dir / "sp.mha",
             "ObjectType = Image\nNDims = 3\nDimSize = 3 2 2\nElementSpacing = 1 0 1\n"
             "ElementType = MET_UCHAR\nElementDataFile = LOCAL\n" +
                 bytes_0_to(12));
  expect_error(dir / "sp.mha", Code::BadHeader);
  write_file(dir / "bad.nrrd",
             "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 3 2\nencoding: raw\n\n" + bytes_0_to(12));
  const auto r = read_volume(dir / "bad.nrrd");
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error->message.find('\n'), std::string::npos);
  write_file(
      dir / "fourd.nrrd",
      "NRRD0004\ntype: uint8\ndimension: 4\nsizes: 3 2 2 1\nencoding: raw\n\n" + bytes_0_to(12));
  expect_error(dir / "fourd.nrrd", Code::BadDimensions);
}

TEST(Write, ErrorsAreValues) {
  TempDir dir;
  const Volume v = random_volume(VoxelType::UInt8);
  const auto a = write_volume(v, dir / "no_such_dir" / "x.nrrd");
  ASSERT_TRUE(a.has_value());
  EXPECT_EQ(a->code, Code::IoError);
  EXPECT_EQ(a->message.find('\n'), std::string::npos) << a->message;
  const auto b = write_volume(v, dir / "no_such_dir" / "x.mha");
  ASSERT_TRUE(b.has_value());
  EXPECT_EQ(b->code, Code::IoError);
  const auto c = write_volume(v, dir / "x.png");
  ASSERT_TRUE(c.has_value());
  EXPECT_EQ(c->code, Code::UnknownFormat);
  EXPECT_TRUE(write_volume(Volume{}, dir / "e.nrrd").has_value());
}

TEST(Malformed, OutOfRangeGeometryIsBadHeader) {
  TempDir dir;
  write_file(dir / "sp.nrrd",
             nrrd_header("(1e300,0,0) (0,2,0) (0,0,3)") + "encoding: raw\n\n" + bytes_0_to(12));
  expect_error(dir / "sp.nrrd", Code::BadHeader);
  write_file(dir / "tiny.nrrd",
             nrrd_header("(1e-300,0,0) (0,2,0) (0,0,3)") + "encoding: raw\n\n" + bytes_0_to(12));
  expect_error(dir / "tiny.nrrd", Code::BadHeader);
  std::string h = mha_header("1 0 0 0 1 0 0 0 1") + bytes_0_to(12);
  h.replace(h.find("Offset = 10 20 30"), 17, "Offset = 1e300 0 0");
  write_file(dir / "org.mha", h);
  expect_error(dir / "org.mha", Code::BadHeader);
  std::string n = nrrd_header("(1,0,0) (0,2,0) (0,0,3)") + "encoding: raw\n\n" + bytes_0_to(12);
  n.replace(n.find("space origin: (10,20,30)"), 24, "space origin: (1e300,0,0)");
  write_file(dir / "org.nrrd", n);
  expect_error(dir / "org.nrrd", Code::BadHeader);
}

TEST(Malformed, EveryTruncationAndHeaderMutationIsHandled) {
  TempDir dir;
  Volume v(Vec3i(6, 5, 4), Vec3f(1, 1, 1), Vec3f(0, 0, 0), VoxelType::UInt16);
  for (std::size_t n = 0; n < v.voxel_count(); ++n) v.u16()[n] = static_cast<std::uint16_t>(n * 37);
  std::mt19937 rng(13);
  for (const std::string name : {"f.nrrd", "f.mha"})
    for (const Compression c : {Compression::Raw, Compression::Gzip}) {
      ASSERT_FALSE(write_volume(v, dir / name, c).has_value());
      const std::string good = read_file(dir / name);
      const std::size_t header_end = good.find(name == "f.nrrd" ? "\n\n" : "LOCAL\n");
      const fs::path cut = dir / ("cut_" + name);
      // Every cut inside the header and just after it, then random cuts in the data.
      std::vector<std::size_t> lengths;
      for (std::size_t len = 0; len < std::min(good.size(), header_end + 24); ++len)
        lengths.push_back(len);
      for (int n = 0; n < 20; ++n)
        lengths.push_back(header_end + rng() % (good.size() - header_end));
      for (const std::size_t len : lengths) {
        write_file(cut, good.substr(0, len));
        const auto r = read_volume(cut);
        // gzip's 8-byte trailer (CRC, size) is not needed to decode: Teem may accept its loss,
        // but only with every voxel intact.
        if (r && name == "f.nrrd" && c == Compression::Gzip && len + 8 >= good.size()) {
          EXPECT_TRUE(same_voxels(r.volume, v));
          continue;
        }
        ASSERT_FALSE(r) << name << " cut at " << len << " of " << good.size() << " was accepted";
        ASSERT_EQ(r.error->message.find('\n'), std::string::npos);
      }
      // Random single-byte changes in the header: any outcome but a crash, and a successful read
      // must be a consistent volume.
      for (int trial = 0; trial < 100; ++trial) {
        std::string bad = good;
        bad[rng() % header_end] = static_cast<char>(rng());
        write_file(cut, bad);
        const auto r = read_volume(cut);
        if (r) {
          ASSERT_EQ(r.volume.voxel_count(), r.volume.to_float().size());
        } else {
          ASSERT_EQ(r.error->message.find('\n'), std::string::npos) << r.error->message;
        }
      }
    }
}

TEST(Threads, ConcurrentReadsAndWritesAreIndependent) {
  TempDir dir;
  const Volume v = random_volume(VoxelType::UInt16);
  std::vector<std::thread> threads;
  std::atomic<int> ok{0};
  for (int t = 0; t < 4; ++t)
    threads.emplace_back([&, t] {
      for (int n = 0; n < 10; ++n) {
        const fs::path p = dir / ("t" + std::to_string(t) + (t % 2 ? ".nrrd" : ".mha"));
        if (write_volume(v, p, n % 2 ? Compression::Gzip : Compression::Raw)) return;
        const auto r = read_volume(p);
        const auto bad = read_volume(dir / "missing.nrrd");
        if (r && same_voxels(r.volume, v) && !bad) ++ok;
      }
    });
  for (auto& th : threads) th.join();
  EXPECT_EQ(ok.load(), 40);
}
