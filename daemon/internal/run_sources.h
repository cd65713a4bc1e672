#pragma once
/// @file
/// @brief Opening the `run` source: sim: (the built-in simulator), everything else through
/// acquire::open_source, with the volume-file reader directory replay needs.

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
  std::optional<std::string> fatal_error;                // cannot run at all (bad URI, no file)
};

/// Registers volume::read_volume as acquire's reader for replay of .nrrd/.nhdr/.mha/.mhd files.
void register_volume_file_reader();

/// Opens config.source. Live sockets/probes that are not reachable yet are not fatal (the
/// daemon waits for them); a bad URI or a missing replay path is.
OpenedSource open_run_source(const RunConfig& config);

}  // namespace sonomesh::daemon
