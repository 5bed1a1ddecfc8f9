// Internal: derivatives of the Simulable's total gradient with respect to its parameters and its
// previous states (for the adjoint, ARCHITECTURE.md §6). Simulable fills a read-only view of its
// data; the formulas live in parameter_derivatives.cpp.
#pragma once

#include <vector>

#include "flsh/sim/simulable.h"

namespace flsh::detail {

/// Read-only view of one Simulable's data at its current state (references stay owned by it).
struct SimulableParameterView {
  int num_bones;
  const std::vector<int>& parents;         // 24, root −1
  const MatX3& J;                          // 24 × 3 rest joint centres, m
  const std::vector<BoneInertia>& inertia;  // 24
  const SimulableOptions& options;
  bool tracking;   // tracking and root springs active
  bool is_static;  // no inertia term
  const std::vector<Mat3>& R;
  const MatX3& t;  // current state
  const std::vector<Mat3>& R_n;
  const MatX3& t_n;  // q_n
  const std::vector<Mat3>& R_nm1;
  const MatX3& t_nm1;  // q_{n−1}
  const std::vector<Mat3>& target_R;  // per bone (root: global)
  const Vec3& target_t0;
  const MatX& weights;  // #V × 24 skinning weights
  const MatX3& X;       // #V × 3 rest vertices
  // Contact cache (up to date): candidate vertices, their positions, areas and node gradient.
  const std::vector<int>& candidates;
  const MatX3& contact_nodes;
  const VecX& contact_areas;
  const VecX& contact_gradient;  // 3 per candidate
  const std::vector<Collider>& colliders;
  double time;
  // Shape derivatives of the avatar's rest data (for SimParameter::Shape).
  const MatX& shapedirs;               // 3#V × K
  const MatX& joints_shape_jacobian;   // 72 × K
  const MatX& inertia_shape_jacobian;  // 240 × K
  const MatX& areas_shape_jacobian;    // #V × K
};

/// Subtree of every bone (itself included, ascending), from the parent list (root −1).
std::vector<std::vector<int>> boneSubtrees(const std::vector<int>& parents);
/// The moment tracking spring b's stiffness scales (kg·m²): I_b = Σ_{c ∈ subtree} tr(S_c) +
/// 2 m̄_c·d + M_c‖d‖², d = J_c − J_b (each bone's moments shifted to J_b), plus
/// options.tracking_inertia_floor for every bone but the root (a constant: it adds nothing to
/// the derivatives with respect to the joints or the inertias). k_b = ω_T² · this (b ≥ 1);
/// the root's rotation spring is root_stiffness · this (b = 0).
double trackingMoment(const MatX3& J, const std::vector<BoneInertia>& inertia,
                      const SimulableOptions& options, const std::vector<int>& subtree, int b);

int simParameterSize(SimParameter p, int num_colliders, int num_betas);
MatX gradientParameterJacobian(const SimulableParameterView& v, SimParameter p);
/// `shape_surface_only`: the Shape entry is only the contact-surface part (see the VJPs below).
std::vector<MatX> gradientParameterJacobians(const SimulableParameterView& v,
                                             const std::vector<SimParameter>& groups,
                                             bool shape_surface_only = false);
MatX gradientPreviousStateJacobian(const SimulableParameterView& v, int which);

/// (∂g/∂p)ᵀ λ per group (λ: 6 · num_bones), without forming ∂g/∂p. `shape_surface_only`: the
/// Shape entry holds only the contact-surface part (X(β), a(β)); the caller chains the
/// RestJoints and BoneInertia cotangents through dJ/dβ and dI/dβ itself (once per rollout).
std::vector<VecX> gradientParameterVJPs(const SimulableParameterView& v, const VecX& lambda,
                                        const std::vector<SimParameter>& groups,
                                        bool shape_surface_only);
/// (∂g/∂q_n)ᵀ λ and (∂g/∂q_{n−1})ᵀ λ from the per-bone 6 × 6 inertia blocks (either may be
/// null); and the tangent ∂g/∂q_n dq_n + ∂g/∂q_{n−1} dq_{n−1}.
void gradientPreviousStatesVJP(const SimulableParameterView& v, const VecX& lambda, VecX* a_n,
                               VecX* a_nm1);
VecX gradientPreviousStatesJVP(const SimulableParameterView& v, const VecX& dq_n,
                               const VecX& dq_nm1);

}  // namespace flsh::detail
