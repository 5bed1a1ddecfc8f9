// The parameter registry's table and the β chain (include/flsh/sim/sim_parameter.h).
#include "flsh/sim/sim_parameter.h"

#include <string>

#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "flsh/volume/materials.h"
#include "flsh/volume/soft_avatar.h"

namespace flsh {

const std::array<SimParameterInfo, kNumSimParameters>& simParameters() {
  static const std::array<SimParameterInfo, kNumSimParameters> table = {{
      {SimParameter::Shape, "shape", "Shape", "1 (SMPL shape coefficients)", false, -1,
       "through the rest joints and bone inertias; collider contact (rest surface, areas)",
       "(K,) the avatar's shape β (read only on a simulable: build a new SoftAvatar instead)"},
      {SimParameter::RestJoints, "rest_joints", "RestJoints", "m", false, 3 * kNumJoints,
       "joint springs, tracking and root springs, collider contact",
       "(72,) rest joint centres J_b, m, 3 per bone (joint springs, skinning, tracking "
       "moments, root target)"},
      {SimParameter::BoneInertia, "bone_inertia", "BoneInertia", "kg, kg·m, kg·m²", false,
       kBoneInertiaValues * kNumJoints, "rigid inertia, bone gravity, tracking and root springs",
       "(240,) per bone: mass (kg), first moment (3, kg·m), second moment (6, kg·m²: xx, yy, "
       "zz, xy, xz, yz)"},
      {SimParameter::PoseTargets, "pose_targets", "PoseTargets", "rad", true, 3 * kNumJoints,
       "tracking and root springs",
       "(72,) tracking target rotation vectors θ_b, rad (b ≥ 1 relative to the parent, θ_0 the "
       "root orientation); recomputed from the mocap by preUpdate/initialize"},
      {SimParameter::RootTranslationTarget, "root_targets", "RootTranslationTarget", "m", true, 3,
       "root spring",
       "(3,) target position of the root joint centre t_0 = J_0 + trans, m; recomputed by "
       "preUpdate"},
      {SimParameter::Stiffnesses, "stiffnesses", "Stiffnesses", "N/m, 1/s², 1/s², N/m³", false, 4,
       "joint springs, tracking and root springs, collider contact",
       "(4,) joint_stiffness (N/m), tracking_stiffness (1/s²), root_stiffness (1/s²), contact "
       "stiffness (N/m³)"},
      {SimParameter::ColliderOffsets, "collider_offsets", "ColliderOffsets", "m", false, -1,
       "collider contact", "(3·#colliders,) translation offset of each collider's path, m"},
      {SimParameter::Material, "material", "Material",
       "1 (log of each coefficient's value; log-slopes per unit β)", false, -1,
       "soft skeletons: elasticity, nodal inertia and gravity (node masses)",
       "(40·(1+K),) the material file's coefficients as MaterialModel::parameters(): per "
       "coefficient a = log c₀, then its K log-slopes (read only on a simulable: build the "
       "avatar with SoftAvatar::withMaterial instead); empty for the articulated skeleton"},
  }};
  return table;
}

const SimParameterInfo& simParameterInfo(SimParameter p) {
  const int k = int(p);
  if (k < 0 || k >= kNumSimParameters)
    throw InputError("SimParameter: unknown parameter group " + std::to_string(k));
  return simParameters()[size_t(k)];
}

int simParameterSize(SimParameter p, int num_colliders, int num_betas, bool soft_tissue) {
  const SimParameterInfo& info = simParameterInfo(p);
  if (info.fixed_size >= 0) return info.fixed_size;
  switch (p) {
    case SimParameter::Shape:
      return num_betas;
    case SimParameter::Material:
      return soft_tissue ? MaterialModel::numCoefficients() * (1 + num_betas) : 0;
    default:
      return 3 * num_colliders;
  }
}

namespace {

template <class Block>
void chain(const SoftAvatar& avatar, const Block& joints, const Block& inertia, Block& shape) {
  if (joints.size()) shape.noalias() += avatar.restJointsShapeJacobian().transpose() * joints;
  if (inertia.size()) shape.noalias() += avatar.boneInertiaShapeJacobian().transpose() * inertia;
}

}  // namespace

void chainShapeCotangent(const SoftAvatar& avatar, const MatX& joints, const MatX& inertia,
                         MatX& shape) {
  chain(avatar, joints, inertia, shape);
}

void chainShapeCotangent(const SoftAvatar& avatar, const VecX& joints, const VecX& inertia,
                         VecX& shape) {
  chain(avatar, joints, inertia, shape);
}

void shapeTangent(const SoftAvatar& avatar, const VecX& dbeta, VecX* joints, VecX* inertia) {
  if (joints) *joints = avatar.restJointsShapeJacobian() * dbeta;
  if (inertia) *inertia = avatar.boneInertiaShapeJacobian() * dbeta;
}

}  // namespace flsh
