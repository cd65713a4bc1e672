#pragma once
/// @file
/// @brief Opening the `run` source through acquire's scheme table, to which the daemon adds
/// sim: (the built-in simulator) and replay of volume files (read by volume::read_volume).

#include <array>
#include <memory>
#include <optional>
#include <string>

#include "daemon/internal/live_runner.h"
#include "daemon/internal/run_config.h"

namespace sonomesh::daemon {

struct OpenedSource {
  std::unique_ptr<acquire::Source> source;  // null: not up yet, the runner retries with factory
  SourceFactory factory;                    // opens the same source again
  bool live = true;
  std::optional<std::array<float, 3>> phantom_seed_mm;  // sim: the phantom's seed
  std::optional<std::string> fatal_error;               // cannot run at all (bad URI, no file)
};

/// Adds sim: and the volume-file replay: to acquire's scheme table (once; thread-safe).
void register_daemon_sources();

/// Registers the daemon's schemes, then opens config.source. A device that is not reachable
/// yet (a scheme marked `device`) is not fatal: the daemon waits for it; a bad URI or a missing
/// replay path is.
OpenedSource open_run_source(const RunConfig& config);

}  // namespace sonomesh::daemon
