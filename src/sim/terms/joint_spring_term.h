// Joint springs between every bone and its parent: Σ_b ½k_J‖R_p(J_b − J_p) + t_p − t_b‖², the
// kernel jointSpringEnergy (skeleton_energies.h). Depends on the rest joints and on
// Stiffnesses[0] (k_J).
#pragma once

#include "flsh/sim/energy_term.h"

namespace flsh::detail {

class JointSpringTerm final : public TermWithProducts<JointSpringTerm> {
 public:
  const char* name() const override { return "joint springs"; }
  double evaluate(const TermContext& c, VecX* g, int offset) const override;
  void addHessian(const TermContext& c, std::vector<Triplet>& H, int offset,
                  bool psd) const override;
  template <class Lambda, class Block>
  void products(const TermContext& c, const Lambda& lambda, ParameterProducts<Block>& out) const;
};

}  // namespace flsh::detail
