#include "reconstruct/internal/fft_plans.h"

#include <fftw3.h>

#include <map>
#include <mutex>
#include <new>
#include <tuple>

namespace sonomesh::reconstruct::internal {
namespace {

using Key = std::tuple<int, int, int, bool, int, bool>;  // nx, ny, nz, forward, threads, measure

struct PlanCache {
  std::mutex mutex;
  std::map<Key, fftwf_plan> plans;
  FftPlanStats stats;
  // Plans live for the whole process: a daemon sees a handful of grid sizes, and destroying a
  // plan while another thread may execute it would need reference counting for no gain.
};

PlanCache& cache() {
  static PlanCache* c = new PlanCache();  // never destroyed: plans may be used during shutdown
  return *c;
}

fftwf_plan get_plan(const std::array<int, 3>& dims, bool forward, int threads, bool measure) {
  PlanCache& c = cache();
  std::lock_guard lock(c.mutex);
  static const bool threads_ok = fftwf_init_threads() != 0;
  const Key key{dims[0], dims[1], dims[2], forward, threads, measure};
  if (auto it = c.plans.find(key); it != c.plans.end()) {
    ++c.stats.cache_hits;
    return it->second;
  }
  if (threads_ok) fftwf_plan_with_nthreads(threads);
  const std::size_t n_real = std::size_t(dims[0]) * dims[1] * dims[2];
  const std::size_t n_cplx = std::size_t(dims[0] / 2 + 1) * dims[1] * dims[2];
  // Planning arrays: FFTW_MEASURE scribbles on them, so they are scratch, never user data.
  float* real = fftwf_alloc_real(n_real);
  fftwf_complex* cplx = fftwf_alloc_complex(n_cplx);
  if (!real || !cplx) {
    fftwf_free(real);
    fftwf_free(cplx);
    throw std::bad_alloc();
  }
  const unsigned flags = measure ? FFTW_MEASURE : FFTW_ESTIMATE;
  // FFTW is row-major: the last (fastest) FFTW dimension is our x.
  fftwf_plan plan = forward ? fftwf_plan_dft_r2c_3d(dims[2], dims[1], dims[0], real, cplx, flags)
                            : fftwf_plan_dft_c2r_3d(dims[2], dims[1], dims[0], cplx, real, flags);
  fftwf_free(real);
  fftwf_free(cplx);
  if (!plan) throw std::bad_alloc();
  ++c.stats.plans_created;
  c.plans.emplace(key, plan);
  return plan;
}

}  // namespace

FftPlanStats fft_plan_stats() {
  std::lock_guard lock(cache().mutex);
  return cache().stats;
}

FftBuffer::FftBuffer(std::size_t floats) : size_(floats) {
  data_ = fftwf_alloc_real(floats);
  if (!data_) throw std::bad_alloc();
}
FftBuffer::~FftBuffer() { fftwf_free(data_); }

void fft_forward(const std::array<int, 3>& dims, float* in, std::complex<float>* out, int threads,
                 bool measure) {
  fftwf_execute_dft_r2c(get_plan(dims, true, threads, measure), in,
                        reinterpret_cast<fftwf_complex*>(out));
}

void fft_inverse(const std::array<int, 3>& dims, std::complex<float>* in, float* out, int threads,
                 bool measure) {
  fftwf_execute_dft_c2r(get_plan(dims, false, threads, measure),
                        reinterpret_cast<fftwf_complex*>(in), out);
}

}  // namespace sonomesh::reconstruct::internal
