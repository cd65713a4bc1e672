#include "daemon/internal/slice_renderer.h"

#include <algorithm>
#include <cmath>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "daemon/internal/png_writer.h"

namespace sonomesh::daemon {

namespace {

// Index axes shown by each slice as (u, v, normal): axial (i, j) at k, coronal (i, k) at j,
// sagittal (j, k) at i.
constexpr std::array<std::array<int, 3>, 3> kAxes{{{0, 1, 2}, {0, 2, 1}, {1, 2, 0}}};

int axis_number(SliceAxis axis) { return static_cast<int>(axis); }

// Coronal and sagittal images put k (superior in LPS) up; axial keeps j down the rows.
bool flips_v(SliceAxis axis) { return axis != SliceAxis::Axial; }

const cv::Scalar kContourBgr(40, 40, 255);
const cv::Scalar kSeedBgr(80, 220, 80);

}  // namespace

const char* to_string(SliceAxis axis) {
  switch (axis) {
    case SliceAxis::Axial:
      return "axial";
    case SliceAxis::Coronal:
      return "coronal";
    case SliceAxis::Sagittal:
      return "sagittal";
  }
  return "unknown";
}

std::optional<SliceAxis> slice_axis_from(const std::string& name) {
  for (SliceAxis a : {SliceAxis::Axial, SliceAxis::Coronal, SliceAxis::Sagittal}) {
    if (name == to_string(a)) return a;
  }
  return std::nullopt;
}

std::vector<SliceSegment> mesh_contour(const segment::Mesh& mesh_mm, const volume::Volume& grid,
                                       SliceAxis axis, float plane_vox) {
  const auto [u, v, n] = kAxes[axis_number(axis)];
  std::vector<volume::Vec3f> ijk(mesh_mm.vertices.size());
  for (std::size_t i = 0; i < ijk.size(); ++i) ijk[i] = grid.mm_to_index(mesh_mm.vertices[i]);
  std::vector<SliceSegment> out;
  for (const auto& tri : mesh_mm.triangles) {
    SlicePoint hits[3];
    int count = 0;
    for (int e = 0; e < 3 && count < 2; ++e) {
      const volume::Vec3f& p = ijk[tri[e]];
      const volume::Vec3f& q = ijk[tri[(e + 1) % 3]];
      // A vertex on the plane counts as above it, so an edge is cut at most once and a
      // triangle gives at most one segment.
      const float dp = p[n] - plane_vox, dq = q[n] - plane_vox;
      if ((dp >= 0) == (dq >= 0)) continue;
      const float t = dp / (dp - dq);
      hits[count++] = {p[u] + t * (q[u] - p[u]), p[v] + t * (q[v] - p[v])};
    }
    if (count == 2) out.push_back({hits[0], hits[1]});
  }
  return out;
}

void SliceRenderer::update(const volume::Volume& input, const segment::Mesh& mesh_mm,
                           const volume::Vec3f& seed_mm, std::uint64_t sequence) {
  auto frame = std::make_shared<Frame>();
  frame->sequence = sequence;
  frame->dims = input.dims();
  frame->spacing_mm = input.spacing_mm();
  frame->origin_mm = input.origin_mm();
  frame->direction = input.direction();
  const volume::Vec3f seed_vox = input.mm_to_index(seed_mm);
  for (int a = 0; a < 3; ++a) {
    frame->seed_index[a] =
        std::clamp(static_cast<int>(std::lround(seed_vox[a])), 0, frame->dims[a] - 1);
  }
  std::vector<float> all;
  for (SliceAxis axis : {SliceAxis::Axial, SliceAxis::Coronal, SliceAxis::Sagittal}) {
    const auto [u, v, n] = kAxes[axis_number(axis)];
    Slice& s = frame->slices[axis_number(axis)];
    s.width_vox = frame->dims[u];
    s.height_vox = frame->dims[v];
    s.u_mm = frame->spacing_mm[u];
    s.v_mm = frame->spacing_mm[v];
    s.pixels.resize(static_cast<std::size_t>(s.width_vox) * s.height_vox);
    volume::Vec3i ijk = frame->seed_index;
    for (int y = 0; y < s.height_vox; ++y) {
      for (int x = 0; x < s.width_vox; ++x) {
        ijk[u] = x;
        ijk[v] = y;
        s.pixels[static_cast<std::size_t>(y) * s.width_vox + x] =
            input.value(ijk.x(), ijk.y(), ijk.z());
      }
    }
    all.insert(all.end(), s.pixels.begin(), s.pixels.end());
    s.contour = mesh_contour(mesh_mm, input, axis, static_cast<float>(frame->seed_index[n]));
  }
  // Window: 1st to 99th percentile of the three slices, so one bright speck does not grey out
  // the rest.
  if (!all.empty()) {
    const std::size_t lo = all.size() / 100, hi = all.size() - 1 - all.size() / 100;
    std::nth_element(all.begin(), all.begin() + lo, all.end());
    frame->low = all[lo];
    std::nth_element(all.begin(), all.begin() + hi, all.end());
    frame->high = std::max(all[hi], frame->low + 1e-3f);
  }
  std::lock_guard lock(mutex_);
  frame_ = std::move(frame);
}

std::string SliceRenderer::encode(const Frame& frame, const Slice& slice, SliceAxis axis) {
  cv::Mat gray(slice.height_vox, slice.width_vox, CV_8U);
  const float scale = 255.0f / (frame.high - frame.low);
  for (int y = 0; y < slice.height_vox; ++y) {
    const int row = flips_v(axis) ? slice.height_vox - 1 - y : y;
    for (int x = 0; x < slice.width_vox; ++x) {
      const float g =
          (slice.pixels[static_cast<std::size_t>(y) * slice.width_vox + x] - frame.low) * scale;
      gray.at<std::uint8_t>(row, x) = cv::saturate_cast<std::uint8_t>(g);
    }
  }
  // One pixel scale for all three slices: the largest physical extent maps to kTargetEdgePx.
  const volume::Vec3f extent = frame.dims.cast<float>().cwiseProduct(frame.spacing_mm);
  const float px_per_mm = kTargetEdgePx / std::max(1e-6f, extent.maxCoeff());
  const int out_w =
      std::max(1, static_cast<int>(std::lround(slice.width_vox * slice.u_mm * px_per_mm)));
  const int out_h =
      std::max(1, static_cast<int>(std::lround(slice.height_vox * slice.v_mm * px_per_mm)));
  cv::Mat big, bgr;
  cv::resize(gray, big, cv::Size(out_w, out_h), 0, 0, cv::INTER_LINEAR);
  cv::cvtColor(big, bgr, cv::COLOR_GRAY2BGR);
  const float sx = static_cast<float>(out_w) / slice.width_vox;
  const float sy = static_cast<float>(out_h) / slice.height_vox;
  constexpr int kShift = 4;  // sub-pixel drawing: coordinates in 1/16 pixel
  auto to_px = [&](const SlicePoint& p) {
    const float v = flips_v(axis) ? slice.height_vox - 1 - p.v : p.v;
    return cv::Point(static_cast<int>(std::lround((p.u + 0.5f) * sx * (1 << kShift))),
                     static_cast<int>(std::lround((v + 0.5f) * sy * (1 << kShift))));
  };
  for (const SliceSegment& s : slice.contour) {
    cv::line(bgr, to_px(s.a), to_px(s.b), kContourBgr, 2, cv::LINE_AA, kShift);
  }
  const auto [u, v, n] = kAxes[axis_number(axis)];
  const cv::Point seed =
      to_px({static_cast<float>(frame.seed_index[u]), static_cast<float>(frame.seed_index[v])});
  cv::drawMarker(bgr, cv::Point(seed.x >> kShift, seed.y >> kShift), kSeedBgr, cv::MARKER_CROSS, 14,
                 1, cv::LINE_AA);
  return internal::encode_png_bgr(bgr.data, bgr.cols, bgr.rows, bgr.step);
}

std::optional<std::string> SliceRenderer::png(SliceAxis axis) {
  std::shared_ptr<Frame> frame;
  {
    std::lock_guard lock(mutex_);
    frame = frame_;
    if (!frame) return std::nullopt;
    if (!frame->png[axis_number(axis)].empty()) return frame->png[axis_number(axis)];
  }
  // Encoded outside the lock (a few ms); two requests racing both encode, the same bytes.
  std::string bytes = encode(*frame, frame->slices[axis_number(axis)], axis);
  std::lock_guard lock(mutex_);
  frame->png[axis_number(axis)] = bytes;
  return bytes;
}

nlohmann::json SliceRenderer::info() const {
  std::shared_ptr<Frame> frame;
  {
    std::lock_guard lock(mutex_);
    frame = frame_;
  }
  if (!frame) return nullptr;
  auto vec = [](const auto& v) { return nlohmann::json{v[0], v[1], v[2]}; };
  nlohmann::json j = {
      {"sequence", frame->sequence},
      {"dims", vec(frame->dims)},
      {"spacing_mm", vec(frame->spacing_mm)},
      {"origin_mm", vec(frame->origin_mm)},
      {"direction", std::vector<float>(frame->direction.data(), frame->direction.data() + 9)},
      {"seed_index", vec(frame->seed_index)}};
  for (SliceAxis axis : {SliceAxis::Axial, SliceAxis::Coronal, SliceAxis::Sagittal}) {
    const auto [u, v, n] = kAxes[axis_number(axis)];
    j["slices"][to_string(axis)] = {
        {"u_axis", u}, {"v_axis", v}, {"plane_axis", n}, {"v_up", flips_v(axis)}};
  }
  return j;
}

}  // namespace sonomesh::daemon
