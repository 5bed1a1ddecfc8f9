// SMPL's skeleton: 24 joints, their names, order and parent table, and pose vector sizes.
//
// Axes of SMPL (and of every flsh body): y up, the body faces +z, its left side is +x.
#pragma once

#include <array>
#include <string>

#include "flsh/core/types.h"

namespace flsh {

constexpr int kNumJoints = 24;
constexpr int kSmplPoseSize = 72;    // 24 joints × 3 (axis-angle)
constexpr int kSmplhPoseSize = 156;  // SMPL-H (AMASS): 52 joints × 3
constexpr int kNumBodyJointsSmplh = 22;  // SMPL-H joints 0..21 are SMPL joints 0..21
constexpr int kPoseFeatureSize = 207;    // 23 joints × 9 entries of (R_j − I)

/// SMPL joint names in SMPL order ("pelvis", "left_hip", …, "right_hand").
extern const std::array<const char*, kNumJoints> kSmplJointNames;
/// Parent of each joint in SMPL order; the root (pelvis) has parent −1.
extern const std::array<int, kNumJoints> kSmplParents;

/// Index of a joint by its SMPL name; throws InputError for an unknown name.
int smplJointIndex(const std::string& name);

/// Throws InputError naming `what` and the joint unless every rotation vector of `pose`
/// (3 values per joint) is finite with angle |θ| ≤ kMaxRotationAngle (1e6 rad, rotation.h).
void checkPoseAngles(const Eigen::Ref<const VecX>& pose, const std::string& what = "pose");

/// Converts a pose of 72 (SMPL) or 156 (SMPL-H) values to SMPL's 72: SMPL-H body joints
/// 0–21 map to SMPL 0–21 and SMPL's hand joints 22–23 are set to identity (zero).
/// Throws InputError (naming `what`) for any other length, for non-finite values and for
/// angles above kMaxRotationAngle (checkPoseAngles).
VecX toSmplPose(const Eigen::Ref<const VecX>& pose, const std::string& what = "pose");

/// Row-wise toSmplPose for a T × 72 or T × 156 matrix.
RowMatX toSmplPoses(const Eigen::Ref<const RowMatX>& poses, const std::string& what = "poses");

}  // namespace flsh
