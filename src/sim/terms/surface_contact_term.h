// Collider contact on the skinned surface of the articulated skeleton (ARCHITECTURE.md §5): the
// per-vertex penalty colliderContactEnergy (contact/contact_energy.h) of the surface nodes
// x_i = Σ_b w_ib (R_b (X_i − J_b) + t_b), pulled back to the bones. The simulable's broad phase
// fills TermContext::contact (candidates, their positions, areas, node gradient and energy)
// before the term runs. Depends on the rest joints, the surface X(β) and areas a(β) (Shape),
// Stiffnesses[3] (the contact stiffness, linear) and the collider offsets.
#pragma once

#include <vector>

#include "flsh/sim/energy_term.h"
#include "sim/hessian_blocks.h"

namespace flsh::detail {

class SurfaceContactTerm final : public TermWithParameterBlocks<SurfaceContactTerm> {
 public:
  explicit SurfaceContactTerm(int num_bones);
  const char* name() const override { return "collider contact"; }
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
  mutable BonePairBlocks pair_blocks_;
  mutable std::vector<Triplet> node_hessian_;
};

}  // namespace flsh::detail
