// Filling the surface's tunnels through the target's own darkness (reconstruct.h).
#include <algorithm>
#include <array>
#include <bit>
#include <cstdint>
#include <limits>
#include <vector>

#include "mesh/parallel.h"
#include "reconstruct/reconstruct.h"

namespace sonomesh::reconstruct {
namespace {

using volume::Vec3i;

// The box's cells as bytes, 1 where χ is inside: every slice reads it (its rows one byte per
// cell rather than a float), and a filled cell is set in it so the next axis sees the fill.
struct InsideMask {
  Vec3i lo, dims;
  std::vector<std::uint8_t> inside;

  InsideMask(const volume::Volume& chi, float iso, const Vec3i& lo_cell, const Vec3i& hi_cell)
      : lo(lo_cell), dims(hi_cell - lo_cell + Vec3i::Ones()), inside(cells(), 0) {
    for (int k = 0; k < dims.z(); ++k)
      for (int j = 0; j < dims.y(); ++j) {
        const float* row = &chi.f32()[chi.linear_index(lo.x(), lo.y() + j, lo.z() + k)];
        std::uint8_t* out = &inside[at(Vec3i(0, j, k))];
        for (int i = 0; i < dims.x(); ++i) out[i] = row[i] > iso;
      }
  }
  std::size_t cells() const {
    return static_cast<std::size_t>(dims.x()) * dims.y() * static_cast<std::size_t>(dims.z());
  }
  std::size_t at(const Vec3i& d) const {  // d from the box's corner
    return (static_cast<std::size_t>(d.z()) * dims.y() + d.y()) * dims.x() + d.x();
  }
};

// A run of outside cells along one row of a slice, and its union-find parent among the slice's
// runs; `border` on a root: its region reaches the slice's edge.
struct Run {
  int row, first, last;
  int parent;
  bool border;
};

int root(std::vector<Run>& runs, int r) {
  while (runs[r].parent != r) r = runs[r].parent = runs[runs[r].parent].parent;
  return r;
}

void join(std::vector<Run>& runs, int a, int b) {
  a = root(runs, a);
  b = root(runs, b);
  if (a == b) return;
  runs[b].parent = a;
  runs[a].border = runs[a].border || runs[b].border;
}

// The holes of the slice across `axis` at box coordinate `s`: its outside cells (4-connected)
// that do not reach the box's edge, each hole as its grid cells. The slice is read as runs of
// outside cells along its rows (x where the slice has it: the mask's contiguous axis), and the
// runs of neighbouring rows that overlap are joined: a row crosses the surface a few times, so
// the work is the mask's bytes and a few runs per row, not a flood over every outside cell.
std::vector<std::vector<Vec3i>> slice_holes(const InsideMask& mask, int axis, int s,
                                            std::vector<Run>& runs) {
  const int along = axis == 0 ? 1 : 0, across = axis == 2 ? 1 : 2;
  const int n_along = mask.dims[along], n_rows = mask.dims[across];
  const std::ptrdiff_t step = along == 0 ? 1 : mask.dims.x();
  runs.clear();
  std::size_t row_begin = 0;
  for (int row = 0; row < n_rows; ++row) {
    Vec3i d = Vec3i::Zero();
    d[axis] = s;
    d[across] = row;
    const std::uint8_t* cell = &mask.inside[mask.at(d)];
    const std::size_t this_row = runs.size();
    for (int c = 0; c < n_along;) {
      if (cell[c * step]) {
        ++c;
        continue;
      }
      const int first = c;
      while (c < n_along && !cell[c * step]) ++c;
      const int id = static_cast<int>(runs.size());
      runs.push_back(
          {row, first, c - 1, id, row == 0 || row == n_rows - 1 || first == 0 || c == n_along});
    }
    // Runs of the row before that overlap one of this row's (both lists are in order).
    for (std::size_t a = row_begin, b = this_row; a < this_row && b < runs.size();) {
      if (runs[a].first <= runs[b].last && runs[b].first <= runs[a].last)
        join(runs, static_cast<int>(a), static_cast<int>(b));
      (runs[a].last < runs[b].last ? a : b)++;
    }
    row_begin = this_row;
  }
  std::vector<std::vector<Vec3i>> holes;
  std::vector<int> hole_of(runs.size(), -1);
  for (std::size_t r = 0; r < runs.size(); ++r) {
    const int top = root(runs, static_cast<int>(r));
    if (runs[top].border) continue;
    if (hole_of[top] < 0) {
      hole_of[top] = static_cast<int>(holes.size());
      holes.emplace_back();
    }
    for (int c = runs[r].first; c <= runs[r].last; ++c) {
      Vec3i cell = mask.lo;
      cell[axis] += s;
      cell[across] += runs[r].row;
      cell[along] += c;
      holes[hole_of[top]].push_back(cell);
    }
  }
  return holes;
}

// The inside cells' box grown by one cell (clipped to the grid): outside it nothing is enclosed,
// and its rim is outside. Empty (lo > hi) when nothing is inside.
std::pair<Vec3i, Vec3i> inside_box(const volume::Volume& chi, float iso) {
  Vec3i lo = chi.dims(), hi = Vec3i::Constant(-1);
  const int nx = chi.dims().x();
  const float* row = chi.f32().data();
  for (int k = 0; k < chi.dims().z(); ++k)
    for (int j = 0; j < chi.dims().y(); ++j, row += nx) {
      // A row's first and last inside cell (rows are read as they lie in memory).
      int first = 0, last = nx - 1;
      while (first < nx && !(row[first] > iso)) ++first;
      if (first == nx) continue;
      while (!(row[last] > iso)) --last;
      lo = lo.cwiseMin(Vec3i(first, j, k));
      hi = hi.cwiseMax(Vec3i(last, j, k));
    }
  return {(lo - Vec3i::Ones()).cwiseMax(Vec3i::Zero()),
          (hi + Vec3i::Ones()).cwiseMin(chi.dims() - Vec3i::Ones())};
}

// The brightest the image gets over the cells: a needle's tunnel holds the needle, a false one
// nothing brighter than the inside.
float max_image(const volume::Volume& chi, const volume::Volume& image,
                const std::vector<Vec3i>& cells) {
  float brightest = -std::numeric_limits<float>::infinity();
  for (const Vec3i& c : cells)
    brightest = std::max(brightest, volume::sample_mm(image, chi.index_to_mm(c.cast<float>())));
  return brightest;
}

// The closing's half-width in χ cells: a handle through the target's darkness up to twice this
// across is closed (the false one seen beside a needle was 4-7 cells across); a torus's hole
// holds tissue, bright, and stays whatever its width.
constexpr int kClosingCells = 4;
// The half-widths for a sheet where the balloon's fronts met, a few cells thick: the narrower
// first, as a wider closing also fills more of the wall's concave places, which can make a new
// handle (docs/stopping.md item 11).
constexpr std::array<int, 2> kSheetCells{2, kWidestSheetCells};

// A box of cells as bits, 64 along x per word, each (y, z) row starting a word; cells beyond the
// box are 0. The closing's passes then take 64 cells per operation.
class BitBox {
 public:
  explicit BitBox(const Vec3i& dims)
      : dims_(dims), words_((dims.x() + 63) / 64), bits_(row(0, dims.z()), 0) {}
  void set(int i, int j, int k) { bits_[row(j, k) + i / 64] |= std::uint64_t{1} << (i % 64); }
  // f(i, j, k) for each cell set here and not in `other` (a box of the same dims).
  template <typename F>
  void for_each_not_in(const BitBox& other, F&& f) const {
    for (int k = 0; k < dims_.z(); ++k)
      for (int j = 0; j < dims_.y(); ++j)
        for (int w = 0; w < words_; ++w)
          for (std::uint64_t v = bits_[row(j, k) + w] & ~other.bits_[row(j, k) + w]; v; v &= v - 1)
            f(64 * w + std::countr_zero(v), j, k);
  }
  // Each cell the OR (dilate) or AND (erode) of the cells within r of it along every axis in
  // turn: a cube of half-width r.
  void dilate(int r) {
    for (int axis = 0; axis < 3; ++axis) pass(axis, r, true);
  }
  void erode(int r) {
    for (int axis = 0; axis < 3; ++axis) pass(axis, r, false);
  }

 private:
  std::size_t row(int j, int k) const {
    return (static_cast<std::size_t>(k) * dims_.y() + j) * words_;
  }
  // Row `from` (words_ words) shifted by d cells along x (d > 0: towards larger x), 0 shifted in.
  void shifted(const std::uint64_t* from, int d, std::uint64_t* to) const {
    for (int w = 0; w < words_; ++w) {
      std::uint64_t v = 0;
      if (d > 0) {
        v = from[w] << d;
        if (w > 0) v |= from[w - 1] >> (64 - d);
      } else {
        v = from[w] >> -d;
        if (w + 1 < words_) v |= from[w + 1] << (64 + d);
      }
      to[w] = v;
    }
  }
  void pass(int axis, int r, bool dilate) {
    const std::vector<std::uint64_t> in = bits_;
    std::vector<std::uint64_t> other(static_cast<std::size_t>(words_));
    for (int k = 0; k < dims_.z(); ++k)
      for (int j = 0; j < dims_.y(); ++j) {
        std::uint64_t* out = &bits_[row(j, k)];
        for (int d = -r; d <= r; ++d) {
          if (d == 0) continue;
          const std::uint64_t* from = other.data();
          if (axis == 0) {
            shifted(&in[row(j, k)], d, other.data());
          } else {
            const int jj = axis == 1 ? j + d : j, kk = axis == 2 ? k + d : k;
            const bool inside = jj >= 0 && jj < dims_.y() && kk >= 0 && kk < dims_.z();
            if (inside)
              from = &in[row(jj, kk)];
            else
              std::fill(other.begin(), other.end(), 0);
          }
          for (int w = 0; w < words_; ++w) out[w] = dilate ? out[w] | from[w] : out[w] & from[w];
        }
        if (dims_.x() % 64) out[words_ - 1] &= (std::uint64_t{1} << dims_.x() % 64) - 1;
      }
  }

  Vec3i dims_;
  int words_;
  std::vector<std::uint64_t> bits_;
};

// Marching cubes and the seed's component again on χ as `filled` left it: kept, returning true,
// where that lowered the genus and the surface is closed and encloses the seed; else χ is given
// back.
bool remesh_if_fewer_handles(SurfaceResult& surface, const Vec3f& seed_mm,
                             const std::vector<FilledCell>& filled) {
  volume::Volume& chi = surface.indicator;
  if (filled.empty()) return false;
  bool enclosed = false;
  Mesh mesh = mesh::component_enclosing(marching_cubes(chi, surface.iso), seed_mm, &enclosed);
  const Topology topology = analyze_topology(mesh);
  if (!enclosed || topology.genus >= surface.topology.genus || !topology.watertight) {
    for (const FilledCell& cell : filled) chi.f32()[cell.index] = cell.was;
    return false;
  }
  surface.mesh = std::move(mesh);
  surface.topology = topology;
  return true;
}

}  // namespace

std::vector<FilledCell> fill_dark_tunnels(volume::Volume& chi, float iso, float inside_value,
                                          const volume::Volume& image, float dark_below,
                                          int threads) {
  std::vector<FilledCell> filled;
  const std::pair<Vec3i, Vec3i> box = inside_box(chi, iso);
  const Vec3i lo = box.first, hi = box.second;  // (a lambda cannot capture structured bindings)
  if ((hi - lo).minCoeff() < 0) return filled;
  InsideMask mask(chi, iso, lo, hi);
  mesh::Workers workers(threads);
  // The slices across one axis hold disjoint cells, so they are filled in parallel; an axis
  // sees what the axes before it filled. Each chunk's cells are appended in chunk order.
  std::vector<std::vector<FilledCell>> by_chunk(static_cast<std::size_t>(workers.threads()));
  for (int axis = 0; axis < 3; ++axis) {
    workers.parallel_chunks(0, mask.dims[axis], [&](int first, int last, int chunk) {
      std::vector<FilledCell>& mine = by_chunk[static_cast<std::size_t>(chunk)];
      std::vector<Run> runs;
      for (int s = first; s < last; ++s)
        for (const auto& hole : slice_holes(mask, axis, s, runs)) {
          if (max_image(chi, image, hole) >= dark_below) continue;
          for (const Vec3i& c : hole) {
            const std::size_t at = chi.linear_index(c.x(), c.y(), c.z());
            mine.push_back({at, chi.f32()[at]});  // (outside: below iso < inside_value)
            chi.f32()[at] = inside_value;
            mask.inside[mask.at(c - lo)] = 1;
          }
        }
    });
    for (std::vector<FilledCell>& mine : by_chunk) {
      filled.insert(filled.end(), mine.begin(), mine.end());
      mine.clear();
    }
  }
  return filled;
}

std::vector<FilledCell> fill_dark_closing(volume::Volume& chi, float iso, float inside_value,
                                          const volume::Volume& image, float dark_below,
                                          int half_width_cells) {
  std::vector<FilledCell> filled;
  const std::pair<Vec3i, Vec3i> box = inside_box(chi, iso);
  const Vec3i lo = (box.first - Vec3i::Constant(half_width_cells)).cwiseMax(Vec3i::Zero());
  const Vec3i hi =
      (box.second + Vec3i::Constant(half_width_cells)).cwiseMin(chi.dims() - Vec3i::Ones());
  if ((hi - lo).minCoeff() < 0) return filled;
  BitBox inside(hi - lo + Vec3i::Ones());
  for (int k = lo.z(); k <= hi.z(); ++k)
    for (int j = lo.y(); j <= hi.y(); ++j)
      for (int i = lo.x(); i <= hi.x(); ++i)
        if (chi.f32()[chi.linear_index(i, j, k)] > iso)
          inside.set(i - lo.x(), j - lo.y(), k - lo.z());
  BitBox closed = inside;
  closed.dilate(half_width_cells);
  closed.erode(half_width_cells);
  closed.for_each_not_in(inside, [&](int i, int j, int k) {
    const Vec3i cell = lo + Vec3i(i, j, k);
    if (volume::sample_mm(image, chi.index_to_mm(cell.cast<float>())) >= dark_below) return;
    const std::size_t c = chi.linear_index(cell.x(), cell.y(), cell.z());
    filled.push_back({c, chi.f32()[c]});
    chi.f32()[c] = inside_value;
  });
  return filled;
}

bool close_dark_tunnels(SurfaceResult& surface, const Vec3f& seed_mm, const volume::Volume& image,
                        const TunnelLevels& levels, int threads) {
  if (surface.topology.genus <= 0 || surface.indicator.empty()) return false;
  volume::Volume& chi = surface.indicator;
  const float at_seed = volume::sample_mm(chi, seed_mm);
  if (!(at_seed > surface.iso)) return false;
  const float inside_value = 0.5f * (surface.iso + at_seed);
  // χ is filled in place and given back unless the genus fell (no copy of the grid per volume).
  if (remesh_if_fewer_handles(
          surface, seed_mm,
          fill_dark_tunnels(chi, surface.iso, inside_value, image, levels.dark_below, threads)))
    return true;
  // More than one handle: one of them may be a dark tunnel running obliquely, which no slice
  // across an axis cuts into a closed hole (a single needle's tunnel is the common case, and
  // its own gap is not worth the closing's passes). The closing also takes in the concave
  // places the surface passes, on the wall's flank: it asks for darkness half way from the
  // target's level to `dark_below`, which the flank does not reach.
  if (surface.topology.genus < 2) return false;
  const float closing_below = 0.5f * (levels.target_level + levels.dark_below);
  if (remesh_if_fewer_handles(
          surface, seed_mm,
          fill_dark_closing(chi, surface.iso, inside_value, image, closing_below, kClosingCells)))
    return true;
  // Or a sheet of outside where the fronts met round a needle, from its tunnel to the wall: its
  // cells are the inside's, on the grains where the balloon stopped, so only the tissue's level
  // tells them from a needle's echo.
  if (!levels.sheet_below) return false;
  for (const int half_width : kSheetCells)
    if (half_width <= levels.widest_sheet_cells &&
        remesh_if_fewer_handles(surface, seed_mm,
                                fill_dark_closing(chi, surface.iso, inside_value, image,
                                                  *levels.sheet_below, half_width)))
      return true;
  return false;
}

}  // namespace sonomesh::reconstruct
