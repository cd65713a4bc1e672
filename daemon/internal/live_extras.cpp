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

LiveHooks LiveExtras::hooks() {
  LiveHooks h;
  h.worker_turn = [this] { notifier_.watchdog(); };
  h.result = [this](const volume::Volume& input, const segment::Mesh& mesh_mm,
                    const volume::Vec3f& seed_mm,
                    std::uint64_t sequence) { slices_.update(input, mesh_mm, seed_mm, sequence); };
  return h;
}

}  // namespace sonomesh::daemon
