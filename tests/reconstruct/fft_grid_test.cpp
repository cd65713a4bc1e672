// The reconstruction grid's sizes come from a coarse ladder (so a breathing target keeps its FFTW
// plans), and FFTW wisdom is kept in a file between processes.
#include <fftw3.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <optional>
#include <string>

#include "reconstruct/internal/fft_plans.h"
#include "shapes.h"

namespace sonomesh::reconstruct {
namespace {

bool friendly(int n) {
  for (int p : {2, 3, 5})
    while (n % p == 0) n /= p;
  return n == 1;
}

TEST(FftGrid, LadderIsFftFriendlyInCoarseSteps) {
  int previous = 0;
  for (int n = 1; n <= 1100; ++n) {
    const int size = internal::fft_ladder_size(n);
    ASSERT_GE(size, n);
    EXPECT_TRUE(friendly(size) && size % 2 == 0) << size;
    if (size != previous && previous > 0) {
      EXPECT_GE(size, 1.1 * previous) << previous;
    }
    previous = size;
  }
}

TEST(FftGrid, DimsFallInTheLadderWithTheMargin) {
  for (float radius_mm = 6.0f; radius_mm <= 14.0f; radius_mm += 1.0f) {
    const PointCloud s = test::sphere_samples(Vec3f(0.3f, -0.2f, 0.1f), radius_mm, 1500);
    const IndicatorGrid g = poisson_indicator(s, {.cell_mm = 0.5f});
    for (int a = 0; a < 3; ++a) {
      const int n = g.chi.dims()[a];
      EXPECT_EQ(internal::fft_ladder_size(n), n) << "radius " << radius_mm;
      // method.md §5: at least 10 % of the extent on each side.
      EXPECT_GE((n - 1) * g.cell_mm, 2.0f * radius_mm * 1.2f * 0.99f);
    }
  }
}

TEST(FftGrid, BoxesAFewVoxelsApartShareTheirDims) {
  // Extents 23.6 and 24.8 mm at 0.5 mm cells: 63 and 66 cells with the padding, both below the
  // ladder size 72 and above 60, so a target breathing between them keeps one grid size.
  const IndicatorGrid a =
      poisson_indicator(test::sphere_samples(Vec3f::Zero(), 11.8f, 3000), {.cell_mm = 0.5f});
  const IndicatorGrid b =
      poisson_indicator(test::sphere_samples(Vec3f::Zero(), 12.4f, 3000), {.cell_mm = 0.5f});
  EXPECT_EQ(a.chi.dims(), b.chi.dims());
  EXPECT_EQ(a.chi.dims().x(), 72);
}

TEST(FftGrid, SpheresAcrossALadderStepKeepGenusAndAccuracy) {
  const Vec3f c(1.0f, 2.0f, -1.0f);
  const float cell = 0.5f;
  for (float radius_mm : {7.7f, 8.4f, 9.1f}) {  // 48, 54 and 60 cells: three ladder sizes
    const SurfaceResult r =
        reconstruct_surface(test::sphere_samples(c, radius_mm, 4000), c, {.cell_mm = cell});
    EXPECT_TRUE(r.topology.watertight && r.topology.manifold);
    EXPECT_EQ(r.topology.genus, 0);
    double sum = 0.0;
    for (const auto& v : r.mesh.vertices) sum += std::abs((v - c).norm() - radius_mm);
    EXPECT_LE(sum / double(r.mesh.vertices.size()), 0.25 * cell) << radius_mm;
  }
}

// Points SONOMESH_FFTW_WISDOM at a path for one test, restoring the old value after.
class WisdomEnv {
 public:
  explicit WisdomEnv(const std::string& path) {
    if (const char* old = std::getenv("SONOMESH_FFTW_WISDOM")) old_ = old;
    setenv("SONOMESH_FFTW_WISDOM", path.c_str(), 1);
  }
  ~WisdomEnv() {
    if (old_)
      setenv("SONOMESH_FFTW_WISDOM", old_->c_str(), 1);
    else
      unsetenv("SONOMESH_FFTW_WISDOM");
  }

 private:
  std::optional<std::string> old_;
};

TEST(FftWisdom, NewPlanWritesTheFileAndItImportsAgain) {
  const auto dir =
      std::filesystem::temp_directory_path() / ("sonomesh-wisdom-" + std::to_string(getpid()));
  const auto file = dir / "sub" / "fftw-wisdom";  // the directory is made on the way
  std::filesystem::remove_all(dir);
  const WisdomEnv env(file.string());
  EXPECT_EQ(internal::fft_wisdom_path(), file.string());
  const std::array<int, 3> dims{26, 14, 22};  // a size no other test plans
  internal::FftBuffer real(26 * 14 * 22), spectrum(2 * 14 * 14 * 22);
  std::fill(real.data(), real.data() + real.size(), 0.0f);
  internal::fft_forward(dims, real.data(), spectrum.complex(), 1, false);
  ASSERT_TRUE(std::filesystem::exists(file));
  EXPECT_GT(std::filesystem::file_size(file), 0u);
  for (const auto& e : std::filesystem::directory_iterator(file.parent_path()))
    EXPECT_EQ(e.path(), file) << "a temporary file was left behind";

  // A fresh process is a planner without wisdom: after forgetting it, this size can only be
  // planned from wisdom once the file is imported again.
  auto wisdom_only_plan = [&] {
    fftwf_plan_with_nthreads(1);
    fftwf_plan p = fftwf_plan_dft_r2c_3d(22, 14, 26, real.data(),
                                         reinterpret_cast<fftwf_complex*>(spectrum.data()),
                                         FFTW_ESTIMATE | FFTW_WISDOM_ONLY);
    const bool ok = p != nullptr;
    if (p) fftwf_destroy_plan(p);
    return ok;
  };
  fftwf_forget_wisdom();
  EXPECT_FALSE(wisdom_only_plan());
  EXPECT_TRUE(internal::fft_import_wisdom());
  EXPECT_TRUE(wisdom_only_plan());
  std::filesystem::remove_all(dir);
}

// A plan the wisdom already has is made from it without writing the file again (a one-shot
// process rewrote ~0.5 MB for each of its plans).
TEST(FftWisdom, APlanFromWisdomLeavesTheFileAlone) {
  const auto dir =
      std::filesystem::temp_directory_path() / ("sonomesh-wisdom2-" + std::to_string(getpid()));
  const auto file = dir / "fftw-wisdom";
  std::filesystem::remove_all(dir);
  const WisdomEnv env(file.string());
  const std::array<int, 3> dims{34, 6, 14};  // a size no other test plans
  internal::FftBuffer real(34 * 6 * 14), spectrum(2 * 18 * 6 * 14);
  std::fill(real.data(), real.data() + real.size(), 1.0f);
  fftwf_plan_with_nthreads(1);
  fftwf_plan learned = fftwf_plan_dft_r2c_3d(14, 6, 34, real.data(),
                                             reinterpret_cast<fftwf_complex*>(spectrum.data()),
                                             FFTW_ESTIMATE);  // now in this process's wisdom
  ASSERT_NE(learned, nullptr);
  fftwf_destroy_plan(learned);
  std::fill(real.data(), real.data() + real.size(), 1.0f);
  internal::fft_forward(dims, real.data(), spectrum.complex(), 1, false);
  EXPECT_NEAR(spectrum.complex()[0].real(), 34.0f * 6 * 14, 1e-2f);
  EXPECT_FALSE(std::filesystem::exists(file));
  std::filesystem::remove_all(dir);
}

TEST(FftWisdom, UnwritableOrDisabledWisdomIsSkipped) {
  {
    const WisdomEnv env("");
    EXPECT_EQ(internal::fft_wisdom_path(), "");
    EXPECT_FALSE(internal::fft_import_wisdom());
  }
  const WisdomEnv env("/proc/self/no-such-dir/fftw-wisdom");
  EXPECT_FALSE(internal::fft_import_wisdom());
  const std::array<int, 3> dims{18, 26, 10};  // a new size: the export fails, the plan does not
  internal::FftBuffer real(18 * 26 * 10), spectrum(2 * 10 * 26 * 10);
  std::fill(real.data(), real.data() + real.size(), 1.0f);
  internal::fft_forward(dims, real.data(), spectrum.complex(), 1, false);
  EXPECT_NEAR(spectrum.complex()[0].real(), 18.0f * 26 * 10, 1e-2f);
}

}  // namespace
}  // namespace sonomesh::reconstruct
