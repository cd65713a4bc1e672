#include "sim/phantom_source.h"

#include <algorithm>
#include <cmath>
#include <condition_variable>
#include <mutex>
#include <optional>
#include <stdexcept>

namespace sonomesh::sim {
namespace {

using Clock = std::chrono::steady_clock;
using acquire::AcquireError;

tl::unexpected<AcquireError> invalid(const std::string& uri, const std::string& what) {
  return tl::make_unexpected(
      AcquireError{AcquireError::Code::InvalidArgument, 0, uri + ": " + what, {}, 0});
}

bool parse_number(const std::string& text, double& out) {
  char* end = nullptr;
  out = std::strtod(text.c_str(), &end);
  return !text.empty() && *end == '\0' && std::isfinite(out);
}

// One option's value, checked; an error names the option.
std::optional<std::string> set_option(PhantomSourceOptions& options, const std::string& key,
                                      double x) {
  if (key == "rate") {
    if (!(x > 0) || x > 1000) return "rate must be in (0, 1000] Hz";
    options.rate_hz = x;
  } else if (key == "size") {
    if (x < 16 || x > 512 || x != std::floor(x)) return "size must be an integer 16..512";
    options.spec.size_vox = static_cast<int>(x);
  } else if (key == "count") {
    if (x < 0 || x != std::floor(x)) return "count must be a non-negative integer";
    options.count = static_cast<std::uint64_t>(x);
  } else if (key == "seed") {
    if (x < 0 || x > 4294967295.0 || x != std::floor(x)) {
      return "seed must be a 32-bit unsigned integer";
    }
    options.spec.seed = static_cast<std::uint32_t>(x);
  } else if (key == "oblique") {
    if (x != 0 && x != 1) return "oblique must be 0 or 1";
    options.spec.oblique = x == 1;
  } else if (key == "contrast") {
    if (!(x >= 0 && x <= 1)) return "contrast must be in [0, 1]";
    options.spec.contrast = static_cast<float>(x);
  }
  return std::nullopt;
}

}  // namespace

tl::expected<PhantomSourceOptions, AcquireError> parse_sim_uri(const std::string& uri) {
  auto parsed = acquire::parse_source_uri(uri.rfind("sim:", 0) == 0 ? uri : "sim:" + uri);
  if (!parsed) return tl::make_unexpected(parsed.error());
  PhantomSourceOptions options;
  options.spec.phantom = parsed->body;
  const auto& names = phantom_names();
  if (std::find(names.begin(), names.end(), options.spec.phantom) == names.end()) {
    std::string list;
    for (const auto& n : names) list += (list.empty() ? "" : ", ") + n;
    return invalid(uri, "unknown phantom '" + options.spec.phantom + "' (" + list + ")");
  }
  if (auto refused = acquire::refuse_unknown_keys(
          *parsed, {"rate", "size", "count", "seed", "contrast", "realism", "oblique"})) {
    return tl::make_unexpected(*refused);
  }
  for (const auto& [key, value] : parsed->query) {
    if (key == "realism") {
      if (value != "simple" && value != "echo")
        return invalid(uri, "realism must be simple or echo");
      if (value == "echo") options.spec = with_echo_realism(options.spec);
      continue;
    }
    double x = 0;
    if (!parse_number(value, x)) return invalid(uri, key + "='" + value + "' is not a number");
    if (auto why = set_option(options, key, x)) return invalid(uri, *why);
  }
  return options;
}

acquire::RawVolume make_stream_volume(const PhantomSourceOptions& options, std::uint64_t sequence) {
  PhantomSpec spec = options.spec;
  const double t_s = static_cast<double>(sequence) / options.rate_hz;
  spec.time_s = static_cast<float>(t_s);
  const Phantom phantom = make_phantom(spec);
  return to_raw(phantom.image, sequence, static_cast<std::uint64_t>(std::llround(t_s * 1e9)));
}

struct PhantomSource::State {
  std::mutex mutex;
  std::condition_variable wake;
  bool interrupted = false;
  std::uint64_t next_sequence = 0;
  Clock::time_point start{};
};

PhantomSource::PhantomSource(PhantomSourceOptions options)
    : options_(std::move(options)), state_(std::make_unique<State>()) {
  if (!(options_.rate_hz > 0)) throw std::invalid_argument("PhantomSource: rate_hz must be > 0");
  const auto& names = phantom_names();
  if (std::find(names.begin(), names.end(), options_.spec.phantom) == names.end()) {
    throw std::invalid_argument("PhantomSource: unknown phantom '" + options_.spec.phantom + "'");
  }
  if (options_.spec.size_vox < 16) throw std::invalid_argument("PhantomSource: size below 16");
}

PhantomSource::~PhantomSource() = default;

tl::expected<acquire::RawVolume, AcquireError> PhantomSource::next(
    std::chrono::milliseconds timeout) {
  const auto deadline = Clock::now() + timeout;
  std::uint64_t sequence = 0;
  {
    std::unique_lock lock(state_->mutex);
    if (options_.count > 0 && state_->next_sequence >= options_.count) {
      return tl::make_unexpected(
          AcquireError{AcquireError::Code::EndOfStream, 0,
                       "phantom stream ended after " + std::to_string(options_.count) + " volumes",
                       state_->next_sequence, 0});
    }
    sequence = state_->next_sequence;
    if (sequence == 0) state_->start = Clock::now();
    const auto due =
        state_->start + std::chrono::nanoseconds(static_cast<std::int64_t>(
                            std::llround(static_cast<double>(sequence) * 1e9 / options_.rate_hz)));
    const auto until = std::min(due, deadline);
    state_->wake.wait_until(lock, until, [&] { return state_->interrupted; });
    if (state_->interrupted) {
      state_->interrupted = false;
      return tl::make_unexpected(
          AcquireError{AcquireError::Code::Timeout, 0, "interrupted", {}, 0});
    }
    if (Clock::now() < due) {
      return tl::make_unexpected(
          AcquireError{AcquireError::Code::Timeout, 0, "no volume due", {}, 0});
    }
    ++state_->next_sequence;
  }
  try {
    acquire::RawVolume v = make_stream_volume(options_, sequence);
    v.received = Clock::now();
    return v;
  } catch (const std::exception& e) {
    return tl::make_unexpected(
        AcquireError{AcquireError::Code::BadRecord, 0, e.what(), sequence, 0});
  }
}

std::string PhantomSource::describe() const {
  char rate[32];
  std::snprintf(rate, sizeof rate, "%g", options_.rate_hz);
  return "sim:" + options_.spec.phantom + "?rate=" + rate +
         "&size=" + std::to_string(options_.spec.size_vox);
}

void PhantomSource::interrupt() {
  {
    std::lock_guard lock(state_->mutex);
    state_->interrupted = true;
  }
  state_->wake.notify_all();
}

tl::expected<std::unique_ptr<acquire::Source>, AcquireError> open_phantom_source(
    const std::string& uri) {
  auto options = parse_sim_uri(uri);
  if (!options) return tl::make_unexpected(options.error());
  try {
    return std::make_unique<PhantomSource>(std::move(*options));
  } catch (const std::exception& e) {
    return invalid(uri, e.what());
  }
}

}  // namespace sonomesh::sim
