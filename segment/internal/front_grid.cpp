// FrontGrid on OpenVDB: the only translation unit of segment/ that includes it (slow headers).
#include "segment/internal/front_grid.h"

#include <openvdb/math/Transform.h>
#include <openvdb/openvdb.h>

#include <algorithm>
#include <cstdint>
#include <mutex>
#include <stdexcept>

namespace sonomesh::segment::internal {
namespace {

using volume::Volume;

void init_openvdb() {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
}

openvdb::Coord coord(const Vec3i& ijk) { return openvdb::Coord(ijk.x(), ijk.y(), ijk.z()); }

// Index space (i, j, k) -> mm: p = origin + spacing ⊙ ijk, a scale-then-translate map.
openvdb::math::Transform::Ptr make_transform(const Volume& like) {
  const openvdb::Vec3d scale(like.spacing_mm().x(), like.spacing_mm().y(), like.spacing_mm().z());
  const openvdb::Vec3d translate(like.origin_mm().x(), like.origin_mm().y(), like.origin_mm().z());
  openvdb::math::MapBase::Ptr map(new openvdb::math::ScaleTranslateMap(scale, translate));
  return openvdb::math::Transform::Ptr(new openvdb::math::Transform(map));
}

// The normal packed into one int32: x, y, z as int8 in units of 1/127, bit 24 set so that a zero
// normal differs from the background 0 (unmarked).
std::int32_t encode_normal(const Vec3f& n) {
  auto q = [](float v) {
    // lround (halves away from zero) without its libm call: x − trunc(x) is exact for |x| <= 127.
    const float x = std::clamp(v, -1.0f, 1.0f) * 127.0f;
    const int t = static_cast<int>(x);
    const float frac = x - static_cast<float>(t);
    const int rounded = t + (frac >= 0.5f ? 1 : frac <= -0.5f ? -1 : 0);
    return static_cast<std::uint32_t>(static_cast<std::uint8_t>(static_cast<std::int8_t>(rounded)));
  };
  return static_cast<std::int32_t>(q(n.x()) | (q(n.y()) << 8) | (q(n.z()) << 16) | (1u << 24));
}

Vec3f decode_normal(std::int32_t packed) {
  const auto c = static_cast<std::uint32_t>(packed);
  auto d = [](std::uint32_t b) {
    return static_cast<float>(static_cast<std::int8_t>(static_cast<std::uint8_t>(b & 0xffu))) /
           127.0f;
  };
  return {d(c), d(c >> 8), d(c >> 16)};
}

}  // namespace

struct FrontGrid::Impl {
  Vec3i dims;
  Vec3f spacing_mm;
  Vec3f origin_mm;
  openvdb::Int32Grid::Ptr grid;
  openvdb::Int32Grid::Accessor accessor;  // for mark(), one thread; readers make their own

  explicit Impl(const Volume& like)
      : dims(like.dims()),
        spacing_mm(like.spacing_mm()),
        origin_mm(like.origin_mm()),
        grid(make_grid(like)),
        accessor(grid->getAccessor()) {}

  static openvdb::Int32Grid::Ptr make_grid(const Volume& like) {
    init_openvdb();
    auto g = openvdb::Int32Grid::create(0);
    g->setTransform(make_transform(like));
    g->setName("front");
    return g;
  }
};

struct FrontGrid::Reader::Impl {
  // Unregistered: making one per task costs nothing; valid because the tree does not change
  // while Readers are in use (see the class comment).
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
  // One descent to the leaf (created if needed), then test and set in it.
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

bool FrontGrid::Reader::marked(const Vec3i& ijk) const {
  return impl_->accessor.isValueOn(coord(ijk));
}

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
  Volume labels(impl_->dims, impl_->spacing_mm, impl_->origin_mm, volume::VoxelType::UInt8);
  auto& out = labels.u8();
  const Vec3i& d = impl_->dims;
  for (auto it = impl_->grid->cbeginValueOn(); it; ++it) {
    const openvdb::CoordBBox box = it.getBoundingBox();  // a tile may cover many voxels
    for (int k = std::max(box.min().z(), 0); k <= std::min(box.max().z(), d.z() - 1); ++k)
      for (int j = std::max(box.min().y(), 0); j <= std::min(box.max().y(), d.y() - 1); ++j)
        for (int i = std::max(box.min().x(), 0); i <= std::min(box.max().x(), d.x() - 1); ++i)
          out[labels.linear_index(i, j, k)] = 1;
  }
  return labels;
}

}  // namespace sonomesh::segment::internal
