// The precomputed data of the ROM soft skeleton (ARCHITECTURE.md §4), the third level of the
// avatar build after the template (tet mesh, fields) and the shape (X̄(β), bone nodes,
// materials):
//  - handles: surface soft-tissue nodes chosen by geodesic farthest-point sampling;
//  - basis: bounded biharmonic weights φ_h on the tet mesh at X̄(β), so that the soft-tissue
//    displacement of node j is u_j = Σ_h φ_h(j) z_h (z_h ∈ R³, m, unposed space);
//  - elastic cubature: sample tets and weights w_e ≥ 0 with Σ_{e∈S} w_e Ψ_e ≈ Σ_e Ψ_e for the
//    elastic energy of subspace deformations, and the subspace's exact rest stiffness K (the
//    simulation integrates ½ zᵀKz exactly and the samples' excess over their own rest quadratic:
//    the rest-stiffness split, docs/rom.md);
//  - inertial cubature: sample tets and weights for the lumped-mass kinetic energy of the nodes,
//    Σ_{e∈S} w_e Σ_{a∈e} (m_e/4) ‖v_a‖² ≈ Σ_e Σ_{a∈e} (m_e/4) ‖v_a‖², for velocities made of
//    skinned rigid bone motions plus subspace motions, and for the skeleton's unit articulated
//    motions (each bone turning about its joint, alone and in coupled pairs), so that the bones'
//    rigid inertia comes out right too. Equivalently a sparse set of node masses
//    (inertialNodeMasses).
// Both cubatures are trained without simulation data (random subspace deformations and
// velocities) by Optimized Cubature (cubature.h) and checked on held-out samples (random ones
// only). Everything is
// cached on disk under a key that hashes the shape level's key and these settings.
#pragma once

#include <cstdint>
#include <string>

#include "flsh/core/types.h"
#include "flsh/volume/avatar_cache.h"
#include "flsh/volume/cubature.h"
#include "flsh/volume/modal_basis.h"
#include "flsh/volume/reduced_basis.h"
#include "flsh/volume/volumetric_data.h"

namespace flsh {

/// What spans the reduced soft tissue's displacements (docs/rom.md). The soft state z is the
/// handles' 3-vectors first (3 per handle), then the modal coordinates (one per column).
enum class ReducedBasisKind {
  /// Point handles with bounded biharmonic weights (reduced_basis.h): u_j = Σ_h φ_h(j) z_h.
  Handles,
  /// The avatar's modal basis (modal_basis.h: static-correction and fixed-interface vibration
  /// modes): u_j = Ψ_j z, Ψ_j node j's 3 rows of the 3#N × r basis.
  Modes,
  /// Both, the handles' weights appended to the modes (for local contact): u_j = Σ_h φ_h(j) z_h
  /// + Ψ_j z_modes.
  ModesAndHandles,
};
/// "handles", "modes" or "modes+handles" (the scene file's and `flsh avatar`'s names).
const char* reducedBasisKindName(ReducedBasisKind kind);
/// The kind of a name reducedBasisKindName gives; InputError naming `where` and the known
/// names otherwise.
ReducedBasisKind parseReducedBasisKind(const std::string& name, const std::string& where);

/// The modal basis a ROM avatar uses by default: the static-correction modes of the 144 bone
/// DoFs plus the 24 lowest fixed-interface vibration modes, compressed to 72 columns. It won
/// the speed–accuracy table of docs/benchmarks.md (5 / 11 / 7.5 % off the FEM on walk / jumping
/// jacks / ball, against 64–66 % for 87 handles, at the same steps/s; built in 10–13 s at the
/// default resolution). ModalBasisSettings' own defaults (50 modes, every column) are those of
/// the basis as a standalone tool (computeModalBasis).
ModalBasisSettings defaultReducedModes();

struct ReducedSettings {
  /// Modes by default (docs/rom.md); Handles is the FLSH paper's basis, kept for the control
  /// handles give (and the scene files and `flsh avatar` calls that name handles without a
  /// basis choose it).
  ReducedBasisKind basis_kind = ReducedBasisKind::Modes;
  /// The modal basis of the kinds with modes. Its column count is cut to a multiple of 3 (the
  /// last columns, the least important, go): the simulation groups the modal coordinates in
  /// threes.
  ModalBasisSettings modes = defaultReducedModes();
  int num_handles = 87;  ///< point handles on the surface (≥ 1; kinds with handles)
  /// Sample tets of each cubature (≥ 1); a cubature that is switched off is not built.
  int elastic_cubature_points = 500;
  int inertial_cubature_points = 500;
  /// Random training samples per cubature; a quarter as many (at least 100, at most 200, at most
  /// as many), from another seed, measure the held-out error. 600: with 400 a cubature stops
  /// at ~390 tets whatever count is asked (a fit to 400 rows needs no more), and which tets it
  /// picks moved the default ROM's error against the FEM by ±1 % between bases of the same
  /// quality; with 600 the default (modes 24:72, 500/500) is 4.5–8.9 % off on five motions,
  /// at ~1.3× the build time (docs/benchmarks.md, "The compression's weight of the rotations").
  int training_samples = 600;
  /// Largest handle displacement of an elastic training sample, m (samples spread their
  /// amplitudes from small to this, so that the Fung stiffening is represented).
  double training_amplitude = 0.03;
  std::uint64_t seed = 1;          ///< of the training samples (deterministic)
  BoundedBiharmonicOptions basis;  ///< the QP solver of the weights
  /// Basis entries below this (in [0, 0.01]) are dropped after the solve: the far tails of the
  /// weights, which move a node by at most this fraction of a handle's displacement, cost the
  /// simulation as much as the rest. Measured on the default body: 1e-4 drops 29 % of the
  /// entries (elastic sample tets couple 4.2 instead of 6.6 handles, mass nodes 3.1 instead of
  /// 4.3), see docs/rom.md; 0 keeps every entry above 1e-12. (With surface_partition_of_unity
  /// the weights are dropped before their rows are rescaled.)
  double basis_drop_below = 1e-4;
  /// Off: the bounded biharmonic weights as ARCHITECTURE.md §4 defines them. On:
  /// φ̃_h(j) = f_j φ_h(j) / Σ_k φ_k(j), with f harmonic, 1 on the soft surface and 0 on bone
  /// nodes: a partition of unity on the soft surface (the weights as given fade to 0 towards the
  /// bones between handles: Σ_h φ_h has median 0.27 on the default body's surface), still 0 on
  /// bone nodes, 1 at the own handle, 0 at the others, within [0, 1] (rows no handle reaches stay
  /// 0). With the elastic cubature's rest-stiffness split it halves the displacement error
  /// against the FEM (87 handles: 32 / 57 / 31 % against 68 / 69 / 67 % on walk / jumping jacks /
  /// ball) at the same speed on the walk (about 80 % of it on jumping jacks). See docs/rom.md.
  bool surface_partition_of_unity = false;
};

struct ReducedData {
  ReducedBasisKind basis_kind = ReducedBasisKind::Handles;
  /// The modal columns (kinds with modes; empty otherwise): Ψ, 3#N × r with r a multiple of 3,
  /// node j's rows 3j .. 3j + 2, zero on bone nodes (ModalBasis::basis, its last r mod 3
  /// columns dropped).
  MatX modes;
  VecXi handles;  ///< H tet-node (= surface vertex) indices, farthest-point order (none for Modes)
  /// #N × H (compressed columns), entry (j, h) = φ_h at node j in [0, 1]; bone-node rows are
  /// empty, handle rows are unit vectors. Weights below ReducedSettings::basis_drop_below (and
  /// below 1e-12) are dropped.
  SpMat basis;
  double basis_max_bound_violation = 0;  ///< BoundedBiharmonicReport figures of the solve
  double basis_max_constraint_error = 0;
  bool basis_converged = true;
  /// Elastic cubature (tet indices into the template mesh, ascending, weights > 0); empty when
  /// not built. Held-out relative error of the elastic energy, 0 when not built.
  Cubature elastic;
  double elastic_test_error = 0;
  /// With the elastic cubature, the exact rest stiffness of the subspace K = Σ_e Φ̂_eᵀ K_e Φ̂_e
  /// over every elastic tet (numSoftDofs square: 3H × 3H for handles; symmetric positive
  /// definite, N/m; K_e the tet's elastic
  /// Hessian at rest, Φ̂_e its nodes' basis rows ⊗ I₃; elasticRestStiffness). The reduced
  /// elastic energy is then split into this quadratic, integrated exactly, and the sample tets'
  /// excess over it (docs/rom.md, "Elastic cubature"):
  ///   E(z) = ½ zᵀ K z + Σ_{e∈S} f_e,  f_e = w_e (Ψ_e − q_e) bounded below by −c_e q_e,
  /// q_e = ½ zᵀ K̃_e z the tet's own rest quadratic. Small deformations (gravity's sag, small
  /// jiggle) thus get the exact stiffness whatever tets the cubature drew. The simulable sets the
  /// floors c_e = 1 + s w_e once (restSplitFloors in flsh/energy/fem_material.h) so that
  /// Σ_S c_e K̃_e ≼ ½ K: E ≥ ½ · ½ zᵀ K z in every state. Empty without the elastic cubature.
  MatX elastic_rest_stiffness;
  /// With the rest-stiffness split, the floors c_e of each elastic cubature sample (same order
  /// as elastic.elements; kUnusedRestSplitFloor for a sample without a soft node, which has no
  /// energy): elasticCubatureFloors at the avatar's materials when it was built. Part of the
  /// discretization like the samples and weights: an avatar with other materials
  /// (SoftAvatar::withMaterial) keeps them, so that the Material group's gradient is exact for
  /// the model simulated. SoftAvatar fills them (not cached on disk); empty otherwise.
  VecX elastic_floors;
  /// Inertial cubature, same conventions (kinetic energy).
  Cubature inertial;
  double inertial_test_error = 0;
  /// Largest relative error of the inertial cubature over the skeleton's rigid motions (the
  /// kinetic energy of the root's translation and of each bone turning about its joint, alone
  /// and in coupled pairs: the rigid-motion rows of its training set), |cubature / exact − 1|;
  /// 0 when off.
  double inertial_rigid_error = 0;
  std::string key;  ///< cache key of this level
  int numHandles() const { return int(handles.size()); }
  int numModes() const { return int(modes.cols()); }
  /// Entries of the soft state: 3 per handle, then one per mode.
  int numSoftDofs() const { return 3 * numHandles() + numModes(); }
};

/// How the build went; seconds are 0 for stages skipped because the level came from the cache.
struct ReducedBuildReport {
  bool from_cache = false;
  std::string warnings;  ///< one line per problem (e.g. a corrupted cache file rebuilt)
  double seconds_handles = 0, seconds_basis = 0, seconds_training = 0, seconds_cubature = 0;
  /// The modal basis' build (kinds with modes, built rather than loaded); its seconds are part
  /// of seconds_basis.
  ModalBasisReport modes;
  double seconds_cache_load = 0, seconds_cache_store = 0, seconds_total = 0;
};

/// Builds (or loads from `cache`, when not null) the reduced data of the volumetric body `data`.
/// The elastic / inertial cubature is built only when the corresponding flag is on (the key
/// includes the flags). Throws InputError for settings out of range (naming the field and the
/// allowed range) or more handles than soft-tissue surface nodes; cache problems only warn.
ReducedData buildReducedData(const VolumetricData& data, const BodyModel& body,
                             const ReducedSettings& settings, bool elastic_cubature,
                             bool inertial_cubature, const AvatarCache* cache,
                             ReducedBuildReport* report = nullptr);

/// The same for rom's subspace, whatever its kind (handles, modes or both): numSoftDofs square.
/// InputError when the basis or the modes do not have a row (block) per node.
MatX elasticRestStiffness(const VolumetricData& data, const ReducedData& rom);

/// K = Σ_e Φ̂_eᵀ K_e Φ̂_e over the elastic tets (those with a soft node) at rest: the exact
/// elastic stiffness of the subspace spanned by `basis` (#N × H) at z = 0, 3H × 3H, N/m, exactly
/// symmetric (ReducedData::elastic_rest_stiffness).
MatX elasticRestStiffness(const VolumetricData& data, const SpMat& basis);

/// Floor of a cubature sample that has no soft node (never read).
constexpr double kUnusedRestSplitFloor = 2.0;

/// The floors c_e of the rest-stiffness split (ReducedData::elastic_floors) of `rom`'s elastic
/// cubature at `data`'s materials: restSplitFloors (fem_material.h) of K =
/// rom.elastic_rest_stiffness and the samples' own rest Hessians in the subspace, without and
/// with their weights, so that the split energy keeps at least half of K in every direction.
/// Empty cubature or K: every entry kUnusedRestSplitFloor. InputError (naming the cubature) when
/// the samples cannot be bounded that way or the sizes do not match.
VecX elasticCubatureFloors(const VolumetricData& data, const ReducedData& rom);

/// The inertial cubature as node masses (#N, kg): m̃_j = Σ_{e∈S, j∈e} w_e ρ_e vol_e / 4 at X̄(β).
/// Zero outside the sample tets' nodes.
VecX inertialNodeMasses(const VolumetricData& data, const Cubature& inertial);

}  // namespace flsh
