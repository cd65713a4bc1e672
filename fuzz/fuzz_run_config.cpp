/// @file
/// @brief libFuzzer target: the TOML configuration of `sonomeshd run` (load_config_text through
/// toml++, then validate without touching the file system).
///
/// Property beyond "no crash": a text that loads prints (to_toml) to a text that loads again to
/// the same printed form, as --print-config promises.

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "daemon/internal/run_config.h"

using namespace sonomesh::daemon;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  RunConfig config;
  if (load_config_text(text, "fuzz.toml", config)) return 0;  // refused with a message: fine
  (void)validate(config, /*require_io=*/false);
  const std::string printed = to_toml(config);
  RunConfig again;
  if (load_config_text(printed, "printed.toml", again)) std::abort();
  if (to_toml(again) != printed) std::abort();
  return 0;
}
