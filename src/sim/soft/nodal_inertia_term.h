// Nodal inertia of the soft skeletons (ARCHITECTURE.md §4): ½ Σ_j m_j ‖x_j(q) − x̂_j‖² / h² over
// the mass nodes (every tet node with its lumped mass, or the ROM's inertial cubature's nodes),
// x̂ = 2 x(q_n) − x(q_{n−1}) with the held pose blend. The node forces and the node Hessians
// m_j / h² I go to the state through the kinematics (its curvature of the rotating nodes in the
// exact form). Parameter derivatives: the rest joints (the nodes' skinning, in x and in x̂);
// the material (the masses m_j, MaterialChain::massDerivatives);
// the nodes' unposed positions (node_offset_derivatives.h); the previous states q_n, q_{n−1}
// through x̂ (the held pose blend's share is SoftTissue's). Private to Simulable.
#pragma once

#include <vector>

#include "flsh/sim/energy_term.h"
#include "sim/soft/held_mass_moments.h"
#include "sim/soft/material_chain.h"
#include "sim/soft/node_masses.h"
#include "sim/soft/node_offset_derivatives.h"
#include "sim/soft/node_term.h"
#include "sim/soft/shape_chain.h"
#include "sim/soft/soft_kinematics.h"

namespace flsh::detail {

class NodalInertiaTerm final : public NodeTerm<0, TermWithParameterBlocks<NodalInertiaTerm>>,
                               public WithNodeOffsetBlocks<NodalInertiaTerm> {
 public:
  /// The ROM's Hessian on two threads maps this share of the mass nodes beside the potential
  /// terms (soft_tissue.cpp): hessianPart(1) maps it, hessianPart(0) the rest.
  static constexpr double kShareBesidePotential = 0.1;

  NodalInertiaTerm(const SoftKinematics& kinematics, const NodeMasses& masses,
                   const HeldMassMoments& moments, const MaterialChain& chain,
                   const ShapeChain& shape, double time_step);

  const char* name() const override { return "nodal inertia"; }
  double evaluate(const TermContext& c, VecX* g, int offset) const override {
    if (c.bone_block_only) return boneOnly(g, nullptr, offset, true);
    return evaluate(g, nullptr, offset, true, nullptr);
  }
  /// FEM: the bone–tissue coupling and node-diagonal blocks as fixed blocks; ROM: value list 0.
  void addHessianBlocks(const TermContext& c, std::vector<Triplet>& H,
                        std::vector<FixedHessianBlocks>* blocks, int offset,
                        bool psd) const override;

  /// ∂g/∂p as local blocks (term_blocks.h).
  template <class Sink>
  void parameterBlocks(const TermContext& c, Sink& sink) const;
  /// ∂g/∂Y as local blocks (node_offset_blocks.h).
  template <class Sink>
  void nodeOffsetBlocks(const TermContext& c, Sink& sink) const;

  /// x̂'s own dependence on q_n and q_{n−1} (bones and soft state, skinned with the held pose
  /// blend): ∂g/∂x̂_j = −κ_j J_jᵀ, ∂x̂_j = 2 J_j(q_n) dq_n − J_j(q_{n−1}) dq_{n−1}. None when
  /// static. The dense blocks: columns of the tangent (numDofs products; for tests).
  bool dependsOnPreviousStates() const override { return true; }
  void addPreviousStatesProducts(const TermContext& c, const VecX& lambda, VecX* a_n,
                                 VecX* a_nm1) const override;
  void addPreviousStatesTangent(const TermContext& c, const VecX& dq_n, const VecX& dq_nm1,
                                VecX& out) const override;
  void addPreviousStateJacobian(const TermContext& c, int which, MatX& D) const override;

  /// x̂ = 2 x(q_n) − x(q_{n−1}) of the mass nodes (the kinematics' u_n and u_nm1).
  void setPrediction(const BoneFrames& bones_n, const BoneFrames& bones_nm1);
  const MatX3& prediction() const { return x_hat_; }
  double timeStep() const { return h_; }

  /// At the prepared state: the energy, its gradient ADDED into g, its Hessian (FEM: triplets
  /// appended to H, or with `blocks` the bone–tissue coupling and node-diagonal blocks returned
  /// at the kinematics' coupling positions; ROM: into value list 0). The bones' rows and block
  /// alone (TermContext::bone_block_only) are boneOnly's.
  double evaluate(VecX* g, std::vector<Triplet>* H, int offset, bool psd,
                  FixedHessianBlocks* blocks = nullptr) const;
  /// The energy, the gradient's bone rows (ADDED into g) and the bone–bone Hessian blocks
  /// (appended to H) from the mass nodes' moments at held unposed positions
  /// (held_mass_moments.h; TermContext::bone_block_only, the bones' presolve): O(bone pairs),
  /// no pass over the nodes while Y and the prediction stay. Relative to the reference frames
  /// (R⁰, t⁰) of the moments' build, where e⁰_j = x_j − x̂_j: with d_jb = ΔR_b Ỹ_jb + Δt_b,
  ///   E = κ/2 Σ_j m_j ‖e⁰_j + Σ_b w_jb d_jb‖²,
  /// so no large terms cancel. Equal to evaluate()'s bone rows and blocks up to rounding.
  double boneOnly(VecX* g, std::vector<Triplet>* H, int offset, bool psd) const;
  /// ROM: the Hessian of one share of the mass nodes (see kShareBesidePotential) into value list
  /// `part` (bone triplets into H). `approximate`: the exact form without the soft–soft blocks
  /// κ_j B_jᵀ M_jᵀ M_j B_j, which part 0 replaces by constantSoftBlock() (see there).
  void hessianPart(int part, std::vector<Triplet>& H, int offset, bool psd,
                   bool approximate = false) const;
  /// ROM: C = Σ_j κ_j B_jᵀ B_j over the mass nodes (numSoftDofs² dense, B_j node j's row of the
  /// basis, κ_j = m_j / h²): the soft–soft block of the Hessian where M_jᵀ M_j = I, exact for
  /// the nodes one bone moves and a constant. Computed on first use and again when the masses
  /// change (a material).
  const MatX& constantSoftBlock() const;

 private:
  /// visit(j, κ_j, f_j, point) for every mass node j: κ_j = m_j / h², its force
  /// f_j = κ_j (x_j − x̂_j) and its skinned point (id: its index among the mass nodes; with a
  /// λ, its known cotangent J_j λ from SoftKinematics::massCotangents).
  template <class Visit>
  void forEachMassNode(const VecX* lambda, Visit&& visit) const;

  const NodeMasses& masses_;
  const HeldMassMoments& moments_;
  const MaterialChain& chain_;
  const ShapeChain& shape_;
  double h_;
  MatX3 x_hat_;
  long prediction_stamp_ = 0;  // setPrediction calls
  // boneOnly's reference: the frames (R⁰, t⁰) at the moments' build `moments` and prediction
  // `prediction`, with P_b = Σ_j m_j w_jb e⁰_j, Q_b = Σ_j m_j w_jb Ỹ_jb e⁰_jᵀ, E0 = Σ_j m_j
  // ‖e⁰_j‖².
  struct HeldReference {
    long moments = -1, prediction = -1;
    std::vector<Mat3> R0, Q;
    MatX3 t0;
    std::vector<Vec3> P;
    double E0 = 0.0;
  };
  mutable HeldReference held_;
  void updateHeldReference() const;
  std::vector<int> parts_[2];
  mutable std::vector<Vec3> forces_;
  mutable std::vector<double> scalars_;
  mutable std::vector<Mat3> fixed_;
  mutable std::vector<double> part_scalars_[2];
  mutable std::vector<Vec3> part_forces_[2];
  mutable MatX constant_soft_;               // constantSoftBlock()
  mutable std::vector<double> constant_of_;  // the mass nodes' masses it was computed with
};

}  // namespace flsh::detail
