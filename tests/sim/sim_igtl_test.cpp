// probe-sim serve --igtl: a plain-socket client reads IMAGE messages and checks them byte by byte
// against the OpenIGTLink protocol (not through the library that wrote them).
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <signal.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include "sim/phantom_source.h"
#include "sim/sim.h"

extern char** environ;

namespace sonomesh::sim {
namespace {

// CRC-64/ECMA-182 as OpenIGTLink uses it: polynomial 0x42F0E1EBA9EA3693, MSB first, init 0.
std::uint64_t crc64(const std::uint8_t* data, std::size_t size) {
  std::uint64_t crc = 0;
  for (std::size_t i = 0; i < size; ++i) {
    crc ^= static_cast<std::uint64_t>(data[i]) << 56;
    for (int b = 0; b < 8; ++b)
      crc = (crc & (1ull << 63)) ? (crc << 1) ^ 0x42F0E1EBA9EA3693ull : crc << 1;
  }
  return crc;
}

std::uint64_t be(const std::uint8_t* p, int bytes) {
  std::uint64_t v = 0;
  for (int b = 0; b < bytes; ++b) v = (v << 8) | p[b];
  return v;
}

float be_float(const std::uint8_t* p) {
  const auto bits = static_cast<std::uint32_t>(be(p, 4));
  float f;
  std::memcpy(&f, &bits, 4);
  return f;
}

int free_port() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a);
  socklen_t len = sizeof a;
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
  ::close(fd);
  return ntohs(a.sin_port);
}

// probe-sim serve running in the background for one test; killed at the end.
class Server {
 public:
  explicit Server(const std::vector<std::string>& extra) : port_(free_port()) {
    std::vector<std::string> args{PROBE_SIM_EXE, "serve", "--igtl",
                                  "127.0.0.1:" + std::to_string(port_)};
    args.insert(args.end(), extra.begin(), extra.end());
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    if (::posix_spawn(&pid_, PROBE_SIM_EXE, nullptr, nullptr, argv.data(), environ) != 0) pid_ = -1;
  }
  ~Server() {
    if (pid_ > 0) {
      ::kill(pid_, SIGTERM);
      ::waitpid(pid_, nullptr, 0);
    }
  }
  /// A connected socket, retrying while the server starts (up to 10 s); -1 if it never listens.
  int connect_client() const {
    for (int attempt = 0; attempt < 200; ++attempt) {
      const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
      sockaddr_in a{};
      a.sin_family = AF_INET;
      a.sin_port = htons(static_cast<std::uint16_t>(port_));
      a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
      if (::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0) {
        const timeval timeout{10, 0};
        ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &timeout, sizeof timeout);
        return fd;
      }
      ::close(fd);
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    return -1;
  }

 private:
  int port_;
  pid_t pid_ = -1;
};

bool read_exact(int fd, std::uint8_t* out, std::size_t size) {
  while (size > 0) {
    const ssize_t n = ::recv(fd, out, size, 0);
    if (n <= 0) return false;
    out += n;
    size -= static_cast<std::size_t>(n);
  }
  return true;
}

struct Message {
  int version = 0;
  std::string type, device;
  std::vector<std::uint8_t> body;
  bool crc_ok = false;
};

bool read_message(int fd, Message& m) {
  std::uint8_t h[58];
  if (!read_exact(fd, h, sizeof h)) return false;
  m.version = static_cast<int>(be(h, 2));
  m.type = std::string(reinterpret_cast<char*>(h + 2), strnlen(reinterpret_cast<char*>(h + 2), 12));
  m.device =
      std::string(reinterpret_cast<char*>(h + 14), strnlen(reinterpret_cast<char*>(h + 14), 20));
  const std::uint64_t size = be(h + 42, 8);
  if (size > (64u << 20)) return false;
  m.body.resize(size);
  if (!read_exact(fd, m.body.data(), size)) return false;
  m.crc_ok = crc64(m.body.data(), size) == be(h + 50, 8);
  return true;
}

// The IMAGE content's header (72 bytes) checked against a phantom volume's geometry.
void expect_image(const std::uint8_t* c, std::size_t content_bytes,
                  const volume::Volume& expected) {
  const Vec3i n = expected.dims();
  ASSERT_EQ(content_bytes, 72u + static_cast<std::size_t>(expected.voxel_count()));
  EXPECT_EQ(be(c, 2), 1u);  // IMAGE content version
  EXPECT_EQ(c[2], 1);       // components
  EXPECT_EQ(c[3], 3);       // uint8
  EXPECT_EQ(c[5], 1);       // RAS
  const volume::Mat3f& dir = expected.direction();
  const Vec3f h = expected.spacing_mm();
  Vec3f centre_lps = expected.origin_mm();
  for (int a = 0; a < 3; ++a) {
    EXPECT_EQ(static_cast<int>(be(c + 6 + 2 * a, 2)), n[a]);
    EXPECT_EQ(be(c + 60 + 2 * a, 2), 0u);                      // subvolume offset
    EXPECT_EQ(static_cast<int>(be(c + 66 + 2 * a, 2)), n[a]);  // subvolume size
    centre_lps += dir.col(a) * (h[a] * static_cast<float>(n[a] - 1) / 2.0f);
  }
  const Vec3f ras(-1.0f, -1.0f, 1.0f);
  for (int col = 0; col < 3; ++col)
    for (int a = 0; a < 3; ++a)  // matrix column = RAS direction times spacing
      EXPECT_NEAR(be_float(c + 12 + 4 * (3 * col + a)), ras[a] * dir(a, col) * h[col], 1e-5)
          << col << "," << a;
  for (int a = 0; a < 3; ++a)
    EXPECT_NEAR(be_float(c + 48 + 4 * a), ras[a] * centre_lps[a], 1e-3) << a;
  EXPECT_EQ(0, std::memcmp(c + 72, expected.u8().data(), expected.voxel_count())) << "voxels";
}

// What serve sends as volume `sequence` of `uri` at `rate_hz` (its time is sequence / rate).
volume::Volume stream_image(const std::string& uri, int size, double rate_hz, bool oblique,
                            std::uint64_t sequence) {
  auto options = parse_sim_uri(uri);
  EXPECT_TRUE(options);
  PhantomSpec spec = options->spec;
  spec.size_vox = size;
  spec.oblique = oblique;
  spec.time_s = static_cast<float>(static_cast<double>(sequence) / rate_hz);
  return make_phantom(spec).image;
}

TEST(ProbeSimIgtl, SendsVersion1ImageMessagesOfThePhantom) {
  Server server({"--phantom", "torus", "--size", "48", "--rate", "20", "--count", "2"});
  const int fd = server.connect_client();
  ASSERT_GE(fd, 0);
  for (std::uint64_t seq = 0; seq < 2; ++seq) {
    Message m;
    ASSERT_TRUE(read_message(fd, m)) << seq;
    EXPECT_EQ(m.version, 1);
    EXPECT_EQ(m.type, "IMAGE");
    EXPECT_EQ(m.device, "Image_Reference");
    EXPECT_TRUE(m.crc_ok);
    expect_image(m.body.data(), m.body.size(), stream_image("torus", 48, 20.0, false, seq));
  }
  ::close(fd);
}

TEST(ProbeSimIgtl, ObliqueVersion2CarriesMessageIdAndMetadata) {
  Server server({"--phantom", "sim:cyst-needle?realism=echo", "--size", "48", "--rate", "20",
                 "--count", "2", "--oblique", "--igtl-header", "2", "--igtl-device", "US"});
  const int fd = server.connect_client();
  ASSERT_GE(fd, 0);
  // A client talks too (Slicer sends a STATUS on connect): the server must keep sending.
  const std::uint8_t junk[64] = {0, 1, 'S', 'T', 'A', 'T', 'U', 'S'};
  ASSERT_EQ(::send(fd, junk, sizeof junk, MSG_NOSIGNAL), static_cast<ssize_t>(sizeof junk));
  for (std::uint64_t seq = 0; seq < 2; ++seq) {
    Message m;
    ASSERT_TRUE(read_message(fd, m)) << seq;
    EXPECT_EQ(m.version, 2);
    EXPECT_EQ(m.device, "US");
    EXPECT_TRUE(m.crc_ok);
    const std::uint8_t* b = m.body.data();
    const std::size_t ext = be(b, 2), meta_header = be(b + 2, 2), meta = be(b + 4, 4);
    EXPECT_EQ(ext, 12u);
    EXPECT_EQ(be(b + 8, 4), seq) << "MESSAGE_ID";
    ASSERT_EQ(m.body.size(), ext + 72 + 48u * 48u * 48u + meta_header + meta);
    const volume::Volume expected =
        stream_image("sim:cyst-needle?realism=echo", 48, 20.0, true, seq);
    EXPECT_FALSE(expected.direction().isIdentity());
    expect_image(b + ext, m.body.size() - ext - meta_header - meta, expected);
    const std::uint8_t* mh = b + m.body.size() - meta_header - meta;
    ASSERT_EQ(be(mh, 2), 1u);  // one metadata entry: key "Source"
    const std::size_t key = be(mh + 2, 2), value = be(mh + 6, 4);
    EXPECT_EQ(std::string(reinterpret_cast<const char*>(mh + meta_header), key), "Source");
    EXPECT_EQ(key + value, meta);
  }
  ::close(fd);
}

TEST(ProbeSimIgtl, EveryConnectedClientGetsTheVolumes) {
  Server server({"--phantom", "sphere", "--size", "32", "--rate", "5", "--count", "4"});
  const int a = server.connect_client();
  const int b = server.connect_client();
  ASSERT_GE(a, 0);
  ASSERT_GE(b, 0);
  // Both are connected before the second volume (rate 5: 200 ms apart); each reads the last two.
  std::vector<std::uint8_t> last_a, last_b;
  for (int fd : {a, b}) {
    Message m;
    int got = 0;
    while (read_message(fd, m)) {
      EXPECT_TRUE(m.crc_ok);
      (fd == a ? last_a : last_b) = m.body;
      ++got;
    }
    EXPECT_GE(got, 3) << "client " << fd;
  }
  EXPECT_EQ(last_a, last_b);
  ::close(a);
  ::close(b);
}

TEST(ProbeSimIgtl, BadOptionsGiveOneLineAndNonZeroExit) {
  for (const std::string& args :
       {std::string("serve --phantom torus --igtl 127.0.0.1"),
        std::string("serve --phantom torus --igtl 127.0.0.1:1 --listen tcp:127.0.0.1:2"),
        std::string("serve --phantom torus --igtl 127.0.0.1:18944 --igtl-header 3"),
        std::string("serve --phantom torus --igtl 127.0.0.1:18944 --drop-every 2")}) {
    const std::string cmd = std::string(PROBE_SIM_EXE) + " " + args + " 2>&1";
    FILE* p = ::popen(cmd.c_str(), "r");
    ASSERT_NE(p, nullptr);
    std::string out;
    char buf[256];
    while (std::fgets(buf, sizeof buf, p)) out += buf;
    const int status = ::pclose(p);
    EXPECT_NE(status, 0) << args;
    EXPECT_EQ(std::count(out.begin(), out.end(), '\n'), 1) << args << ": " << out;
  }
}

}  // namespace
}  // namespace sonomesh::sim
