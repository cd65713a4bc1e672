#pragma once
/// @file
/// @brief `probe-sim serve --igtl`: an OpenIGTLink server sending IMAGE messages, as PlusServer
/// does.

#include <cstdint>
#include <functional>
#include <optional>
#include <string>

#include "acquire/raw_volume.h"

namespace sonomesh::sim::internal {

struct IgtlServeOptions {
  std::string address;      // HOST:PORT to listen on (PlusServer's default port is 18944)
  double rate_hz = 10.0;    // IMAGE messages per second while a client is connected
  std::uint64_t count = 0;  // volumes to send before exiting; 0 = endless
  int header_version = 1;   // 1, or 2 (extended header, MESSAGE_ID = the volume's sequence)
  std::string device = "Image_Reference";  // PlusServer's usual image device name
};

/// The next volume to send (its sequence as given), or nullopt at the end of a recording.
using VolumeSupplier = std::function<std::optional<acquire::RawVolume>(std::uint64_t sequence)>;

/// Listens on options.address and sends every volume, paced at rate_hz, to every connected client
/// (each gets the same message). Pacing starts with the first client; while no client is
/// connected no volume is made. What clients send (Slicer's STATUS, GET_ queries) is read and
/// ignored; a client that fails a send (gone, or stalled for 2 s) is dropped. Returns 0 after
/// `count` volumes or the supplier's end. @throws std::runtime_error if it cannot listen.
int run_igtl_serve(const IgtlServeOptions& options, const VolumeSupplier& next);

}  // namespace sonomesh::sim::internal
