// A reduced basis for the soft tissue built from the physics of the avatar (issue 26), in the
// spirit of component-mode synthesis (Craig–Bampton) and the mode-acceleration method: the soft
// tissue linearized at rest, with its bone nodes fixed (the interface), answers the skeleton's
// motion through
//   - static-correction modes, one per bone DoF k (24 bones × (δt, δω)): ψ_k = K_uu⁻¹ M_ub e_k,
//     the tissue's static response to the inertial load of that DoF's unit acceleration;
//   - fixed-interface vibration modes: the lowest solutions of K_uu φ = λ M_uu φ, which carry the
//     tissue's own dynamics (jiggle) that the static responses leave out.
// K_uu is the elastic Hessian at rest over the soft-tissue nodes' displacements (the material's
// orthotropic StVK with Fung stiffening, whose Hessian at rest is the linear one), M_uu the lumped
// node masses, M_ub the inertial coupling of the nodes to the bones' rigid motions at rest (node j
// moves with bone b by w_jb (δt_b + δω_b × (X̄_j − J_b)), w the skinning weights). No simulation
// data is used: the basis is a function of the avatar's rest shape, materials and skinning.
//
// Unlike the handle basis (reduced_basis.h: one scalar weight per handle and node, z_h ∈ R³),
// each column is a vector field: u = Ψ z with Ψ 3#N × r, node j's rows 3j .. 3j + 2, zero on
// bone nodes. Measured on the full-size synthetic body with the linear test
// (docs/rom.md, "A basis from the physics"): 144 static modes leave 0.9 % of the soft-tissue
// displacement of walk and jumping jacks, with 50 vibration modes 0.1 %, against 77–88 % for 87
// handles.
#pragma once

#include <cstdint>

#include "flsh/core/types.h"
#include "flsh/volume/volumetric_data.h"

namespace flsh {

/// The soft tissue linearized at rest with its bone nodes fixed. DoF 3i + a is coordinate a of
/// soft node soft_nodes[i].
struct SoftTissueRestOperators {
  VecXi soft_nodes;   ///< S ascending node indices with bone_of_node −1
  VecXi dof_of_node;  ///< #N: 3i for soft node soft_nodes[i], −1 on bone nodes
  SpMat stiffness;    ///< K_uu, 3S × 3S, N/m, symmetric positive definite (both triangles)
  VecX masses;        ///< M_uu's diagonal, 3S, kg (lumped: a quarter of each tet's mass per node)
  /// M_ub, 3S × 6B (B bones; column 6b + a: δt_b's coordinate a for a < 3, δω_b's coordinate
  /// a − 3 else), kg (translations) and kg·m (rotations).
  MatX coupling;
  int numSoftNodes() const { return int(soft_nodes.size()); }
};

/// Assembles the operators from the volumetric data at X̄(β) and its materials. InputError for
/// data without a template, without soft-tissue nodes, or whose sizes do not fit.
SoftTissueRestOperators softTissueRestOperators(const VolumetricData& data);

struct ModalBasisSettings {
  /// One static-correction mode per bone DoF (6 per bone).
  bool static_modes = true;
  /// Lowest fixed-interface vibration modes (≥ 0).
  int vibration_modes = 50;
  /// > 0: keep the r mass-principal components of the columns, each weighted by the load it
  /// answers (a translation's static mode as it is: the response to a unit acceleration,
  /// 1 m/s², of its bone; a rotation's times rotation_weight; each vibration mode φ scaled by its
  /// static participation ‖φᵀ M_ub W‖ / λ, W those weights), instead of all of them; 0: keep
  /// every independent column.
  int columns = 0;
  /// The compression's weight of each bone rotation's static mode (the response to 1 rad/s²
  /// about the bone's joint) against a translation's (1 m/s²), in m/s² per rad/s² (> 0; unused
  /// without `columns`). Chosen by measurement (docs/benchmarks.md, "The compression's weight of
  /// the rotations"): the rotations about the joints largely repeat the translations of the
  /// bones further down the chain, and counted at 1 they crowd those out. 72 columns of the
  /// full-size body, integrated exactly, against the FEM: 0.3 instead of 1 takes jumping jacks
  /// from 10.9 to 9.6 % and a jump from 10.5 to 8.6 % (largest frames 32 → 23 % and 34 → 17 %),
  /// walk, ball and arm swings unchanged (±0.2 %).
  double rotation_weight = 0.3;
  /// The vibration modes are converged when ‖K φ − λ M φ‖_{M⁻¹} ≤ tol · λ ‖φ‖_M for each.
  double eigen_tolerance = 1e-5;
  /// Columns whose M-Gram eigenvalue (each column M-normalized first) is below this fraction of
  /// the largest are dropped as dependent.
  double dependence_tolerance = 1e-10;
  std::uint64_t seed = 1;  ///< the eigensolver's start block (deterministic)
};

struct ModalBasisReport {
  int static_columns = 0;         ///< static-correction modes computed
  int vibration_columns = 0;      ///< vibration modes computed
  int dropped_columns = 0;        ///< dependent (or, with `columns`, compressed away)
  VecX frequencies;               ///< Hz, ascending, of the vibration modes: √λ / 2π
  double max_eigen_residual = 0;  ///< largest relative residual of a vibration mode
  int eigen_iterations = 0;       ///< block Lanczos steps of the eigensolver
  int factor_solves = 0;          ///< columns solved with K_uu's factor
  double seconds_operators = 0, seconds_factor = 0, seconds_static = 0, seconds_vibration = 0;
  double seconds_orthonormalize = 0, seconds_total = 0;
};

struct ModalBasis {
  /// Ψ, 3#N × r, mass-orthonormal (Ψᵀ M Ψ = I with M the lumped node masses), zero rows on
  /// bone nodes; columns ordered by decreasing mass-Gram eigenvalue.
  MatX basis;
  ModalBasisReport report;
  int columns() const { return int(basis.cols()); }
};

/// Builds the basis of `data` (see the file comment). InputError for settings out of range
/// (naming the field and the range) or data as softTissueRestOperators rejects; Error when the
/// eigensolver does not converge within its largest Krylov space (naming the residual reached).
ModalBasis computeModalBasis(const VolumetricData& data, const ModalBasisSettings& settings = {});

/// The same from operators already assembled (the basis' rows come out per soft DoF, 3S × r:
/// expand with the operators' dof_of_node).
MatX modalColumns(const SoftTissueRestOperators& ops, const ModalBasisSettings& settings,
                  ModalBasisReport* report = nullptr);

}  // namespace flsh
