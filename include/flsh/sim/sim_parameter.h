// The parameter registry: every parameter group a simulable's gradient depends on, declared
// once (name, size, unit, which terms own it, whether it changes per step). The adjoint's
// groups (SimulableAdjointModel::parameterGroups, RolloutVariables), the Python enum and the
// Ceres costs read this table; the chain from the shape β through the rest joints and the bone
// inertias is written here once (chainShape).
#pragma once

#include <array>

#include "flsh/core/types.h"

namespace flsh {

class SoftAvatar;

/// Parameter groups the total gradient depends on (for the adjoint, ARCHITECTURE.md §6), in the
/// order of the adjoint's groups (SimulableAdjointModel::parameterGroups).
enum class SimParameter {
  /// K: the avatar's shape β (fixed by the SoftAvatar: setParameter throws, build one with
  /// SoftAvatar::withShape instead). Its gradient Jacobian goes through the rest joints J(β),
  /// the bone inertias (SoftAvatar::boneInertiaShapeJacobian), and the rest surface X(β) and
  /// vertex areas a(β) of the contact nodes x_i = Σ_b w_ib (R_b (X_i − J_b) + t_b); with soft
  /// tissue also the rest nodes X̄(β), node masses and the tets' materials (docs/adjoint.md).
  Shape,
  RestJoints,   ///< 72: rest joint centres J_b (m), 3 per bone: joint springs, skinning
                ///< (x_i = Σ w (R(X − J) + t)), tracking/root stiffness moments and the
                ///< root target J_0 + trans. Bone inertias are separate parameters
                ///< (their moments are about J_b as stored).
  BoneInertia,  ///< 24 × 10: per bone mass (kg), first moment (3, kg·m), second
                ///< moment (6, kg·m²: xx, yy, zz, xy, xz, yz)
  PoseTargets,  ///< 72: current tracking target rotation vectors θ_b (rad): b ≥ 1
                ///< relative to the parent, θ_0 the root orientation target
  RootTranslationTarget,  ///< 3: target position of the root joint centre t_0 (m)
  Stiffnesses,            ///< 4: joint_stiffness (N/m), tracking_stiffness (1/s²),
                          ///< root_stiffness (1/s²), contact stiffness (N/m³)
  ColliderOffsets,        ///< 3 per collider: current translation offset of its path (m)
  /// The soft skeletons' material file as MaterialModel::parameters() (per coefficient
  /// a = log c₀ and its K log-slopes b; flsh/volume/materials.h): fixed by the SoftAvatar like
  /// Shape (setParameter throws, build one with SoftAvatar::withMaterial instead). Empty (size
  /// 0) for the articulated skeleton, which has no material.
  Material,
};
constexpr int kNumSimParameters = 8;

/// Values per bone of SimParameter::BoneInertia: mass, first moment (3), second moment (6).
constexpr int kBoneInertiaValues = 10;

/// One row of the registry.
struct SimParameterInfo {
  SimParameter id;
  const char* name;       ///< snake_case: the adjoint's group name and the Python keyword
  const char* enum_name;  ///< the C++ / Python enum value
  const char* unit;
  bool per_step;      ///< a value per step in a rollout (targets), else one per rollout
  int fixed_size;     ///< values (per step), or −1 where it depends on β or the colliders
  const char* terms;  ///< the energy terms whose gradient depends on it
  const char* doc;    ///< shape, layout and meaning, for documentation (the Python enum)
};

/// The registry, in SimParameter order.
const std::array<SimParameterInfo, kNumSimParameters>& simParameters();
const SimParameterInfo& simParameterInfo(SimParameter p);
/// Number of values of group p for a simulable with `num_colliders` colliders and `num_betas`
/// shape coefficients, with soft tissue or not (Material: MaterialModel::numParameters() =
/// numCoefficients() · (1 + K) with it, 0 without). Throws InputError for a value outside the
/// enum.
int simParameterSize(SimParameter p, int num_colliders, int num_betas, bool soft_tissue = false);

/// The β chain, in one place: ADDS (dJ/dβ)ᵀ joints + (dI/dβ)ᵀ inertia into shape, for
/// cotangents of the rest joints (72 × m) and bone inertias (240 × m) of `avatar` (either may be
/// empty: no contribution), shape: K × m.
void chainShapeCotangent(const SoftAvatar& avatar, const MatX& joints, const MatX& inertia,
                         MatX& shape);
void chainShapeCotangent(const SoftAvatar& avatar, const VecX& joints, const VecX& inertia,
                         VecX& shape);
/// The forward form: the rest-joint (72) and bone-inertia (240) directions of a β direction.
void shapeTangent(const SoftAvatar& avatar, const VecX& dbeta, VecX* joints, VecX* inertia);

}  // namespace flsh
