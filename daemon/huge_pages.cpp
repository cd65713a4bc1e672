// sonomeshd's replacement of the global operator new: large blocks on transparent huge pages.
// A fresh process first-touches every float volume it allocates (smoothing, gradients, χ, FFT
// buffers: ~40 MB at 128³, ~330 MB at 256³), and with the kernel's THP mode "madvise" (Debian's
// default) each 4 KiB page of them costs a fault. Blocks of kHugeBlockBytes and more are
// therefore 2 MiB-aligned and advised MADV_HUGEPAGE before anything touches them (measurements:
// docs/results.md). Every block comes from malloc or aligned_alloc, so libstdc++'s default
// operator delete (free) releases it, aligned or not; the array and nothrow forms call these two.
// Sanitizer builds keep their runtime's own allocation functions.
#include "daemon/huge_pages.h"

#include <malloc.h>
#include <sys/mman.h>

#include <algorithm>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <new>

#if defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer) || \
    __has_feature(memory_sanitizer)
#define SONOMESH_SANITIZED 1
#endif
#endif
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define SONOMESH_SANITIZED 1
#endif

#ifndef SONOMESH_SANITIZED
namespace {

constexpr std::size_t kHugePageBytes = std::size_t{2} << 20;
constexpr std::size_t kHugeBlockBytes = std::size_t{4} << 20;

// `alignment`: 0 for malloc's own, else a power of two (aligned_alloc wants a multiple of it).
void* allocate(std::size_t bytes, std::size_t alignment) {
  if (bytes == 0) bytes = 1;
  if (bytes >= kHugeBlockBytes && alignment <= kHugePageBytes) {
    const std::size_t rounded = (bytes + kHugePageBytes - 1) / kHugePageBytes * kHugePageBytes;
    void* block = std::aligned_alloc(kHugePageBytes, rounded);
    if (block) ::madvise(block, rounded, MADV_HUGEPAGE);  // advice: a refusal changes nothing
    return block;
  }
  if (alignment == 0) return std::malloc(bytes);
  return std::aligned_alloc(alignment, (bytes + alignment - 1) / alignment * alignment);
}

void* allocate_or_throw(std::size_t bytes, std::size_t alignment) {
  for (;;) {
    if (void* block = allocate(bytes, alignment)) return block;
    const std::new_handler handler = std::get_new_handler();
    if (!handler) throw std::bad_alloc();
    handler();
  }
}

}  // namespace

void* operator new(std::size_t bytes) { return allocate_or_throw(bytes, 0); }
void* operator new(std::size_t bytes, std::align_val_t alignment) {
  return allocate_or_throw(bytes, static_cast<std::size_t>(alignment));
}

namespace sonomesh::daemon {

constexpr int kHeapBlockBytes = 256 << 20;

void tune_heap() {
  mallopt(M_ARENA_MAX, 1);
  mallopt(M_MMAP_THRESHOLD, kHeapBlockBytes);
  mallopt(M_TRIM_THRESHOLD, kHeapBlockBytes);
}

double keep_heap_warm(std::size_t reserve_mb) {
  if (reserve_mb == 0) return 0.0;
  const auto start = std::chrono::steady_clock::now();
  const std::size_t bytes = reserve_mb << 20;
  mallopt(M_TOP_PAD, static_cast<int>(bytes));
  mallopt(M_TRIM_THRESHOLD, std::max(kHeapBlockBytes, static_cast<int>(2 * bytes)));
  auto* block = static_cast<volatile char*>(std::malloc(bytes));
  if (!block) return 0.0;
  const auto first = (reinterpret_cast<std::uintptr_t>(block) + kHugePageBytes - 1) &
                     ~std::uintptr_t{kHugePageBytes - 1};
  if (bytes > 2 * kHugePageBytes)
    ::madvise(reinterpret_cast<void*>(first), bytes - 2 * kHugePageBytes, MADV_HUGEPAGE);
  for (std::size_t i = 0; i < bytes; i += 4096) block[i] = 1;  // (volatile: not elided)
  std::free(const_cast<char*>(block));
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
      .count();
}

}  // namespace sonomesh::daemon
#else
namespace sonomesh::daemon {
void tune_heap() {}
double keep_heap_warm(std::size_t) { return 0.0; }
}  // namespace sonomesh::daemon
#endif
