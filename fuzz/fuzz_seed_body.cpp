/// @file
/// @brief libFuzzer target: the body parser of POST /seed (parse_seed_text: "x,y,z" or JSON).
///
/// Property beyond "no crash": an accepted seed is three finite numbers.

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "daemon/internal/http_status.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string body(reinterpret_cast<const char*>(data), size);
  const auto seed = sonomesh::daemon::parse_seed_text(body);
  if (!seed) return 0;
  for (float v : *seed) {
    if (!std::isfinite(v)) std::abort();
  }
  return 0;
}
