#pragma once
/// @file
/// @brief Triangle meshes and oriented point clouds as they cross module boundaries (positions in
/// mm), with their topology, normals and files. Below segment/ and reconstruct/, which share it.
///
/// Caller bugs (indices out of range, mismatched arrays) throw std::invalid_argument naming the
/// argument; file errors are returned as values.

#include <array>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "volume/volume.h"

namespace sonomesh::mesh {

using volume::Vec3f;

/// Why a balloon vertex stopped; the values are the `stop` codes of the balloon PLY (DESIGN.md).
enum class StopReason : std::uint8_t {
  Moving = 0,            // still moving when evolution ended without a limit
  Boundary = 1,          // accumulated boundary cost Ψ_cost exceeded τ_cost
  Curvature = 2,         // edge curvature exceeded τ_curv (a spike leaking through a gap)
  SelfIntersection = 3,  // about to enter voxels the other side of the balloon already swept
  IterationLimit = 4,    // still moving at the iteration limit
};

/// Triangle mesh; triangles index `vertices` counter-clockwise seen from outside.
struct Mesh {
  std::vector<Vec3f> vertices;
  std::vector<std::array<std::uint32_t, 3>> triangles;
};

/// Oriented samples for the reconstruction: positions (mm), outward unit normals, and each
/// sample's share of the surface area in mm² (its weight in Kazhdan's splat).
struct PointCloud {
  std::vector<Vec3f> points;
  std::vector<Vec3f> normals;
  std::vector<float> area_mm2;  // same length as points
};

// ---------------------------------------------------------------------------------------------
// Topology.

struct Topology {
  int components = 0;  // connected by shared vertices
  int vertices = 0;    // referenced vertices
  int edges = 0;
  int faces = 0;
  int euler = 0;            // V − E + F
  int genus = 0;            // Σ over components of (2 − χ_c)/2; meaningful when watertight
  bool watertight = false;  // every edge has exactly two faces with opposite orientations
  bool manifold = false;    // watertight and every vertex has one fan of triangles around it
  double volume_ml = 0.0;   // enclosed volume (divergence theorem), mm³/1000; > 0 when outward
};

/// Counts and checks of a triangle mesh. @throws std::invalid_argument on out-of-range indices.
Topology analyze_topology(const Mesh& mesh);

/// Topology::manifold alone (watertight, one fan per vertex), without the counts.
/// @throws std::invalid_argument on out-of-range indices.
bool is_closed_manifold(const Mesh& mesh);

/// Topology::euler alone: V − E + F over the referenced vertices.
int euler_characteristic(const Mesh& mesh);

/// Topology::volume_ml alone: for a mesh whose vertices moved but whose connectivity did not.
double enclosed_volume_ml(const Mesh& mesh);
/// The sum of the triangles' areas (mm²).
double surface_area_mm2(const Mesh& mesh);
/// A closed mesh's thickness 3V/A (mm): a ball's radius, 1.5 times a tube's; 0 without area.
double thickness_mm(const Mesh& closed_mesh);

/// The axis-aligned box of a mesh's vertices (mm); lo = hi = 0 for a mesh without vertices.
struct Box {
  Vec3f lo_mm = Vec3f::Zero(), hi_mm = Vec3f::Zero();
};
Box bounding_box(const Mesh& mesh);

/// Splits a mesh into its connected components (by shared vertices), vertices renumbered.
std::vector<Mesh> connected_components(const Mesh& mesh);

/// True if p_mm lies inside the closed mesh (ray parity along a slightly jittered direction).
bool encloses(const Mesh& closed_mesh, const Vec3f& p_mm);

/// The component that encloses seed_mm; if several do, the smallest of them (the innermost
/// shell); if none does, the largest one (by triangle count) and *seed_enclosed = false.
/// `component_count` receives the number of components.
Mesh component_enclosing(const Mesh& mesh, const Vec3f& seed_mm, bool* seed_enclosed = nullptr,
                         int* component_count = nullptr);

// ---------------------------------------------------------------------------------------------
// Normals.

/// Each vertex's unit normal, equation (2)'s: the normalised sum of the unit normals of the
/// triangles around it (zero where they are all degenerate or cancel).
/// @throws std::invalid_argument on out-of-range indices.
std::vector<Vec3f> vertex_normals(const Mesh& mesh);

/// Vertex samples of a closed mesh: outward unit normals (the normalised sum of the unit normals
/// of the adjacent triangles, method.md eq. 2) and one-third-area weights.
/// @throws std::invalid_argument if a triangle indexes a vertex that does not exist.
PointCloud oriented_samples(const Mesh& mesh);

/// Same from the triangles with keep_triangle[t] set, skipping vertices with drop_vertex[v] set
/// and vertices left without a kept triangle (they have no normal).
/// @throws std::invalid_argument on out-of-range indices or arrays of the wrong length.
PointCloud oriented_samples(const Mesh& mesh, const std::vector<char>& keep_triangle,
                            const std::vector<char>& drop_vertex);

// ---------------------------------------------------------------------------------------------
// Files. A stop array of the wrong length is a bug and throws.

struct MeshIoError {
  enum class Code { OpenFailed, WriteFailed, BadHeader, Unsupported, Truncated, BadIndex };
  Code code = Code::WriteFailed;
  std::string message;  // one line naming the file and the problem
};

/// Binary little-endian PLY with exactly `float x y z` and `list uchar int vertex_indices`.
std::optional<MeshIoError> write_ply(const Mesh& mesh, const std::filesystem::path& path);
/// As write_ply plus a per-vertex `uchar stop` (StopReason codes) after z.
/// @throws std::invalid_argument if stop.size() != mesh.vertices.size().
std::optional<MeshIoError> write_balloon_ply(const Mesh& mesh, const std::vector<StopReason>& stop,
                                             const std::filesystem::path& path);
/// Binary STL (facet normals from the triangle winding).
std::optional<MeshIoError> write_stl(const Mesh& mesh, const std::filesystem::path& path);
/// Wavefront OBJ (`v` and 1-based `f` lines).
std::optional<MeshIoError> write_obj(const Mesh& mesh, const std::filesystem::path& path);
/// By extension: .ply, .stl or .obj (anything else is an Unsupported error).
std::optional<MeshIoError> write_mesh(const Mesh& mesh, const std::filesystem::path& path);

struct MeshReadResult {
  Mesh mesh;
  std::vector<std::uint8_t> stop;  // the per-vertex `stop` property if the file has one
  std::optional<MeshIoError> error;
  explicit operator bool() const { return !error.has_value(); }
};

/// Reads PLY (ascii or binary_little_endian; any scalar property types; polygons fanned into
/// triangles). Needs x, y, z vertex properties and a vertex_indices (or vertex_index) face list.
MeshReadResult read_ply(const std::filesystem::path& path);

}  // namespace sonomesh::mesh
