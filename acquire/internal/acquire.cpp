// open_source(): URI dispatch, error text, the volume file reader registry.
#include "acquire/acquire.h"

#include <mutex>

#include "acquire/internal/sources.h"

namespace sonomesh::acquire {
namespace {

std::mutex& reader_mutex() {
  static std::mutex m;
  return m;
}
VolumeFileReader& reader_slot() {
  static VolumeFileReader reader;
  return reader;
}

}  // namespace

const char* to_string(AcquireError::Code code) {
  switch (code) {
    case AcquireError::Code::Timeout: return "timeout";
    case AcquireError::Code::Disconnected: return "disconnected";
    case AcquireError::Code::BadRecord: return "bad-record";
    case AcquireError::Code::Lost: return "lost";
    case AcquireError::Code::Incomplete: return "incomplete";
    case AcquireError::Code::EndOfStream: return "end-of-stream";
    case AcquireError::Code::InvalidArgument: return "invalid-argument";
    case AcquireError::Code::NotFound: return "not-found";
    case AcquireError::Code::IoError: return "io-error";
  }
  return "unknown";
}

std::string to_string(const AcquireError& error) {
  std::string text = to_string(error.code);
  if (!error.detail.empty()) text += ": " + error.detail;
  std::string extra;
  if (error.sequence) extra += "seq " + std::to_string(*error.sequence);
  if (error.count > 0) extra += (extra.empty() ? "" : ", ") + std::string("count ") +
                                std::to_string(error.count);
  if (error.os_errno != 0) extra += (extra.empty() ? "" : ", ") + std::string("errno ") +
                                    std::to_string(error.os_errno);
  if (!extra.empty()) text += " (" + extra + ")";
  return text;
}

void set_volume_file_reader(VolumeFileReader reader) {
  std::lock_guard lock(reader_mutex());
  reader_slot() = std::move(reader);
}

namespace internal {

VolumeFileReader volume_file_reader() {
  std::lock_guard lock(reader_mutex());
  return reader_slot();
}

SplitSpec split_query(const std::string& spec) {
  SplitSpec out;
  const auto q = spec.find('?');
  out.path = spec.substr(0, q);
  if (q == std::string::npos) return out;
  std::string rest = spec.substr(q + 1);
  std::size_t start = 0;
  while (start <= rest.size()) {
    const auto amp = rest.find('&', start);
    const std::string item = rest.substr(start, amp == std::string::npos ? amp : amp - start);
    if (!item.empty()) {
      const auto eq = item.find('=');
      out.query[item.substr(0, eq)] = eq == std::string::npos ? "" : item.substr(eq + 1);
    }
    if (amp == std::string::npos) break;
    start = amp + 1;
  }
  return out;
}

}  // namespace internal

tl::expected<std::unique_ptr<Source>, AcquireError> open_source(const std::string& uri,
                                                                const SourceOptions& options) {
  const auto colon = uri.find(':');
  if (colon == std::string::npos) {
    return tl::make_unexpected(AcquireError{
        AcquireError::Code::InvalidArgument, 0,
        "source '" + uri + "' has no scheme (unix:, tcp:, replay:, usb:, v4l2:)", {}, 0});
  }
  const std::string scheme = uri.substr(0, colon);
  const std::string spec = uri.substr(colon + 1);
  tl::expected<std::unique_ptr<Source>, AcquireError> source = tl::make_unexpected(AcquireError{});
  if (scheme == "unix") {
    source = internal::open_unix_source(spec, options);
  } else if (scheme == "tcp") {
    source = internal::open_tcp_source(spec, options);
  } else if (scheme == "replay") {
    source = internal::open_replay_source(spec, options);
  } else if (scheme == "usb") {
    source = internal::open_usb_source(spec, options);
  } else if (scheme == "v4l2") {
    source = internal::open_v4l2_source(spec, options);
  } else {
    return tl::make_unexpected(AcquireError{
        AcquireError::Code::InvalidArgument, 0,
        "unknown source scheme '" + scheme + "' (unix:, tcp:, replay:, usb:, v4l2:)", {}, 0});
  }
  if (!source || options.record_path.empty()) return source;
  return tee_to_recording(std::move(*source), options.record_path);
}

}  // namespace sonomesh::acquire
