#pragma once
// An OpenIGTLink server for the tests: messages packed by hand here (own big-endian writer, own
// bitwise CRC-64), not through acquire's codec, so the source is checked against the protocol.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace sonomesh::acquire::test {

using Bytes = std::vector<std::uint8_t>;

inline void put_be(Bytes& out, std::uint64_t value, int bytes) {
  for (int i = bytes - 1; i >= 0; --i) out.push_back(static_cast<std::uint8_t>(value >> (8 * i)));
}
inline void put_float(Bytes& out, float f) {
  std::uint32_t bits;
  std::memcpy(&bits, &f, sizeof bits);
  put_be(out, bits, 4);
}
inline void put_name(Bytes& out, const std::string& name, std::size_t size) {
  for (std::size_t i = 0; i < size; ++i) out.push_back(i < name.size() ? name[i] : 0);
}

// Bit by bit, MSB first, ECMA-182: the textbook definition (acquire uses a table).
inline std::uint64_t crc64_bitwise(const Bytes& data) {
  std::uint64_t crc = 0;
  for (std::uint8_t byte : data) {
    crc ^= std::uint64_t{byte} << 56;
    for (int bit = 0; bit < 8; ++bit) {
      crc = (crc >> 63) ? (crc << 1) ^ 0x42F0E1EBA9EA3693ull : crc << 1;
    }
  }
  return crc;
}

struct ImageSpec {
  std::array<int, 3> size{12, 10, 8};
  int scalar = 3;  // 3 uint8, 5 uint16, 4 int16
  int components = 1;
  int endian = 2;      // 1 big, 2 little
  int coordinate = 2;  // 1 RAS, 2 LPS
  std::array<std::array<float, 3>, 3> columns{{{0.5f, 0, 0}, {0, 0.6f, 0}, {0, 0, 0.7f}}};
  std::array<float, 3> centre{1.0f, 2.0f, 3.0f};
  std::array<int, 3> sub_offset{0, 0, 0};
  std::array<int, 3> sub_size{0, 0, 0};  // 0: the whole size
  int image_header_version = 1;
  int data_bytes_delta = 0;  // >0 extra bytes, <0 fewer bytes of voxel data
  bool no_data = false;      // the header alone (a size its data could never have)
};

// Voxel value v at linear index i: (i * 7 + 3) mod 251 (uint16: times 257).
inline std::uint16_t voxel_value(std::size_t i, bool wide) {
  const auto v = static_cast<std::uint16_t>((i * 7 + 3) % 251);
  return wide ? static_cast<std::uint16_t>(v * 257) : v;
}

// The IMAGE content of `s`; voxels are the test pattern unless given (then as they are).
inline Bytes image_content(const ImageSpec& s, const Bytes* voxels = nullptr) {
  Bytes c;
  put_be(c, s.image_header_version, 2);
  c.push_back(static_cast<std::uint8_t>(s.components));
  c.push_back(static_cast<std::uint8_t>(s.scalar));
  c.push_back(static_cast<std::uint8_t>(s.endian));
  c.push_back(static_cast<std::uint8_t>(s.coordinate));
  for (int a = 0; a < 3; ++a) put_be(c, s.size[a], 2);
  for (const auto& col : s.columns) {
    for (float f : col) put_float(c, f);
  }
  for (float f : s.centre) put_float(c, f);
  for (int a = 0; a < 3; ++a) put_be(c, s.sub_offset[a], 2);
  for (int a = 0; a < 3; ++a) put_be(c, s.sub_size[a] ? s.sub_size[a] : s.size[a], 2);
  const std::size_t n = static_cast<std::size_t>(s.size[0]) * s.size[1] * s.size[2];
  const bool wide = s.scalar == 5 || s.scalar == 4;
  if (voxels) c.insert(c.end(), voxels->begin(), voxels->end());
  for (std::size_t i = 0; !voxels && !s.no_data && i < n * s.components; ++i) {
    const std::uint16_t v = voxel_value(i, wide);
    if (!wide) {
      c.push_back(static_cast<std::uint8_t>(v));
    } else if (s.endian == 1) {
      put_be(c, v, 2);
    } else {
      c.push_back(static_cast<std::uint8_t>(v & 0xff));
      c.push_back(static_cast<std::uint8_t>(v >> 8));
    }
  }
  if (s.data_bytes_delta < 0) c.resize(c.size() - static_cast<std::size_t>(-s.data_bytes_delta));
  for (int i = 0; i < s.data_bytes_delta; ++i) c.push_back(0);
  return c;
}

struct MessageSpec {
  int version = 1;  // 2: extended header, MESSAGE_ID, metadata
  std::string type = "IMAGE";
  std::string device = "Image_Reference";
  std::uint32_t message_id = 0;
  std::uint64_t timestamp = (std::uint64_t{1700000000} << 32) | 0x80000000u;  // x.5 s
  bool corrupt_crc = false;
  std::uint64_t body_bytes_override = 0;  // nonzero: the header claims this body size
};

inline Bytes message(const MessageSpec& m, const Bytes& content) {
  Bytes body;
  if (m.version >= 2) {
    // Metadata: one key "Status" = "OK" (encoding 3 = US-ASCII).
    Bytes meta_header, meta;
    put_be(meta_header, 1, 2);
    put_be(meta_header, 6, 2);
    put_be(meta_header, 3, 2);
    put_be(meta_header, 2, 4);
    for (char ch : std::string("StatusOK")) meta.push_back(static_cast<std::uint8_t>(ch));
    put_be(body, 12, 2);
    put_be(body, meta_header.size(), 2);
    put_be(body, meta.size(), 4);
    put_be(body, m.message_id, 4);
    body.insert(body.end(), content.begin(), content.end());
    body.insert(body.end(), meta_header.begin(), meta_header.end());
    body.insert(body.end(), meta.begin(), meta.end());
  } else {
    body = content;
  }
  Bytes out;
  put_be(out, m.version, 2);
  put_name(out, m.type, 12);
  put_name(out, m.device, 20);
  put_be(out, m.timestamp, 8);
  put_be(out, m.body_bytes_override ? m.body_bytes_override : body.size(), 8);
  put_be(out, crc64_bitwise(body) ^ (m.corrupt_crc ? 1u : 0u), 8);
  out.insert(out.end(), body.begin(), body.end());
  return out;
}

// Listens on 127.0.0.1 (a given port, or any); each accepted client gets `script` written, then
// the connection is closed (close_after_script) or stays open until the server ends.
class IgtlTestServer {
 public:
  explicit IgtlTestServer(Bytes script, bool close_after_script = false, int port = 0)
      : script_(std::move(script)), close_after_script_(close_after_script) {
    fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    const int on = 1;
    ::setsockopt(fd_, SOL_SOCKET, SO_REUSEADDR, &on, sizeof on);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    addr.sin_port = htons(static_cast<std::uint16_t>(port));
    ok_ =
        ::bind(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0 && ::listen(fd_, 4) == 0;
    socklen_t len = sizeof addr;
    ::getsockname(fd_, reinterpret_cast<sockaddr*>(&addr), &len);
    port_ = ntohs(addr.sin_port);
    thread_ = std::thread([this] { serve(); });
  }
  ~IgtlTestServer() { stop(); }

  bool ok() const { return ok_; }
  int port() const { return port_; }
  std::string uri(const std::string& query = "") const {
    return "igtl:127.0.0.1:" + std::to_string(port_) + query;
  }
  int accepted() const { return accepted_.load(); }
  void stop() {
    if (!thread_.joinable()) return;
    stopping_ = true;
    ::shutdown(fd_, SHUT_RDWR);
    ::close(fd_);
    thread_.join();
    std::lock_guard lock(mutex_);
    for (int c : clients_) ::close(c);
    clients_.clear();
  }

 private:
  void serve() {
    while (!stopping_) {
      const int c = ::accept(fd_, nullptr, nullptr);
      if (c < 0) return;
      ++accepted_;
      std::size_t sent = 0;
      while (sent < script_.size()) {
        const ssize_t n = ::send(c, script_.data() + sent, script_.size() - sent, MSG_NOSIGNAL);
        if (n <= 0) break;
        sent += static_cast<std::size_t>(n);
      }
      if (close_after_script_) {
        ::close(c);
        continue;
      }
      std::lock_guard lock(mutex_);
      clients_.push_back(c);
    }
  }

  Bytes script_;
  int fd_ = -1;
  int port_ = 0;
  bool ok_ = false;
  std::atomic<bool> stopping_{false};
  bool close_after_script_ = false;
  std::atomic<int> accepted_{0};
  std::mutex mutex_;
  std::vector<int> clients_;
  std::thread thread_;
};

}  // namespace sonomesh::acquire::test
