// Motions in flsh's y-up world (motion_frame.h): AMASS's z-up clips turned upright on loading,
// exactly; placement by yaw and offset; the floor under a clip; the upright check.
#include "flsh/body/motion_frame.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <random>

#include "flsh/body/body_forward.h"
#include "flsh/body/motion.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "flsh/format/npz.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::messageOf;
using ::testing::HasSubstr;

/// The built-in walk as an AMASS file stores it: z up (the walk turned by the inverse of
/// worldFromUpAxis("z")), SMPL-H's 156 pose values (random hands), 16 betas, no `up` key.
struct AmassClip {
  Motion world = makeBuiltinMotion("walk", 0.5, 30.0);  // y up: the truth
  Motion stored;

  AmassClip() {
    stored = world;
    rotateMotion(stored, worldFromUpAxis("z").transpose());
  }

  std::string write(const std::string& path, bool with_up_key = false) const {
    std::mt19937 rng(7);
    std::normal_distribution<double> normal(0.0, 0.2);
    RowMatX poses(stored.numFrames(), 156);
    for (long k = 0; k < poses.size(); ++k) poses.data()[k] = normal(rng);
    poses.leftCols(66) = stored.poses.leftCols(66);
    io::NpzWriter writer;
    writer.add("poses", poses);
    writer.add("trans", stored.trans);
    writer.add("betas", VecX::LinSpaced(16, -0.5, 0.5));
    writer.addScalar("mocap_framerate", 30.0);
    writer.addString("gender", "female");
    if (with_up_key) writer.addString("up", "z");
    writer.save(path, true);
    return path;
  }
};

/// Largest difference of rotations given as axis-angle rows (compared as matrices).
double rotationDistance(const RowMatX& a, const RowMatX& b) {
  double worst = 0.0;
  for (Eigen::Index t = 0; t < a.rows(); ++t)
    worst = std::max(worst, (rodrigues(a.row(t).head<3>().transpose()) -
                             rodrigues(b.row(t).head<3>().transpose()))
                                .norm());
  return worst;
}

TEST(MotionFrame, UpAxisRotations) {
  const Mat3 R = worldFromUpAxis("z");
  EXPECT_TRUE((R * Vec3::UnitZ()).isApprox(Vec3::UnitY()));
  EXPECT_TRUE((R * Vec3::UnitX()).isApprox(Vec3::UnitX()));
  EXPECT_NEAR(R.determinant(), 1.0, 1e-15);
  EXPECT_TRUE((R.transpose() * R).isIdentity(1e-15));
  EXPECT_TRUE(worldFromUpAxis("y").isIdentity(0.0));
  EXPECT_THAT(messageOf<InputError>([] { worldFromUpAxis("x", "scene.json: avatars[0].up"); }),
              HasSubstr("scene.json: avatars[0].up: expected \"y\" or \"z\""));
}

TEST(MotionFrame, RotationTurnsThePosedBodyAboutTheRestRootJoint) {
  // Exact for any shape: each posed vertex v ↦ J₀ + R (v − J₀), J₀ the shaped rest root joint.
  const BodyModel body = test::makeRandomModel(200, 6, 3);
  const VecX betas = test::randomVector(6, 1.0, 4);
  Motion motion = makeBuiltinMotion("jumping_jacks", 0.2, 30.0);
  motion.trans.rowwise() += Eigen::RowVector3d(0.3, -0.2, 1.1);
  const Mat3 R = Eigen::AngleAxisd(0.7, Vec3(0.3, -1.0, 0.5).normalized()).toRotationMatrix();
  Motion turned = motion;
  rotateMotion(turned, R);
  for (int t : {0, 3, motion.numFrames() - 1}) {
    const PosedBody before =
        poseBody(body, betas, motion.poses.row(t).transpose(), motion.trans.row(t).transpose());
    const PosedBody after =
        poseBody(body, betas, turned.poses.row(t).transpose(), turned.trans.row(t).transpose());
    const Vec3 J0 = before.rest_joints.row(0).transpose();
    const MatX3 expected =
        ((before.vertices.rowwise() - J0.transpose()) * R.transpose()).rowwise() + J0.transpose();
    ASSERT_GT((after.vertices - before.vertices).norm(), 0.1);  // it moved
    EXPECT_LT((after.vertices - expected).cwiseAbs().maxCoeff(), 1e-12) << "frame " << t;
  }
}

TEST(MotionFrame, AmassFileWithoutUpKeyIsReadZUpAndTurnedUpright) {
  const std::string dir = test::freshTempDir("motion_frame_amass");
  const AmassClip clip;
  const std::string path = clip.write(dir + "/clip.npz");
  ::testing::internal::CaptureStderr();
  const Motion motion = loadMotion(path);
  const std::string warnings = ::testing::internal::GetCapturedStderr();
  EXPECT_EQ(motion.up, "z");
  ASSERT_GT((clip.stored.trans - clip.world.trans).norm(), 0.1);  // the file is not y up
  EXPECT_LT((motion.trans - clip.world.trans).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT(rotationDistance(motion.poses, clip.world.poses), 1e-12);
  EXPECT_EQ(motion.poses.middleCols(3, 63), clip.world.poses.middleCols(3, 63));  // not the root
  EXPECT_GT(bodyUpAtStart(motion).y(), 0.95);
  EXPECT_EQ(uprightWarning(motion), "");
  EXPECT_THAT(warnings, ::testing::Not(HasSubstr("upright")));

  // The same file read as y up lies on its back, and says so.
  ::testing::internal::CaptureStderr();
  const Motion lying = loadMotion(path, "y");
  const std::string lying_warning = ::testing::internal::GetCapturedStderr();
  EXPECT_EQ(lying.up, "y");
  EXPECT_EQ(lying.trans, clip.stored.trans);
  EXPECT_LT(bodyUpAtStart(lying).y(), 0.1);
  EXPECT_THAT(lying_warning, HasSubstr(path + ": the body is not upright at frame 0"));
  EXPECT_THAT(lying_warning, HasSubstr("\"up\": \"z\""));

  // An explicit key in the file is followed, and a bad one is named.
  const Motion keyed = loadMotion(clip.write(dir + "/keyed.npz", true));
  EXPECT_EQ(keyed.up, "z");
  EXPECT_LT((keyed.trans - clip.world.trans).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_THAT(messageOf<InputError>([&] { loadMotion(path, "x"); }),
              HasSubstr(path + ": up axis asked for: expected \"y\" or \"z\""));
}

TEST(MotionFrame, SavedMotionsAreYUpAndRoundTripExactly) {
  const std::string path = test::freshTempDir("motion_frame_save") + "/walk.npz";
  const Motion walk = makeBuiltinMotion("walk", 0.3, 30.0);
  EXPECT_EQ(walk.up, "y");
  saveMotion(walk, path);
  EXPECT_EQ(io::NpzFile(path).string("up"), "y");
  const Motion loaded = loadMotion(path);
  EXPECT_EQ(loaded.up, "y");
  EXPECT_EQ(loaded.poses, walk.poses);
  EXPECT_EQ(loaded.trans, walk.trans);
  EXPECT_THAT(messageOf<InputError>([&] { loadOrMakeMotion("builtin:walk", 1.0, 30.0, "z"); }),
              HasSubstr("applies to motion files only"));
}

TEST(MotionFrame, PlacedMotionIsAYawAboutTheRootThenAnOffset) {
  const Motion walk = makeBuiltinMotion("walk", 0.3, 30.0);
  const Vec3 offset(1.0, 0.5, -2.0);
  const Motion placed = placedMotion(walk, 0.4, offset);
  Motion expected = walk;
  rotateMotion(expected, Eigen::AngleAxisd(0.4, Vec3::UnitY()).toRotationMatrix());
  ASSERT_GT((placed.trans - walk.trans).norm(), 0.1);
  EXPECT_LT(((placed.trans.rowwise() - offset.transpose()) - expected.trans).cwiseAbs().maxCoeff(),
            1e-14);
  EXPECT_LT(rotationDistance(placed.poses, expected.poses), 1e-14);
}

TEST(MotionFrame, LowestPointIsTheLowestPosedVertexOverTheFirstSeconds) {
  const BodyModel body = test::makeRandomModel(150, 4, 5);
  const VecX betas = test::randomVector(4, 0.5, 6);
  Motion motion = makeBuiltinMotion("jumping_jacks", 1.0, 20.0);
  motion.trans.col(1) += VecX::LinSpaced(motion.numFrames(), 0.0, -1.0);  // sinks with time
  const auto brute = [&](int frames) {
    double lowest = 1e9;
    for (int t = 0; t < frames; ++t)
      lowest = std::min(lowest, poseBody(body, betas, motion.poses.row(t).transpose(),
                                         motion.trans.row(t).transpose())
                                    .vertices.col(1)
                                    .minCoeff());
    return lowest;
  };
  EXPECT_DOUBLE_EQ(lowestPointHeight(body, betas, motion, 0.0), brute(1));
  EXPECT_DOUBLE_EQ(lowestPointHeight(body, betas, motion, 0.25), brute(6));  // frames 0–5
  EXPECT_DOUBLE_EQ(lowestPointHeight(body, betas, motion, 100.0), brute(motion.numFrames()));
  EXPECT_LT(brute(motion.numFrames()), brute(1) - 0.5);  // the window matters
}

}  // namespace
}  // namespace flsh
