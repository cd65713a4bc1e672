// write_vdb: the only translation unit of volume/ that includes OpenVDB (slow headers).
#include <openvdb/io/File.h>
#include <openvdb/math/Transform.h>
#include <openvdb/openvdb.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <mutex>
#include <stdexcept>

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

}  // namespace

std::optional<VolumeIoError> write_vdb(const Volume& field, const std::filesystem::path& path,
                                       const std::string& grid_name) {
  using Code = VolumeIoError::Code;
  if (field.empty()) return VolumeIoError{Code::BadDimensions, path.string() + ": empty volume"};
  if (field.type() != VoxelType::Float32)
    return VolumeIoError{
        Code::UnsupportedType,
        path.string() + ": write_vdb needs a float volume, got " + to_string(field.type())};
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
