// The held pose blend's derivatives in the rotations it was set from
// (SoftKinematics::poseBlendTangent / poseBlendCotangent), the chain the soft skeletons' adjoint
// needs from q_n: the tangent against central differences of setPoseBlend, and the cotangent
// as its transpose (FEM and ROM).
#include "flsh/core/rotation.h"
#include "sim/soft/soft_kinematics.h"
#include "sim/soft/soft_term_checks.h"

namespace flsh {
namespace {

using test::SoftModel;

class PoseBlendDerivatives : public ::testing::TestWithParam<SoftModel> {};

TEST_P(PoseBlendDerivatives, TangentMatchesDifferencesAndCotangentIsItsTranspose) {
  const std::shared_ptr<const SoftAvatar> avatar = test::smallSoftAvatar(GetParam());
  detail::SoftKinematics kin(*avatar, avatar->restJoints(), avatar->body().parents);
  const int bones = kin.numBones();
  const VecX theta = test::randomVector(3 * bones, 0.5, 3);
  std::vector<Mat3> R;
  for (int b = 0; b < bones; ++b) R.push_back(rodrigues(theta.segment<3>(3 * b)));
  std::vector<int> nodes;
  for (int j = 0; j < kin.numNodes(); j += 7) nodes.push_back(j);
  const VecX d = test::randomVector(3 * bones, 1.0, 4);

  MatX3 dP;
  kin.poseBlendTangent(R, d, nodes, dP);
  ASSERT_GT(dP.norm(), 0.0);
  const auto blendAt = [&](double eps) {
    std::vector<Mat3> moved = R;
    for (int b = 0; b < bones; ++b) moved[b] = rodrigues(eps * d.segment<3>(3 * b)) * R[b];
    kin.setPoseBlend(moved);
    const MatX3& P = kin.poseBlend();
    MatX3 rows(Eigen::Index(nodes.size()), 3);
    for (size_t k = 0; k < nodes.size(); ++k) rows.row(Eigen::Index(k)) = P.row(nodes[k]);
    return rows;
  };
  const double eps = 1e-6;
  const MatX3 fd = (blendAt(eps) - blendAt(-eps)) / (2 * eps);
  EXPECT_LT((dP - fd).norm(), 1e-7 * dP.norm());

  std::vector<Vec3> mu;
  const VecX m = test::randomVector(3 * int(nodes.size()), 1.0, 5);
  double expected = 0.0;
  for (size_t k = 0; k < nodes.size(); ++k) {
    mu.push_back(m.segment<3>(3 * Eigen::Index(k)));
    expected += mu.back().dot(dP.row(Eigen::Index(k)).transpose());
  }
  VecX cotangent = VecX::Zero(3 * bones);
  kin.poseBlendCotangent(R, nodes, mu, cotangent);
  ASSERT_GT(cotangent.norm(), 0.0);
  EXPECT_NEAR(cotangent.dot(d), expected, 1e-10 * std::abs(expected));
  EXPECT_EQ(cotangent.head<3>().norm() > 0.0, true) << "the root turns its children's blocks";
}

INSTANTIATE_TEST_SUITE_P(Models, PoseBlendDerivatives,
                         ::testing::Values(SoftModel::Fem, SoftModel::Rom, SoftModel::RomModes),
                         test::modelName);

}  // namespace
}  // namespace flsh
