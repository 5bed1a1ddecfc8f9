// Built-in procedural motions for demos and tests.
//
// Joint rotations are SMPL's: axis-angle of each joint relative to its parent, in the T-pose
// rest frame (y up, facing +z, left = +x). Useful signs, worked out once:
//   hip flexion (leg forward)   = rotation about −x;  knee flexion (shin back) = about +x
//   left arm down               = about −z;           right arm down           = about +z
//   left leg sideways (abduct)  = about +z;           right leg                = about −z
#include <Eigen/Geometry>
#include <cmath>
#include <filesystem>
#include <functional>
#include <map>

#include "flsh/body/motion.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"

namespace flsh {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;

/// One frame being built: 24 rotation vectors and the root translation.
struct Frame {
  RowMatX pose = RowMatX::Zero(1, kSmplPoseSize);
  Vec3 trans = Vec3::Zero();
  void set(int joint, const Vec3& rotvec) {
    for (int a = 0; a < 3; ++a) pose(0, 3 * joint + a) = rotvec[a];
  }
  /// Sets joint rotation R_second · R_first (first applied first), as a rotation vector.
  void compose(int joint, const Vec3& first, const Vec3& second) {
    set(joint, logSO3(rodrigues(second) * rodrigues(first)));
  }
};

using FrameFunction = std::function<void(double t, Frame&)>;

// Arms relaxed at the sides, elbows slightly bent: the neutral standing posture.
void relaxedArms(Frame& f, double swing_left = 0.0, double swing_right = 0.0,
                 double elbow_left = 10 * kDeg, double elbow_right = 10 * kDeg) {
  const int ls = smplJointIndex("left_shoulder"), rs = smplJointIndex("right_shoulder");
  // Lower the arm, then swing it forward (+z) about the x axis by `swing`.
  f.compose(ls, Vec3(0, 0, -75 * kDeg), Vec3(-swing_left, 0, 0));
  f.compose(rs, Vec3(0, 0, 75 * kDeg), Vec3(-swing_right, 0, 0));
  // Elbow flexion brings the forearm forward: about −y on the left, +y on the right.
  f.set(smplJointIndex("left_elbow"), Vec3(0, -elbow_left, 0));
  f.set(smplJointIndex("right_elbow"), Vec3(0, elbow_right, 0));
}

void walk(double t, Frame& f) {
  const double period = 1.1;  // s per gait cycle (two steps)
  const double phase = 2 * kPi * t / period;
  const double s = std::sin(phase);
  const double hip_amp = 25 * kDeg;
  f.set(smplJointIndex("left_hip"), Vec3(-hip_amp * s, 0, 0));
  f.set(smplJointIndex("right_hip"), Vec3(hip_amp * s, 0, 0));
  // The knee bends mostly while its leg swings forward.
  const double kl = 30 * kDeg * std::max(0.0, std::sin(phase + 0.6)) + 5 * kDeg;
  const double kr = 30 * kDeg * std::max(0.0, -std::sin(phase + 0.6)) + 5 * kDeg;
  f.set(smplJointIndex("left_knee"), Vec3(kl, 0, 0));
  f.set(smplJointIndex("right_knee"), Vec3(kr, 0, 0));
  f.set(smplJointIndex("left_ankle"), Vec3(-8 * kDeg * std::cos(phase), 0, 0));
  f.set(smplJointIndex("right_ankle"), Vec3(8 * kDeg * std::cos(phase), 0, 0));
  // Arms swing against the legs; the torso counter-rotates a little.
  relaxedArms(f, -20 * kDeg * s, 20 * kDeg * s, 15 * kDeg, 15 * kDeg);
  f.set(smplJointIndex("spine1"), Vec3(0, 4 * kDeg * s, 0));
  f.set(smplJointIndex("pelvis"), Vec3(0, -5 * kDeg * s, 0));
  const double speed = 1.2;  // m/s forward (+z)
  f.trans = Vec3(0.0, 0.02 * std::cos(2 * phase), speed * t);
}

void jumpingJacks(double t, Frame& f) {
  const double period = 0.9;
  const double open = 0.5 - 0.5 * std::cos(2 * kPi * t / period);  // 0 closed … 1 open
  const int ls = smplJointIndex("left_shoulder"), rs = smplJointIndex("right_shoulder");
  const double arm = -75 * kDeg + open * 150 * kDeg;  // from at the sides to above the head
  f.set(ls, Vec3(0, 0, arm));
  f.set(rs, Vec3(0, 0, -arm));
  f.set(smplJointIndex("left_hip"), Vec3(0, 0, 20 * kDeg * open));
  f.set(smplJointIndex("right_hip"), Vec3(0, 0, -20 * kDeg * open));
  // Hop: airborne in the middle of each half cycle.
  const double hop = std::abs(std::sin(2 * kPi * t / period));
  f.trans = Vec3(0, 0.08 * hop * hop, 0);
  f.set(smplJointIndex("left_knee"), Vec3(10 * kDeg * (1 - hop), 0, 0));
  f.set(smplJointIndex("right_knee"), Vec3(10 * kDeg * (1 - hop), 0, 0));
}

void armSwings(double t, Frame& f) {
  const double period = 1.4;
  const double s = std::sin(2 * kPi * t / period);
  relaxedArms(f, 80 * kDeg * s, -80 * kDeg * s, 20 * kDeg, 20 * kDeg);
  f.set(smplJointIndex("spine2"), Vec3(0, 8 * kDeg * s, 0));
}

void jump(double t, Frame& f) {
  // One vertical jump per 1.6 s: crouch (0–0.5 s), flight (0.5–0.95 s), landing (0.95–1.6 s).
  const double period = 1.6;
  const double u = std::fmod(t, period);
  double crouch = 0.0, height = 0.0;
  if (u < 0.5) {
    crouch = std::sin(kPi * u / 0.5);  // down and up again, pushing off
  } else if (u < 0.95) {
    const double s = (u - 0.5) / 0.45;
    height = 0.25 * 4 * s * (1 - s);  // parabola, 25 cm apex
  } else {
    crouch = 0.6 * std::sin(kPi * (u - 0.95) / 0.65);  // absorb the landing
  }
  const double knee = 70 * kDeg * crouch, hip = 50 * kDeg * crouch;
  f.set(smplJointIndex("left_hip"), Vec3(-hip, 0, 0));
  f.set(smplJointIndex("right_hip"), Vec3(-hip, 0, 0));
  f.set(smplJointIndex("left_knee"), Vec3(knee, 0, 0));
  f.set(smplJointIndex("right_knee"), Vec3(knee, 0, 0));
  f.set(smplJointIndex("left_ankle"), Vec3(-0.4 * hip, 0, 0));
  f.set(smplJointIndex("right_ankle"), Vec3(-0.4 * hip, 0, 0));
  f.set(smplJointIndex("spine1"), Vec3(0.3 * hip, 0, 0));
  relaxedArms(f, -30 * kDeg * crouch + 60 * kDeg * (height / 0.25),
              -30 * kDeg * crouch + 60 * kDeg * (height / 0.25));
  // Crouching lowers the pelvis (about 15 cm at the deepest crouch).
  f.trans = Vec3(0, height - 0.15 * crouch, 0);
}

void stand(double, Frame& f) { relaxedArms(f); }

void tPose(double, Frame&) {}

const std::map<std::string, FrameFunction>& registry() {
  static const std::map<std::string, FrameFunction> motions = {{"walk", walk},
                                                               {"jumping_jacks", jumpingJacks},
                                                               {"arm_swings", armSwings},
                                                               {"jump", jump},
                                                               {"stand", stand},
                                                               {"t_pose", tPose}};
  return motions;
}

std::string knownMotions() {
  std::string known;
  for (const auto& [name, fn] : registry()) known += (known.empty() ? "" : ", ") + name;
  return known;
}

}  // namespace

std::vector<std::string> builtinMotionNames() {
  std::vector<std::string> names;
  for (const auto& [name, fn] : registry()) names.push_back(name);
  return names;
}

Motion makeBuiltinMotion(const std::string& name, double seconds, double fps) {
  const auto it = registry().find(name);
  if (it == registry().end())
    throw InputError("unknown built-in motion '" + name + "' (known: " + knownMotions() + ")");
  if (!(fps > 0.0) || !std::isfinite(fps))
    throw InputError("built-in motion '" + name + "': fps must be > 0, got " + std::to_string(fps));
  if (!(seconds >= 0.0) || !std::isfinite(seconds))
    throw InputError("built-in motion '" + name + "': seconds must be >= 0, got " +
                     std::to_string(seconds));
  const int frames = int(std::lround(seconds * fps)) + 1;
  Motion m;
  m.poses = RowMatX::Zero(frames, kSmplPoseSize);
  m.trans = RowMatX::Zero(frames, 3);
  m.fps = fps;
  m.source = "builtin:" + name;
  for (int k = 0; k < frames; ++k) {
    Frame f;
    it->second(k / fps, f);
    m.poses.row(k) = f.pose;
    m.trans.row(k) = f.trans.transpose();
  }
  return m;
}

Motion loadOrMakeMotion(const std::string& spec, double seconds, double fps,
                        const std::string& up) {
  const std::string prefix = "builtin:";
  const auto builtin = [&](const std::string& name) {
    if (!up.empty() && up != "y")
      throw InputError("motion '" + spec + "' is a built-in motion, made y up; up \"" + up +
                       "\" applies to motion files only");
    return makeBuiltinMotion(name, seconds, fps);
  };
  if (spec.rfind(prefix, 0) == 0) return builtin(spec.substr(prefix.size()));
  if (std::filesystem::exists(spec)) return loadMotion(spec, up);
  if (registry().count(spec)) return builtin(spec);
  throw FileError("motion '" + spec + "' is neither an existing file nor a built-in motion (" +
                  knownMotions() + ")");
}

}  // namespace flsh
