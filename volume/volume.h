#pragma once
/// @file
/// @brief The Volume value type, its file formats, smoothing, gradients and sampling.
///
/// Index space (i, j, k), i fastest in memory; the grid frame in millimetres:
/// p_mm = origin_mm + spacing_mm ⊙ ijk; the world (LPS) position is grid_to_world_mm(p_mm)
/// (DESIGN.md "Geometry and files").

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "acquire/raw_volume.h"

namespace sonomesh::volume {

using Vec3f = Eigen::Vector3f;
using Vec3d = Eigen::Vector3d;
using Vec3i = Eigen::Vector3i;
using Mat3f = Eigen::Matrix3f;

enum class VoxelType : std::uint8_t { UInt8, UInt16, Float32 };

const char* to_string(VoxelType type);

/// A 3D scalar image on an axis-aligned grid. A plain value: copies copy the voxels (move it).
class Volume {
 public:
  Volume() = default;
  /// Zero-filled volume. @throws std::invalid_argument on non-positive dims or spacing.
  Volume(const Vec3i& dims, const Vec3f& spacing_mm, const Vec3f& origin_mm, VoxelType type);

  /// Wraps a probe volume (copies its voxels). @throws std::invalid_argument if the payload size
  /// does not match dims and type.
  static Volume from_raw(const acquire::RawVolume& raw);

  const Vec3i& dims() const { return dims_; }
  const Vec3f& spacing_mm() const { return spacing_mm_; }
  const Vec3f& origin_mm() const { return origin_mm_; }
  void set_origin_mm(const Vec3f& origin_mm) { origin_mm_ = origin_mm; }
  /// Orientation in the world (LPS) frame: column c is the unit direction of index axis c.
  /// Processing runs in the grid frame (origin_mm + spacing_mm ⊙ ijk, as if the direction were
  /// the identity); grid_to_world_mm maps its results into the world.
  const Mat3f& direction() const { return direction_; }
  void set_direction(const Mat3f& direction) { direction_ = direction; }
  Vec3f grid_to_world_mm(const Vec3f& p_mm) const {
    return origin_mm_ + direction_ * (p_mm - origin_mm_);
  }
  Vec3f world_to_grid_mm(const Vec3f& p_mm) const {
    return origin_mm_ + direction_.transpose() * (p_mm - origin_mm_);
  }
  VoxelType type() const;
  bool empty() const { return voxel_count() == 0; }
  std::size_t voxel_count() const {
    return static_cast<std::size_t>(dims_.x()) * dims_.y() * dims_.z();
  }
  std::size_t linear_index(int i, int j, int k) const {
    return (static_cast<std::size_t>(k) * dims_.y() + j) * dims_.x() + i;
  }
  bool contains_index(const Vec3i& ijk) const {
    return (ijk.array() >= 0).all() && (ijk.array() < dims_.array()).all();
  }

  /// Typed access. @throws std::logic_error if the volume holds another type.
  std::vector<std::uint8_t>& u8();
  const std::vector<std::uint8_t>& u8() const;
  std::vector<std::uint16_t>& u16();
  const std::vector<std::uint16_t>& u16() const;
  std::vector<float>& f32();
  const std::vector<float>& f32() const;

  /// Value at a voxel as float, whatever the voxel type. No bounds check beyond assert.
  float value(int i, int j, int k) const;
  /// The whole volume converted to float (a copy).
  std::vector<float> to_float() const;

  Vec3f index_to_mm(const Vec3f& ijk) const { return origin_mm_ + spacing_mm_.cwiseProduct(ijk); }
  Vec3f mm_to_index(const Vec3f& p_mm) const {
    return (p_mm - origin_mm_).cwiseQuotient(spacing_mm_);
  }
  /// True if p_mm lies within the box spanned by the voxel centres.
  bool contains_mm(const Vec3f& p_mm) const;
  /// Lowest and highest voxel centre, in mm.
  Vec3f min_mm() const { return origin_mm_; }
  Vec3f max_mm() const { return index_to_mm((dims_ - Vec3i::Ones()).cast<float>()); }

 private:
  Vec3i dims_ = Vec3i::Zero();
  Vec3f spacing_mm_ = Vec3f::Ones();
  Vec3f origin_mm_ = Vec3f::Zero();
  Mat3f direction_ = Mat3f::Identity();
  std::variant<std::vector<std::uint8_t>, std::vector<std::uint16_t>, std::vector<float>> data_;
};

// ---------------------------------------------------------------------------------------------
// Files. Errors are values: a malformed file is a normal outcome of reading user input.

struct VolumeIoError {
  enum class Code {
    NotFound,
    UnknownFormat,
    BadHeader,
    UnsupportedType,
    BadDimensions,
    TruncatedData,
    SizeMismatch,
    UnsupportedOrientation,
    Compression,
    IoError
  };
  Code code = Code::IoError;
  std::string message;  // one line naming the file and the problem
};

/// Result of a read: a volume, or an error.
struct VolumeReadResult {
  VolumeReadResult() = default;
  VolumeReadResult(Volume v, std::optional<VolumeIoError> e, std::string n = {})
      : volume(std::move(v)), error(std::move(e)), note(std::move(n)) {}
  Volume volume;
  std::optional<VolumeIoError> error;
  /// One line worth telling the user about a successful read (e.g. only the first frame of a 4D
  /// NIfTI was read); empty otherwise.
  std::string note;
  explicit operator bool() const { return !error.has_value(); }
};

struct ReadOptions {
  /// Refuse files whose header announces more voxels than this, before allocating anything.
  std::size_t max_voxels = std::size_t{1} << 30;
};

enum class Compression { Raw, Gzip };

/// Reads NRRD (.nrrd, .nhdr + detached data; raw or gzip; through Teem), MetaImage (.mha, .mhd +
/// .raw; raw or zlib) or NIfTI-1 (.nii, .nii.gz; through nifticlib), by extension.
/// Geometry: any orthonormal direction matrix is accepted. Axis-aligned ones (flips only) are
/// applied to the data so that index space maps to mm with an identity direction, as before;
/// oblique or permuted ones are kept as Volume::direction() with origin_mm = the first voxel's
/// world position and spacing_mm = the axes' lengths (the pipeline runs in that grid frame,
/// grid_to_world_mm maps results back). Sheared or degenerate directions are refused
/// (UnsupportedOrientation). World space is LPS: NRRD in RAS or LAS and NIfTI (RAS) are converted.
/// uint8/uint16/float load as such; other numeric types (int8/16/32/64, uint32/64, double, and
/// NIfTI data with an intensity scaling) are converted to Float32. A 4D NIfTI loads its first frame
/// (`note` says so). The mm position of every file voxel is kept, so after a flip its index changes
/// (file j -> ny-1-j): use mm, not file indices. Sizes are checked against options.max_voxels and
/// the data on disk before allocating. NRRD header field lines over 400 bytes are refused (Teem
/// would overflow a buffer on them).
VolumeReadResult read_volume(const std::filesystem::path& path, const ReadOptions& options = {});

/// Writes NRRD (.nrrd attached, .nhdr detached), MetaImage (.mha, .mhd + .raw) or NIfTI-1 (.nii,
/// .nii.gz; `compression` is decided by the name) by extension, with the volume's direction.
/// Returns an error instead of throwing.
std::optional<VolumeIoError> write_volume(const Volume& volume, const std::filesystem::path& path,
                                          Compression compression = Compression::Raw);

/// One labelled segment, as 3D Slicer and ITK-SNAP describe it.
struct SegmentInfo {
  std::string name = "sonomesh";
  std::array<float, 3> color_rgb{0.902f, 0.706f, 0.235f};  // 0..1
  std::uint8_t label_value = 1;
};

/// Writes a UInt8 label volume as a 3D Slicer segmentation (.seg.nrrd: gzip NRRD with one segment,
/// the Segment0_* and Segmentation_* fields Slicer writes, extent = the labelled voxels' box).
std::optional<VolumeIoError> write_segmentation(const Volume& labels,
                                                const std::filesystem::path& path,
                                                const SegmentInfo& segment = {});

/// Writes an ITK-SNAP label description file (the clear label 0 and the segment).
std::optional<VolumeIoError> write_label_description(const std::filesystem::path& path,
                                                     const SegmentInfo& segment = {});

// ---------------------------------------------------------------------------------------------
// Processing.

/// 3D Gaussian smoothing, sigma in mm per axis (so anisotropic spacing is handled), separable
/// (OpenCV), both cores. Returns a Float32 volume on the same grid. sigma_mm <= 0 only converts.
Volume smooth_gaussian(const Volume& input, float sigma_mm);
/// Same, into `out`, reusing its voxel buffer when it already is a Float32 volume of the same dims
/// (a per-volume pipeline then allocates nothing; fresh 8 MB buffers cost page faults). `out` must
/// not be `input`.
void smooth_gaussian(const Volume& input, float sigma_mm, Volume& out);
/// Same, but only the voxels of the index box [lo, hi) (clamped to the grid) are written, each
/// as the whole volume's smoothing gives it (the filter reads the input beyond the box); the rest
/// of `out` keeps what it held (sigma_mm <= 0: the whole volume is converted). For a reader that
/// looks only near a known place (a tracked surface): a box round a target costs a fraction of
/// the whole.
void smooth_gaussian(const Volume& input, float sigma_mm, const Vec3i& lo, const Vec3i& hi,
                     Volume& out);
/// How many voxels along each axis smooth_gaussian reads beyond a voxel of `like`'s grid.
Vec3i smoothing_reach_vox(const Volume& like, float sigma_mm);

/// The speckle's grain around a point, in mm: per grid axis, the lag at which the normalised
/// autocorrelation of the raw intensities in a cube of `radius_vox` voxels around `centre_mm`
/// falls to one half (linear between integer lags), the largest over the axes. An axis still
/// correlated above 0.25 at three voxels holds structure, not grain (a thin target's walls): it
/// is read in the six cubes beside that one (2 radii off along each axis), the median of those
/// that read it, or else left out. A smoothing of this sigma averages a grain away; one of a
/// voxel leaves a coarse grain as blobs that stop a balloon. 0 if the cube holds no variation (a
/// noise-free image); capped at `radius_vox` voxels. With `excluded`, the voxels (indices) it is
/// true of are not speckle (a needle) and take no part; it is asked only of the cubes' voxels.
float speckle_grain_mm(const Volume& input, const Vec3f& centre_mm, int radius_vox = 6,
                       const std::function<bool(const Vec3i&)>& excluded = {});

/// Central-difference gradient of a volume, in intensity units per mm (one-sided at the borders).
struct Gradient {
  Volume gx, gy, gz;  // Float32, same grid as the input
};
Gradient central_gradient(const Volume& input);
/// Same, into `out`, reusing its buffers when they match (see smooth_gaussian).
void central_gradient(const Volume& input, Gradient& out);

/// Trilinear sample at a point in mm; points outside are clamped to the border voxels.
float sample_mm(const Volume& volume, const Vec3f& p_mm);
/// Trilinear sample of the gradient at a point in mm (clamped like sample_mm).
Vec3f sample_gradient_mm(const Gradient& gradient, const Vec3f& p_mm);

// ---------------------------------------------------------------------------------------------
// OpenVDB grids (OpenVDB itself stays private to this module).

/// Writes a Float32 volume as an OpenVDB float grid named `grid_name`, with the volume's transform.
std::optional<VolumeIoError> write_vdb(const Volume& field, const std::filesystem::path& path,
                                       const std::string& grid_name = "density");

}  // namespace sonomesh::volume
