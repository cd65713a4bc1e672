#pragma once
/// @file
/// @brief Second step of the two-step segmentation (method.md §4-6): opening the balloon at its
/// self-intersections, Kazhdan's FFT reconstruction of an indicator function from oriented points
/// (Kazhdan, SGP 2005), marching cubes, the component around the seed, topology checks, label
/// volumes (the mesh types, topology and files are mesh/mesh.h).
///
/// Positions are in millimetres throughout. Caller bugs (mismatched array lengths, indices out of
/// range, bad options) throw std::invalid_argument naming the argument; numerical outcomes (seed
/// not enclosed, open mesh) are reported in result structs; file errors are returned as values.

#include <array>
#include <cstdint>
#include <filesystem>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "mesh/mesh.h"
#include "volume/volume.h"

namespace sonomesh::reconstruct {

// The mesh types, topology, normals and files live in mesh/ and keep their reconstruct:: names.
using mesh::analyze_topology;
using mesh::component_enclosing;
using mesh::connected_components;
using mesh::enclosed_volume_ml;
using mesh::encloses;
using mesh::Mesh;
using mesh::MeshIoError;
using mesh::MeshReadResult;
using mesh::oriented_samples;
using mesh::PointCloud;
using mesh::read_ply;
using mesh::StopReason;
using mesh::Topology;
using mesh::write_balloon_ply;
using mesh::write_mesh;
using mesh::write_obj;
using mesh::write_ply;
using mesh::write_stl;
using volume::Vec3f;

// ---------------------------------------------------------------------------------------------
// Oriented samples.

/// Opening (method.md §4, paper §4 "Opening of mesh for topology adaption"): marks the triangles
/// that touch a SelfIntersection ("type 1") vertex, recomputes the normal of every vertex of a
/// marked triangle from its unmarked triangles only (normalised sum of unit triangle normals,
/// eq. 2), and deletes the marked triangles and the type-1 vertices. Returns the remaining
/// vertices with outward unit normals and area weights (one third of the area of the adjacent
/// remaining triangles). Vertices left without any triangle are dropped (they have no normal).
/// @throws std::invalid_argument if stop.size() != balloon.vertices.size() or a triangle indexes
///         a vertex that does not exist.
PointCloud open_balloon(const Mesh& balloon, const std::vector<StopReason>& stop);

// ---------------------------------------------------------------------------------------------
// Kazhdan's FFT reconstruction.

/// How the divergence of the splatted normal field is formed.
enum class DivergenceMode : std::uint8_t {
  Spectral,          // three forward FFTs of the splatted field, i k·V̂ exactly (most accurate)
  CentralDifference  // central-difference divergence on the grid, one forward FFT (faster)
};

struct PoissonOptions {
  float cell_mm = 0.5f;            // grid cell edge; pass the volume's voxel size
  float padding_fraction = 0.15f;  // margin per side, fraction of the largest extent; >= 0.10
  float smoothing_cells = 1.0f;    // Gaussian sigma applied to the splatted normals, in cells
  // Thin features. The trilinear splat and the Gaussian blur χ over ~2.5 cells (full width at half
  // maximum, smoothing_cells = 1): a gap or a solid about that narrow is lost (a needle's tunnel
  // closes, a thin tube pinches off). The cell shrinks below cell_mm until the narrowest feature
  // of the samples (narrowest_feature_mm, counted once it covers 8 cells² of cell_mm) spans this
  // many cells. At 4, χ on the axis of a round tunnel is ~0.2 of its inside value, clear of the
  // iso-value (~0.5) with room for sparse samples. Raise it with smoothing_cells. 0 = always
  // cell_mm, the default: the finer grid also keeps the small gaps the opening leaves where a
  // balloon's fronts met off the tunnel, as extra handles (docs/tuning.md).
  float min_feature_cells = 0.0f;
  float min_cell_fraction = 1.0f / 3.0f;  // the thin-feature cell stops at this fraction of
                                          // cell_mm (so at most 27x the cells), in [0.1, 1]
  int max_grid_dim = 256;  // the cell grows when an axis would need more cells than this
  int fft_threads = 2;     // FFTW threads (the target machine has two cores)
  DivergenceMode divergence = DivergenceMode::Spectral;
  bool measure_fft_plans = false;  // FFTW_MEASURE: slow first plan per grid size, faster after
};

/// The indicator function χ on the FFT grid: larger inside than outside, the surface is χ = iso.
struct IndicatorGrid {
  volume::Volume chi;    // Float32; origin/spacing of the FFT grid (write with volume::write_vdb)
  float iso = 0.0f;      // area-weighted mean of χ at the sample positions
  float cell_mm = 0.0f;  // the cell actually used: options.cell_mm, finer for a thin feature,
                         // coarser where max_grid_dim forced it
  float feature_mm = std::numeric_limits<float>::infinity();  // narrowest feature found; infinity:
                                                              // none within min_feature_cells ·
                                                              // cell_mm (or the search is off)
};

/// Narrowest feature the oriented samples describe, in mm. A sample's local width is the distance
/// along its normal to the nearest sample that faces it across empty space (a gap: the tunnel of a
/// needle through a cyst) or backs onto it across the solid (a thin tube), counting only pairs
/// with roughly opposite normals that each lie within the other's normal cone (half-angle ~27°),
/// so that the walls of a wedge, which meet at an edge, mostly do not count. The result is the
/// smallest width w whose samples (local width <= w) carry at least min_area_mm2 of area, or
/// +infinity if no width up to max_width_mm does. On a round feature the nearest partner may sit
/// off the diameter: the width is then 80-100 % of the diameter. Cost: near-linear (a bucket grid
/// of max_width_mm), both cores; ~2 ms for 5000 samples.
/// @throws std::invalid_argument on mismatched arrays, non-finite samples, max_width_mm <= 0 or a
///         negative min_area_mm2.
float narrowest_feature_mm(const PointCloud& samples, float max_width_mm, float min_area_mm2);

/// Solves Δχ = ∇·V for the area-weighted, Gaussian-smoothed normal field V by FFT (Kazhdan 2005):
/// χ̂(k) = i k·V̂(k) / |k|², χ̂(0) = 0, sign chosen so that χ is larger inside. The grid is the
/// bounding box of the points padded by options.padding_fraction on each side, its dimensions
/// rounded up to 2^a 3^b 5^c, its cell options.cell_mm or finer where a thin feature needs it
/// (PoissonOptions::min_feature_cells). FFTW plans are cached per grid size (thread-safe).
/// @throws std::invalid_argument on empty or mismatched arrays, non-finite samples, or options
///         out of range (cell_mm <= 0, padding_fraction < 0.1, smoothing_cells < 0, ...).
IndicatorGrid poisson_indicator(const PointCloud& samples, const PoissonOptions& options = {});

// ---------------------------------------------------------------------------------------------
// Marching cubes and mesh analysis.

/// Marching cubes (Lorensen & Cline 1987) on a Float32 volume; inside is field > iso. Ambiguous
/// faces are resolved by the asymptotic decider from the face's own four values, so neighbouring
/// cubes agree and the mesh is watertight; one vertex per grid edge (welded, indexed). Grid
/// border samples count as outside, so the result is always closed. Triangles are oriented
/// outward (counter-clockwise seen from outside). Uses two threads.
/// @throws std::invalid_argument if the volume is not Float32 or has fewer than 2 samples per axis.
Mesh marching_cubes(const volume::Volume& field, float iso);

// ---------------------------------------------------------------------------------------------
// The whole second step.

struct SurfaceResult {
  Mesh mesh;                 // the component around the seed, outward, in mm
  Topology topology;         // of `mesh`
  volume::Volume indicator;  // χ on the FFT grid (Float32)
  float iso = 0.0f;
  float cell_mm = 0.0f;
  float feature_mm = std::numeric_limits<float>::infinity();  // as IndicatorGrid::feature_mm
  std::array<int, 3> grid_dims{};
  int components_before_selection = 0;  // components marching cubes produced
  bool seed_enclosed = false;           // false: fell back to the largest component
  double reconstruct_ms = 0.0;          // splat + FFT solve + iso
  double mesh_ms = 0.0;                 // marching cubes + component selection
};

/// poisson_indicator, marching_cubes on χ − iso, then the component that encloses the seed.
/// @throws std::invalid_argument as poisson_indicator does.
SurfaceResult reconstruct_surface(const PointCloud& samples, const Vec3f& seed_mm,
                                  const PoissonOptions& options = {});

/// Beyond the paper (issue 15): where the balloon's sheets met round a stretch of the target's
/// own inside, the reconstruction has a tunnel no wall explains (a false handle). In every slice
/// of χ across each axis, an outside region enclosed by inside cells (a tunnel's or a void's
/// cross-section) where the image nowhere reaches `dark_below` is set to `inside_value`.
/// Returns the cells filled with their values before, so a caller can give them back. With
/// `dark_below` under the tissue's level, a tunnel round a needle or through a torus' hole (as
/// bright as tissue) stays; a level above the tissue's fills tunnels round columns of tissue.
/// The slices across an axis are scanned on `threads` workers (0: all hardware threads).
struct FilledCell {
  std::size_t index;  // linear index in χ
  float was;          // χ there before
};
std::vector<FilledCell> fill_dark_tunnels(volume::Volume& chi, float iso, float inside_value,
                                          const volume::Volume& image, float dark_below,
                                          int threads = 0);

/// The same for a tunnel through the dark that no slice across an axis cuts into a closed hole
/// (one running obliquely): the outside cells the inside closed by a cube of `half_width_cells`
/// (dilated, then eroded) takes in, where the image there is under `dark_below`.
std::vector<FilledCell> fill_dark_closing(volume::Volume& chi, float iso, float inside_value,
                                          const volume::Volume& image, float dark_below,
                                          int half_width_cells);

/// The image's levels close_dark_tunnels fills under.
struct TunnelLevels {
  float dark_below;    // a slice's hole whose cells are all under it
  float target_level;  // the target's own (e.g. the balloon's seed region's)
  // A thin sheet's cells under it (the tissue's level); none: no sheet is sought.
  std::optional<float> sheet_below;
  // The sheet's closing goes up to this half-width (2 or kWidestSheetCells): the wider one also
  // takes in a double torus's narrow hole, so a caller asks for it where a needle was seen.
  int widest_sheet_cells = 2;
};
inline constexpr int kWidestSheetCells = 3;

/// fill_dark_tunnels on the surface's χ (`image` the smoothed volume with the target dark), then
/// marching cubes and the seed's component again. On a surface of two handles or more whose
/// genus that did not lower, fill_dark_closing instead with 4 cells' half-width, at the level half
/// way from `target_level` to `dark_below`; then with 2 cells', then up to `widest_sheet_cells` (a
/// sheet a few cells thick where the balloon's fronts met) at `sheet_below` where it is given. Each
/// is kept, returning true, only where it lowered the genus and the surface is closed and encloses
/// the seed; otherwise `surface` is unchanged.
bool close_dark_tunnels(SurfaceResult& surface, const Vec3f& seed_mm, const volume::Volume& image,
                        const TunnelLevels& levels, int threads = 0);

/// Label volume on the grid of `like` (UInt8, same dims/spacing/origin): 1 where the voxel centre
/// is inside the closed mesh, by ray parity along x per (j, k) row. Rays are offset by a tiny,
/// irrational fraction of a voxel so they never pass exactly through mesh vertices or edges.
volume::Volume rasterize_labels(const Mesh& closed_mesh, const volume::Volume& like);

}  // namespace sonomesh::reconstruct
