#pragma once
/// @file
/// @brief Synthetic ultrasound phantoms with ground truth: what a probe would deliver.

#include <cstdint>
#include <string>
#include <vector>

#include "acquire/raw_volume.h"
#include "volume/volume.h"

namespace sonomesh::sim {

using volume::Vec3f;
using volume::Vec3i;

/// How the image is rendered from the same geometry and truth.
/// - Simple: the whole cube is tissue, the target darker by the contrast, mild speckle, attenuation
///   along z. The original model; its bytes do not change.
/// - Echo: what a 3D echo probe shows (sim/internal/echo.h): a pyramidal sector from an apex above
///   the volume with zeros outside it, fully developed speckle of a set grain in tissue and blood
///   pool alike (the cavity's echo is (1 - contrast) of the tissue's, not black), near-field
///   clutter, wall dropout where the wall runs along the beam and a specular echo where it faces
///   it, attenuation along the beam with an imperfect time-gain compensation, electronic noise, the
///   needle's shadow along the beam, and for the LV a brighter myocardium and a valve-plane echo.
enum class Realism { Simple, Echo };

/// "simple" or "echo". @throws std::invalid_argument naming the value otherwise.
Realism parse_realism(const std::string& name);
const char* to_string(Realism realism);

/// Parameters of a synthetic volume. Defaults give a typical speckled hypoechoic target.
struct PhantomSpec {
  // sphere | ellipsoid | torus | cyst-needle | double-torus | lv (an apical view's left ventricle:
  // elongated, trabeculated uneven wall, apex towards the probe, base closed by a valve plane)
  std::string phantom = "sphere";
  int size_vox = 64;  // edge of the cubic volume, voxels
  Vec3f spacing_mm{0.5f, 0.5f, 0.5f};
  float contrast = 0.7f;               // 1 - target_mean / tissue_mean: 0 invisible, 1 black target
  float speckle = 0.5f;                // speckle strength, 0 = none
  float attenuation_db_per_cm = 0.5f;  // attenuation with depth (z) in dB/cm (round trip)
  std::uint32_t seed = 1;              // random seed: same seed, same bytes
  float time_s = 0.0f;           // breathing phase for streamed phantoms: moves/deforms a little
  Vec3f axis{0.0f, 0.0f, 1.0f};  // orientation of the torus / ellipsoid / cyst major axis
  // Direction the biopsy needle points (cyst-needle only), from entry towards its tip. Default:
  // 30 degrees below lateral, as a needle guided into the beam; a needle along the beam (z) would
  // cast its shadow into itself and show nothing a probe could see.
  Vec3f needle_axis{0.866f, 0.0f, 0.5f};
  // cyst-needle only: false leaves the needle out (withdrawn, or not yet inserted): the cyst
  // alone, genus 0. A stream switches it at some volume to change the topology.
  bool needle = true;
  // cyst-needle only: how far the needle reaches, as a share of its full reach past its point
  // nearest the cyst's centre. 1: through the cyst and out (genus 1); 0: withdrawn half-way,
  // its tip in the cyst's middle (a dent, genus 0); in [-1, 1].
  float needle_reach = 1.0f;
  Realism realism = Realism::Simple;
  // Echo only: speckle grain, the Gaussian sigma in mm of the speckle's lateral correlation (axial:
  // half of it, as a pulse is shorter than a beam is wide). Simple mode uses 1.0/0.6 voxel.
  float speckle_mm = 0.6f;
  // The grid lies obliquely in the world: image and truth get direction oblique_direction()
  // (about the origin, volume::Volume::grid_to_world_mm). Voxels and truth are unchanged.
  bool oblique = false;
};

/// The fixed rotation of PhantomSpec::oblique: 30 degrees about x, then 20 degrees about z (LPS).
volume::Mat3f oblique_direction();

/// The echo preset: realism Echo, fully developed speckle (1) and 3 dB/cm round-trip attenuation
/// (soft tissue at ~3 MHz), the other fields as given.
PhantomSpec with_echo_realism(PhantomSpec spec);

/// A phantom: the image a probe would deliver and its ground truth.
struct Phantom {
  volume::Volume image;  // UInt8, the ultrasound-like image
  volume::Volume truth;  // UInt8 labels on the same grid, inside the target = 1
  std::string name;
  int genus = 0;                     // topology of the target surface
  Vec3i seed_index = Vec3i::Zero();  // a voxel well inside the target
  Vec3f seed_mm = Vec3f::Zero();     // the same point in mm, grid frame (image.index_to_mm)
};

/// Names accepted in PhantomSpec::phantom.
const std::vector<std::string>& phantom_names();

/// Builds a phantom. Deterministic in the spec: the same spec gives the same bytes.
///
/// Grid: size_vox^3 voxels, origin 0 (z = 0 is the transducer face, the beam runs along +z).
/// Shapes are sized relative to the volume, centred, and keep >= 3 voxels from the border at any
/// time_s; thin parts (torus tube, needle tunnel) are resolved so the truth has exactly the stated
/// genus for size_vox >= 48 (tested 48..256, any axis). Image: tissue ~120 grey levels at mid
/// depth, target (1 - contrast) times that, Rayleigh speckle, depth attenuation, and for
/// cyst-needle a bright needle with an acoustic shadow below it. time_s: breathing with a 4 s
/// period (a shift of ~0.08 of the half extent, +-3 % scale), the speckle stays put. The first call
/// for a new (seed, size) builds the speckle field; later calls reuse it (one field is cached).
/// seed_index is the deepest target voxel (largest distance to the boundary, so away from the
/// needle).
/// @throws std::invalid_argument naming the field for an unknown phantom, a size outside 16..512,
/// non-positive spacing, contrast/speckle outside [0, 1], speckle_mm outside [0.1, 5] (echo), or a
/// zero axis. In echo mode the truth is the same as in simple mode (same spec, same labels).
Phantom make_phantom(const PhantomSpec& spec);

/// The phantom's image as a probe record (sequence and timestamp as given; direction and origin
/// from the volume). UInt8 and UInt16 volumes only. @throws std::invalid_argument for a Float32
/// volume.
acquire::RawVolume to_raw(const volume::Volume& image, std::uint64_t sequence,
                          std::uint64_t timestamp_ns);

}  // namespace sonomesh::sim
