#pragma once
/// @file
/// @brief sonomeshd's heap: blocks of 4 MiB and more on transparent huge pages (huge_pages.cpp,
/// the global operator new), and for the daemon a heap kept warm from start-up.

#include <cstddef>

namespace sonomesh::daemon {

/// For a process that segments volume after volume (`run`): one malloc arena for all threads,
/// blocks up to 256 MiB from the heap rather than fresh mappings, freed memory kept up to
/// `reserve_mb` (more is given back), and that much of the heap touched now, on huge pages. A
/// fresh process otherwise faults in every page its first volumes allocate, and each lane's own
/// arena again for itself. Returns the milliseconds it took; does nothing in sanitizer builds
/// (their runtime allocates) or at 0.
double keep_heap_warm(std::size_t reserve_mb);

}  // namespace sonomesh::daemon
