#include <gtest/gtest.h>

#include "flsh/body/motion.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"

namespace flsh {
namespace {

Mat3 jointRotation(const Motion& m, int frame, const std::string& joint) {
  const int j = smplJointIndex(joint);
  return rodrigues(
      Vec3(m.poses(frame, 3 * j), m.poses(frame, 3 * j + 1), m.poses(frame, 3 * j + 2)));
}

TEST(BuiltinMotion, EveryMotionHasTheRequestedFramesAndIsFinite) {
  const auto names = builtinMotionNames();
  ASSERT_GE(names.size(), 3u);
  for (const auto& name : names) {
    const Motion m = makeBuiltinMotion(name, 1.0, 25.0);
    EXPECT_EQ(m.numFrames(), 26) << name;
    EXPECT_EQ(m.poses.cols(), kSmplPoseSize) << name;
    EXPECT_EQ(m.trans.cols(), 3) << name;
    EXPECT_TRUE(m.poses.allFinite() && m.trans.allFinite()) << name;
    EXPECT_DOUBLE_EQ(m.fps, 25.0);
    EXPECT_EQ(m.source, "builtin:" + name);
  }
}

TEST(BuiltinMotion, RequiredMotionsExist) {
  for (const char* name : {"walk", "jumping_jacks", "arm_swings"})
    EXPECT_NO_THROW(makeBuiltinMotion(name));
}

TEST(BuiltinMotion, StandingArmsHangDown) {
  const Motion m = makeBuiltinMotion("stand", 0.0);
  // The left arm points along +x in the T-pose; relaxed it points mostly down.
  EXPECT_LT((jointRotation(m, 0, "left_shoulder") * Vec3::UnitX()).y(), -0.9);
  EXPECT_LT((jointRotation(m, 0, "right_shoulder") * -Vec3::UnitX()).y(), -0.9);
}

TEST(BuiltinMotion, WalkSwingsLegsForwardAlternatelyAndAdvances) {
  const double fps = 100.0;
  const Motion m = makeBuiltinMotion("walk", 1.1, fps);
  const int quarter = int(0.275 * fps), three_quarters = int(0.825 * fps);  // sin(phase) = ±1
  const Vec3 down(0, -1, 0);
  EXPECT_GT((jointRotation(m, quarter, "left_hip") * down).z(), 0.3);    // left leg forward
  EXPECT_LT((jointRotation(m, quarter, "right_hip") * down).z(), -0.3);  // right leg back
  EXPECT_LT((jointRotation(m, three_quarters, "left_hip") * down).z(), -0.3);
  EXPECT_GT(m.trans(m.numFrames() - 1, 2), 1.0);  // about 1.2 m/s along +z
}

TEST(BuiltinMotion, JumpingJacksRaiseTheArmsAboveTheHead) {
  const double fps = 100.0;
  const Motion m = makeBuiltinMotion("jumping_jacks", 0.9, fps);
  const int open = 45;  // half a period: fully open
  EXPECT_GT((jointRotation(m, open, "left_shoulder") * Vec3::UnitX()).y(), 0.7);
  EXPECT_GT((jointRotation(m, open, "right_shoulder") * -Vec3::UnitX()).y(), 0.7);
  EXPECT_GT((jointRotation(m, open, "left_hip") * Vec3(0, -1, 0)).x(), 0.2);  // legs apart
  EXPECT_LT((jointRotation(m, 0, "left_shoulder") * Vec3::UnitX()).y(), -0.9);
}

TEST(BuiltinMotion, JumpLeavesTheGround) {
  const Motion m = makeBuiltinMotion("jump", 1.6, 100.0);
  EXPECT_GT(m.trans.col(1).maxCoeff(), 0.2);
  EXPECT_LT(m.trans.col(1).minCoeff(), -0.1);  // crouch
}

TEST(BuiltinMotion, BadArgumentsAreRejectedWithTheirNames) {
  try {
    makeBuiltinMotion("moonwalk");
    FAIL() << "expected InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("moonwalk"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("walk"), std::string::npos);
  }
  EXPECT_THROW(makeBuiltinMotion("walk", 1.0, 0.0), InputError);
  EXPECT_THROW(makeBuiltinMotion("walk", -1.0, 30.0), InputError);
  EXPECT_THROW(loadOrMakeMotion("no/such/file.npz"), FileError);
  EXPECT_EQ(loadOrMakeMotion("builtin:walk", 1.0, 10.0).numFrames(), 11);
  EXPECT_EQ(loadOrMakeMotion("walk", 1.0, 10.0).numFrames(), 11);
}

}  // namespace
}  // namespace flsh
