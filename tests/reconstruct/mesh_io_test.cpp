#include <gtest/gtest.h>
#include <unistd.h>

#include <fstream>
#include <iterator>
#include <limits>

#include "shapes.h"

namespace sonomesh::reconstruct {
namespace {

namespace fs = std::filesystem;

fs::path temp(const std::string& name) {
  const fs::path dir =
      fs::temp_directory_path() / ("sonomesh_reconstruct_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  return dir / name;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), {}};
}

TEST(MeshIo, PlyHeaderIsExactlyTheDesignedOne) {
  const Mesh m = test::uv_sphere(Vec3f(1, 2, 3), 4.0f, 10, 11);
  const auto path = temp("sphere.ply");
  ASSERT_FALSE(write_ply(m, path).has_value());
  const std::string bytes = slurp(path);
  const std::string header =
      "ply\nformat binary_little_endian 1.0\ncomment SPACE=LPS\nelement vertex 102\nproperty float "
      "x\n"
      "property float "
      "y\n"
      "property float z\nelement face 200\nproperty list uchar int vertex_indices\nend_header\n";
  ASSERT_EQ(bytes.substr(0, header.size()), header);
  EXPECT_EQ(bytes.size(), header.size() + 102 * 12 + 200 * 13);
}

TEST(MeshIo, PlyRoundTripIsExact) {
  const Mesh m = test::uv_sphere(Vec3f(1.25f, -2.5f, 3.125f), 4.3f, 12, 9);
  const auto path = temp("round.ply");
  ASSERT_FALSE(write_ply(m, path).has_value());
  const MeshReadResult r = read_ply(path);
  ASSERT_TRUE(r) << r.error->message;
  EXPECT_EQ(r.mesh.vertices, m.vertices);
  EXPECT_EQ(r.mesh.triangles, m.triangles);
  EXPECT_TRUE(r.stop.empty());
}

TEST(MeshIo, BalloonPlyCarriesStopReasons) {
  const Mesh m = test::uv_sphere(Vec3f::Zero(), 4.0f, 10, 11);
  std::vector<StopReason> stop(m.vertices.size());
  for (std::size_t i = 0; i < stop.size(); ++i) stop[i] = static_cast<StopReason>(i % 5);
  const auto path = temp("balloon.ply");
  ASSERT_FALSE(write_balloon_ply(m, stop, path).has_value());
  EXPECT_NE(slurp(path).find("property float z\nproperty uchar stop\nelement face"),
            std::string::npos);
  const MeshReadResult r = read_ply(path);
  ASSERT_TRUE(r);
  ASSERT_EQ(r.stop.size(), stop.size());
  for (std::size_t i = 0; i < stop.size(); ++i)
    EXPECT_EQ(r.stop[i], static_cast<std::uint8_t>(stop[i]));
  EXPECT_EQ(r.mesh.vertices, m.vertices);
  EXPECT_THROW(write_balloon_ply(m, std::vector<StopReason>(2), path), std::invalid_argument);
}

// fuzz_ply's finding: a stop value no uchar holds was cast anyway (undefined behaviour).
TEST(MeshIo, StopValueOutsideTheCodesIsRefused) {
  const auto path = temp("badstop.ply");
  std::ofstream(path) << "ply\nformat ascii 1.0\nelement vertex 3\n"
                         "property float x\nproperty float y\nproperty float z\nproperty int stop\n"
                         "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                         "0 0 0 -1\n1 0 0 0\n0 1 0 0\n3 0 1 2\n";
  const MeshReadResult r = read_ply(path);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error->message.find("stop value"), std::string::npos) << r.error->message;
}

// fuzz_ply's finding: a header claiming 5·10¹⁶ vertices made the reader allocate them. Counts
// are now checked against the bytes the file has left, in ascii and binary; an exact file still
// reads, to its last value without a newline.
TEST(MeshIo, ElementCountsBeyondTheFileAreRefused) {
  const std::string head =
      "property double x\nproperty double y\nproperty double z\n"
      "element face 1\nproperty list uchar int vertex_indices\nend_header\n";
  const auto ascii = temp("hugecount.ply");
  std::ofstream(ascii) << "ply\nformat ascii 1.0\nelement vertex 51111111111111111\n"
                       << head << "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
  const auto binary = temp("hugecount_bin.ply");
  std::ofstream(binary) << "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\n"
                        << head << std::string(100, '\0');
  for (const auto& path : {ascii, binary}) {
    const MeshReadResult r = read_ply(path);
    ASSERT_FALSE(r) << path;
    EXPECT_EQ(r.error->code, MeshIoError::Code::Truncated);
    EXPECT_NE(r.error->message.find("claims"), std::string::npos) << r.error->message;
  }
  const auto exact = temp("exact.ply");
  std::ofstream(exact) << "ply\nformat ascii 1.0\nelement vertex 3\n"
                       << head << "0 0 0\n1 0 0\n0 1 0\n3 0 1 2";
  const MeshReadResult r = read_ply(exact);
  ASSERT_TRUE(r) << r.error->message;
  EXPECT_EQ(r.mesh.triangles.size(), 1u);
}

TEST(MeshIo, ReadsAsciiPlyWithQuads) {
  const auto path = temp("ascii.ply");
  std::ofstream(path)
      << "ply\nformat ascii 1.0\ncomment hand made\nelement vertex 4\n"
         "property double x\nproperty double y\nproperty double z\nproperty uchar red\n"
         "element face 1\nproperty list uchar uint vertex_indices\nend_header\n"
         "0 0 0 255\n1 0 0 0\n1 1 0 0\n0 1 0 0\n4 0 1 2 3\n";
  const MeshReadResult r = read_ply(path);
  ASSERT_TRUE(r) << r.error->message;
  EXPECT_EQ(r.mesh.vertices.size(), 4u);
  ASSERT_EQ(r.mesh.triangles.size(), 2u);
  EXPECT_EQ(r.mesh.vertices[2], Vec3f(1, 1, 0));
}

TEST(MeshIo, BadPlyFilesGiveErrorsNotCrashes) {
  const Mesh m = test::uv_sphere(Vec3f::Zero(), 4.0f, 10, 11);
  const auto path = temp("truncated.ply");
  ASSERT_FALSE(write_ply(m, path).has_value());
  const std::string bytes = slurp(path);
  std::ofstream(path, std::ios::binary | std::ios::trunc) << bytes.substr(0, bytes.size() - 20);
  const MeshReadResult t = read_ply(path);
  ASSERT_FALSE(t);
  EXPECT_EQ(t.error->code, MeshIoError::Code::Truncated);
  EXPECT_FALSE(read_ply(temp("missing.ply")));
  std::ofstream(temp("junk.ply")) << "not a ply\n";
  EXPECT_EQ(read_ply(temp("junk.ply")).error->code, MeshIoError::Code::BadHeader);
  std::ofstream(temp("badindex.ply"))
      << "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
         "property float y\nproperty float z\nelement face 1\n"
         "property list uchar int vertex_indices\nend_header\n0 0 0\n3 0 1 2\n";
  EXPECT_EQ(read_ply(temp("badindex.ply")).error->code, MeshIoError::Code::BadIndex);
}

// A second vertex element would replace the vertices the stop reasons (or the faces) were read
// against: refused, never a result whose stop reasons or faces do not match its vertices.
TEST(MeshIo, ASecondVertexOrFaceElementIsRefused) {
  const std::string xyz = "property float x\nproperty float y\nproperty float z\n";
  const std::string face = "element face 1\nproperty list uchar int vertex_indices\n";
  std::ofstream(temp("two_vertex.ply"))
      << "ply\nformat ascii 1.0\nelement vertex 3\n"
      << xyz << "property uchar stop\n"
      << "element vertex 4\n"
      << xyz << face << "end_header\n"
      << "0 0 0 1\n1 0 0 1\n0 1 0 1\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n";
  const MeshReadResult two_vertex = read_ply(temp("two_vertex.ply"));
  ASSERT_FALSE(two_vertex);
  EXPECT_EQ(two_vertex.error->code, MeshIoError::Code::BadHeader);
  EXPECT_NE(two_vertex.error->message.find("a second vertex element"), std::string::npos)
      << two_vertex.error->message;
  const std::string one_vertex = "ply\nformat ascii 1.0\nelement vertex 3\n" + xyz;
  const std::string points = "0 0 0\n1 0 0\n0 1 0\n";
  std::ofstream(temp("two_face.ply")) << one_vertex << face << face << "end_header\n"
                                      << points << "3 0 1 2\n3 0 2 1\n";
  EXPECT_EQ(read_ply(temp("two_face.ply")).error->code, MeshIoError::Code::BadHeader);
  std::ofstream(temp("one_each.ply")) << one_vertex << face << "end_header\n"
                                      << points << "3 0 1 2\n";
  EXPECT_TRUE(read_ply(temp("one_each.ply")));
}

// A list's count of a floating-point type, and a vertex index that is NaN or a fraction, are
// refused (a NaN count or index was cast to an integer: undefined; found by fuzz_ply).
TEST(MeshIo, NonIntegerListCountsAndIndicesAreRefused) {
  const std::string vertices =
      "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n";
  std::ofstream(temp("float_count.ply"))
      << "ply\nformat ascii 1.0\n"
      << vertices << "element face 1\nproperty list float int vertex_indices\nend_header\n"
      << "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
  const MeshReadResult float_count = read_ply(temp("float_count.ply"));
  ASSERT_FALSE(float_count);
  EXPECT_EQ(float_count.error->code, MeshIoError::Code::BadHeader);
  // Binary: three vertices, then one face whose float indices are 0, 1 and NaN (or 1.5).
  for (const float bad : {std::numeric_limits<float>::quiet_NaN(), 1.5f}) {
    std::string body(3 * 3 * sizeof(float), '\0');
    body += static_cast<char>(3);
    for (const float index : {0.0f, 1.0f, bad})
      body.append(reinterpret_cast<const char*>(&index), sizeof index);
    std::ofstream(temp("float_index.ply"), std::ios::binary)
        << "ply\nformat binary_little_endian 1.0\n"
        << vertices << "element face 1\nproperty list uchar float vertex_indices\nend_header\n"
        << body;
    const MeshReadResult float_index = read_ply(temp("float_index.ply"));
    ASSERT_FALSE(float_index) << bad;
    EXPECT_EQ(float_index.error->code, MeshIoError::Code::BadIndex) << bad;
  }
}

TEST(MeshIo, StlAndObjAreWritten) {
  const Mesh m = test::uv_sphere(Vec3f::Zero(), 4.0f, 10, 11);
  ASSERT_FALSE(write_mesh(m, temp("s.stl")).has_value());
  EXPECT_EQ(fs::file_size(temp("s.stl")), 84u + 50u * 200u);
  ASSERT_FALSE(write_mesh(m, temp("s.obj")).has_value());
  const std::string obj = slurp(temp("s.obj"));
  EXPECT_EQ(std::count(obj.begin(), obj.end(), 'v'), 102);
  EXPECT_EQ(std::count(obj.begin(), obj.end(), 'f'), 200);
  EXPECT_NE(obj.find("\nf 1 "), std::string::npos);  // 1-based
  EXPECT_EQ(obj.rfind("# SPACE=LPS\n", 0), 0u);      // 3D Slicer: the world frame is LPS
  EXPECT_EQ(slurp(temp("s.stl")).rfind("SPACE=LPS", 0), 0u);
}

TEST(MeshIo, WriteFailuresAreErrorValues) {
  const Mesh m = test::uv_sphere(Vec3f::Zero(), 4.0f, 10, 11);
  const auto e = write_ply(m, "/nonexistent-dir/x.ply");
  ASSERT_TRUE(e.has_value());
  EXPECT_EQ(e->code, MeshIoError::Code::OpenFailed);
  EXPECT_EQ(write_mesh(m, temp("x.vtk"))->code, MeshIoError::Code::Unsupported);
}

}  // namespace
}  // namespace sonomesh::reconstruct
