// Oblique geometry through every format, NIfTI-1 in and out, and the Slicer / ITK-SNAP label files.
#include <gtest/gtest.h>
#include <nifti1_io.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>

#include "tests/temp_dir.h"
#include "volume/volume.h"

using namespace sonomesh::volume;
namespace fs = std::filesystem;
using Code = VolumeIoError::Code;

using sonomesh::testing::TempDir;

namespace {

std::string read_text(const fs::path& path) {
  std::ifstream f(path, std::ios::binary);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

Mat3f rotation(float angle_rad, const Vec3f& axis) {
  return Eigen::AngleAxisf(angle_rad, axis.normalized()).toRotationMatrix();
}

Volume oblique_volume(VoxelType type, const Mat3f& direction) {
  Volume v(Vec3i(9, 7, 5), Vec3f(0.5f, 0.75f, 1.25f), Vec3f(-3.5f, 4.25f, 10.0f), type);
  v.set_direction(direction);
  std::mt19937 rng(5);
  for (int k = 0; k < 5; ++k)
    for (int j = 0; j < 7; ++j)
      for (int i = 0; i < 9; ++i) {
        const auto idx = v.linear_index(i, j, k);
        if (type == VoxelType::UInt8) v.u8()[idx] = static_cast<std::uint8_t>(rng() % 256);
        if (type == VoxelType::UInt16) v.u16()[idx] = static_cast<std::uint16_t>(rng() % 65536);
        if (type == VoxelType::Float32) v.f32()[idx] = static_cast<float>(rng() % 10000) / 7.0f;
      }
  return v;
}

// Same world position for every voxel and the same values (the file may flip axis-aligned data).
void expect_same_world(const Volume& a, const Volume& b, float tolerance_mm = 1e-4f) {
  ASSERT_EQ(a.dims(), b.dims());
  EXPECT_TRUE(a.spacing_mm().isApprox(b.spacing_mm(), 1e-5f)) << b.spacing_mm().transpose();
  EXPECT_TRUE(a.direction().isApprox(b.direction(), 1e-5f)) << "\n" << b.direction();
  EXPECT_LT((a.origin_mm() - b.origin_mm()).norm(), tolerance_mm) << b.origin_mm().transpose();
  for (int k = 0; k < a.dims().z(); ++k)
    for (int j = 0; j < a.dims().y(); ++j)
      for (int i = 0; i < a.dims().x(); ++i)
        ASSERT_EQ(a.value(i, j, k), b.value(i, j, k)) << i << j << k;
}

// Writes a NIfTI-1 file with nifticlib: RAS index-to-world `ras` (spacing included), `nt` frames.
void write_nifti_file(const fs::path& path, const mat44& ras, int nt, int datatype,
                      float slope = 0.0f, float inter = 0.0f, int nu = 1) {
  const int dims[8] = {nu > 1 ? 5 : (nt > 1 ? 4 : 3), 3, 2, 2, nt, nu, 1, 1};
  nifti_image* nim = nifti_make_new_nim(dims, datatype, 1);
  nim->sform_code = 1;
  nim->sto_xyz = ras;
  nim->scl_slope = slope;
  nim->scl_inter = inter;
  for (std::size_t n = 0; n < nim->nvox; ++n) {
    if (datatype == NIFTI_TYPE_UINT8)
      static_cast<std::uint8_t*>(nim->data)[n] = static_cast<std::uint8_t>(n);
    if (datatype == NIFTI_TYPE_INT16)
      static_cast<std::int16_t*>(nim->data)[n] = static_cast<std::int16_t>(-n);
  }
  nim->nifti_type = NIFTI_FTYPE_NIFTI1_1;
  nifti_set_filenames(nim, path.c_str(), 0, 1);
  nifti_image_write(nim);
  nifti_image_free(nim);
}

mat44 ras_matrix(const Mat3f& axes_times_spacing, const Vec3f& origin) {
  mat44 m{};
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) m.m[r][c] = axes_times_spacing(r, c);
    m.m[r][3] = origin[r];
  }
  m.m[3][3] = 1;
  return m;
}

}  // namespace

TEST(ObliqueRoundTrip, EveryFormatKeepsDirectionOriginSpacingAndVoxels) {
  TempDir dir;
  Mat3f reflection = rotation(0.4f, Vec3f(1, 2, 3));
  reflection.col(2) *= -1.0f;  // left-handed axes: an orthonormal matrix with determinant -1
  const Mat3f directions[] = {rotation(0.7f, Vec3f(0.3f, -1.0f, 0.5f)), reflection,
                              (Mat3f() << 0, 1, 0, 0, 0, 1, 1, 0, 0).finished()};
  int n = 0;
  for (const Mat3f& direction : directions)
    for (VoxelType type : {VoxelType::UInt8, VoxelType::UInt16, VoxelType::Float32})
      for (const char* ext : {".nrrd", ".nhdr", ".mha", ".mhd", ".nii", ".nii.gz"}) {
        const Volume v = oblique_volume(type, direction);
        const fs::path path = dir.path / ("v" + std::to_string(n++) + ext);
        for (Compression c : {Compression::Raw, Compression::Gzip}) {
          ASSERT_FALSE(write_volume(v, path, c)) << path;
          const auto r = read_volume(path);
          ASSERT_TRUE(r) << r.error->message;
          SCOPED_TRACE(path.string());
          EXPECT_EQ(r.volume.type(), type);
          expect_same_world(v, r.volume);
        }
      }
}

TEST(NiftiRead, RasFileIsConvertedToLpsKeepingEveryVoxelsWorldPosition) {
  TempDir dir;
  const auto path = dir.path / "ras.nii";
  // Identity RAS axes with spacing 1 2 3: in LPS, x and y point the other way (data flipped).
  write_nifti_file(path, ras_matrix(Vec3f(1, 2, 3).asDiagonal(), Vec3f(10, 20, 30)), 1,
                   NIFTI_TYPE_UINT8);
  const auto r = read_volume(path);
  ASSERT_TRUE(r) << r.error->message;
  const Volume& v = r.volume;
  ASSERT_EQ(v.dims(), Vec3i(3, 2, 2));
  EXPECT_TRUE(v.direction().isIdentity());
  for (int k = 0; k < 2; ++k)
    for (int j = 0; j < 2; ++j)
      for (int i = 0; i < 3; ++i) {
        const Vec3f lps(-(10.0f + i), -(20.0f + 2 * j), 30.0f + 3 * k);  // file voxel (i, j, k)
        const Vec3f ijk = v.mm_to_index(v.world_to_grid_mm(lps));
        const Vec3i at = ijk.array().round().cast<int>();
        EXPECT_LT((ijk - at.cast<float>()).norm(), 1e-4f);
        EXPECT_EQ(v.value(at.x(), at.y(), at.z()), static_cast<float>(i + 3 * j + 6 * k));
      }
  EXPECT_TRUE(r.note.empty());
}

TEST(NiftiRead, FourDimensionalFileLoadsItsFirstFrameAndSaysSo) {
  TempDir dir;
  const auto path = dir.path / "t.nii.gz";
  write_nifti_file(path, ras_matrix(Mat3f::Identity(), Vec3f::Zero()), 3, NIFTI_TYPE_UINT8);
  const auto r = read_volume(path);
  ASSERT_TRUE(r) << r.error->message;
  EXPECT_EQ(r.volume.dims(), Vec3i(3, 2, 2));
  EXPECT_NE(r.note.find("3 frames"), std::string::npos) << r.note;
  float max_value = 0;  // frame 0 holds 0..11; frames 1 and 2 hold 12..35
  for (auto x : r.volume.u8()) max_value = std::max(max_value, static_cast<float>(x));
  EXPECT_EQ(max_value, 11.0f);
  const auto vec = dir.path / "vector.nii";
  write_nifti_file(vec, ras_matrix(Mat3f::Identity(), Vec3f::Zero()), 1, NIFTI_TYPE_UINT8, 0, 0, 3);
  const auto refused = read_volume(vec);
  ASSERT_FALSE(refused);
  EXPECT_EQ(refused.error->code, Code::BadDimensions) << refused.error->message;
}

TEST(NiftiRead, ScaledSignedDataBecomesFloatAndBadFilesAreRefused) {
  TempDir dir;
  const auto path = dir.path / "scaled.nii";
  write_nifti_file(path, ras_matrix(Mat3f::Identity(), Vec3f::Zero()), 1, NIFTI_TYPE_INT16, 2.0f,
                   1.0f);
  auto r = read_volume(path);
  ASSERT_TRUE(r) << r.error->message;
  ASSERT_EQ(r.volume.type(), VoxelType::Float32);
  const auto& f = r.volume.f32();  // file values 0, -1, ..., -11, scaled by 2 and offset by 1
  EXPECT_EQ(*std::max_element(f.begin(), f.end()), 1.0f);
  EXPECT_EQ(*std::min_element(f.begin(), f.end()), -21.0f);

  const auto truncated = dir.path / "truncated.nii";
  write_nifti_file(truncated, ras_matrix(Mat3f::Identity(), Vec3f::Zero()), 1, NIFTI_TYPE_INT16);
  fs::resize_file(truncated, fs::file_size(truncated) - 5);
  r = read_volume(truncated);
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error->code, Code::TruncatedData) << r.error->message;

  for (const char* name : {"garbage.nii", "garbage.nii.gz"}) {
    std::ofstream(dir.path / name) << std::string(400, 'x');
    r = read_volume(dir.path / name);
    ASSERT_FALSE(r) << name;
    EXPECT_EQ(r.error->message.find('\n'), std::string::npos);
  }

  // A sheared sform without a qform to fall back on is refused, not replaced by pixdim.
  const auto sheared = dir.path / "sheared.nii";
  write_nifti_file(sheared,
                   ras_matrix((Mat3f() << 1, 0.5f, 0, 0, 1, 0, 0, 0, 1).finished(), Vec3f::Zero()),
                   1, NIFTI_TYPE_UINT8);
  r = read_volume(sheared);
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error->code, Code::UnsupportedOrientation) << r.error->message;
}

// ITK-SNAP's test image: float32, 56 x 52 x 56 x 3 frames, qform code 1 with an identity
// quaternion.
TEST(NiftiRead, RealFourDimensionalEchoLoadsItsFirstFrame) {
  const fs::path path =
      fs::path(SONOMESH_SHARED_DATA) / "real/echo3d-lv-itksnap-coarse/ultrasound_img4d.nii.gz";
  ASSERT_TRUE(fs::exists(path)) << path << " missing (expected shared/data beside the checkout)";
  const auto r = read_volume(path);
  ASSERT_TRUE(r) << r.error->message;
  EXPECT_EQ(r.volume.dims(), Vec3i(56, 52, 56));
  EXPECT_EQ(r.volume.type(), VoxelType::Float32);
  EXPECT_TRUE(r.volume.spacing_mm().isApprox(Vec3f(3.7766f, 3.7216f, 3.2873f), 1e-3f))
      << r.volume.spacing_mm().transpose();
  EXPECT_TRUE(
      r.volume.direction().isIdentity());  // RAS identity: LPS x and y flipped into the data
  EXPECT_NE(r.note.find("3 frames"), std::string::npos) << r.note;
  const auto& f = r.volume.f32();
  const auto [lo, hi] = std::minmax_element(f.begin(), f.end());
  EXPECT_GE(*lo, 0.0f);
  EXPECT_LE(*hi, 255.0f);
  EXPECT_GT(*hi, 100.0f);
}

TEST(Segmentation, SlicerSegNrrdCarriesTheSegmentFieldsAndTheGeometry) {
  TempDir dir;
  Volume labels = oblique_volume(VoxelType::UInt8, rotation(0.3f, Vec3f(0, 0, 1)));
  std::fill(labels.u8().begin(), labels.u8().end(), 0);
  labels.u8()[labels.linear_index(2, 3, 1)] = 1;
  labels.u8()[labels.linear_index(5, 4, 3)] = 1;
  const auto path = dir.path / "labels.seg.nrrd";
  ASSERT_FALSE(write_segmentation(labels, path));
  const auto r = read_volume(path);
  ASSERT_TRUE(r) << r.error->message;
  expect_same_world(labels, r.volume);
  const std::string text = read_text(path);
  for (const char* field :
       {"Segment0_ID:=Segment_1\n", "Segment0_Name:=sonomesh\n",
        "Segment0_Color:=0.902 0.706 0.235\n", "Segment0_ColorAutoGenerated:=0\n",
        "Segment0_Extent:=2 5 3 4 1 3\n", "Segment0_Layer:=0\n", "Segment0_LabelValue:=1\n",
        "Segment0_NameAutoGenerated:=0\n",
        "Segment0_Tags:=", "Segmentation_MasterRepresentation:=Binary labelmap\n",
        "Segmentation_ContainedRepresentationNames:=Binary labelmap|\n", "encoding: gzip\n",
        "space: left-posterior-superior\n"})
    EXPECT_NE(text.find(field), std::string::npos) << field;
  std::fill(labels.u8().begin(), labels.u8().end(), 0);
  ASSERT_FALSE(write_segmentation(labels, path));
  EXPECT_NE(read_text(path).find("Segment0_Extent:=0 -1 0 -1 0 -1\n"), std::string::npos);
  const Volume wrong(Vec3i(2, 2, 2), Vec3f::Ones(), Vec3f::Zero(), VoxelType::Float32);
  const auto refused = write_segmentation(wrong, path);
  ASSERT_TRUE(refused);
  EXPECT_EQ(refused->code, Code::UnsupportedType);
}

TEST(Segmentation, ItkSnapLabelDescriptionListsClearLabelAndSegment) {
  TempDir dir;
  const auto path = dir.path / "labels.txt";
  ASSERT_FALSE(write_label_description(path));
  const std::string text = read_text(path);
  EXPECT_NE(text.find("# ITK-SnAP Label Description File"), std::string::npos);
  EXPECT_NE(text.find("\"Clear Label\""), std::string::npos);
  std::istringstream lines(text);
  std::string line;
  int rows = 0;
  while (std::getline(lines, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream row(line);
    int idx, r, g, b, vis, msh;
    float a;
    ASSERT_TRUE(row >> idx >> r >> g >> b >> a >> vis >> msh) << line;
    if (++rows == 2) {
      EXPECT_EQ(idx, 1);
      EXPECT_EQ(r, 230);
      EXPECT_EQ(g, 180);
      EXPECT_EQ(b, 60);
      EXPECT_NE(line.find("\"sonomesh\""), std::string::npos);
    }
  }
  EXPECT_EQ(rows, 2);
}
