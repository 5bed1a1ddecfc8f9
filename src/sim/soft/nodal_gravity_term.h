// Gravity on the soft skeletons' mass nodes (ARCHITECTURE.md §4): −Σ_j m_j g · x_j(q). The
// constant node forces −m_j g go to the state through the kinematics; their Hessian is the
// curvature of the rotating nodes alone (no node–node blocks). Parameter derivatives: the rest
// joints, the material (the masses m_j) and the nodes' unposed positions
// (node_offset_derivatives.h), both through the lever arms of the rotation rows. Private to
// Simulable.
#pragma once

#include <vector>

#include "flsh/sim/energy_term.h"
#include "sim/block_hessian_term.h"
#include "sim/soft/held_mass_moments.h"
#include "sim/soft/material_chain.h"
#include "sim/soft/node_masses.h"
#include "sim/soft/node_offset_derivatives.h"
#include "sim/soft/node_term.h"
#include "sim/soft/shape_chain.h"
#include "sim/soft/soft_kinematics.h"

namespace flsh::detail {

class NodalGravityTerm final : public NodeTerm<1, TermWithParameterBlocks<NodalGravityTerm>>,
                               public WithNodeOffsetBlocks<NodalGravityTerm> {
 public:
  /// Call after the kinematics' buildReducedPattern (the ROM's rotation–handle slots).
  NodalGravityTerm(const SoftKinematics& kinematics, const NodeMasses& masses,
                   const HeldMassMoments& moments, const MaterialChain& chain,
                   const ShapeChain& shape);

  const char* name() const override { return "nodal gravity"; }
  double evaluate(const TermContext& c, VecX* g, int offset) const override {
    if (c.bone_block_only) return boneOnly(c.options.gravity, g, nullptr, offset, true);
    return evaluate(c.options.gravity, g, nullptr, offset, true, nullptr);
  }
  /// FEM: the coupling blocks as fixed blocks; ROM: bone triplets, handle blocks into list 1.
  void addHessianBlocks(const TermContext& c, std::vector<Triplet>& H,
                        std::vector<FixedHessianBlocks>* blocks, int offset,
                        bool psd) const override;

  /// At the prepared state: the energy, its gradient ADDED into g, its Hessian (FEM:
  /// femHessian's, with `blocks` its fixed-block list; ROM: bone triplets into H, rotation–handle
  /// blocks into value list 1). The bones' rows and block alone (TermContext::bone_block_only)
  /// are boneOnly's.
  double evaluate(const Vec3& gravity, VecX* g, std::vector<Triplet>* H, int offset, bool psd,
                  FixedHessianBlocks* blocks = nullptr) const;
  /// The energy −g · Σ_b (R_b L_b + G_b t_b) (G_b = Σ_j m_j w_jb, bone_mass_), the gradient's
  /// bone rows (ADDED into g: −G_b g and −(R_b L_b) × g) and the bones' rotation curvature
  /// (appended to H) from the mass nodes' moments at held unposed positions (held_mass_moments.h;
  /// TermContext::bone_block_only, the bones' presolve): no pass over the nodes while Y stays.
  /// Equal to evaluate()'s bone rows up to rounding.
  double boneOnly(const Vec3& gravity, VecX* g, std::vector<Triplet>* H, int offset,
                  bool psd) const;
  /// ∂g/∂p as local blocks (term_blocks.h).
  template <class Sink>
  void parameterBlocks(const TermContext& c, Sink& sink) const;
  /// ∂g/∂Y as local blocks (node_offset_blocks.h).
  template <class Sink>
  void nodeOffsetBlocks(const TermContext& c, Sink& sink) const;
  /// ROM: the Hessian alone (the node loop of the energy is not needed).
  void reducedHessian(const Vec3& gravity, std::vector<Triplet>& H, int offset, bool psd) const;
  /// FEM: the Hessian alone. The rotation curvature per bone (boneCurvature) and, in the exact
  /// form, the rotation–displacement blocks w_jb m_j [g]× R_b of every mass node with a DoF and
  /// its bones (the only nonzero blocks: x is linear in u and f_j = −m_j g is constant): as
  /// fixed blocks at coupling_positions_ with `blocks` (an empty list in the PSD form, which
  /// keeps the lists' order), else as triplets.
  void femHessian(const Vec3& gravity, std::vector<Triplet>& H,
                  std::vector<FixedHessianBlocks>* blocks, int offset, bool psd) const;

 private:
  const NodeMasses& masses_;
  const HeldMassMoments& moments_;
  const MaterialChain& chain_;
  const ShapeChain& shape_;
  // ROM: the rotation–handle blocks D_bh [g]× R_b into value list 1 at `slot`, D_bh = Σ_j m_j
  // w_jb φ_jh over the mass nodes (constant).
  struct HandleBlock {
    int slot, bone;
    double weight;
  };
  std::vector<HandleBlock> handle_blocks_;
  // With modes: the rotation–modal-group blocks [g]× R_b D_bg, D_bg = Σ_j m_j w_jb Ψ_jg (3 × 3,
  // constant).
  struct ModeBlock {
    int slot, bone;
    Mat3 D;
  };
  std::vector<ModeBlock> mode_blocks_;
  /// Σ_b C(−g, R_b Σ_j m_j w_jb (Y_j − J_b)) into the bones' rotation blocks (the node sum of
  /// each bone's rotation curvature against the constant node forces, C bilinear).
  void boneCurvature(const Vec3& gravity, std::vector<Triplet>& H, int offset, bool psd) const;

  std::vector<double> bone_mass_;  // Σ_j m_j w_jb per bone over the mass nodes (constant)
  // FEM: (6b + 3, u) and (u, 6b + 3) per mass node with a DoF and influence, in node order.
  std::vector<std::pair<int, int>> coupling_positions_, no_positions_;
  const std::vector<Mat3> no_values_;
  mutable std::vector<Vec3> forces_;
  mutable std::vector<Mat3> fixed_;
};

}  // namespace flsh::detail
