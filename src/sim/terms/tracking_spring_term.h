// Mocap tracking: a rotation spring per joint to its target relative rotation,
// ½k_b‖log(R_targetᵀ R_pᵀ R_b)‖² (b ≥ 1), and the root springs to the target root position and
// orientation (kernels trackingSpringEnergy, rootSpringEnergy in skeleton_energies.h). The
// stiffnesses scale with the bones' moments (SimulableOptions::tracking_stiffness):
// k_b = ω_T² (I_b + I_floor), k_pos = root_stiffness · M, k_rot = root_stiffness · I_0, so the
// gradient depends on the rest joints and bone inertias through I_b and M, on the targets and
// on Stiffnesses[1, 2]. Active only with a mocap and options.track_mocap.
#pragma once

#include <vector>

#include "flsh/sim/energy_term.h"

namespace flsh::detail {

/// The moment tracking spring b's stiffness scales (kg·m²): I_b = Σ_{c ∈ subtree} tr(S_c) +
/// 2 m̄_c·d + M_c‖d‖², d = J_c − J_b (each bone's moments shifted to J_b), plus
/// options.tracking_inertia_floor for every bone but the root (a constant: it adds nothing to
/// the derivatives with respect to the joints or the inertias). k_b = ω_T² · this (b ≥ 1);
/// the root's rotation spring is root_stiffness · this (b = 0).
double trackingMoment(const MatX3& J, const std::vector<BoneInertia>& inertia,
                      const SimulableOptions& options, const std::vector<int>& subtree, int b);

class TrackingSpringTerm final : public TermWithParameterBlocks<TrackingSpringTerm> {
 public:
  explicit TrackingSpringTerm(const std::vector<int>& parents);
  const char* name() const override { return "tracking and root springs"; }
  double evaluate(const TermContext& c, VecX* g, int offset) const override;
  void addHessian(const TermContext& c, std::vector<Triplet>& H, int offset,
                  bool psd) const override;
  /// ∂g/∂p as local blocks (term_blocks.h).
  template <class Sink>
  void parameterBlocks(const TermContext& c, Sink& sink) const;

  /// The stiffnesses of the current options, joints and inertias (what TermContext's
  /// tracking_k, root_k_pos and root_k_rot hold).
  void stiffnesses(const MatX3& J, const std::vector<BoneInertia>& inertia,
                   const SimulableOptions& options, std::vector<double>& tracking_k,
                   double& root_k_pos, double& root_k_rot) const;

 private:
  std::vector<std::vector<int>> subtrees_;
};

}  // namespace flsh::detail
