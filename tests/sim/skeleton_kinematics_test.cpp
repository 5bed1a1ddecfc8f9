// The articulated skeleton's kinematics (src/sim/skeleton_kinematics.h) against finite
// differences of its own surface positions: the surface Jacobian in the increment chart, and
// mapForces / mapHessian as Jᵀ f and Jᵀ K J.
#include "sim/skeleton_kinematics.h"

#include <gtest/gtest.h>

#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/rotation.h"
#include "flsh/volume/soft_avatar.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using detail::BoneFrames;
using detail::SkeletonKinematics;

struct Posed {
  std::vector<Mat3> R;
  MatX3 t;
};

Posed randomBones(int bones, unsigned seed) {
  Posed p;
  const VecX theta = test::randomVector(3 * bones, 0.6, seed);
  const VecX shift = test::randomVector(3 * bones, 0.3, seed + 1);
  p.t.resize(bones, 3);
  for (int b = 0; b < bones; ++b) {
    p.R.push_back(rodrigues(theta.segment<3>(3 * b)));
    p.t.row(b) = shift.segment<3>(3 * b).transpose();
  }
  return p;
}

// q in the increment chart: t_b += δt_b, R_b ← exp(δω_b) R_b.
Posed moved(const Posed& p, const VecX& dq) {
  Posed out = p;
  for (int b = 0; b < int(p.R.size()); ++b) {
    out.t.row(b) += dq.segment<3>(6 * b).transpose();
    out.R[b] = rodrigues(dq.segment<3>(6 * b + 3)) * p.R[b];
  }
  return out;
}

MatX denseSurfaceJacobian(const SkeletonKinematics& kin, int bones) {
  std::vector<Triplet> triplets;
  kin.surfaceJacobian(triplets);
  SpMat D(3 * kin.numSurface(), 6 * bones);
  D.setFromTriplets(triplets.begin(), triplets.end());
  return MatX(D);
}

class SkeletonKinematicsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const test::SmallScene& scene = test::smallScene(300);
    rest = scene.avatar->restVertices();
    joints = scene.avatar->restJoints();
    surface = SkinnedSurface::build(scene.avatar->body().weights, rest, joints, 48);
    bones = int(joints.rows());
  }
  MatX3 rest, joints;
  SkinnedSurface surface;
  int bones = 0;
};

TEST_F(SkeletonKinematicsTest, SurfaceJacobianMatchesFiniteDifferences) {
  const SkeletonKinematics kin(surface, rest, joints);
  const Posed p = randomBones(bones, 11);
  kin.prepare(0, {p.R, p.t});
  const MatX J = denseSurfaceJacobian(kin, bones);
  const int n = 6 * bones, V = kin.numSurface();
  ASSERT_GT(J.norm(), 0.0);
  const MatX fd = test::finiteDifferenceJacobian(
      [&](const VecX& dq) {
        const Posed q = moved(p, dq);
        kin.prepare(1, {q.R, q.t});
        MatX3 x;
        kin.surface(&x, nullptr);
        return VecX(Eigen::Map<const VecX>(RowMatX(x).data(), 3 * V));
      },
      VecX::Zero(n), 1e-6);
  EXPECT_LT((J - fd).norm(), 1e-7 * J.norm());
}

TEST_F(SkeletonKinematicsTest, PositionsForcesAndHessiansAreTheSurfaceJacobiansProducts) {
  const SkeletonKinematics kin(surface, rest, joints);
  const Posed p = randomBones(bones, 21);
  const BoneFrames frames{p.R, p.t};
  kin.prepare(0, frames);
  MatX3 x_all, Y;
  kin.surface(&x_all, &Y);
  EXPECT_EQ((Y - rest).norm(), 0.0);
  const MatX J = denseSurfaceJacobian(kin, bones);
  const int n = 6 * bones, V = kin.numSurface();

  const std::vector<int> vertices = {3, 40, 41, 150, V - 1};
  MatX3 x;
  kin.positions(vertices, frames, x);
  for (size_t j = 0; j < vertices.size(); ++j)
    EXPECT_LT((x.row(Eigen::Index(j)) - x_all.row(vertices[j])).norm(), 1e-12);

  // Σ_j J_jᵀ f_j (a zero force is skipped, and must give nothing).
  VecX f = test::randomVector(3 * int(vertices.size()), 1.0, 22);
  f.segment<3>(3).setZero();
  VecX g = VecX::Zero(n);
  kin.mapForces(vertices, f, p.R, g, 0);
  VecX expected = VecX::Zero(n);
  for (size_t j = 0; j < vertices.size(); ++j)
    expected += J.middleRows<3>(3 * vertices[j]).transpose() * f.segment<3>(3 * Eigen::Index(j));
  ASSERT_GT(g.norm(), 0.0);
  EXPECT_LT((g - expected).norm(), 1e-12 * expected.norm());

  // Σ J_iᵀ K J_i with zero forces (no curvature); an index may repeat.
  std::vector<std::pair<int, Mat3>> node_blocks;
  MatX H_expected = MatX::Zero(n, n);
  for (int j : {0, 2, 2, 4}) {
    const VecX r = test::randomVector(9, 1.0, 30 + unsigned(j) + unsigned(node_blocks.size()));
    const Mat3 A = Eigen::Map<const Mat3>(r.data());
    const Mat3 K = A * A.transpose();
    node_blocks.emplace_back(j, K);
    const auto Jj = J.middleRows<3>(3 * vertices[size_t(j)]);
    H_expected += Jj.transpose() * K * Jj;
  }
  detail::BonePairBlocks blocks(bones);
  kin.mapHessian(vertices, node_blocks, VecX::Zero(f.size()), p.R, false, blocks);
  std::vector<Triplet> H;
  blocks.emit(H, 0);
  const MatX H_dense = test::denseFromTriplets(H, n);
  ASSERT_GT(H_dense.norm(), 0.0);
  EXPECT_LT((H_dense - H_expected).norm(), 1e-12 * H_expected.norm());

  double margin[kNumJoints];
  kin.contactMargins(margin);
  for (int b = 0; b < bones; ++b) EXPECT_EQ(margin[b], 0.0);
}

// The curvature part: with forces f_i held fixed, the exact Hessian of Σ f_i · x_i(q) in the
// chart is the derivative of mapForces' gradient (symmetrized: the chart's second derivative).
TEST_F(SkeletonKinematicsTest, RotationCurvatureMatchesTheGradientsDerivative) {
  const SkeletonKinematics kin(surface, rest, joints);
  const Posed p = randomBones(bones, 41);
  const std::vector<int> vertices = {5, 77, 120, 200};
  const VecX f = test::randomVector(3 * int(vertices.size()), 1.0, 42);
  const int n = 6 * bones;
  detail::BonePairBlocks blocks(bones);
  kin.mapHessian(vertices, {}, f, p.R, false, blocks);
  std::vector<Triplet> H;
  blocks.emit(H, 0);
  const MatX H_dense = test::denseFromTriplets(H, n);
  ASSERT_GT(H_dense.norm(), 0.0);
  // E(q) = Σ f_i · x_i(q) along the chart: its Hessian at dq = 0 by differences of energies.
  auto energy = [&](const VecX& dq) {
    const Posed q = moved(p, dq);
    MatX3 x;
    kin.positions(vertices, {q.R, q.t}, x);
    double E = 0.0;
    for (size_t j = 0; j < vertices.size(); ++j)
      E += f.segment<3>(3 * Eigen::Index(j)).dot(x.row(Eigen::Index(j)).transpose());
    return E;
  };
  const double eps = 1e-4;
  MatX fd = MatX::Zero(n, n);
  for (int b = 0; b < bones; ++b)
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) {
        const int i = 6 * b + 3 + r, k = 6 * b + 3 + c;
        VecX a = VecX::Zero(n), d = VecX::Zero(n);
        a[i] = eps;
        d[k] = eps;
        fd(i, k) =
            (energy(a + d) - energy(a - d) - energy(d - a) + energy(-a - d)) / (4 * eps * eps);
      }
  EXPECT_LT((H_dense - fd).norm(), 1e-5 * H_dense.norm());
}

}  // namespace
}  // namespace flsh
