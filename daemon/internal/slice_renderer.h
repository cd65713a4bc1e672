#pragma once
/// @file
/// @brief GET /slices/{axial,coronal,sagittal}.png: three orthogonal slices of the latest volume
/// through its seed, with the mesh's contour in each slice plane drawn over them.
///
/// The worker hands over the volume, the mesh and the seed (all in the grid frame: origin +
/// spacing ⊙ ijk) once per result; only the three planes and the contour segments are kept, and
/// PNGs (libpng, png_writer.h) are encoded when asked for, once per result.

#include <array>
#include <cstdint>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "segment/mesh.h"
#include "volume/volume.h"

namespace sonomesh::daemon {

enum class SliceAxis { Axial, Coronal, Sagittal };
/// "axial", "coronal", "sagittal".
const char* to_string(SliceAxis axis);
std::optional<SliceAxis> slice_axis_from(const std::string& name);

/// A 2D point on a slice in voxel units of the slice's (u, v) axes.
struct SlicePoint {
  float u = 0, v = 0;
};
struct SliceSegment {
  SlicePoint a, b;
};

/// The mesh's intersection with the plane `axis index` = `plane_vox` (index coordinates), as
/// segments in the slice's (u, v) voxel coordinates: axial (i, j) at k, coronal (i, k) at j,
/// sagittal (j, k) at i. `mesh_mm` is in the grid frame of `grid`.
std::vector<SliceSegment> mesh_contour(const segment::Mesh& mesh_mm, const volume::Volume& grid,
                                       SliceAxis axis, float plane_vox);

class SliceRenderer {
 public:
  /// Largest edge of a rendered slice in pixels (small volumes are scaled up to it).
  static constexpr int kTargetEdgePx = 384;

  /// Keeps the three planes through `seed_mm` and the mesh's contours in them.
  void update(const volume::Volume& input, const segment::Mesh& mesh_mm,
              const volume::Vec3f& seed_mm, std::uint64_t sequence);

  /// The PNG of one slice of the latest result, or nothing before the first one.
  std::optional<std::string> png(SliceAxis axis);
  /// What the page needs to turn a click into a (world-frame) seed: sequence, dims, spacing,
  /// origin, direction (column-major: column c is index axis c in LPS), the seed index, and per
  /// slice its pixel size and which index axes it shows. Null before a result.
  nlohmann::json info() const;

 private:
  struct Slice {
    int width_vox = 0, height_vox = 0;  // u and v extent
    float u_mm = 1, v_mm = 1;           // spacing along u and v
    std::vector<float> pixels;          // row-major, v rows of u values
    std::vector<SliceSegment> contour;
  };
  struct Frame {
    std::uint64_t sequence = 0;
    volume::Vec3i dims = volume::Vec3i::Zero();
    volume::Vec3f spacing_mm = volume::Vec3f::Ones(), origin_mm = volume::Vec3f::Zero();
    volume::Mat3f direction = volume::Mat3f::Identity();  // the grid's axes in the world
    volume::Vec3i seed_index = volume::Vec3i::Zero();
    float low = 0, high = 1;  // intensity window shared by the three slices
    std::array<Slice, 3> slices;
    std::array<std::string, 3> png;  // encoded on first request
  };

  static std::string encode(const Frame& frame, const Slice& slice, SliceAxis axis);

  mutable std::mutex mutex_;
  std::shared_ptr<Frame> frame_;
};

}  // namespace sonomesh::daemon
