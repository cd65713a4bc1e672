// OpenVDB grids. The only translation unit that includes OpenVDB (its headers compile slowly).
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <mutex>
#include <stdexcept>

#include <openvdb/io/File.h>
#include <openvdb/math/Transform.h>
#include <openvdb/openvdb.h>

#include "volume/volume.h"

namespace sonomesh::volume {
namespace {

void init_openvdb() {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
}

// Index space (i, j, k) -> mm: p = origin + spacing ⊙ ijk, i.e. a scale-then-translate map.
openvdb::math::Transform::Ptr make_transform(const Volume& like) {
  const openvdb::Vec3d scale(like.spacing_mm().x(), like.spacing_mm().y(), like.spacing_mm().z());
  const openvdb::Vec3d translate(like.origin_mm().x(), like.origin_mm().y(), like.origin_mm().z());
  openvdb::math::MapBase::Ptr map(new openvdb::math::ScaleTranslateMap(scale, translate));
  return openvdb::math::Transform::Ptr(new openvdb::math::Transform(map));
}

openvdb::Coord coord(const Vec3i& ijk) { return openvdb::Coord(ijk.x(), ijk.y(), ijk.z()); }

}  // namespace

// A grid in the volume's index space (voxel size = spacing, same origin) with one cached
// accessor, which is what makes neighbour-by-neighbour access cheap (it keeps the last leaf).
template <typename GridT>
struct IndexSpaceGrid {
  Vec3i dims;
  Vec3f spacing_mm;
  Vec3f origin_mm;
  typename GridT::Ptr grid;
  // For writing (FrontGrid::mark), from one thread; readers make their own.
  typename GridT::Accessor accessor;

  IndexSpaceGrid(const Volume& like, typename GridT::ValueType background, const char* name)
      : dims(like.dims()),
        spacing_mm(like.spacing_mm()),
        origin_mm(like.origin_mm()),
        grid(make_grid(like, background, name)),
        accessor(grid->getAccessor()) {}

  // Dense uint8 labels, 1 where a voxel is active.
  Volume to_labels() const {
    Volume labels(dims, spacing_mm, origin_mm, VoxelType::UInt8);
    auto& out = labels.u8();
    const Vec3i& d = dims;
    for (auto it = grid->cbeginValueOn(); it; ++it) {
      const openvdb::CoordBBox box = it.getBoundingBox();  // a tile may cover many voxels
      for (int k = std::max(box.min().z(), 0); k <= std::min(box.max().z(), d.z() - 1); ++k)
        for (int j = std::max(box.min().y(), 0); j <= std::min(box.max().y(), d.y() - 1); ++j)
          for (int i = std::max(box.min().x(), 0); i <= std::min(box.max().x(), d.x() - 1); ++i)
            out[labels.linear_index(i, j, k)] = 1;
    }
    return labels;
  }

  static typename GridT::Ptr make_grid(const Volume& like, typename GridT::ValueType background,
                                       const char* name) {
    init_openvdb();
    auto g = GridT::create(background);
    g->setTransform(make_transform(like));
    g->setName(name);
    return g;
  }
};


// ---------------------------------------------------------------------------------------------
// FrontGrid: A_t with the sweeping front's normal per voxel, packed into one int32 (x, y, z as
// int8 in units of 1/127; the grid's background 0 means unmarked, marked voxels are also active).

namespace {

std::int32_t encode_normal(const Vec3f& n) {
  auto q = [](float v) {
    // lround (halves away from zero) without its libm call: x − trunc(x) is exact for |x| <= 127.
    const float x = std::clamp(v, -1.0f, 1.0f) * 127.0f;
    const int t = static_cast<int>(x);
    const float frac = x - static_cast<float>(t);
    const int rounded = t + (frac >= 0.5f ? 1 : frac <= -0.5f ? -1 : 0);
    return static_cast<std::uint32_t>(static_cast<std::uint8_t>(static_cast<std::int8_t>(rounded)));
  };
  // Bit 24 keeps a zero normal distinguishable from the background.
  return static_cast<std::int32_t>(q(n.x()) | (q(n.y()) << 8) | (q(n.z()) << 16) | (1u << 24));
}

Vec3f decode_normal(std::int32_t packed) {
  const auto c = static_cast<std::uint32_t>(packed);
  auto d = [](std::uint32_t b) {
    return static_cast<float>(static_cast<std::int8_t>(static_cast<std::uint8_t>(b & 0xffu))) / 127.0f;
  };
  return {d(c), d(c >> 8), d(c >> 16)};
}

}  // namespace

struct FrontGrid::Impl : IndexSpaceGrid<openvdb::Int32Grid> {
  explicit Impl(const Volume& like) : IndexSpaceGrid(like, 0, "front") {}
};

struct FrontGrid::Reader::Impl {
  // Unregistered: no entry in the tree's accessor registry, so making one per task costs nothing;
  // valid because the tree does not change while Readers are in use (see the class comment).
  openvdb::Int32Grid::ConstUnsafeAccessor accessor;
  explicit Impl(const openvdb::Int32Grid& grid) : accessor(grid.getConstUnsafeAccessor()) {}
};

FrontGrid::FrontGrid(const Volume& like) {
  if (like.empty()) throw std::invalid_argument("FrontGrid: empty reference volume");
  impl_ = std::make_unique<Impl>(like);
}
FrontGrid::~FrontGrid() = default;
FrontGrid::FrontGrid(FrontGrid&&) noexcept = default;
FrontGrid& FrontGrid::operator=(FrontGrid&&) noexcept = default;

bool FrontGrid::mark(const Vec3i& ijk, const Vec3f& normal) {
  if (!impl_) throw std::logic_error("FrontGrid: used after move");
  const openvdb::Coord c = coord(ijk);
  // One descent to the leaf (created if the voxel's brick has none yet, as setValueOn would),
  // then test and set in it: the accessor's isValueOn and setValueOn descended twice.
  auto* leaf = impl_->accessor.touchLeaf(c);
  if (leaf->isValueOn(c)) return false;
  leaf->setValueOn(c, encode_normal(normal));
  return true;
}

FrontGrid::Reader::Reader(const FrontGrid& grid) {
  if (!grid.impl_) throw std::logic_error("FrontGrid: used after move");
  impl_ = std::make_unique<Impl>(*grid.impl_->grid);
}
FrontGrid::Reader::~Reader() = default;
FrontGrid::Reader::Reader(Reader&&) noexcept = default;

bool FrontGrid::Reader::normal(const Vec3i& ijk, Vec3f& normal) const {
  std::int32_t packed = 0;
  if (!impl_->accessor.probeValue(coord(ijk), packed)) return false;
  normal = decode_normal(packed);
  return true;
}

bool FrontGrid::Reader::marked(const Vec3i& ijk) const { return impl_->accessor.isValueOn(coord(ijk)); }

std::size_t FrontGrid::marked_count() const {
  if (!impl_) throw std::logic_error("FrontGrid: used after move");
  return static_cast<std::size_t>(impl_->grid->activeVoxelCount());
}

std::size_t FrontGrid::memory_bytes() const {
  if (!impl_) throw std::logic_error("FrontGrid: used after move");
  return static_cast<std::size_t>(impl_->grid->memUsage());
}

Volume FrontGrid::to_labels() const {
  if (!impl_) throw std::logic_error("FrontGrid: used after move");
  return impl_->to_labels();
}

std::optional<VolumeIoError> write_vdb(const Volume& field, const std::filesystem::path& path,
                                       const std::string& grid_name) {
  using Code = VolumeIoError::Code;
  if (field.empty()) return VolumeIoError{Code::BadDimensions, path.string() + ": empty volume"};
  if (field.type() != VoxelType::Float32)
    return VolumeIoError{Code::UnsupportedType,
                         path.string() + ": write_vdb needs a float volume, got " +
                             to_string(field.type())};
  try {
    init_openvdb();
    auto grid = openvdb::FloatGrid::create(0.0f);
    grid->setTransform(make_transform(field));
    grid->setName(grid_name);
    grid->setGridClass(openvdb::GRID_FOG_VOLUME);
    auto acc = grid->getAccessor();
    const Vec3i& d = field.dims();
    const auto& v = field.f32();
    std::size_t idx = 0;
    for (int k = 0; k < d.z(); ++k)
      for (int j = 0; j < d.y(); ++j)
        for (int i = 0; i < d.x(); ++i, ++idx)
          if (v[idx] != 0.0f) acc.setValueOn(openvdb::Coord(i, j, k), v[idx]);
    openvdb::io::File file(path.string());
    file.write({grid});
    file.close();
  } catch (const std::exception& e) {
    std::string msg = e.what();
    std::replace(msg.begin(), msg.end(), '\n', ' ');
    return VolumeIoError{Code::IoError, path.string() + ": cannot write VDB: " + msg};
  }
  return std::nullopt;
}

}  // namespace sonomesh::volume
