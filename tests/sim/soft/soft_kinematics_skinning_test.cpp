// The prepared nodes of SoftKinematics (prepare / skinNodes) against positions() evaluated from
// scratch, as the soft state, the held pose blend and the bones change in turn: the unposed
// nodes Y_j = X̄_j + P_j + u_j are kept between evaluations while the soft state and the pose
// blend stay, and must follow each of them (FEM, handle ROM, modal ROM).
#include "flsh/core/rotation.h"
#include "sim/soft/soft_kinematics.h"
#include "sim/soft/soft_term_checks.h"

namespace flsh {
namespace {

using test::SoftModel;

class SoftKinematicsSkinning : public ::testing::TestWithParam<SoftModel> {};

TEST_P(SoftKinematicsSkinning, PreparedNodesFollowSoftStateBlendAndBones) {
  const std::shared_ptr<const SoftAvatar> avatar = test::smallSoftAvatar(GetParam());
  detail::SoftKinematics kin(*avatar, avatar->restJoints(), avatar->body().parents);
  const int bones = kin.numBones();
  std::vector<int> all(size_t(kin.numNodes()));
  std::iota(all.begin(), all.end(), 0);

  const auto rotations = [&](unsigned seed) {
    const VecX theta = test::randomVector(3 * bones, 0.4, seed);
    std::vector<Mat3> R;
    for (int b = 0; b < bones; ++b) R.push_back(rodrigues(theta.segment<3>(3 * b)));
    return R;
  };
  const auto translations = [&](unsigned seed) {
    const VecX t = test::randomVector(3 * bones, 0.3, seed);
    return MatX3(Eigen::Map<const MatX3>(t.data(), bones, 3));
  };
  long version = 0;
  // Prepares a new version at (R, t), skins every node and compares with positions().
  const auto check = [&](const std::vector<Mat3>& R, const MatX3& t, const char* what) {
    const detail::BoneFrames frames{R, t};
    kin.prepare(++version, frames);
    kin.skinNodes(all);
    MatX3 expected;
    kin.positions(frames, kin.u, expected);
    ASSERT_GT(expected.norm(), 0.0);
    EXPECT_LE((kin.x() - expected).cwiseAbs().maxCoeff(), 1e-12) << what;
    const MatX3 rest_posed = kin.restNodes() + kin.poseBlend();
    MatX3 Y_expected = rest_posed;
    for (int j = 0; j < kin.numNodes(); ++j)
      Y_expected.row(j) += kin.nodeDisplacement(kin.u, j).transpose();
    EXPECT_LE((kin.Y() - Y_expected).cwiseAbs().maxCoeff(), 1e-12) << what;
  };

  const std::vector<Mat3> R1 = rotations(3), R2 = rotations(4);
  const MatX3 t1 = translations(5), t2 = translations(6);
  kin.u = test::randomVector(kin.numSoftDofs(), 0.01, 7);
  kin.setPoseBlend(R1);
  check(R1, t1, "first evaluation");
  const MatX3 Y_first = kin.Y();
  check(R2, t2, "other bones, same soft state and blend");
  kin.u = test::randomVector(kin.numSoftDofs(), 0.01, 8);
  check(R2, t2, "a new soft state");
  ASSERT_GT((kin.Y() - Y_first).cwiseAbs().maxCoeff(), 1e-6) << "the soft state moves Y";
  const MatX3 Y_second = kin.Y();
  kin.setPoseBlend(R2);
  check(R2, t2, "a new held pose blend from rotations");
  ASSERT_GT((kin.Y() - Y_second).cwiseAbs().maxCoeff(), 1e-6) << "the pose blend moves Y";
  const VecX offsets = test::randomVector(3 * kin.numNodes(), 0.01, 9);
  kin.setPoseBlendOffsets(Eigen::Map<const MatX3>(offsets.data(), kin.numNodes(), 3));
  check(R1, t1, "offsets set directly");
  kin.setPoseBlend(R1);
  std::vector<int> some;
  MatX3 seeded;
  for (int j = 0; j < kin.numNodes(); j += 3) some.push_back(j);
  seeded.setConstant(Eigen::Index(some.size()), 3, 0.02);
  kin.poseBlend();  // evaluates every row (ROM)
  kin.seedPoseBlend(some, seeded);
  if (kin.heldPoseRotations()) check(R1, t1, "seeded offsets");
}

INSTANTIATE_TEST_SUITE_P(Models, SoftKinematicsSkinning,
                         ::testing::Values(SoftModel::Fem, SoftModel::Rom, SoftModel::RomModes),
                         test::modelName);

}  // namespace
}  // namespace flsh
