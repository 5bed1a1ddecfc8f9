// A tet's deformation in the reduced soft tissue's subspace, for any basis kind
// (ReducedBasisKind: handles, modes or both): F = I + mat(D z_e), with z_e the soft-state
// entries the tet's nodes move with (`dofs`, ascending) and D (9 × #dofs, vec column-major) the
// map from them to vec(F − I). With the shape-function gradients g_a of the tet's nodes and u_a
// = Σ_h φ_h(a) z_h + Ψ_a z_modes:
//   D = Σ_a (g_a ⊗ I₃) ∂u_a/∂z_e,
// so a handle's three columns are G̃_h ⊗ I₃ (G̃_h = Σ_a φ_h(a) g_a, reducedShapeGradients) and
// the modes' columns Σ_a g_a Ψ_a row by row. The elastic energy, its gradient and Hessian are
// then those of the law at F chained through D (sim/soft/modal_elasticity_term), and so is its rest
// quadratic: K̃_e = V Dᵀ A₀ D with A₀ the law's tangent at F = I. Used where the ROM's
// precomputation (rest stiffness, floors) and its modal elastic term (sim/) need one form for
// every kind; the handle-only term keeps its own Z G̃ᵀ form (reducedTetElasticEnergy), which
// is cheaper. Summed over every elastic tet, the rest quadratics are the subspace's exact rest
// stiffness K (subspaceRestStiffness, and elasticRestStiffness of reduced_data.h here too).
#pragma once

#include <vector>

#include "flsh/core/types.h"
#include "flsh/energy/fem_material.h"
#include "flsh/volume/elastic_tets.h"
#include "flsh/volume/reduced_data.h"
#include "flsh/volume/volumetric_data.h"

namespace flsh::detail {

struct SubspaceTet {
  std::vector<int> dofs;  ///< soft-state entries (ascending)
  MatX D;                 ///< 9 × dofs.size()
};

/// Tet t (rest data `rest`) in rom's subspace (rows of rom.basis for the handles, of rom.modes
/// for the modes; bone nodes do not move). No dofs when no node of t moves.
SubspaceTet subspaceTet(const VolumetricData& data, const ReducedData& rom, const SpMat& basis_rows,
                        const TetElementRest& rest, int t);

/// The law's tangent at rest, ∂P/∂F at F = I (9 × 9, symmetric PSD): a tet's rest Hessian in the
/// subspace is volume · Dᵀ restTangent D.
Mat9 restTangent(const FemMaterialPoint& material);

/// The exact rest stiffness of rom's subspace, Σ over `elements` of their rest Hessians in it
/// (numSoftDofs square, exactly symmetric, N/m): for handles alone per tet in sparse 3 × 3
/// blocks, with modes as Bᵀ K_uu B through the assembled K_uu (softTissueRestOperators; B the
/// subspace's columns on the soft DoFs) — one sparse product instead of a dense 9 m² sum per tet.
/// The modes' form assumes `elements` are every elastic tet (K_uu sums them all).
MatX subspaceRestStiffness(const VolumetricData& data, const ReducedData& rom,
                           const ElasticTets& elements);

}  // namespace flsh::detail
