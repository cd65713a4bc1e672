#include "daemon/internal/file_sink.h"

#include <chrono>
#include <stdexcept>

#include "daemon/internal/atomic_file.h"
#include "daemon/internal/outputs.h"

namespace sonomesh::daemon {

namespace fs = std::filesystem;

std::string ProcessedVolume::stem() const {
  return epoch == 0 ? std::to_string(sequence)
                    : "e" + std::to_string(epoch) + "-" + std::to_string(sequence);
}

void FileSink::write(const ProcessedVolume& volume, nlohmann::json& line) {
  const std::string stem = volume.stem();
  const fs::path mesh_rel = fs::path("meshes") / (stem + ".ply");
  const fs::path report_rel = fs::path("reports") / (stem + ".json");
  if (auto error = internal::write_mesh_ply(volume.mesh, out_ / mesh_rel)) {
    throw std::runtime_error(*error);
  }
  const std::pair<std::uint64_t, std::uint64_t> id{volume.epoch, volume.sequence};
  if (!latest_ || id > *latest_) {
    publish_copy_atomically(out_ / mesh_rel, out_ / "latest.ply");
    latest_ = id;
  }
  line["latency_ms"] =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - volume.received)
          .count();
  if (auto error =
          internal::write_text_atomically(out_ / report_rel, volume.report.dump(2) + "\n")) {
    throw std::runtime_error(*error);
  }
  line["mesh"] = mesh_rel.string();
  line["report"] = report_rel.string();
  written_stems_.push_back(stem);
  prune(config_.snapshot().keep_meshes);
}

void FileSink::prune(std::uint64_t keep) {
  if (keep == 0) return;
  while (written_stems_.size() > keep) {
    std::error_code ec;
    fs::remove(out_ / "meshes" / (written_stems_.front() + ".ply"), ec);
    fs::remove(out_ / "reports" / (written_stems_.front() + ".json"), ec);
    written_stems_.pop_front();
  }
}

}  // namespace sonomesh::daemon
