// Collider contact on the skinned surface of the articulated skeleton (ARCHITECTURE.md §5): the
// per-vertex penalty colliderContactEnergy (contact/contact_energy.h) of the surface nodes
// x_i = Σ_b w_ib (R_b (X_i − J_b) + t_b) (the skeleton's kinematics, sim/skeleton_kinematics.h),
// pulled back to the bones. The simulable's broad phase puts the candidates in
// TermContext::contact and refresh() fills the rest (positions, areas, node gradient, energy)
// before the term runs. Depends on the rest joints, the surface X(β) and areas a(β) (Shape),
// Stiffnesses[3] (the contact stiffness, linear) and the collider offsets.
#pragma once

#include <vector>

#include "flsh/sim/energy_term.h"
#include "sim/contact_term.h"
#include "sim/hessian_blocks.h"
#include "sim/skeleton_kinematics.h"

namespace flsh::detail {

class SurfaceContactTerm final : public TermWithParameterBlocks<SurfaceContactTerm>,
                                 public ContactTerm {
 public:
  SurfaceContactTerm(const SkeletonKinematics& kinematics, int num_bones);
  const char* name() const override { return "collider contact"; }
  /// The candidates' positions and areas, the energy and its node gradient.
  void refresh(const TermContext& c, SurfaceContactState& s) const override;
  double evaluate(const TermContext& c, VecX* g, int offset) const override;
  /// Jᵀ H_x J per active vertex, accumulated per bone pair; the exact form adds the curvature
  /// of the rotating points, Σ_b w_ib (g_i · ∂²y_ib), in each bone's rotation block (the PSD
  /// form its projection on the PSD cone).
  void addHessian(const TermContext& c, std::vector<Triplet>& H, int offset,
                  bool psd) const override;
  /// ∂g/∂p as local blocks (term_blocks.h).
  template <class Sink>
  void parameterBlocks(const TermContext& c, Sink& sink) const;

 private:
  const SkeletonKinematics& kin_;
  mutable BonePairBlocks pair_blocks_;
  mutable std::vector<Triplet> node_hessian_;
  mutable std::vector<std::pair<int, Mat3>> node_blocks_;
  mutable std::vector<ContactPoint> points_;
};

}  // namespace flsh::detail
