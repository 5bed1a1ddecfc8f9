// Joint springs between every bone and its parent: Σ_b ½k_J‖R_p(J_b − J_p) + t_p − t_b‖², the
// kernel jointSpringEnergy (skeleton_energies.h). Depends on the rest joints and on
// Stiffnesses[0] (k_J).
#pragma once

#include "flsh/sim/energy_term.h"

namespace flsh::detail {

class JointSpringTerm final : public TermWithParameterBlocks<JointSpringTerm> {
 public:
  const char* name() const override { return "joint springs"; }
  double evaluate(const TermContext& c, VecX* g, int offset) const override;
  void addHessian(const TermContext& c, std::vector<Triplet>& H, int offset,
                  bool psd) const override;
  /// ∂g/∂p as local blocks (term_blocks.h).
  template <class Sink>
  void parameterBlocks(const TermContext& c, Sink& sink) const;
};

}  // namespace flsh::detail
