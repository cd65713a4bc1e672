#include "daemon/internal/live_extras.h"

#include <spdlog/spdlog.h>

namespace sonomesh::daemon {

LiveExtras::LiveExtras(const std::filesystem::path& out, const RunStats& stats)
    : stats_(stats),
      hub_(out / "journal.jsonl", [this] { return stats_.status_json(); }),
      monitor_(notifier_, [this] { return stats_.status_json(); }) {}

LiveExtras::~LiveExtras() { stop(); }

void LiveExtras::start() { hub_.start(); }

void LiveExtras::serving(bool http_ready) {
  if (notifier_.enabled()) {
    spdlog::info("systemd notify socket set; watchdog {}",
                 notifier_.watchdog_interval().count() > 0
                     ? std::to_string(notifier_.watchdog_interval().count() / 1000) + " ms"
                     : std::string("off"));
  }
  monitor_.start(http_ready);
}

void LiveExtras::stop_requested() {
  if (stop_sent_) return;
  stop_sent_ = true;
  notifier_.stopping();
}

void LiveExtras::stop() {
  hub_.stop();
  monitor_.stop();  // STOPPING=1 (again, harmless) and the last STATUS
  stop_sent_ = true;
}

WebContext LiveExtras::web() {
  return WebContext{&hub_, &slices_, locate_web_dir(), locate_three_dir()};
}

std::function<void()> LiveExtras::worker_turn_hook() {
  return [this] { notifier_.watchdog(); };
}

namespace {

// The slices are cut in the grid frame the pipeline ran in; the sink gets the world-frame mesh.
class SliceSink : public OutputSink {
 public:
  explicit SliceSink(SliceRenderer& slices) : slices_(slices) {}
  const char* name() const override { return "slices"; }
  void write(const ProcessedVolume& volume, nlohmann::json&) override {
    if (!volume.input) return;
    segment::Mesh grid_mesh;
    grid_mesh.triangles = volume.mesh.triangles;  // contours only: the winding does not matter
    grid_mesh.vertices.reserve(volume.mesh.vertices.size());
    for (const auto& p : volume.mesh.vertices)
      grid_mesh.vertices.push_back(volume.input->world_to_grid_mm(p));
    try {
      slices_.update(*volume.input, grid_mesh, volume.seed_grid_mm, volume.sequence);
    } catch (const std::exception& e) {
      // The page's slices are a view, not an output: their failure does not fail the volume.
      spdlog::warn("sequence {}: slices: {}", volume.sequence, e.what());
    }
  }

 private:
  SliceRenderer& slices_;
};

}  // namespace

std::shared_ptr<OutputSink> LiveExtras::slice_sink() {
  return std::make_shared<SliceSink>(slices_);
}

}  // namespace sonomesh::daemon
