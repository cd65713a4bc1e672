#include "daemon/internal/igtl_messages.h"

#include <igtlImageMessage.h>
#include <igtlPolyDataMessage.h>
#include <igtlStringMessage.h>

#include <chrono>
#include <cstring>
#include <stdexcept>

namespace sonomesh::daemon {

namespace {

constexpr std::uint16_t kUtf8MibEnum = 106;

template <typename Message>
std::string packed(Message& message, IgtlTime time) {
  message->SetTimeStamp(time.seconds, time.fraction);
  message->Pack();
  return std::string(static_cast<const char*>(message->GetPackPointer()),
                     static_cast<std::size_t>(message->GetPackSize()));
}

}  // namespace

IgtlTime IgtlTime::now() {
  const auto since = std::chrono::system_clock::now().time_since_epoch();
  const auto s = std::chrono::duration_cast<std::chrono::seconds>(since);
  const double frac = std::chrono::duration<double>(since - s).count();
  return {static_cast<std::uint32_t>(s.count()), static_cast<std::uint32_t>(frac * 4294967296.0)};
}

std::string pack_igtl_mesh(const segment::Mesh& mesh, IgtlTime time) {
  auto points = igtl::PolyDataPointArray::New();
  points->SetNumberOfPoints(static_cast<int>(mesh.vertices.size()));
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    const auto& p = mesh.vertices[i];
    points->SetPoint(static_cast<unsigned>(i), -p.x(), -p.y(), p.z());  // LPS -> RAS
  }
  auto polygons = igtl::PolyDataCellArray::New();
  for (const auto& t : mesh.triangles) {
    igtlUint32 cell[3] = {static_cast<igtlUint32>(t[0]), static_cast<igtlUint32>(t[1]),
                          static_cast<igtlUint32>(t[2])};
    polygons->AddCell(3, cell);
  }
  auto message = igtl::PolyDataMessage::New();
  message->SetDeviceName(kIgtlMeshDevice);
  message->SetPoints(points);
  message->SetPolygons(polygons);
  return packed(message, time);
}

std::string pack_igtl_labels(const volume::Volume& labels, IgtlTime time) {
  if (labels.type() != volume::VoxelType::UInt8) {
    throw std::invalid_argument("OpenIGTLink labels: the label volume is not UInt8");
  }
  const volume::Vec3i dims = labels.dims();
  const volume::Vec3f spacing = labels.spacing_mm();
  const volume::Mat3f& d = labels.direction();
  // IMAGE places the volume by its centre: first voxel + D (spacing ⊙ (N - 1) / 2).
  const volume::Vec3f half =
      spacing.cwiseProduct((dims - volume::Vec3i::Ones()).cast<float>()) * 0.5f;
  const volume::Vec3f centre = labels.origin_mm() + d * half;
  auto message = igtl::ImageMessage::New();
  message->SetDeviceName(kIgtlLabelsDevice);
  message->SetDimensions(dims.x(), dims.y(), dims.z());
  message->SetSpacing(spacing.x(), spacing.y(), spacing.z());
  message->SetScalarTypeToUint8();
  message->SetNumComponents(1);
  message->SetCoordinateSystem(igtl::ImageMessage::COORDINATE_RAS);
  float t[3] = {-d(0, 0), -d(1, 0), d(2, 0)};
  float s[3] = {-d(0, 1), -d(1, 1), d(2, 1)};
  float n[3] = {-d(0, 2), -d(1, 2), d(2, 2)};
  message->SetNormals(t, s, n);
  message->SetOrigin(-centre.x(), -centre.y(), centre.z());
  message->AllocateScalars();
  const auto& voxels = labels.u8();
  std::memcpy(message->GetScalarPointer(), voxels.data(), voxels.size());
  return packed(message, time);
}

std::string pack_igtl_string(const std::string& device, const std::string& text, IgtlTime time) {
  auto message = igtl::StringMessage::New();
  message->SetDeviceName(device.c_str());
  message->SetEncoding(kUtf8MibEnum);
  message->SetString(text.c_str());
  return packed(message, time);
}

}  // namespace sonomesh::daemon
