#pragma once
/// @file
/// @brief The Float32 output volume that smoothing and gradients write into.

#include "volume/volume.h"

namespace sonomesh::volume::internal {

/// Makes `out` a Float32 volume on the grid of `like`, keeping its buffer if it already is one.
void prepare_float(const Volume& like, Volume& out);

}  // namespace sonomesh::volume::internal
