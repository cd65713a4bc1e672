#pragma once
/// @file
/// @brief The balloon's occupancy A_t (method.md §2): the voxels its front has swept, each with
/// the normal of the front that swept it first. Private to segment/.

#include <cstddef>
#include <memory>

#include "volume/volume.h"

namespace sonomesh::segment::internal {

using volume::Vec3f;
using volume::Vec3i;

/// A_t as a sparse openvdb::Int32Grid in the volume's index space (memory follows the swept
/// region), each marked voxel holding the unit normal quantised to 1/127.
/// Marking is for one thread at a time; reading goes through Readers, one per thread, and is safe
/// from several threads at once while nothing marks (the balloon alternates the two phases).
class FrontGrid {
 public:
  explicit FrontGrid(const volume::Volume& like);
  ~FrontGrid();
  FrontGrid(FrontGrid&&) noexcept;
  FrontGrid& operator=(FrontGrid&&) noexcept;

  /// Marks voxel `ijk` with `normal` unless it is marked already (the first front wins), so the
  /// result depends only on the order of the calls. Returns whether it marked.
  bool mark(const Vec3i& ijk, const Vec3f& normal);

  /// Cached read access (an unregistered OpenVDB accessor: cheap to make, one per thread).
  class Reader {
   public:
    explicit Reader(const FrontGrid& grid);
    ~Reader();
    Reader(Reader&&) noexcept;
    /// Whether `ijk` is marked; if so, `normal` receives the front normal stored there.
    bool normal(const Vec3i& ijk, Vec3f& normal) const;
    bool marked(const Vec3i& ijk) const;

   private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
  };

  std::size_t marked_count() const;
  /// Bytes the sparse tree holds (for benchmarks: memory follows the swept region).
  std::size_t memory_bytes() const;
  /// Dense uint8 labels (marked = 1) on the grid of `like`.
  volume::Volume to_labels() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// A_t with the voxel lookup of mesh positions. "Already inside before P's own front got there"
/// is decided by the direction of the front that marked the voxel, not by its age: where two
/// fronts meet head-on both marked their voxels in the last iteration or two, while their normals
/// are opposite.
class FrontMarks {
 public:
  explicit FrontMarks(const volume::Volume& grid)
      : grid_(grid),
        dims_(grid.dims()),
        origin_mm_(grid.origin_mm()),
        inv_spacing_(grid.spacing_mm().cwiseInverse()) {}

  /// Voxel containing p (voxel centres at integer indices); false outside the volume.
  bool voxel(const Vec3f& p_mm, Vec3i& ijk) const {
    // Per axis and by truncation (u >= 0 here): Eigen's cwise form and lround were out of line.
    const float ux = (p_mm.x() - origin_mm_.x()) * inv_spacing_.x() + 0.5f;
    const float uy = (p_mm.y() - origin_mm_.y()) * inv_spacing_.y() + 0.5f;
    const float uz = (p_mm.z() - origin_mm_.z()) * inv_spacing_.z() + 0.5f;
    if (!(ux >= 0.0f && uy >= 0.0f && uz >= 0.0f)) return false;
    ijk = Vec3i(static_cast<int>(ux), static_cast<int>(uy), static_cast<int>(uz));
    return ijk.x() < dims_.x() && ijk.y() < dims_.y() && ijk.z() < dims_.z();
  }

  /// True if the voxel was swept by a front whose normal opposes n (cosine < cos_limit).
  static bool other_side(const FrontGrid::Reader& reader, const Vec3i& ijk, const Vec3f& n,
                         float cos_limit) {
    Vec3f marked_normal;
    return reader.normal(ijk, marked_normal) && marked_normal.dot(n) < cos_limit;
  }

  FrontGrid& grid() { return grid_; }
  const FrontGrid& grid() const { return grid_; }

 private:
  FrontGrid grid_;
  Vec3i dims_;
  Vec3f origin_mm_;
  Vec3f inv_spacing_;
};

}  // namespace sonomesh::segment::internal
