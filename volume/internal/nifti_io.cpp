// NIfTI-1 (.nii, .nii.gz) through nifticlib. NIfTI's world is RAS; this project's is LPS, so the
// first two rows of its index-to-world matrix change sign on the way in and out.
//
// nifticlib keeps global options and is not thread-safe: every call runs under one mutex. It reads
// the header first (read_data = 0); dimensions and the bytes on disk are checked before any voxel
// buffer is allocated. A 4D file (a time series) loads its first frame (ReadResult::note says so).
#include <nifti1_io.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <mutex>

#include "volume/internal/io.h"

namespace sonomesh::volume::internal {
namespace {

std::mutex& nifti_mutex() {
  static std::mutex m;
  return m;
}

struct NiftiDeleter {
  void operator()(nifti_image* n) const { nifti_image_free(n); }
};
using NiftiPtr = std::unique_ptr<nifti_image, NiftiDeleter>;

std::optional<VoxelType> target_type(int datatype) {
  switch (datatype) {
    case NIFTI_TYPE_UINT8:
      return VoxelType::UInt8;
    case NIFTI_TYPE_UINT16:
      return VoxelType::UInt16;
    case NIFTI_TYPE_FLOAT32:
    case NIFTI_TYPE_INT8:
    case NIFTI_TYPE_INT16:
    case NIFTI_TYPE_INT32:
    case NIFTI_TYPE_UINT32:
    case NIFTI_TYPE_INT64:
    case NIFTI_TYPE_UINT64:
    case NIFTI_TYPE_FLOAT64:
      return VoxelType::Float32;
    default:
      return std::nullopt;
  }
}

template <typename Src>
void to_float(const void* src, std::vector<float>& dst, float slope, float inter) {
  const auto* s = static_cast<const Src*>(src);
  for (std::size_t i = 0; i < dst.size(); ++i) dst[i] = static_cast<float>(s[i]) * slope + inter;
}

void fill_volume(Volume& v, int datatype, const void* data, float slope, float inter) {
  auto& f = v.f32();
  switch (datatype) {
    case NIFTI_TYPE_FLOAT32:
      to_float<float>(data, f, slope, inter);
      break;
    case NIFTI_TYPE_UINT8:
      to_float<std::uint8_t>(data, f, slope, inter);
      break;
    case NIFTI_TYPE_UINT16:
      to_float<std::uint16_t>(data, f, slope, inter);
      break;
    case NIFTI_TYPE_INT8:
      to_float<std::int8_t>(data, f, slope, inter);
      break;
    case NIFTI_TYPE_INT16:
      to_float<std::int16_t>(data, f, slope, inter);
      break;
    case NIFTI_TYPE_INT32:
      to_float<std::int32_t>(data, f, slope, inter);
      break;
    case NIFTI_TYPE_UINT32:
      to_float<std::uint32_t>(data, f, slope, inter);
      break;
    case NIFTI_TYPE_INT64:
      to_float<std::int64_t>(data, f, slope, inter);
      break;
    case NIFTI_TYPE_UINT64:
      to_float<std::uint64_t>(data, f, slope, inter);
      break;
    case NIFTI_TYPE_FLOAT64:
      to_float<double>(data, f, slope, inter);
      break;
    default:
      break;
  }
}

// Axis directions (with spacing, LPS) and origin from a RAS index-to-world matrix.
void lps_axes(const mat44& ras, std::array<std::array<double, 3>, 3>& dirs, Vec3f& origin) {
  const double sign[3] = {-1.0, -1.0, 1.0};
  for (int c = 0; c < 3; ++c) {
    for (int a = 0; a < 3; ++a) dirs[a][c] = sign[c] * ras.m[c][a];
    origin[c] = static_cast<float>(sign[c] * ras.m[c][3]);
  }
}

// sform when it is set and orthonormal, else qform (nifticlib fills qto_xyz from pixdim when the
// file sets neither, as ITK reads such files); a bad sform without a qform is refused.
std::optional<VolumeIoError> geometry(const std::filesystem::path& path, const nifti_image* nim,
                                      AxisGeometry& axes, Vec3f& origin) {
  std::array<std::array<double, 3>, 3> dirs{};
  if (nim->sform_code > 0) {
    lps_axes(nim->sto_xyz, dirs, origin);
    auto err = axis_geometry(path, dirs, axes);
    if (!err && origin.allFinite()) return std::nullopt;
    if (nim->qform_code <= 0)  // pixdim alone would silently put the voxels elsewhere
      return err ? err : io_error(Code::BadHeader, path, "sform origin out of range");
  }
  lps_axes(nim->qto_xyz, dirs, origin);
  if (auto err = axis_geometry(path, dirs, axes)) return err;
  if (!origin.allFinite()) return io_error(Code::BadHeader, path, "origin out of range");
  return std::nullopt;
}

// Dimensions: 3D, or 4D (first frame read); vector/tensor images are refused.
std::optional<VolumeIoError> check_dims_nifti(const std::filesystem::path& path,
                                              const nifti_image* nim, const ReadOptions& options,
                                              Vec3i& dims, std::string& note) {
  if (nim->ndim < 3 || nim->ndim > 4)
    return io_error(Code::BadDimensions, path,
                    "has " + std::to_string(nim->ndim) + " dimensions, need 3 (or 4: first frame)");
  for (int d = 5; d <= 7 && d <= nim->dim[0]; ++d)
    if (nim->dim[d] > 1)
      return io_error(Code::BadDimensions, path,
                      "has more than one value per voxel (dim[" + std::to_string(d) +
                          "] = " + std::to_string(nim->dim[d]) + ")");
  if (auto err = check_dims(path, {nim->nx, nim->ny, nim->nz}, options)) return err;
  dims = Vec3i(static_cast<int>(nim->nx), static_cast<int>(nim->ny), static_cast<int>(nim->nz));
  if (nim->ndim == 4 && nim->nt > 1)
    note = path.filename().string() + ": 4D with " + std::to_string(nim->nt) +
           " frames; read the first";
  return std::nullopt;
}

std::optional<VolumeIoError> check_size(const std::filesystem::path& path, const nifti_image* nim,
                                        std::uintmax_t frame_bytes) {
  const auto size = data_file_size(path);
  if (!size) return io_error(Code::IoError, path, "cannot stat");
  const bool gz = lower_extension(path) == ".nii.gz";
  const std::uintmax_t offset =
      nim->iname_offset > 0 ? static_cast<std::uintmax_t>(nim->iname_offset) : 0;
  if (!gz && *size < offset + frame_bytes)
    return io_error(Code::TruncatedData, path,
                    "data has " + std::to_string(*size > offset ? *size - offset : 0) +
                        " bytes, the header needs " + std::to_string(frame_bytes));
  if (gz && *size * kMaxDeflateRatio + 1024 < frame_bytes)
    return io_error(Code::TruncatedData, path,
                    "compressed data of " + std::to_string(*size) +
                        " bytes cannot hold the header's " + std::to_string(frame_bytes));
  return std::nullopt;
}

}  // namespace

VolumeReadResult read_nifti(const std::filesystem::path& path, const ReadOptions& options) {
  std::lock_guard<std::mutex> lock(nifti_mutex());
  nifti_set_debug_level(0);  // errors become our messages, not nifticlib's stderr lines
  NiftiPtr nim(nifti_image_read(path.c_str(), 0));
  if (!nim) return {Volume{}, io_error(Code::BadHeader, path, "not a readable NIfTI-1 header")};
  VolumeReadResult result;
  Vec3i dims;
  if (auto err = check_dims_nifti(path, nim.get(), options, dims, result.note))
    return {Volume{}, err};
  const auto type = target_type(nim->datatype);
  if (!type)
    return {Volume{}, io_error(Code::UnsupportedType, path,
                               std::string("unsupported voxel type ") +
                                   nifti_datatype_string(nim->datatype))};
  const std::uintmax_t voxels = static_cast<std::uintmax_t>(dims.x()) * dims.y() * dims.z();
  const std::size_t frame_bytes = voxels * static_cast<std::size_t>(nim->nbyper);
  if (auto err = check_size(path, nim.get(), frame_bytes)) return {Volume{}, err};
  AxisGeometry axes;
  Vec3f origin;
  if (auto err = geometry(path, nim.get(), axes, origin)) return {Volume{}, err};

  const int frame[8] = {0, -1, -1, -1, 0, 0, 0, 0};  // all of x, y, z; index 0 of the rest
  void* raw = nullptr;
  const int got = nifti_read_collapsed_image(nim.get(), frame, &raw);
  const std::unique_ptr<void, decltype(&std::free)> data(raw, &std::free);
  if (got < 0 || static_cast<std::size_t>(got) != frame_bytes || !raw)
    return {Volume{},
            io_error(nim->iname && lower_extension(path) == ".nii.gz" ? Code::Compression
                                                                      : Code::TruncatedData,
                     path, "cannot read " + std::to_string(frame_bytes) + " bytes of voxels")};
  // Intensity scaling (scl_slope 0 means none); scaled data is stored as float.
  const bool scaled = nim->scl_slope != 0.0f && std::isfinite(nim->scl_slope) &&
                      std::isfinite(nim->scl_inter) &&
                      (nim->scl_slope != 1.0f || nim->scl_inter != 0.0f);
  Volume volume(dims, axes.spacing_mm, origin, scaled ? VoxelType::Float32 : *type);
  if (!scaled && *type == VoxelType::UInt8)
    std::memcpy(volume.u8().data(), raw, frame_bytes);
  else if (!scaled && *type == VoxelType::UInt16)
    std::memcpy(volume.u16().data(), raw, frame_bytes);
  else
    fill_volume(volume, nim->datatype, raw, scaled ? nim->scl_slope : 1.0f,
                scaled ? nim->scl_inter : 0.0f);
  apply_geometry(volume, axes, origin);
  result.volume = std::move(volume);
  return result;
}

std::optional<VolumeIoError> write_nifti(const Volume& volume, const std::filesystem::path& path) {
  int datatype = NIFTI_TYPE_FLOAT32;
  const void* data = nullptr;
  switch (volume.type()) {
    case VoxelType::UInt8:
      datatype = NIFTI_TYPE_UINT8, data = volume.u8().data();
      break;
    case VoxelType::UInt16:
      datatype = NIFTI_TYPE_UINT16, data = volume.u16().data();
      break;
    case VoxelType::Float32:
      datatype = NIFTI_TYPE_FLOAT32, data = volume.f32().data();
      break;
  }
  const bool gz = lower_extension(path) == ".nii.gz";
  std::lock_guard<std::mutex> lock(nifti_mutex());
  nifti_set_debug_level(0);
  if (gz && !nifti_compiled_with_zlib())
    return io_error(Code::Compression, path, "nifticlib was built without zlib");
  const Vec3i& d = volume.dims();
  const int dims[8] = {3, d.x(), d.y(), d.z(), 1, 1, 1, 1};
  NiftiPtr nim(nifti_make_new_nim(dims, datatype, 0));
  if (!nim) return io_error(Code::IoError, path, "nifticlib cannot make an image");
  // Index-to-world in RAS: rows 0 and 1 of the LPS matrix change sign.
  mat44 ras{};
  const double sign[3] = {-1.0, -1.0, 1.0};
  for (int r = 0; r < 3; ++r) {
    for (int a = 0; a < 3; ++a)
      ras.m[r][a] = static_cast<float>(sign[r] * volume.direction()(r, a) * volume.spacing_mm()[a]);
    ras.m[r][3] = static_cast<float>(sign[r] * volume.origin_mm()[r]);
  }
  ras.m[3][3] = 1.0f;
  nim->sform_code = nim->qform_code = NIFTI_XFORM_SCANNER_ANAT;
  nim->sto_xyz = nim->qto_xyz = ras;
  nifti_mat44_to_quatern(ras, &nim->quatern_b, &nim->quatern_c, &nim->quatern_d, &nim->qoffset_x,
                         &nim->qoffset_y, &nim->qoffset_z, &nim->dx, &nim->dy, &nim->dz,
                         &nim->qfac);
  nim->pixdim[1] = nim->dx, nim->pixdim[2] = nim->dy, nim->pixdim[3] = nim->dz;
  nim->xyz_units = NIFTI_UNITS_MM;
  nim->nifti_type = NIFTI_FTYPE_NIFTI1_1;
  if (nifti_set_filenames(nim.get(), path.c_str(), 0, 1))
    return io_error(Code::UnknownFormat, path, "nifticlib refuses the file name");
  nifti_set_iname_offset(nim.get());
  std::free(nim->data);
  nim->data = const_cast<void*>(data);  // nifticlib only reads it; given back before the free
  std::error_code ec;
  std::filesystem::remove(path, ec);
  nifti_image_write(nim.get());
  nim->data = nullptr;
  const auto size = data_file_size(path);  // nifti_image_write reports nothing: check the result
  if (!size || *size < 348) return io_error(Code::IoError, path, "cannot write");
  return std::nullopt;
}

}  // namespace sonomesh::volume::internal
