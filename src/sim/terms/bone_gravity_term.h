// Gravity on the rigid bones: Σ_b −g·(M_b t_b + R_b m̄_b), the kernel gravityEnergy
// (skeleton_energies.h). The articulated skeleton's; the soft-tissue models carry gravity on
// their nodes instead. Depends on the bone inertias.
#pragma once

#include "flsh/sim/energy_term.h"

namespace flsh::detail {

class BoneGravityTerm final : public TermWithParameterBlocks<BoneGravityTerm> {
 public:
  const char* name() const override { return "bone gravity"; }
  double evaluate(const TermContext& c, VecX* g, int offset) const override;
  /// Only the rotation blocks (the energy is linear in t).
  void addHessian(const TermContext& c, std::vector<Triplet>& H, int offset,
                  bool psd) const override;
  /// BoneInertia: the gradient [−M g; g × R m̄] is linear in M and m̄.
  /// ∂g/∂p as local blocks (term_blocks.h).
  template <class Sink>
  void parameterBlocks(const TermContext& c, Sink& sink) const;
};

}  // namespace flsh::detail
