#pragma once
// A test client of the OpenIGTLink server: a plain socket, 58-byte headers framed and parsed by
// hand from the protocol description (not through libOpenIGTLink), and the result set decoded.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <Eigen/Dense>
#include <chrono>
#include <cstring>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

namespace sonomesh::testing {

using namespace std::chrono_literals;
using Vec3f = Eigen::Vector3f;
using Vec3i = Eigen::Vector3i;
using Mat3f = Eigen::Matrix3f;

inline std::uint64_t be(const unsigned char* p, int bytes) {
  std::uint64_t v = 0;
  for (int i = 0; i < bytes; ++i) v = (v << 8) | p[i];
  return v;
}
inline float be_f32(const unsigned char* p) {
  const std::uint32_t bits = static_cast<std::uint32_t>(be(p, 4));
  float f;
  std::memcpy(&f, &bits, 4);
  return f;
}
inline void put_be(std::string& out, std::uint64_t v, int bytes) {
  for (int i = bytes - 1; i >= 0; --i) out += static_cast<char>((v >> (8 * i)) & 0xff);
}

struct Message {
  int version = 0;
  std::string type, device;
  std::vector<unsigned char> body;
};

class TestClient {
 public:
  explicit TestClient(int port, int receive_buffer_bytes = 0) {
    fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    if (receive_buffer_bytes > 0) {
      ::setsockopt(fd_, SOL_SOCKET, SO_RCVBUF, &receive_buffer_bytes, sizeof receive_buffer_bytes);
    }
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_port = htons(static_cast<std::uint16_t>(port));
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    connected_ = ::connect(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0;
  }
  ~TestClient() { ::close(fd_); }
  bool connected() const { return connected_; }

  bool read_exact(unsigned char* out, std::size_t n, std::chrono::milliseconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    std::size_t have = 0;
    while (have < n) {
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
          deadline - std::chrono::steady_clock::now());
      if (left.count() <= 0) return false;
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, static_cast<int>(left.count())) <= 0) return false;
      const ssize_t r = ::recv(fd_, out + have, n - have, 0);
      if (r <= 0) return false;
      have += static_cast<std::size_t>(r);
    }
    return true;
  }
  std::optional<Message> read(std::chrono::milliseconds timeout = 5s) {
    unsigned char h[58];
    if (!read_exact(h, 58, timeout)) return std::nullopt;
    Message m;
    m.version = static_cast<int>(be(h, 2));
    m.type.assign(reinterpret_cast<char*>(h + 2), strnlen(reinterpret_cast<char*>(h + 2), 12));
    m.device.assign(reinterpret_cast<char*>(h + 14), strnlen(reinterpret_cast<char*>(h + 14), 20));
    m.body.resize(be(h + 42, 8));
    if (!read_exact(m.body.data(), m.body.size(), timeout)) return std::nullopt;
    return m;
  }
  // A header (version 1 or 2) and body, framed by hand; the CRC is not checked by the server.
  void send(int version, const std::string& type, const std::string& body) {
    std::string out;
    put_be(out, version, 2);
    std::string t = type, d = "TestClient";
    t.resize(12, '\0');
    d.resize(20, '\0');
    out += t + d;
    put_be(out, 0, 8);
    put_be(out, body.size(), 8);
    put_be(out, 0, 8);
    out += body;
    ASSERT_EQ(::send(fd_, out.data(), out.size(), MSG_NOSIGNAL), static_cast<ssize_t>(out.size()));
  }

 private:
  int fd_ = -1;
  bool connected_ = false;
};

struct ResultSet {
  std::vector<Vec3f> points_ras;
  std::size_t polygons = 0;
  Vec3i dims = Vec3i::Zero();
  Mat3f columns;  // direction x spacing, RAS
  Vec3f centre_ras;
  std::vector<unsigned char> voxels;
  nlohmann::json status;
};

// Reads POLYDATA, IMAGE, STRING (in that order) and decodes them.
inline std::optional<ResultSet> read_set(TestClient& client,
                                         std::chrono::milliseconds timeout = 5s) {
  ResultSet set;
  auto mesh = client.read(timeout);
  if (!mesh) return std::nullopt;
  EXPECT_EQ(mesh->version, 1);
  EXPECT_EQ(mesh->type, "POLYDATA");
  EXPECT_EQ(mesh->device, "sonomesh-mesh");
  const unsigned char* b = mesh->body.data();
  const auto npoints = be(b, 4);
  set.polygons = be(b + 20, 4);
  for (std::size_t i = 0; i < npoints; ++i) {
    const unsigned char* p = b + 40 + 12 * i;
    set.points_ras.emplace_back(be_f32(p), be_f32(p + 4), be_f32(p + 8));
  }
  auto image = client.read(timeout);
  if (!image) return std::nullopt;
  EXPECT_EQ(image->type, "IMAGE");
  EXPECT_EQ(image->device, "sonomesh-labels");
  const unsigned char* h = image->body.data();
  EXPECT_EQ(h[2], 1);  // one component
  EXPECT_EQ(h[3], 3);  // uint8
  EXPECT_EQ(h[5], 1);  // RAS
  set.dims = Vec3i(be(h + 6, 2), be(h + 8, 2), be(h + 10, 2));
  for (int c = 0; c < 3; ++c)
    for (int r = 0; r < 3; ++r) set.columns(r, c) = be_f32(h + 12 + 4 * (3 * c + r));
  set.centre_ras = Vec3f(be_f32(h + 48), be_f32(h + 52), be_f32(h + 56));
  set.voxels.assign(image->body.begin() + 72, image->body.end());
  auto text = client.read(timeout);
  if (!text) return std::nullopt;
  EXPECT_EQ(text->type, "STRING");
  EXPECT_EQ(text->device, "sonomesh-status");
  EXPECT_EQ(be(text->body.data(), 2), 106u);  // UTF-8
  const std::size_t length = be(text->body.data() + 2, 2);
  set.status =
      nlohmann::json::parse(std::string(text->body.begin() + 4, text->body.begin() + 4 + length));
  return set;
}

// Every mesh point, mapped through the IMAGE's own geometry, lies in the volume on the label's
// boundary (within a voxel of both a labelled and an unlabelled voxel).
inline void expect_mesh_on_label_boundary(const ResultSet& set) {
  ASSERT_EQ(set.voxels.size(), static_cast<std::size_t>(set.dims.prod()));
  const Vec3f first =
      set.centre_ras - set.columns * ((set.dims - Vec3i::Ones()).cast<float>() * 0.5f);
  const Mat3f inverse = set.columns.inverse();
  auto label = [&](int i, int j, int k) {
    if (i < 0 || j < 0 || k < 0 || i >= set.dims.x() || j >= set.dims.y() || k >= set.dims.z())
      return 0;
    return int(set.voxels[(static_cast<std::size_t>(k) * set.dims.y() + j) * set.dims.x() + i]);
  };
  for (const Vec3f& p : set.points_ras) {
    const Vec3f index = inverse * (p - first);
    ASSERT_TRUE((index.array() >= 0).all() &&
                (index.array() <= (set.dims.cast<float>().array() - 1)).all())
        << index.transpose();
    int inside = 0, outside = 0;
    const Vec3i c = index.array().round().cast<int>();
    for (int dk = -1; dk <= 1; ++dk)
      for (int dj = -1; dj <= 1; ++dj)
        for (int di = -1; di <= 1; ++di)
          (label(c.x() + di, c.y() + dj, c.z() + dk) ? inside : outside)++;
    EXPECT_GT(inside, 0) << index.transpose();
    EXPECT_GT(outside, 0) << index.transpose();
  }
}

}  // namespace sonomesh::testing
