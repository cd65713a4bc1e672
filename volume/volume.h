#pragma once
/// @file
/// @brief The Volume value type, its file formats, smoothing, gradients and sampling.
///
/// Index space (i, j, k), i fastest in memory; physical space in millimetres:
/// p_mm = origin_mm + spacing_mm ⊙ ijk (axis-aligned, DESIGN.md "Coordinates and units").

#include <Eigen/Core>
#include <cstdint>
#include <filesystem>
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
  enum class Code { NotFound, UnknownFormat, BadHeader, UnsupportedType, BadDimensions,
                    TruncatedData, SizeMismatch, UnsupportedOrientation, Compression, IoError };
  Code code = Code::IoError;
  std::string message;  // one line naming the file and the problem
};

/// Result of a read: a volume, or an error.
struct VolumeReadResult {
  Volume volume;
  std::optional<VolumeIoError> error;
  explicit operator bool() const { return !error.has_value(); }
};

struct ReadOptions {
  /// Refuse files whose header announces more voxels than this, before allocating anything.
  std::size_t max_voxels = std::size_t{1} << 30;
};

enum class Compression { Raw, Gzip };

/// Reads NRRD (.nrrd, .nhdr + detached data; raw or gzip; through Teem) or MetaImage (.mha,
/// .mhd + .raw; raw or zlib), by extension. Axis-aligned direction matrices with flips are
/// applied to the data so that index space maps to mm as above; other directions are refused.
/// uint8/uint16/float load as such; other numeric types (int8/16/32, uint32, double) are converted
/// to Float32. NRRD in RAS or LAS space is converted to LPS (the space written). The mm position of
/// every file voxel is kept, so after a flip its index changes (file j -> ny-1-j): use mm, not file
/// indices. Sizes are checked against options.max_voxels and the data on disk before allocating.
VolumeReadResult read_volume(const std::filesystem::path& path, const ReadOptions& options = {});

/// Writes NRRD (.nrrd attached, .nhdr detached) or MetaImage (.mha, .mhd + .raw) by extension.
/// Returns an error instead of throwing.
std::optional<VolumeIoError> write_volume(const Volume& volume, const std::filesystem::path& path,
                                          Compression compression = Compression::Raw);

// ---------------------------------------------------------------------------------------------
// Processing.

/// 3D Gaussian smoothing, sigma in mm per axis (so anisotropic spacing is handled), separable
/// (OpenCV), both cores. Returns a Float32 volume on the same grid. sigma_mm <= 0 only converts.
Volume smooth_gaussian(const Volume& input, float sigma_mm);
/// Same, into `out`, reusing its voxel buffer when it already is a Float32 volume of the same dims
/// (a per-volume pipeline then allocates nothing; fresh 8 MB buffers cost page faults). `out` must
/// not be `input`.
void smooth_gaussian(const Volume& input, float sigma_mm, Volume& out);

/// The speckle's grain around a point, in mm: per grid axis, the lag at which the normalised
/// autocorrelation of the raw intensities in a cube of `radius_vox` voxels around `centre_mm`
/// falls to one half (linear between integer lags), the largest over the axes; an axis still
/// correlated above 0.25 at three voxels holds structure, not grain, and is left out. A smoothing of this
/// sigma averages a grain away; one of a voxel leaves a coarse grain as blobs that stop a balloon.
/// 0 if the cube holds no variation (a noise-free image); capped at `radius_vox` voxels.
float speckle_grain_mm(const Volume& input, const Vec3f& centre_mm, int radius_vox = 6);

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

/// The balloon's occupancy A_t (method.md §2): the voxels its front has swept, each holding the
/// unit normal (quantised to 1/127) of the front that swept it first. Sparse: an openvdb::Int32Grid
/// in the volume's index space, so memory follows the swept region, not the volume.
/// Marking is for one thread at a time; reading goes through Readers, one per thread, and is safe
/// from several threads at once while nothing marks (the balloon alternates the two phases).
class FrontGrid {
 public:
  explicit FrontGrid(const Volume& like);
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
  Volume to_labels() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Writes a Float32 volume as an OpenVDB float grid named `grid_name`, with the volume's transform.
std::optional<VolumeIoError> write_vdb(const Volume& field, const std::filesystem::path& path,
                                       const std::string& grid_name = "density");

}  // namespace sonomesh::volume
