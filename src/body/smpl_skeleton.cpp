#include "flsh/body/smpl_skeleton.h"

#include <cmath>
#include <cstdio>

#include "flsh/core/error.h"
#include "flsh/core/rotation.h"

namespace flsh {

const std::array<const char*, kNumJoints> kSmplJointNames = {
    "pelvis",         "left_hip",       "right_hip",   "spine1",      "left_knee",
    "right_knee",     "spine2",         "left_ankle",  "right_ankle", "spine3",
    "left_foot",      "right_foot",     "neck",        "left_collar", "right_collar",
    "head",           "left_shoulder",  "right_shoulder", "left_elbow", "right_elbow",
    "left_wrist",     "right_wrist",    "left_hand",   "right_hand"};

const std::array<int, kNumJoints> kSmplParents = {-1, 0,  0,  0,  1,  2,  3,  4,
                                                  5,  6,  7,  8,  9,  9,  9,  12,
                                                  13, 14, 16, 17, 18, 19, 20, 21};

int smplJointIndex(const std::string& name) {
  for (int j = 0; j < kNumJoints; ++j)
    if (name == kSmplJointNames[j]) return j;
  throw InputError("unknown SMPL joint name '" + name + "'");
}

void checkPoseAngles(const Eigen::Ref<const VecX>& pose, const std::string& what) {
  for (Eigen::Index k = 0; k + 2 < pose.size(); k += 3) {
    const Vec3 theta = pose.segment<3>(k);
    const long joint = long(k / 3);
    // SMPL-H shares SMPL's joints 0–21; its later ones are finger joints.
    const bool smpl_joint =
        pose.size() == kSmplPoseSize ? joint < kNumJoints : joint < kNumBodyJointsSmplh;
    const std::string name =
        smpl_joint ? std::string(" (") + kSmplJointNames[joint] + ")" : std::string();
    if (!theta.allFinite())
      throw InputError(what + ": joint " + std::to_string(joint) + name +
                       " has a NaN or Inf rotation value (values " + std::to_string(k) + ".." +
                       std::to_string(k + 2) + ")");
    const double angle = theta.stableNorm();
    if (angle > kMaxRotationAngle) {
      char text[64];
      std::snprintf(text, sizeof(text), "%.6g", angle);
      throw InputError(what + ": joint " + std::to_string(joint) + name + " has angle |θ| = " +
                       text + " rad, expected at most 1e6 rad (a rotation vector, axis × angle)");
    }
  }
}

VecX toSmplPose(const Eigen::Ref<const VecX>& pose, const std::string& what) {
  const long n = pose.size();
  if (n != kSmplPoseSize && n != kSmplhPoseSize)
    throw InputError(what + ": expected 72 (SMPL) or 156 (SMPL-H) values, got " +
                     std::to_string(n));
  checkPoseAngles(pose, what);
  VecX out = VecX::Zero(kSmplPoseSize);
  if (n == kSmplPoseSize) {
    out = pose;
  } else {
    out.head(3 * kNumBodyJointsSmplh) = pose.head(3 * kNumBodyJointsSmplh);
  }
  return out;
}

RowMatX toSmplPoses(const Eigen::Ref<const RowMatX>& poses, const std::string& what) {
  const long cols = poses.cols();
  if (cols != kSmplPoseSize && cols != kSmplhPoseSize)
    throw InputError(what + ": expected shape (T, 72) or (T, 156), got " +
                     shapeString({long(poses.rows()), cols}));
  for (Eigen::Index t = 0; t < poses.rows(); ++t)
    checkPoseAngles(poses.row(t).transpose(), what + ": frame " + std::to_string(t));
  RowMatX out = RowMatX::Zero(poses.rows(), kSmplPoseSize);
  const int keep = cols == kSmplPoseSize ? kSmplPoseSize : 3 * kNumBodyJointsSmplh;
  out.leftCols(keep) = poses.leftCols(keep);
  return out;
}

}  // namespace flsh
