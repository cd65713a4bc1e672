// MetaImage writer: the header fields ITK and 3D Slicer read, then raw or zlib-compressed voxels
// (attached .mha, or .mhd + .raw/.zraw). The reader is metaimage_io.cpp.
#include <zlib.h>

#include <charconv>
#include <fstream>
#include <string>
#include <vector>

#include "volume/internal/io.h"

namespace sonomesh::volume::internal {

std::optional<VolumeIoError> write_metaimage(const Volume& volume,
                                             const std::filesystem::path& path,
                                             Compression compression) {
  const char* met = "MET_UCHAR";
  const unsigned char* data = nullptr;
  std::size_t elem = 1;
  switch (volume.type()) {
    case VoxelType::UInt8:
      data = volume.u8().data();
      break;
    case VoxelType::UInt16:
      met = "MET_USHORT", elem = 2;
      data = reinterpret_cast<const unsigned char*>(volume.u16().data());
      break;
    case VoxelType::Float32:
      met = "MET_FLOAT", elem = 4;
      data = reinterpret_cast<const unsigned char*>(volume.f32().data());
      break;
  }
  const std::size_t bytes = volume.voxel_count() * elem;
  std::vector<unsigned char> packed;
  if (compression == Compression::Gzip) {  // MetaImage "compressed" means a zlib stream
    uLongf size = compressBound(static_cast<uLong>(bytes));
    packed.resize(size);
    if (compress2(packed.data(), &size, data, static_cast<uLong>(bytes), 6) != Z_OK)
      return io_error(Code::Compression, path, "zlib compression failed");
    packed.resize(size);
  }
  const bool detached = lower_extension(path) == ".mhd";
  const std::filesystem::path data_path = std::filesystem::path(path).replace_extension(
      compression == Compression::Gzip ? ".zraw" : ".raw");

  auto num = [](float v) {  // shortest form of the float: 10.1, not 10.100000381469727
    char buf[32];
    const auto r = std::to_chars(buf, buf + sizeof buf, v);
    return std::string(buf, r.ptr);
  };
  auto vec = [&](const auto& v) { return num(v.x()) + " " + num(v.y()) + " " + num(v.z()); };
  std::string header =
      "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n";
  header += std::string("CompressedData = ") + (packed.empty() ? "False" : "True") + "\n";
  if (!packed.empty()) header += "CompressedDataSize = " + std::to_string(packed.size()) + "\n";
  // TransformMatrix row a = direction of index axis a (ITK). ITK's label for the identity in an
  // LPS world is "RAI" (where the indices come from); other directions have no such label.
  const Mat3f& dir = volume.direction();
  std::string matrix;
  for (int a = 0; a < 3; ++a)
    for (int c = 0; c < 3; ++c) matrix += (matrix.empty() ? "" : " ") + num(dir(c, a));
  const bool identity = dir == Mat3f::Identity();
  header +=
      "TransformMatrix = " + matrix + "\nOffset = " + vec(volume.origin_mm()) +
      "\nCenterOfRotation = 0 0 0\n" + (identity ? "AnatomicalOrientation = RAI\n" : "") +
      "ElementSpacing = " + vec(volume.spacing_mm()) +
      "\nDimSize = " + std::to_string(volume.dims().x()) + " " + std::to_string(volume.dims().y()) +
      " " + std::to_string(volume.dims().z()) + "\nElementType = " + met +
      "\nElementDataFile = " + (detached ? data_path.filename().string() : std::string("LOCAL")) +
      "\n";

  const unsigned char* out = packed.empty() ? data : packed.data();
  const std::size_t out_size = packed.empty() ? bytes : packed.size();
  std::ofstream hf(path, std::ios::binary | std::ios::trunc);
  if (!hf) return io_error(Code::IoError, path, "cannot open for writing");
  hf.write(header.data(), static_cast<std::streamsize>(header.size()));
  if (detached) {
    std::ofstream df(data_path, std::ios::binary | std::ios::trunc);
    if (!df) return io_error(Code::IoError, path, "cannot open data file " + data_path.string());
    df.write(reinterpret_cast<const char*>(out), static_cast<std::streamsize>(out_size));
    if (!df.flush())
      return io_error(Code::IoError, path, "cannot write data file " + data_path.string());
  } else {
    hf.write(reinterpret_cast<const char*>(out), static_cast<std::streamsize>(out_size));
  }
  if (!hf.flush()) return io_error(Code::IoError, path, "cannot write");
  return std::nullopt;
}

}  // namespace sonomesh::volume::internal
