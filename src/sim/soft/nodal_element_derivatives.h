// The parameter derivatives of one elastic element of a ROM in nodal form, shared by both
// reduced elastic terms (handles: reduced_elasticity_term.h; modes: modal_elasticity_term.h),
// whatever basis gives the element's nodal displacements u (3 × 4) and a nodal direction λ_u
// (3 × 4, the same basis applied to an adjoint's local direction Λ):
// - a sample tet of the elastic cubature: its weighted energy w V Ψ(F), or with the
//   rest-stiffness split its excess f over its rest quadratic (restSplitExcess, fem_material.h);
// - a tet of the split's rest quadratic ½ zᵀ K z: λᵀ K_t z = V ε(λ_u)ᵀ C_world ε(u), ε the
//   linear strain.
// Each gives the material-point cotangent of λᵀ g_e (C_world, μ, γ) and, the material point
// held, the cotangent of the tet's rest node positions.
//
// Under the split, with ψ = V Ψ(F), q = ½ V ε(u)ᵀ C ε(u) (the rest quadratic), b-form
// λᵀb = V ε(λ_u)ᵀ C ε(u) and r = ψ − q: λᵀ∇f = f_r (λᵀ∇ψ − λᵀb) + f_q λᵀb, whose derivative in the
// material or the rest shape adds to f_r, f_q's own terms the second-order part of f in (r, q): in
// the bounded branch (h′ / ((c − 1) q)) (w λᵀ∇r + x λᵀb) (w dr + x dq). The floor c_e is the
// discretization's (held). So d(λᵀ∇f) = a_gψ d(λᵀ∇ψ) + a_gq d(λᵀb) + a_ψ dψ + a_q dq
// (SplitWeights).
#pragma once

#include "flsh/energy/fem_material.h"

namespace flsh::detail {

/// A sample tet: its rest shape, material point, cubature weight and, with the rest-stiffness
/// split, its floor c_e (0: no split).
struct SampleElement {
  const TetElementRest& rest;
  const FemMaterialPoint& material;
  double weight = 1.0;
  double floor = 0.0;
};

/// A sample's products of λᵀ g_e (its nodal displacements u, direction lu), each when asked
/// (non-null): `d` receives its material-point cotangent; X_bar (3 × 4, column a: node a) has
/// the rest nodes' cotangent, the material point held, ADDED. Both at once share the strain and
/// the split's weights.
void sampleProducts(const SampleElement& sample, const Mat34& u, const Mat34& lu,
                    FemMaterialDerivative* d, Mat34* X_bar);
/// The material-point cotangent of a rest-quadratic tet's λᵀ K_t z: V ε(λ_u) ε(u)ᵀ on C_world.
FemMaterialDerivative restFormMaterialGradient(const TetElementRest& rest, const Mat34& u,
                                               const Mat34& lu);

}  // namespace flsh::detail
