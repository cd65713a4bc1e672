#include "daemon/internal/run_sources.h"

#include <cstring>

#include <spdlog/spdlog.h>

#include "sim/phantom_source.h"
#include "sim/sim.h"
#include "volume/volume.h"

namespace sonomesh::daemon {

using acquire::AcquireError;

void register_volume_file_reader() {
  acquire::set_volume_file_reader(
      [](const std::filesystem::path& path) -> tl::expected<acquire::RawVolume, AcquireError> {
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
        switch (v.type()) {
          case volume::VoxelType::UInt8:
            raw.type = acquire::ProbeVoxelType::UInt8;
            raw.voxels = v.u8();
            break;
          case volume::VoxelType::UInt16: {
            raw.type = acquire::ProbeVoxelType::UInt16;
            const auto& src = v.u16();
            raw.voxels.resize(src.size() * 2);
            for (std::size_t i = 0; i < src.size(); ++i) {  // little endian, as on the wire
              raw.voxels[2 * i] = static_cast<std::uint8_t>(src[i] & 0xff);
              raw.voxels[2 * i + 1] = static_cast<std::uint8_t>(src[i] >> 8);
            }
            break;
          }
          default:
            return tl::make_unexpected(AcquireError{
                AcquireError::Code::BadRecord, 0,
                path.string() + ": voxel type " + volume::to_string(v.type()) +
                    " is not a probe type (uint8 or uint16)",
                {}, 0});
        }
        raw.received = std::chrono::steady_clock::now();
        return raw;
      });
}

namespace {

bool starts_with(const std::string& s, const char* prefix) {
  return s.rfind(prefix, 0) == 0;
}

}  // namespace

OpenedSource open_run_source(const RunConfig& config) {
  OpenedSource opened;
  const std::string uri = config.source;
  const acquire::SourceOptions options = source_options(config);

  if (starts_with(uri, "sim:")) {
    auto parsed = sim::parse_sim_uri(uri);
    if (!parsed) {
      opened.fatal_error = acquire::to_string(parsed.error());
      return opened;
    }
    try {
      // The phantom's own seed (at breathing phase 0; the target moves by less than its radius)
      // is the default when none is configured: the demo needs no --seed-mm.
      sim::PhantomSpec spec = parsed->spec;
      spec.time_s = 0.0f;
      const sim::Phantom phantom = sim::make_phantom(spec);
      opened.phantom_seed_mm = std::array<float, 3>{phantom.seed_mm.x(), phantom.seed_mm.y(),
                                                    phantom.seed_mm.z()};
    } catch (const std::exception& e) {
      opened.fatal_error = std::string(uri) + ": " + e.what();
      return opened;
    }
    opened.factory = [uri]() { return sim::open_phantom_source(uri); };
    auto source = sim::open_phantom_source(uri);
    if (!source) {
      opened.fatal_error = acquire::to_string(source.error());
      return opened;
    }
    opened.live = (*source)->live();
    opened.source = std::move(*source);
    return opened;
  }

  opened.factory = [uri, options]() { return acquire::open_source(uri, options); };
  auto source = acquire::open_source(uri, options);
  if (source) {
    opened.live = (*source)->live();
    opened.source = std::move(*source);
    return opened;
  }
  const AcquireError& e = source.error();
  const bool live_scheme = starts_with(uri, "unix:") || starts_with(uri, "tcp:") ||
                           starts_with(uri, "usb:") || starts_with(uri, "v4l2:");
  const bool transient = e.code == AcquireError::Code::NotFound ||
                         e.code == AcquireError::Code::Disconnected ||
                         e.code == AcquireError::Code::Timeout ||
                         e.code == AcquireError::Code::IoError;
  if (live_scheme && transient) {
    // A daemon started before its probe: wait for it rather than exit.
    spdlog::warn("{}: {}; waiting for it", uri, acquire::to_string(e));
    opened.live = true;
    return opened;
  }
  opened.fatal_error = acquire::to_string(e);
  return opened;
}

}  // namespace sonomesh::daemon
