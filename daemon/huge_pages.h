#pragma once
/// @file
/// @brief sonomeshd's heap: blocks of 4 MiB and more on transparent huge pages (huge_pages.cpp,
/// the global operator new), and for the daemon a heap kept warm from start-up.

#include <cstddef>

namespace sonomesh::daemon {

/// sonomeshd's malloc settings, for every subcommand: one arena for all threads, blocks up to
/// 256 MiB from the heap rather than fresh mappings, and up to 256 MiB freed at the heap's top
/// kept. A volume's stages then reuse the memory the stages before them freed, where each of
/// their buffers was a fresh mapping to fault in, and the lanes and TBB's threads share one heap.
/// Does nothing in sanitizer builds (their runtime allocates).
void tune_heap();

/// For a process that segments volume after volume (`run`), after tune_heap: `reserve_mb` of
/// the heap touched now, on huge pages, and kept (freed memory beyond twice it, at least 256 MiB,
/// is given back), so that the first volumes fault in no pages. Returns the milliseconds it took;
/// nothing in sanitizer builds or at 0.
double keep_heap_warm(std::size_t reserve_mb);

}  // namespace sonomesh::daemon
