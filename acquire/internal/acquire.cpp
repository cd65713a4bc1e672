// open_source(): the URI parser, the scheme table, error text.
#include "acquire/acquire.h"

#include <algorithm>
#include <mutex>

#include "acquire/internal/sources.h"

namespace sonomesh::acquire {
namespace {

AcquireError invalid(std::string detail) {
  return AcquireError{AcquireError::Code::InvalidArgument, 0, std::move(detail), {}, 0};
}

// The table starts with acquire's own schemes, so no static-initialisation order matters.
class SchemeTable {
 public:
  SchemeTable() {
    add({"unix", "unix:PATH", true, internal::open_unix_source});
    add({"tcp", "tcp:HOST:PORT", true, internal::open_tcp_source});
    add({"replay", "replay:FILE.usv|DIR|FILE[?rate=HZ]", false, replay_opener({})});
    add({"usb", "usb:VID:PID[/SERIAL]", true, internal::open_usb_source});
    add({"v4l2", "v4l2:/dev/videoN[?slices=N&format=grey|y16]", true, internal::open_v4l2_source});
    add({"igtl", "igtl:HOST:PORT[?device=NAME]", true, internal::open_igtl_source});
  }
  void add(SourceScheme scheme) {
    std::lock_guard lock(mutex_);
    const std::string name = scheme.name;
    schemes_[name] = std::move(scheme);
  }
  std::optional<SourceScheme> find(const std::string& name) {
    std::lock_guard lock(mutex_);
    const auto it = schemes_.find(name);
    if (it == schemes_.end()) return std::nullopt;
    return it->second;
  }
  std::vector<std::string> usages() {
    std::lock_guard lock(mutex_);
    std::vector<std::string> out;
    for (const auto& [name, scheme] : schemes_) out.push_back(scheme.usage);
    return out;
  }

 private:
  std::mutex mutex_;
  std::map<std::string, SourceScheme> schemes_;
};

SchemeTable& table() {
  static SchemeTable instance;
  return instance;
}

std::string scheme_list() {
  std::string list;
  for (const auto& usage : table().usages()) list += (list.empty() ? "" : ", ") + usage;
  return list;
}

}  // namespace

const char* to_string(AcquireError::Code code) {
  switch (code) {
    case AcquireError::Code::Timeout:
      return "timeout";
    case AcquireError::Code::Disconnected:
      return "disconnected";
    case AcquireError::Code::BadRecord:
      return "bad-record";
    case AcquireError::Code::Lost:
      return "lost";
    case AcquireError::Code::Incomplete:
      return "incomplete";
    case AcquireError::Code::EndOfStream:
      return "end-of-stream";
    case AcquireError::Code::InvalidArgument:
      return "invalid-argument";
    case AcquireError::Code::NotFound:
      return "not-found";
    case AcquireError::Code::IoError:
      return "io-error";
  }
  return "unknown";
}

std::string to_string(const AcquireError& error) {
  std::string text = to_string(error.code);
  if (!error.detail.empty()) text += ": " + error.detail;
  std::string extra;
  if (error.sequence) extra += "seq " + std::to_string(*error.sequence);
  if (error.count > 0) {
    extra += (extra.empty() ? "" : ", ") + std::string("count ") + std::to_string(error.count);
  }
  if (error.os_errno != 0) {
    extra += (extra.empty() ? "" : ", ") + std::string("errno ") + std::to_string(error.os_errno);
  }
  if (!extra.empty()) text += " (" + extra + ")";
  return text;
}

tl::expected<SourceUri, AcquireError> parse_source_uri(const std::string& uri) {
  SourceUri out;
  out.text = uri;
  const auto colon = uri.find(':');
  if (colon == std::string::npos || colon == 0) {
    return tl::make_unexpected(
        invalid("source '" + uri + "' has no scheme (" + scheme_list() + ")"));
  }
  out.scheme = uri.substr(0, colon);
  const auto q = uri.find('?', colon + 1);
  out.body = uri.substr(colon + 1, q == std::string::npos ? std::string::npos : q - colon - 1);
  if (q == std::string::npos) return out;
  const std::string rest = uri.substr(q + 1);
  std::size_t start = 0;
  while (start <= rest.size()) {
    auto amp = rest.find('&', start);
    if (amp == std::string::npos) amp = rest.size();
    const std::string item = rest.substr(start, amp - start);
    start = amp + 1;
    if (item.empty()) continue;
    const auto eq = item.find('=');
    const std::string key = item.substr(0, eq);
    if (key.empty())
      return tl::make_unexpected(invalid(uri + ": query item '" + item + "' has no key"));
    if (out.query.count(key) != 0) {
      return tl::make_unexpected(invalid(uri + ": option '" + key + "' given twice"));
    }
    out.query[key] = eq == std::string::npos ? "" : item.substr(eq + 1);
  }
  return out;
}

std::optional<AcquireError> refuse_unknown_keys(const SourceUri& uri,
                                                const std::vector<std::string>& allowed) {
  for (const auto& [key, value] : uri.query) {
    if (std::find(allowed.begin(), allowed.end(), key) != allowed.end()) continue;
    std::string list;
    for (const auto& a : allowed) list += (list.empty() ? "" : ", ") + a;
    return invalid(uri.text + ": unknown option '" + key + "' (" +
                   (list.empty() ? std::string("none") : list) + ")");
  }
  return std::nullopt;
}

void register_source_scheme(SourceScheme scheme) { table().add(std::move(scheme)); }

std::optional<SourceScheme> find_source_scheme(const std::string& name) {
  return table().find(name);
}

std::vector<std::string> source_scheme_usages() { return table().usages(); }

tl::expected<std::unique_ptr<Source>, AcquireError> open_source(const std::string& uri,
                                                                const SourceOptions& options) {
  auto parsed = parse_source_uri(uri);
  if (!parsed) return tl::make_unexpected(parsed.error());
  const auto scheme = table().find(parsed->scheme);
  if (!scheme || !scheme->open) {
    return tl::make_unexpected(
        invalid("unknown source scheme '" + parsed->scheme + "' (" + scheme_list() + ")"));
  }
  auto source = scheme->open(*parsed, options);
  if (!source || options.record_path.empty()) return source;
  return tee_to_recording(std::move(*source), options.record_path);
}

}  // namespace sonomesh::acquire
