// Motions in flsh's y-up world: up axes, placement, the floor under a clip, uprightness.
#include "flsh/body/motion_frame.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "flsh/body/body_forward.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"

namespace flsh {

Mat3 worldFromUpAxis(const std::string& up, const std::string& what) {
  if (up == "y") return Mat3::Identity();
  if (up == "z") {
    Mat3 R;
    R << 1, 0, 0,  //
        0, 0, 1,   //
        0, -1, 0;
    return R;
  }
  throw InputError(what + ": expected \"y\" or \"z\" (the up axis of the motion's frame), got \"" +
                   up + "\"");
}

void rotateMotion(Motion& motion, const Mat3& R) {
  for (int k = 0; k < motion.numFrames(); ++k) {
    const Vec3 trans = motion.trans.row(k).transpose();
    motion.trans.row(k) = (R * trans).transpose();
    const Vec3 root = motion.poses.row(k).head<3>().transpose();
    motion.poses.row(k).head<3>() = logSO3(R * rodrigues(root)).transpose();
  }
}

Motion placedMotion(Motion motion, double yaw, const Vec3& offset) {
  rotateMotion(motion, Eigen::AngleAxisd(yaw, Vec3::UnitY()).toRotationMatrix());
  motion.trans.rowwise() += offset.transpose();
  return motion;
}

double lowestPointHeight(const BodyModel& body, const VecX& betas, const Motion& motion,
                         double seconds) {
  if (motion.numFrames() < 1)
    throw InputError("lowestPointHeight: the motion '" + motion.source + "' has no frames");
  const int frames = std::clamp(1 + int(std::floor(std::max(seconds, 0.0) * motion.fps + 1e-9)), 1,
                                motion.numFrames());
  const PosedBatch posed =
      poseBodyBatch(body, betas, motion.poses.topRows(frames), motion.trans.topRows(frames));
  double lowest = posed.vertices(0, 1);
  for (Eigen::Index t = 0; t < posed.vertices.rows(); ++t)
    for (Eigen::Index i = 1; i < posed.vertices.cols(); i += 3)
      lowest = std::min(lowest, posed.vertices(t, i));
  return lowest;
}

Vec3 bodyUpAtStart(const Motion& motion) {
  if (motion.numFrames() < 1) return Vec3::UnitY();
  return rodrigues(motion.poses.row(0).head<3>().transpose()) * Vec3::UnitY();
}

std::string uprightWarning(const Motion& motion) {
  const Vec3 up = bodyUpAtStart(motion);
  if (up.y() >= 0.5) return "";  // within 60° of +y
  char direction[96];
  std::snprintf(direction, sizeof(direction), "(%.2f, %.2f, %.2f)", up.x(), up.y(), up.z());
  const std::string other = motion.up == "z" ? "y" : "z";
  return motion.source + ": the body is not upright at frame 0: its up axis points along " +
         direction + " in flsh's y-up world, reading the clip as recorded " + motion.up +
         " up. If the clip was recorded " + other + " up, say so: \"up\": \"" + other +
         "\" in a scene file, --up " + other + " for flsh pose, up=\"" + other + "\" in Python";
}

}  // namespace flsh
