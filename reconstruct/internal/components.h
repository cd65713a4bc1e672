#pragma once
// component_enclosing that also reports how many components there were (reconstruct_surface
// needs both and should not split the mesh twice).

#include "reconstruct/reconstruct.h"

namespace sonomesh::reconstruct::internal {

Mesh select_component(const Mesh& mesh, const Vec3f& seed_mm, bool* seed_enclosed,
                      int* component_count);

}  // namespace sonomesh::reconstruct::internal
