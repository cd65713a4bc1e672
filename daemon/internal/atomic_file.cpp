#include "daemon/internal/atomic_file.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <stdexcept>
#include <string>
#include <system_error>

namespace sonomesh::daemon {

namespace fs = std::filesystem;

namespace {

void fsync_path(const fs::path& path, bool directory) {
  const int fd = ::open(path.c_str(), (directory ? O_RDONLY | O_DIRECTORY : O_RDONLY) | O_CLOEXEC);
  if (fd < 0) {
    throw std::runtime_error("cannot open " + path.string() + " to sync: " + std::strerror(errno));
  }
  const int rc = ::fsync(fd);
  const int err = errno;
  ::close(fd);
  // Some file systems (tmpfs on old kernels) refuse fsync on directories: that is not a failure.
  if (rc != 0 && err != EINVAL && err != EROFS) {
    throw std::runtime_error("cannot sync " + path.string() + ": " + std::strerror(err));
  }
}

fs::path parent_or_dot(const fs::path& p) {
  return p.has_parent_path() ? p.parent_path() : fs::path(".");
}

}  // namespace

fs::path temporary_name(const fs::path& target) {
  const std::string name = "." + target.stem().string() + ".tmp-" + std::to_string(::getpid()) +
                           target.extension().string();
  return parent_or_dot(target) / name;
}

bool is_temporary_name(const fs::path& path) {
  const std::string name = path.filename().string();
  return name.size() > 1 && name[0] == '.' && name.find(".tmp-") != std::string::npos;
}

namespace {
void write_atomically_impl(const fs::path& target,
                           const std::function<void(const fs::path&)>& write, bool durable) {
  const fs::path tmp = temporary_name(target);
  try {
    write(tmp);
    if (!fs::exists(tmp)) throw std::runtime_error("writer produced no file " + tmp.string());
    if (durable) fsync_path(tmp, false);
    std::error_code ec;
    fs::rename(tmp, target, ec);
    if (ec) throw std::runtime_error("cannot rename to " + target.string() + ": " + ec.message());
    if (durable) fsync_path(parent_or_dot(target), true);
  } catch (...) {
    std::error_code ignored;
    fs::remove(tmp, ignored);
    throw;
  }
}
}  // namespace

void write_atomically(const fs::path& target, const std::function<void(const fs::path&)>& write) {
  write_atomically_impl(target, write, true);
}

void write_file_atomically(const fs::path& target, std::string_view bytes) {
  write_atomically(target, [&](const fs::path& tmp) {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    out.close();
    if (!out) throw std::runtime_error("cannot write " + tmp.string());
  });
}

void publish_copy_atomically(const fs::path& source, const fs::path& target) {
  write_atomically_impl(
      target,
      [&](const fs::path& tmp) {
        std::error_code ec;
        fs::create_hard_link(source, tmp, ec);
        if (ec) {
          fs::copy_file(source, tmp, fs::copy_options::overwrite_existing, ec);
          if (ec) {
            throw std::runtime_error("cannot copy " + source.string() + " to " + tmp.string() +
                                     ": " + ec.message());
          }
        }
      },
      false);
}

int remove_stale_temporaries(const fs::path& dir) {
  int removed = 0;
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return 0;
  for (const auto& entry : fs::directory_iterator(dir, ec)) {
    if (entry.is_regular_file(ec) && is_temporary_name(entry.path())) {
      if (fs::remove(entry.path(), ec)) ++removed;
    }
  }
  return removed;
}

}  // namespace sonomesh::daemon
