#include "flsh/body/smpl_skeleton.h"

#include <cmath>

#include "flsh/core/error.h"

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

VecX toSmplPose(const Eigen::Ref<const VecX>& pose, const std::string& what) {
  const long n = pose.size();
  if (n != kSmplPoseSize && n != kSmplhPoseSize)
    throw InputError(what + ": expected 72 (SMPL) or 156 (SMPL-H) values, got " +
                     std::to_string(n));
  if (!pose.allFinite()) throw InputError(what + ": contains NaN or Inf");
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
  if (!poses.allFinite()) throw InputError(what + ": contains NaN or Inf");
  RowMatX out = RowMatX::Zero(poses.rows(), kSmplPoseSize);
  const int keep = cols == kSmplPoseSize ? kSmplPoseSize : 3 * kNumBodyJointsSmplh;
  out.leftCols(keep) = poses.leftCols(keep);
  return out;
}

}  // namespace flsh
