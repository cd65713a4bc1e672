#pragma once
/// @file
/// @brief The mesh types under their segment:: names (they live in mesh/mesh.h).

#include "mesh/mesh.h"

namespace sonomesh::segment {

using mesh::Mesh;
using mesh::PointCloud;
using mesh::StopReason;
using volume::Vec3f;

}  // namespace sonomesh::segment
