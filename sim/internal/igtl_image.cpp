#include "sim/internal/igtl_image.h"

#include <igtlImageMessage.h>
#include <igtl_util.h>

#include <cstring>
#include <stdexcept>

namespace sonomesh::sim::internal {
namespace {

constexpr std::size_t kHeaderBytes = 58;  // version, type, device, timestamp, body size, crc
constexpr std::size_t kBodySizeAt = 42, kCrcAt = 50;

void put_be(std::vector<std::uint8_t>& out, std::uint64_t value, int bytes) {
  for (int b = bytes - 1; b >= 0; --b) out.push_back(static_cast<std::uint8_t>(value >> (8 * b)));
}

void set_be64(std::uint8_t* at, std::uint64_t value) {
  for (int b = 0; b < 8; ++b) at[b] = static_cast<std::uint8_t>(value >> (8 * (7 - b)));
}

// Version-2 framing around a version-1 message: the header's version, body size and CRC change;
// the body becomes extended header + content + metadata header + metadata.
std::vector<std::uint8_t> to_version2(const std::uint8_t* v1, std::size_t content_bytes,
                                      std::uint32_t message_id) {
  const std::string key = "Source", value = "probe-sim";
  std::vector<std::uint8_t> out(v1, v1 + kHeaderBytes);
  out[0] = 0;
  out[1] = 2;
  const std::size_t meta_header = 2 + 8;  // index count, then one entry's sizes and encoding
  put_be(out, 12, 2);                     // extended header size
  put_be(out, meta_header, 2);
  put_be(out, key.size() + value.size(), 4);
  put_be(out, message_id, 4);
  out.insert(out.end(), v1 + kHeaderBytes, v1 + kHeaderBytes + content_bytes);
  put_be(out, 1, 2);  // one metadata entry
  put_be(out, key.size(), 2);
  put_be(out, 3, 2);  // value encoding: US-ASCII (IANA MIBenum 3)
  put_be(out, value.size(), 4);
  out.insert(out.end(), key.begin(), key.end());
  out.insert(out.end(), value.begin(), value.end());
  const std::size_t body = out.size() - kHeaderBytes;
  set_be64(out.data() + kBodySizeAt, body);
  set_be64(out.data() + kCrcAt, crc64(out.data() + kHeaderBytes, body, 0));
  return out;
}

}  // namespace

std::vector<std::uint8_t> encode_igtl_image(const acquire::RawVolume& volume,
                                            const std::string& device, int header_version,
                                            std::uint32_t message_id) {
  if (header_version != 1 && header_version != 2)
    throw std::invalid_argument("IGTL header version " + std::to_string(header_version) +
                                " (1 or 2)");
  for (int d : volume.dims)
    if (d < 1 || d > 65535)
      throw std::invalid_argument("IGTL IMAGE: dimension " + std::to_string(d));
  auto msg = igtl::ImageMessage::New();
  msg->SetDeviceName(device.c_str());
  msg->SetDimensions(volume.dims[0], volume.dims[1], volume.dims[2]);
  msg->SetSpacing(volume.spacing_mm[0], volume.spacing_mm[1], volume.spacing_mm[2]);
  if (volume.type == acquire::ProbeVoxelType::UInt16)
    msg->SetScalarTypeToUint16();
  else
    msg->SetScalarTypeToUint8();
  msg->SetEndian(igtl::ImageMessage::ENDIAN_BIG);
  msg->SetCoordinateSystem(igtl::ImageMessage::COORDINATE_RAS);
  float axes[3][3];  // axes[c]: the RAS direction of index axis c (t, s, n)
  float centre[3];
  for (int a = 0; a < 3; ++a) {
    const float ras = a < 2 ? -1.0f : 1.0f;  // LPS -> RAS
    double p = volume.origin_mm[a];
    for (int c = 0; c < 3; ++c) {
      const float dir = volume.direction[3 * c + a];
      axes[c][a] = ras * dir;
      p += dir * volume.spacing_mm[c] * (volume.dims[c] - 1) / 2.0;
    }
    centre[a] = ras * static_cast<float>(p);
  }
  msg->SetNormals(axes[0], axes[1], axes[2]);
  msg->SetOrigin(centre);
  const auto sec = static_cast<std::uint32_t>(volume.timestamp_ns / 1000000000ull);
  const auto nsec = static_cast<std::uint32_t>(volume.timestamp_ns % 1000000000ull);
  msg->SetTimeStamp(sec, igtl_nanosec_to_frac(nsec));
  msg->AllocateScalars();
  const int bpv = acquire::bytes_per_voxel(volume.type);
  const std::size_t bytes =
      static_cast<std::size_t>(volume.dims[0]) * volume.dims[1] * volume.dims[2] * bpv;
  if (volume.voxels.size() != bytes)
    throw std::invalid_argument("IGTL IMAGE: voxel bytes do not match the size");
  auto* dst = static_cast<std::uint8_t*>(msg->GetScalarPointer());
  if (bpv == 1) {
    std::memcpy(dst, volume.voxels.data(), bytes);
  } else {  // the record is little endian, the message says big
    for (std::size_t t = 0; t < bytes; t += 2) {
      dst[t] = volume.voxels[t + 1];
      dst[t + 1] = volume.voxels[t];
    }
  }
  msg->Pack();
  const auto* packed = static_cast<const std::uint8_t*>(msg->GetPackPointer());
  if (header_version == 1) return {packed, packed + msg->GetPackSize()};
  return to_version2(packed, static_cast<std::size_t>(msg->GetPackBodySize()), message_id);
}

}  // namespace sonomesh::sim::internal
