// SMPL-H / SMPL+H model files (smplh.h): read as SMPL's 24 joints with the fingers merged into
// the hands, exactly; other joint counts refused naming the key.
#include "flsh/body/smplh.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <random>

#include "flsh/body/body_forward.h"
#include "flsh/body/body_model.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/core/error.h"
#include "flsh/format/npz.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::messageOf;
using ::testing::HasSubstr;

TEST(Smplh, ParentTableIsATreeUnderTheWrists) {
  for (int j = 1; j < kNumSmplhJoints; ++j) EXPECT_LT(kSmplhParents[size_t(j)], j);
  for (int j = 0; j < 22; ++j) EXPECT_EQ(kSmplhParents[size_t(j)], kSmplParents[size_t(j)]);
  EXPECT_EQ(kSmplhParents[kSmplhLeftMiddle1], 20);
  EXPECT_EQ(kSmplhParents[kSmplhRightMiddle1], 21);
}

TEST(Smplh, FileLoadsAsSmplAndPosesExactlyLikeTheBodyItCameFrom) {
  SyntheticBodyOptions options;
  options.vertices = 600;
  const BodyModel smpl = makeSyntheticBody(options);
  const BodyModel smplh = test::smplhFrom(smpl);
  const std::string path = test::freshTempDir("smplh_load") + "/model.npz";
  saveBodyModel(smplh, path);
  ASSERT_EQ(io::NpzFile(path).raw("kintree_table").shape, (std::vector<long>{2, 52}));

  const BodyModel loaded = loadBodyModel(path);
  EXPECT_EQ(loaded.family, "SMPL-H");
  EXPECT_EQ(loaded.numJoints(), 24);
  EXPECT_EQ(loaded.numBetas(), smpl.numBetas() + 6);
  EXPECT_EQ(loaded.posedirs.cols(), 207);
  EXPECT_EQ(loaded.parents, std::vector<int>(kSmplParents.begin(), kSmplParents.end()));

  // Body poses with the hands at rest: the same vertices and joints as the SMPL body.
  std::mt19937 rng(5);
  std::normal_distribution<double> normal(0.0, 0.4);
  for (int trial = 0; trial < 3; ++trial) {
    VecX pose(72);
    for (int k = 0; k < 72; ++k) pose[k] = normal(rng);
    pose.tail(6).setZero();  // SMPL's hand joints: what clips give them
    VecX betas = VecX::Zero(loaded.numBetas());
    for (int k = 0; k < smpl.numBetas(); ++k) betas[k] = normal(rng);
    const Vec3 trans(0.1, -0.3, 0.2);
    const PosedBody a = poseBody(loaded, betas, pose, trans);
    const PosedBody b = poseBody(smpl, betas.head(smpl.numBetas()), pose, trans);
    ASSERT_GT(a.vertices.norm(), 1.0);
    EXPECT_LT((a.vertices - b.vertices).cwiseAbs().maxCoeff(), 1e-12) << "trial " << trial;
    EXPECT_LT((a.joints - b.joints).cwiseAbs().maxCoeff(), 1e-12) << "trial " << trial;
  }
  // Saved again, it is an SMPL file.
  const std::string again = test::freshTempDir("smplh_resave") + "/smpl.npz";
  saveBodyModel(loaded, again);
  EXPECT_EQ(loadBodyModel(again).family, "SMPL");
}

TEST(Smplh, OtherJointCountsAndTreesAreRefusedNamingTheKey) {
  const BodyModel smpl = test::makeRandomModel(60, 4, 2);
  const std::string dir = test::freshTempDir("smplh_errors");
  BodyModel smplh = test::smplhFrom(smpl);
  smplh.parents[30] = 20;  // pinky3 under the wrist: a tree, but not SMPL-H's
  saveBodyModel(smplh, dir + "/tree.npz");
  EXPECT_THAT(messageOf<InputError>([&] { loadBodyModel(dir + "/tree.npz"); }),
              HasSubstr(dir + "/tree.npz: key 'kintree_table': 52 joints but not SMPL-H's tree "
                              "(joint 30 has another parent)"));

  // 55 joints (SMPL-X's count): refused before any other key is read.
  BodyModel smplx = smpl;
  smplx.parents.resize(55);
  for (int j = 24; j < 55; ++j) smplx.parents[size_t(j)] = 20;
  smplx.weights.conservativeResize(Eigen::NoChange, 55);
  smplx.weights.rightCols(31).setZero();
  smplx.posedirs = MatX::Zero(smplx.posedirs.rows(), 9 * 54);
  MatX regressor = MatX(smpl.J_regressor);
  regressor.conservativeResize(55, Eigen::NoChange);
  for (int j = 24; j < 55; ++j) regressor.row(j) = regressor.row(20);
  smplx.J_regressor = regressor.sparseView(1.0, 0.0);
  saveBodyModel(smplx, dir + "/smplx.npz");
  const std::string message = messageOf<InputError>([&] { loadBodyModel(dir + "/smplx.npz"); });
  EXPECT_THAT(message, HasSubstr(dir + "/smplx.npz: key 'kintree_table' has shape (2, 55): 55 "
                                       "joints (SMPL-X?)"));
  EXPECT_THAT(message, HasSubstr("SMPL (24 joints) and SMPL-H / SMPL+H (52 joints)"));
}

}  // namespace
}  // namespace flsh
