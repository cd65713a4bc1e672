#pragma once
/// @file
/// @brief Configuration of `sonomeshd run`: TOML file (toml++), command-line overrides, printing.
///
/// Every option has a TOML key; `sonomeshd run --print-config` prints the effective configuration
/// (defaults, then the file, then the flags) as TOML that can be fed back with --config.

#include <array>
#include <cstdint>
#include <filesystem>
#include <mutex>
#include <optional>
#include <string>

#include "acquire/acquire.h"
#include "daemon/pipeline.h"

namespace sonomesh::daemon {

/// Default HTTP address. A fixed port on loopback so that `curl localhost:8787/status` works
/// without looking anything up; if the default is taken the daemon runs without HTTP (an address
/// given explicitly must bind or the daemon refuses to start).
inline constexpr const char* kDefaultHttpAddress = "127.0.0.1:8787";

struct RunConfig {
  // [daemon]
  std::string source;                           // SOURCE URI (required)
  std::filesystem::path out;                    // output directory (required)
  std::optional<std::array<float, 3>> seed_mm;  // configured seed; unset: phantom / centre
  std::size_t queue_capacity = 2;               // volumes waiting for the worker
  std::size_t lanes = 0;  // volumes segmented at once; 0: two for a live source on two cores
  std::size_t heap_reserve_mb = 96;  // heap touched at start-up and kept (huge_pages.h)
  std::string log_level = "info";    // trace, debug, info, warn, error
  // [http]
  std::string http_address = kDefaultHttpAddress;  // "off" disables the server
  bool http_explicit = false;      // set by --http / the file: a bind failure is fatal
  bool allow_remote_http = false;  // a non-loopback address needs this
  // [source]
  double rate_hz = 0;  // replay pacing (0 = recorded timing / unpaced)
  std::array<int, 3> max_dims{1024, 1024, 1024};
  std::uint64_t max_payload_bytes = 1ull << 30;
  std::string record_path;  // tee good volumes to this .usv
  int connect_timeout_ms = 1000;
  // [limits]
  std::uint64_t max_lost_lines = 100000;  // a bigger sequence jump is an event, not N lines
  std::uint64_t keep_meshes = 0;          // keep the newest N meshes/reports (0 = all)
  // [outputs]
  std::string igtl_listen;        // OpenIGTLink server ADDR:PORT ("" = none)
  bool igtl_any_address = false;  // a non-loopback igtl_listen needs this
  // [pipeline]
  PipelineConfig pipeline;
};

/// Reads a TOML file over `config` (keys not in the file keep their value).
/// Returns an error line naming the file, the key and the problem.
std::optional<std::string> load_config_file(const std::filesystem::path& path, RunConfig& config);
/// Same from a string (`origin` names it in errors).
std::optional<std::string> load_config_text(const std::string& text, const std::string& origin,
                                            RunConfig& config);

/// The configuration as TOML (round-trips through load_config_text).
std::string to_toml(const RunConfig& config);

/// Checks values (ranges, and with `require_io` the source and output directory). Returns the
/// first problem.
std::optional<std::string> validate(const RunConfig& config, bool require_io = true);

/// The running configuration, shared by the daemon's threads: each takes a snapshot per volume,
/// a reload (SIGHUP) or POST /seed replaces it.
class SharedConfig {
 public:
  explicit SharedConfig(RunConfig config) : config_(std::move(config)) {}
  RunConfig snapshot() const {
    std::lock_guard lock(mutex_);
    return config_;
  }
  template <typename Change>
  void update(Change&& change) {
    std::lock_guard lock(mutex_);
    change(config_);
  }

 private:
  mutable std::mutex mutex_;
  RunConfig config_;
};

/// The acquire::SourceOptions part.
acquire::SourceOptions source_options(const RunConfig& config);

}  // namespace sonomesh::daemon
