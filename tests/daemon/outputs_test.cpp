// Output files in the input's world frame: meshes mapped from the grid frame, labels with the
// input's geometry, NIfTI / Slicer segmentation by extension, the ITK-SNAP description beside them.
#include "daemon/internal/outputs.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "reconstruct/reconstruct.h"
#include "tests/temp_dir.h"

using namespace sonomesh;
using volume::Mat3f;
using volume::Vec3f;
using volume::Vec3i;
using volume::Volume;
namespace fs = std::filesystem;

using sonomesh::testing::TempDir;

namespace {

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), {}};
}

// A closed tetrahedron, counter-clockwise seen from outside.
segment::Mesh tetrahedron(const Vec3f& at) {
  segment::Mesh m;
  m.vertices = {at, at + Vec3f(4, 0, 0), at + Vec3f(0, 4, 0), at + Vec3f(0, 0, 4)};
  m.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  return m;
}

float signed_volume(const segment::Mesh& m) {
  float v = 0;
  for (const auto& t : m.triangles)
    v += m.vertices[t[0]].dot(m.vertices[t[1]].cross(m.vertices[t[2]])) / 6.0f;
  return v;
}

Volume oblique_frame(bool reflect) {
  Volume frame(Vec3i(20, 16, 12), Vec3f(0.5f, 0.6f, 0.8f), Vec3f(-12, 30, 7),
               volume::VoxelType::UInt8);
  Mat3f d = Eigen::AngleAxisf(0.6f, Vec3f(1, -2, 0.5f).normalized()).toRotationMatrix();
  if (reflect) d.col(1) *= -1.0f;
  frame.set_direction(d);
  return frame;
}

}  // namespace

// The mesh lands where the file puts the voxels: a vertex at a voxel's grid position goes to that
// voxel's world position as the oblique NRRD header gives it.
TEST(Outputs, GridMeshLandsOnTheFilesWorldPositions) {
  TempDir dir;
  const auto path = dir.path / "oblique.nrrd";
  std::ofstream(path, std::ios::binary)
      << "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 6 5 4\nspace: left-posterior-superior\n"
         "space directions: (0.8,0.6,0) (-1.2,1.6,0) (0,0,3)\nspace origin: (10,20,30)\n"
         "encoding: raw\n\n"
      << std::string(120, '\0');
  const auto read = volume::read_volume(path);
  ASSERT_TRUE(read) << read.error->message;
  const Volume& input = read.volume;
  segment::Mesh mesh;
  const Vec3i voxel(3, 4, 2);
  mesh.vertices = {input.index_to_mm(voxel.cast<float>())};
  const auto world = daemon::internal::mesh_to_world(mesh, input);
  const Vec3f expected =
      Vec3f(10, 20, 30) + 3 * Vec3f(0.8f, 0.6f, 0) + 4 * Vec3f(-1.2f, 1.6f, 0) + 2 * Vec3f(0, 0, 3);
  EXPECT_LT((world.vertices[0] - expected).norm(), 1e-4f) << world.vertices[0].transpose();
  // --seed-mm is in world mm: mapped back it is the voxel's grid position.
  const Vec3f seed_grid = daemon::internal::seed_world_to_grid_mm(input, expected);
  EXPECT_LT((input.mm_to_index(seed_grid) - voxel.cast<float>()).norm(), 1e-4f);
}

TEST(Outputs, MeshFilesAreInTheWorldFrameAndStayOutwardUnderAReflection) {
  TempDir dir;
  for (bool reflect : {false, true}) {
    const Volume frame = oblique_frame(reflect);
    const segment::Mesh grid = tetrahedron(frame.origin_mm() + Vec3f(1, 2, 3));
    ASSERT_GT(signed_volume(grid), 0.0f);
    const auto world = daemon::internal::mesh_to_world(grid, frame);
    EXPECT_NEAR(signed_volume(world), signed_volume(grid), 1e-3f) << "reflect " << reflect;
    const auto ply = dir.path / "mesh.ply";
    ASSERT_FALSE(daemon::internal::write_mesh_ply(grid, frame, ply));
    EXPECT_NE(slurp(ply).find("\ncomment SPACE=LPS\n"), std::string::npos);
    const auto back = reconstruct::read_ply(ply);
    ASSERT_TRUE(back) << back.error->message;
    ASSERT_EQ(back.mesh.vertices.size(), 4u);
    for (std::size_t i = 0; i < 4; ++i)
      EXPECT_LT((back.mesh.vertices[i] - frame.grid_to_world_mm(grid.vertices[i])).norm(), 1e-4f);
    EXPECT_EQ(back.mesh.triangles, world.triangles);
    for (const char* name : {"mesh.stl", "mesh.obj"}) {
      ASSERT_FALSE(daemon::internal::write_mesh_file(grid, frame, dir.path / name)) << name;
      EXPECT_NE(slurp(dir.path / name).find("SPACE=LPS"), std::string::npos) << name;
    }
  }
}

TEST(Outputs, LabelsCarryTheInputsGeometryInEveryFormat) {
  TempDir dir;
  const Volume frame = oblique_frame(false);
  Volume labels(frame.dims(), frame.spacing_mm(), frame.origin_mm(), volume::VoxelType::UInt8);
  labels.u8()[labels.linear_index(4, 5, 6)] = 1;  // the pipeline's labels: identity direction
  for (const char* name : {"l.nrrd", "l.nhdr", "l.mha", "l.nii", "l.nii.gz", "l.seg.nrrd"}) {
    const auto path = dir.path / name;
    const auto problem = daemon::internal::write_labels(labels, frame, path, {true});
    ASSERT_FALSE(problem) << *problem;
    const auto back = volume::read_volume(path);
    ASSERT_TRUE(back) << back.error->message;
    EXPECT_TRUE(back.volume.direction().isApprox(frame.direction(), 1e-5f)) << name;
    EXPECT_LT((back.volume.origin_mm() - frame.origin_mm()).norm(), 1e-4f) << name;
    EXPECT_EQ(back.volume.u8(), labels.u8()) << name;
    const auto description = daemon::internal::label_description_path(path);
    EXPECT_EQ(description, dir.path / "l.label.txt") << name;
    EXPECT_NE(slurp(description).find("\"sonomesh\""), std::string::npos);
    fs::remove(description);
  }
  EXPECT_NE(slurp(dir.path / "l.seg.nrrd").find("Segment0_Name:=sonomesh"), std::string::npos);
  for (const auto& entry : fs::directory_iterator(dir.path))  // no temporaries left behind
    EXPECT_EQ(entry.path().filename().string().find(".tmp-"), std::string::npos) << entry.path();
  const Volume other(Vec3i(2, 2, 2), Vec3f::Ones(), Vec3f::Zero(), volume::VoxelType::UInt8);
  EXPECT_TRUE(daemon::internal::write_labels(other, frame, dir.path / "x.nrrd"));
}
