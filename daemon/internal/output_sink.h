#pragma once
/// @file
/// @brief Where results go: the files under OUT today, the OpenIGTLink server and the browser's
/// event stream beside them. The worker produces a ProcessedVolume; the writer thread hands it to
/// every sink; a sink never reaches back into the worker.

#include <chrono>
#include <cstdint>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "daemon/pipeline.h"
#include "segment/mesh.h"
#include "volume/volume.h"

namespace sonomesh::daemon {

/// One volume the pipeline turned into a surface, on its way to the outputs.
struct ProcessedVolume {
  std::uint64_t sequence = 0;
  std::uint64_t epoch = 0;
  std::chrono::steady_clock::time_point received;  // when the acquisition got the volume
  segment::Mesh mesh;                              // the final surface, world frame (LPS mm)
  std::optional<volume::Volume> labels;  // UInt8 on the input's grid and direction, inside = 1
  /// The input volume (shared, not copied: the live page's slices are cut from it) and the seed
  /// used, in the grid frame the pipeline ran in (volume::Volume::world_to_grid_mm).
  std::shared_ptr<const volume::Volume> input;
  volume::Vec3f seed_grid_mm = volume::Vec3f::Zero();
  nlohmann::json report;  // the per-volume report (report_json)
  StageTimings timings;
  /// "e<epoch>-<sequence>", or "<sequence>" in epoch 0: the outputs' file stem.
  std::string stem() const;
};

class OutputSink {
 public:
  virtual ~OutputSink() = default;
  virtual const char* name() const = 0;
  /// Writes this volume's outputs before its journal line goes out (writer thread) and adds to
  /// `line` what the line should say about them. Throwing fails the volume with the message.
  virtual void write(const ProcessedVolume& /*volume*/, nlohmann::json& /*line*/) {}
  /// Every journal line once it is written (`volume` is set for `processed` lines). Called on the
  /// thread that wrote the line, one line at a time in journal order; must not block on clients.
  virtual void on_line(const nlohmann::json& /*line*/, const ProcessedVolume* /*volume*/) {}
  /// The daemon is stopping: close connections, join threads.
  virtual void stop() {}
};

}  // namespace sonomesh::daemon
