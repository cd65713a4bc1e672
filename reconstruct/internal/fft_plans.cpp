#include "reconstruct/internal/fft_plans.h"

#include <fftw3.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <mutex>
#include <new>
#include <tuple>
#include <vector>

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

bool friendly(int n) {
  for (int p : {2, 3, 5})
    while (n % p == 0) n /= p;
  return n == 1;
}

const std::vector<int>& ladder() {
  static const std::vector<int> sizes = [] {
    std::vector<int> v{8};
    while (v.back() < 1024) {
      int n = (v.back() * 11 + 9) / 10;  // ceil(1.1 * previous)
      while (!friendly(n) || n % 2 != 0) ++n;
      v.push_back(n);
    }
    return v;
  }();
  return sizes;
}

// Callers hold the planner mutex: FFTW's wisdom functions share the planner's state.
bool import_wisdom_locked() {
  const std::string path = fft_wisdom_path();
  if (path.empty() || access(path.c_str(), R_OK) != 0) return false;
  return fftwf_import_wisdom_from_filename(path.c_str()) != 0;
}

void export_wisdom_locked() {
  const std::string path = fft_wisdom_path();
  if (path.empty()) return;
  std::error_code ec;
  std::filesystem::create_directories(std::filesystem::path(path).parent_path(), ec);
  // Temporary file + rename: a concurrent process never reads half a file.
  const std::string tmp = path + ".tmp." + std::to_string(getpid());
  if (fftwf_export_wisdom_to_filename(tmp.c_str()) == 0 ||
      std::rename(tmp.c_str(), path.c_str()) != 0)
    std::filesystem::remove(tmp, ec);
}

fftwf_plan get_plan(const std::array<int, 3>& dims, bool forward, int threads, bool measure) {
  PlanCache& c = cache();
  std::lock_guard lock(c.mutex);
  static const bool threads_ok = fftwf_init_threads() != 0;
  static const bool wisdom_imported [[maybe_unused]] = import_wisdom_locked();
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
  // FFTW is row-major: the last (fastest) FFTW dimension is our x.
  const auto make = [&](unsigned flags) {
    return forward ? fftwf_plan_dft_r2c_3d(dims[2], dims[1], dims[0], real, cplx, flags)
                   : fftwf_plan_dft_c2r_3d(dims[2], dims[1], dims[0], cplx, real, flags);
  };
  // From the wisdom when it has the plan; the wisdom file is written again only for a plan it
  // did not have (rewriting it for every plan cost a one-shot process a file of ~0.5 MB each).
  const unsigned rigour = measure ? FFTW_MEASURE : FFTW_ESTIMATE;
  fftwf_plan plan = make(rigour | FFTW_WISDOM_ONLY);
  const bool learned = !plan;
  if (!plan) plan = make(rigour);
  fftwf_free(real);
  fftwf_free(cplx);
  if (!plan) throw std::bad_alloc();
  ++c.stats.plans_created;
  c.plans.emplace(key, plan);
  if (learned) export_wisdom_locked();
  return plan;
}

}  // namespace

int fft_ladder_size(int n) {
  for (int size : ladder())
    if (size >= n) return size;
  return 0;
}

int fft_friendly_size(int n) {
  n = std::max(n, 8);
  while (!friendly(n) || n % 2 != 0) ++n;
  return n;
}

std::string fft_wisdom_path() {
  if (const char* p = std::getenv("SONOMESH_FFTW_WISDOM")) return p;
  const char* xdg = std::getenv("XDG_CACHE_HOME");
  if (xdg && xdg[0] == '/') return std::string(xdg) + "/sonomesh/fftw-wisdom";
  const char* home = std::getenv("HOME");
  if (home && home[0] == '/') return std::string(home) + "/.cache/sonomesh/fftw-wisdom";
  return "";
}

bool fft_import_wisdom() {
  std::lock_guard lock(cache().mutex);
  return import_wisdom_locked();
}

FftPlanStats fft_plan_stats() {
  std::lock_guard lock(cache().mutex);
  return cache().stats;
}

// Through the aligned operator new rather than fftwf_malloc: sonomeshd's replacement puts large
// blocks on huge pages (daemon/huge_pages.cpp). 64 bytes satisfy FFTW's SIMD alignment, as its
// own planning arrays have it.
FftBuffer::FftBuffer(std::size_t floats) : size_(floats) {
  data_ = static_cast<float*>(::operator new(floats * sizeof(float), kFftAlignment));
}
FftBuffer::~FftBuffer() { ::operator delete(data_, kFftAlignment); }

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
