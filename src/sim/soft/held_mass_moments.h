// The mass nodes' skinning moments at held unposed positions (private to Simulable), for the
// bones' presolve (NewtonOptions::coarse_presolve): while the soft state and the held pose blend
// stay, each mass node's unposed position Y_j is fixed and its world position
//   x_j = Σ_b w_jb (R_b Ỹ_jb + t_b),  Ỹ_jb = Y_j − J_b,
// is linear in the bones' frames. The nodal inertia's and gravity's energy, bone rows and
// bone–bone Hessian blocks are then sums over bone pairs of mass-weighted moments of the nodes,
// formed once per held Y (one pass over the nodes), per ordered pair (b, c) of bones that skin a
// node together (b = c included):
//   S_bc = Σ_j m_j w_jb w_jc,  U_bc = Σ_j m_j w_jb w_jc Ỹ_jb,  V_bc = Σ_j m_j w_jb w_jc Ỹ_jb Ỹ_jcᵀ
// (so U of the pair (c, b) is the lever sum of c, and V_cb = V_bcᵀ), and per bone
// L_b = Σ_j m_j w_jb Ỹ_jb. A presolve iteration then costs O(bone pairs),
// as the skeleton's rigid inertia does, instead of O(mass nodes × influences²). The terms keep
// their formulas beside them (NodalInertiaTerm::boneOnly, NodalGravityTerm::boneOnly); this file
// holds the geometry they share.
#pragma once

#include <vector>

#include "flsh/core/types.h"
#include "sim/soft/node_masses.h"
#include "sim/soft/soft_kinematics.h"

namespace flsh::detail {

class HeldMassMoments {
 public:
  struct Pair {
    int b = 0, c = 0;
    double S = 0.0;
    Vec3 Ub = Vec3::Zero();  // Σ s Ỹ_jb
    Vec3 Uc = Vec3::Zero();  // Σ s Ỹ_jc
    Mat3 V = Mat3::Zero();   // Σ s Ỹ_jb Ỹ_jcᵀ
  };

  HeldMassMoments(const SoftKinematics& kinematics, const NodeMasses& masses)
      : kin_(kinematics), masses_(masses) {}

  /// Brings the moments to the unposed positions Y of the kinematics' prepared state (rebuilt
  /// when Y or the rest joints changed since the last build; the masses are fixed for the
  /// simulable's life: a material is a new avatar) and returns the build's id (it changes with
  /// every rebuild).
  long update() const;
  /// Every ordered pair (b, c) with a node skinned by both, in first-touch order.
  const std::vector<Pair>& pairs() const { return pairs_; }
  const Vec3& boneLever(int b) const { return L_[size_t(b)]; }  ///< L_b

 private:
  void build() const;
  const SoftKinematics& kin_;
  const NodeMasses& masses_;
  mutable long build_id_ = 0;
  mutable long y_stamp_ = -1;  // the kinematics' unposed stamp of the build
  mutable MatX3 joints_of_;    // the rest joints of the build
  mutable std::vector<Pair> pairs_;
  mutable std::vector<int> index_;  // b · #bones + c → pairs_ index, −1 if none
  mutable std::vector<Vec3> L_;
};

}  // namespace flsh::detail
