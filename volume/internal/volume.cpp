#include "volume/volume.h"

#include <algorithm>
#include <cassert>
#include <cstring>
#include <stdexcept>

#include "volume/decoded_volume.h"

namespace sonomesh::volume {

const char* to_string(VoxelType type) {
  switch (type) {
    case VoxelType::UInt8:
      return "uint8";
    case VoxelType::UInt16:
      return "uint16";
    case VoxelType::Float32:
      return "float";
  }
  return "unknown";
}

Volume::Volume(const Vec3i& dims, const Vec3f& spacing_mm, const Vec3f& origin_mm, VoxelType type)
    : dims_(dims), spacing_mm_(spacing_mm), origin_mm_(origin_mm) {
  if ((dims.array() <= 0).any()) throw std::invalid_argument("Volume: dims must be positive");
  if (!(spacing_mm.array() > 0.0f).all() || !spacing_mm.allFinite())
    throw std::invalid_argument("Volume: spacing_mm must be positive and finite");
  const std::size_t n = voxel_count();
  switch (type) {
    case VoxelType::UInt8:
      data_ = std::vector<std::uint8_t>(n, 0);
      break;
    case VoxelType::UInt16:
      data_ = std::vector<std::uint16_t>(n, 0);
      break;
    case VoxelType::Float32:
      data_ = std::vector<float>(n, 0.0f);
      break;
  }
}

Volume Volume::from_raw(const acquire::RawVolume& raw) {
  if (const auto* decoded = dynamic_cast<const DecodedVolume*>(raw.decoded.get())) {
    return decoded->volume();
  }
  const Vec3i dims(raw.dims[0], raw.dims[1], raw.dims[2]);
  const Vec3f spacing(raw.spacing_mm[0], raw.spacing_mm[1], raw.spacing_mm[2]);
  const Vec3f origin(raw.origin_mm[0], raw.origin_mm[1], raw.origin_mm[2]);
  const VoxelType type =
      raw.type == acquire::ProbeVoxelType::UInt16 ? VoxelType::UInt16 : VoxelType::UInt8;
  Volume v(dims, spacing, origin, type);
  v.set_direction(Eigen::Map<const Mat3f>(raw.direction.data()));
  const std::size_t bytes = v.voxel_count() * acquire::bytes_per_voxel(raw.type);
  if (raw.voxels.size() != bytes)
    throw std::invalid_argument("Volume::from_raw: payload has " +
                                std::to_string(raw.voxels.size()) + " bytes, dims and type need " +
                                std::to_string(bytes));
  if (type == VoxelType::UInt8) {
    std::memcpy(v.u8().data(), raw.voxels.data(), bytes);
  } else {
    auto& out = v.u16();
    for (std::size_t i = 0; i < out.size(); ++i)  // protocol is little endian
      out[i] = static_cast<std::uint16_t>(raw.voxels[2 * i] | (raw.voxels[2 * i + 1] << 8));
  }
  return v;
}

std::vector<std::uint8_t> DecodedVolume::probe_voxels() const {
  std::vector<std::uint8_t> bytes;
  if (volume_.type() == VoxelType::UInt8) {
    bytes = volume_.u8();
  } else if (volume_.type() == VoxelType::UInt16) {
    const auto& src = volume_.u16();
    bytes.resize(src.size() * 2);
    for (std::size_t i = 0; i < src.size(); ++i) {  // little endian, as on the wire
      bytes[2 * i] = static_cast<std::uint8_t>(src[i] & 0xff);
      bytes[2 * i + 1] = static_cast<std::uint8_t>(src[i] >> 8);
    }
  }
  return bytes;
}

VoxelType Volume::type() const { return static_cast<VoxelType>(data_.index()); }

namespace {
template <typename T, typename Variant>
auto& typed(Variant& variant, const char* what) {
  auto* p = std::get_if<T>(&variant);
  if (!p) throw std::logic_error(std::string("Volume: voxels are not ") + what);
  return *p;
}
}  // namespace

std::vector<std::uint8_t>& Volume::u8() { return typed<std::vector<std::uint8_t>>(data_, "uint8"); }
const std::vector<std::uint8_t>& Volume::u8() const {
  return typed<std::vector<std::uint8_t>>(data_, "uint8");
}
std::vector<std::uint16_t>& Volume::u16() {
  return typed<std::vector<std::uint16_t>>(data_, "uint16");
}
const std::vector<std::uint16_t>& Volume::u16() const {
  return typed<std::vector<std::uint16_t>>(data_, "uint16");
}
std::vector<float>& Volume::f32() { return typed<std::vector<float>>(data_, "float"); }
const std::vector<float>& Volume::f32() const { return typed<std::vector<float>>(data_, "float"); }

float Volume::value(int i, int j, int k) const {
  assert(contains_index(Vec3i(i, j, k)));
  const std::size_t idx = linear_index(i, j, k);
  return std::visit([idx](const auto& v) { return static_cast<float>(v[idx]); }, data_);
}

std::vector<float> Volume::to_float() const {
  return std::visit([](const auto& v) { return std::vector<float>(v.begin(), v.end()); }, data_);
}

bool Volume::contains_mm(const Vec3f& p_mm) const {
  if (empty()) return false;
  const Vec3f ijk = mm_to_index(p_mm);
  return (ijk.array() >= 0.0f).all() &&
         (ijk.array() <= (dims_ - Vec3i::Ones()).cast<float>().array()).all();
}

}  // namespace sonomesh::volume
