// Sustained ingest over a unix socket: an in-process writer thread streams 128^3 uint8 volume
// records as fast as the socket takes them; the unix: source receives, checks CRCs and hands out
// RawVolumes. Reports volumes/s and MB/s (target: >= 30 volumes/s).
//
//   ingest_bench [--volumes N] [--size N]
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "acquire/acquire.h"
#include "acquire/protocol.h"

using namespace sonomesh::acquire;
using Clock = std::chrono::steady_clock;

namespace {

// A listening unix socket at `path` (replacing a stale one); -1 after perror.
int listen_unix(const std::string& path) {
  const int fd = ::socket(AF_UNIX, SOCK_STREAM, 0);
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  std::strncpy(addr.sun_path, path.c_str(), sizeof addr.sun_path - 1);
  ::unlink(path.c_str());
  if (fd < 0 || ::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0 ||
      ::listen(fd, 1) != 0) {
    std::perror("bind/listen");
    if (fd >= 0) ::close(fd);
    return -1;
  }
  return fd;
}

// Accepts one client and sends `record` `volumes` times with a new sequence and header CRC (the
// payload and its CRC stay the same), then the end of the stream.
void stream_records(int listen_fd, std::vector<std::uint8_t> bytes, int volumes) {
  const int fd = ::accept(listen_fd, nullptr, nullptr);
  for (int s = 0; s < volumes; ++s) {
    RecordHeader h = decode_header(bytes.data());
    h.sequence = static_cast<std::uint64_t>(s);
    h.timestamp_ns = static_cast<std::uint64_t>(s) * 1'000'000;
    const auto header = encode_header(h);
    std::memcpy(bytes.data(), header.data(), header.size());
    std::size_t off = 0;
    while (off < bytes.size()) {
      const ssize_t n = ::send(fd, bytes.data() + off, bytes.size() - off, MSG_NOSIGNAL);
      if (n <= 0) {
        ::close(fd);
        return;
      }
      off += static_cast<std::size_t>(n);
    }
  }
  const auto eos = encode_end_of_stream(static_cast<std::uint64_t>(volumes), 0);
  ::send(fd, eos.data(), eos.size(), MSG_NOSIGNAL);
  ::close(fd);
}

struct Received {
  int volumes = 0, errors = 0;
  std::uint64_t bytes = 0;
};

// Reads until the end of the stream (or a timeout).
Received receive_all(Source& source) {
  Received got;
  for (;;) {
    auto r = source.next(std::chrono::seconds(5));
    if (r) {
      ++got.volumes;
      got.bytes += r->voxels.size();
      continue;
    }
    if (r.error().code == AcquireError::Code::EndOfStream) break;
    ++got.errors;
    std::fprintf(stderr, "ingest_bench: %s\n", to_string(r.error()).c_str());
    if (r.error().code == AcquireError::Code::Timeout) break;
  }
  return got;
}

}  // namespace

int main(int argc, char** argv) {
  int volumes = 300;
  int size = 128;
  for (int i = 1; i + 1 < argc; i += 2) {
    if (std::strcmp(argv[i], "--volumes") == 0)
      volumes = std::atoi(argv[i + 1]);
    else if (std::strcmp(argv[i], "--size") == 0)
      size = std::atoi(argv[i + 1]);
  }
  const std::string path = (std::filesystem::temp_directory_path() /
                            ("ingest_bench_" + std::to_string(::getpid()) + ".sock"))
                               .string();
  const int listen_fd = listen_unix(path);
  if (listen_fd < 0) return 1;

  RawVolume v;
  v.dims = {size, size, size};
  v.voxels.resize(static_cast<std::size_t>(size) * size * size);
  std::mt19937 rng(1);
  for (auto& b : v.voxels) b = static_cast<std::uint8_t>(rng());
  auto record = encode_volume_record(v);
  if (!record) return 1;
  std::thread writer(stream_records, listen_fd, *record, volumes);

  auto source = open_source("unix:" + path);
  if (!source) {
    std::fprintf(stderr, "ingest_bench: %s\n", to_string(source.error()).c_str());
    return 1;
  }
  const auto start = Clock::now();
  const Received got = receive_all(**source);
  const double seconds = std::chrono::duration<double>(Clock::now() - start).count();
  writer.join();
  ::close(listen_fd);
  ::unlink(path.c_str());
  const double vps = got.volumes / seconds;
  std::printf(
      "ingest_bench: %d volumes of %d^3 uint8 over unix socket in %.3f s: %.1f volumes/s, "
      "%.1f MB/s payload, %d errors (target >= 30 volumes/s: %s)\n",
      got.volumes, size, seconds, vps, got.bytes / seconds / 1e6, got.errors,
      vps >= 30 ? "met" : "MISSED");
  return got.volumes == volumes && got.errors == 0 ? 0 : 1;
}
