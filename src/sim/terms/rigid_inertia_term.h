// Backward-Euler inertia of the rigid bones (ARCHITECTURE.md §4): Σ_b 1/(2h²) Σ m ‖x − x̂‖² over
// each bone's mass points, the kernel rigidInertiaEnergy (skeleton_energies.h). Depends on the
// previous states q_n, q_{n−1} and on the bone inertias; zero when static.
#pragma once

#include "flsh/sim/energy_term.h"

namespace flsh::detail {

class RigidInertiaTerm final : public TermWithParameterBlocks<RigidInertiaTerm> {
 public:
  const char* name() const override { return "rigid inertia"; }
  double evaluate(const TermContext& c, VecX* g, int offset) const override;
  void addHessian(const TermContext& c, std::vector<Triplet>& H, int offset,
                  bool psd) const override;
  /// BoneInertia: the gradient is linear in M, m̄ and S.
  /// ∂g/∂p as local blocks (term_blocks.h).
  template <class Sink>
  void parameterBlocks(const TermContext& c, Sink& sink) const;

  bool dependsOnPreviousStates() const override { return true; }
  void addPreviousStatesProducts(const TermContext& c, const VecX& lambda, VecX* a_n,
                                 VecX* a_nm1) const override;
  void addPreviousStatesTangent(const TermContext& c, const VecX& dq_n, const VecX& dq_nm1,
                                VecX& out) const override;
  void addPreviousStateJacobian(const TermContext& c, int which, MatX& D) const override;
};

}  // namespace flsh::detail
