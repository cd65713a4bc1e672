#pragma once
/// @file
/// @brief A live probe made of phantoms: sim::make_phantom volumes, breathing, paced, numbered.
///
/// The daemon's `sim:PHANTOM[?rate=HZ&size=N&count=N&seed=N&contrast=C&realism=echo]` source.

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <tl/expected.hpp>

#include "acquire/acquire.h"
#include "sim/sim.h"

namespace sonomesh::sim {

struct PhantomSourceOptions {
  PhantomSpec spec;         // time_s is set per volume: sequence / rate_hz (the target breathes)
  double rate_hz = 10.0;    // volumes per second (> 0)
  std::uint64_t count = 0;  // volumes before end of stream; 0 = endless
};

/// Parses `sim:PHANTOM[?rate=HZ&size=N&count=N&seed=N&contrast=C&realism=simple|echo&oblique=0|1]`
/// (the "sim:" prefix is optional); realism=echo applies with_echo_realism, oblique=1 sets
/// PhantomSpec::oblique (the volumes carry oblique_direction()).
/// InvalidArgument with a one-line detail naming the bad part.
tl::expected<PhantomSourceOptions, acquire::AcquireError> parse_sim_uri(const std::string& uri);

/// Generates volume k (sequence k, probe timestamp k / rate_hz) of a phantom stream.
acquire::RawVolume make_stream_volume(const PhantomSourceOptions& options, std::uint64_t sequence);

class PhantomSource final : public acquire::Source {
 public:
  /// @throws std::invalid_argument for an unknown phantom, size below 16 or rate <= 0.
  explicit PhantomSource(PhantomSourceOptions options);
  ~PhantomSource() override;
  PhantomSource(const PhantomSource&) = delete;
  PhantomSource& operator=(const PhantomSource&) = delete;

  /// The next volume when it is due (volume k at start + k / rate_hz); Timeout before that;
  /// EndOfStream after `count` volumes.
  tl::expected<acquire::RawVolume, acquire::AcquireError> next(
      std::chrono::milliseconds timeout) override;
  std::string describe() const override;
  bool live() const override { return true; }
  void interrupt() override;

 private:
  struct State;
  PhantomSourceOptions options_;
  std::unique_ptr<State> state_;
};

/// parse_sim_uri + PhantomSource; errors as values (never throws).
tl::expected<std::unique_ptr<acquire::Source>, acquire::AcquireError> open_phantom_source(
    const std::string& uri);

}  // namespace sonomesh::sim
