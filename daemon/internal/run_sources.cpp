#include "daemon/internal/run_sources.h"

#include <spdlog/spdlog.h>

#include <mutex>

#include "sim/phantom_source.h"
#include "sim/sim.h"
#include "volume/decoded_volume.h"
#include "volume/volume.h"

namespace sonomesh::daemon {
namespace {

using acquire::AcquireError;

// The file is decoded once, into the Volume the worker uses (RawVolume::decoded): any voxel
// type read_volume reads replays, and no bytes are packed for the probe format and unpacked.
tl::expected<acquire::RawVolume, AcquireError> read_volume_file(const std::filesystem::path& path) {
  auto read = volume::read_volume(path);
  if (!read) {
    const auto code = read.error->code == volume::VolumeIoError::Code::NotFound
                          ? AcquireError::Code::NotFound
                          : AcquireError::Code::BadRecord;
    return tl::make_unexpected(AcquireError{code, 0, read.error->message, {}, 0});
  }
  const volume::Volume& v = read.volume;
  acquire::RawVolume raw;
  raw.dims = {v.dims().x(), v.dims().y(), v.dims().z()};
  raw.spacing_mm = {v.spacing_mm().x(), v.spacing_mm().y(), v.spacing_mm().z()};
  raw.origin_mm = {v.origin_mm().x(), v.origin_mm().y(), v.origin_mm().z()};
  for (int c = 0; c < 3; ++c) {
    for (int r = 0; r < 3; ++r) raw.direction[3 * c + r] = v.direction()(r, c);
  }
  raw.type = v.type() == volume::VoxelType::UInt16 ? acquire::ProbeVoxelType::UInt16
                                                   : acquire::ProbeVoxelType::UInt8;
  raw.decoded = std::make_shared<volume::DecodedVolume>(std::move(read.volume));
  raw.received = std::chrono::steady_clock::now();
  return raw;
}

tl::expected<std::unique_ptr<acquire::Source>, AcquireError> open_sim(
    const acquire::SourceUri& uri, const acquire::SourceOptions&) {
  return sim::open_phantom_source(uri.text);
}

// The phantom's own seed (at breathing phase 0; the target moves by less than its radius) is
// the default when none is configured: the demo needs no --seed-mm.
std::optional<std::string> phantom_seed(const std::string& uri, OpenedSource& opened) {
  auto parsed = sim::parse_sim_uri(uri);
  if (!parsed) return acquire::to_string(parsed.error());
  try {
    sim::PhantomSpec spec = parsed->spec;
    spec.time_s = 0.0f;
    const sim::Phantom phantom = sim::make_phantom(spec);
    opened.phantom_seed_mm =
        std::array<float, 3>{phantom.seed_mm.x(), phantom.seed_mm.y(), phantom.seed_mm.z()};
  } catch (const std::exception& e) {
    return uri + ": " + e.what();
  }
  return std::nullopt;
}

}  // namespace

void register_daemon_sources() {
  static std::once_flag once;
  std::call_once(once, [] {
    acquire::register_source_scheme(
        {"sim", "sim:PHANTOM[?rate=HZ&size=N&count=N&seed=N]", false, open_sim});
    acquire::VolumeFiles files{{".nrrd", ".nhdr", ".mha", ".mhd", ".nii", ".nii.gz"},
                               read_volume_file};
    acquire::register_source_scheme({"replay", "replay:FILE.usv|DIR|VOLUME-FILE[?rate=HZ]", false,
                                     acquire::replay_opener(std::move(files))});
  });
}

OpenedSource open_run_source(const RunConfig& config) {
  register_daemon_sources();
  OpenedSource opened;
  const std::string uri = config.source;
  const acquire::SourceOptions options = source_options(config);
  auto parsed = acquire::parse_source_uri(uri);
  if (!parsed) {
    opened.fatal_error = acquire::to_string(parsed.error());
    return opened;
  }
  if (parsed->scheme == "sim") {
    if (auto err = phantom_seed(uri, opened)) {
      opened.fatal_error = *err;
      return opened;
    }
  }
  opened.factory = [uri, options]() { return acquire::open_source(uri, options); };
  auto source = acquire::open_source(uri, options);
  if (source) {
    opened.live = (*source)->live();
    opened.source = std::move(*source);
    return opened;
  }
  const AcquireError& e = source.error();
  const auto scheme = acquire::find_source_scheme(parsed->scheme);
  const bool transient =
      e.code == AcquireError::Code::NotFound || e.code == AcquireError::Code::Disconnected ||
      e.code == AcquireError::Code::Timeout || e.code == AcquireError::Code::IoError;
  if (scheme && scheme->device && transient) {
    // A daemon started before its probe: wait for it rather than exit.
    spdlog::warn("{}: {}; waiting for it", uri, acquire::to_string(e));
    opened.live = true;
    return opened;
  }
  opened.fatal_error = acquire::to_string(e);
  return opened;
}

}  // namespace sonomesh::daemon
