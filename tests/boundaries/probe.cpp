// A translation unit that includes one header, PROBE_HEADER, and uses nothing from it: whether it
// compiles says whether the header is visible to the target that builds it (tests/boundaries).
#include PROBE_HEADER

int sonomesh_boundary_probe() { return 0; }
