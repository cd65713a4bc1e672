#pragma once
// Echo-mode phantoms for the pipeline tests, and their truth's volume.
#include <cstdint>
#include <string>

#include "sim/sim.h"

namespace sonomesh::daemon::test {

inline sim::Phantom echo_phantom(const std::string& name, float contrast, int size_vox = 64,
                                 unsigned seed = 1) {
  sim::PhantomSpec spec{.phantom = name, .size_vox = size_vox, .seed = seed};
  spec.contrast = contrast;
  return sim::make_phantom(sim::with_echo_realism(spec));
}

// The volume of `phantom`'s truth.
inline double truth_ml(const sim::Phantom& phantom) {
  double voxels = 0;
  for (const std::uint8_t v : phantom.truth.u8()) voxels += v != 0;
  return voxels * phantom.truth.spacing_mm().prod() * 1e-3;
}

}  // namespace sonomesh::daemon::test
