/// @file
/// @brief libFuzzer target: the PLY reader (reconstruct::read_ply), ascii and binary.
///
/// Property beyond "no crash": a mesh that is read only has faces whose indices name vertices.

#include <cstddef>
#include <cstdint>
#include <cstdlib>

#include "fuzz/fuzz_util.h"
#include "reconstruct/reconstruct.h"

using namespace sonomesh;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const auto path = fuzz::scratch_dir() / "x.ply";
  fuzz::write_file(path, fuzz::as_text(data, size));
  const auto result = reconstruct::read_ply(path);
  if (!result) return 0;
  const auto n = result.mesh.vertices.size();
  for (const auto& t : result.mesh.triangles) {
    for (const auto index : t) {
      if (index >= n) std::abort();
    }
  }
  if (!result.stop.empty() && result.stop.size() != n) std::abort();
  return 0;
}
