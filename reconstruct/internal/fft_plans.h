#pragma once
// FFTW single-precision plans, made once per (grid size, direction, threads, rigour) and reused.
// FFTW's planner is not thread-safe, so making a plan holds a mutex; executing a cached plan on
// new arrays (fftwf_execute_dft_*) is thread-safe and needs no lock. Arrays passed to the
// execute functions must come from fft_alloc so their alignment matches the planning arrays.

#include <array>
#include <complex>
#include <cstddef>
#include <new>
#include <string>

namespace sonomesh::reconstruct::internal {

struct FftPlanStats {
  std::size_t plans_created = 0;  // planner calls so far (process-wide)
  std::size_t cache_hits = 0;     // requests served from the cache
};
FftPlanStats fft_plan_stats();

/// The smallest size of the grid ladder that is >= n (n >= 1): even 2^a·3^b·5^c sizes, each at
/// least 10 % above the one before (8, 10, 12, 16, 18, 20, 24, 30, 36, 40, 48, ..., 90, 100, 120,
/// 144, 160, ...). Coarse steps make a target that grows or shrinks by a few voxels keep its grid
/// size, so its FFTW plans are reused. Returns 0 above the ladder's top (1152).
int fft_ladder_size(int n);
/// The smallest even 2^a·3^b·5^c size >= max(n, 8): the fine-grained fallback.
int fft_friendly_size(int n);

/// Wisdom file: $SONOMESH_FFTW_WISDOM (set but empty: no wisdom file), else
/// $XDG_CACHE_HOME/sonomesh/fftw-wisdom, else $HOME/.cache/sonomesh/fftw-wisdom; "" if none.
/// The first plan of a process imports it; a plan the wisdom did not have exports all wisdom to
/// it (a temporary file renamed over it). An unreadable or unwritable file is skipped silently.
std::string fft_wisdom_path();
/// Imports fft_wisdom_path() now (under the planner lock); false if there is none or it is bad.
bool fft_import_wisdom();

inline constexpr std::align_val_t kFftAlignment{64};

/// FFTW-aligned float buffer, freed on destruction.
class FftBuffer {
 public:
  explicit FftBuffer(std::size_t floats);
  ~FftBuffer();
  FftBuffer(const FftBuffer&) = delete;
  FftBuffer& operator=(const FftBuffer&) = delete;
  float* data() { return data_; }
  std::complex<float>* complex() { return reinterpret_cast<std::complex<float>*>(data_); }
  std::size_t size() const { return size_; }

 private:
  float* data_ = nullptr;
  std::size_t size_ = 0;
};

/// dims = (nx, ny, nz), x fastest in memory. The half-complex axis is x: (nx/2 + 1) * ny * nz.
/// Forward: real `in` (nx*ny*nz) -> complex `out`. Inverse: complex `in` (destroyed) -> real.
void fft_forward(const std::array<int, 3>& dims, float* in, std::complex<float>* out, int threads,
                 bool measure);
void fft_inverse(const std::array<int, 3>& dims, std::complex<float>* in, float* out, int threads,
                 bool measure);

}  // namespace sonomesh::reconstruct::internal
