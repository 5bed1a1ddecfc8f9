// A soft skeleton's (FEM and ROM) previous-state derivatives, the whole simulable: ∂g/∂q_n and
// ∂g/∂q_{n−1} (the nodal inertia's prediction x̂, and the pose blend held from q_n's rotations,
// which moves the nodes of inertia, gravity and contact) against central differences of the
// total gradient with the previous state moved in a snapshot (restoreStep with an empty pose
// blend holds it from the moved R_n, as preUpdate does); the products against the Jacobians;
// the surface's cotangents.
#include <memory>
#include <vector>

#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "sim/soft/soft_term_checks.h"

namespace flsh {
namespace {

using test::SoftModel;
using test::totalGradient;

// The snapshot with q_n (which = 1) or q_{n−1} (which = 2) moved by increments d (bones:
// t += δt, R ← exp([δω]×) R; soft state: u += δu), its pose blend to be held again.
SimulableStep movedHistory(const SimulableStep& base, int which, const VecX& d) {
  SimulableStep s = base;
  std::vector<Mat3>& R = which == 1 ? s.R_n : s.R_nm1;
  MatX3& t = which == 1 ? s.t_n : s.t_nm1;
  VecX& u = which == 1 ? s.u_n : s.u_nm1;
  for (size_t b = 0; b < R.size(); ++b) {
    t.row(Eigen::Index(b)) += d.segment<3>(6 * Eigen::Index(b)).transpose();
    R[b] = rodrigues(Vec3(d.segment<3>(6 * Eigen::Index(b) + 3))) * R[b];
  }
  u += d.tail(u.size());
  s.pose_blend.resize(0, 3);  // held again from the moved R_n
  s.pose_blend_R.clear();
  return s;
}

// D(:, idx) against differences of the total gradient along the coordinates idx of q_n or
// q_{n−1}; then the products against D.
void expectPreviousStateDerivatives(Simulable& sim, double tol, std::vector<int> states = {1, 2},
                                    double eps = 1e-6) {
  const int n = sim.numDofs();
  const SimulableStep base = sim.saveStep();
  const VecX q0 = sim.getState(), g0 = totalGradient(sim);
  const std::vector<int> idx = test::softTermCoordinates(sim, g0);
  const int m = int(idx.size());
  const MatX D[2] = {sim.getGradientPreviousStateJacobian(1),
                     sim.getGradientPreviousStateJacobian(2)};
  for (int which : states) {
    SCOPED_TRACE(which == 1 ? "q_n" : "q_{n-1}");
    ASSERT_EQ(D[which - 1].rows(), n);
    ASSERT_EQ(D[which - 1].cols(), n);
    const auto gradient = [&](const VecX& sub) {
      VecX d = VecX::Zero(n);
      for (int k = 0; k < m; ++k) d[idx[size_t(k)]] = sub[k];
      sim.restoreStep(movedHistory(base, which, d));
      const VecX g = totalGradient(sim);
      sim.restoreStep(base);
      return g;
    };
    EXPECT_TRUE(test::jacobianMatchesFiniteDifferences(gradient, VecX::Zero(m),
                                                       D[which - 1](Eigen::all, idx), tol, eps));
  }
  const VecX lambda = test::randomVector(n, 1.0, 31);
  VecX a_n, a_nm1;
  sim.getGradientPreviousStatesVJP(lambda, &a_n, &a_nm1);
  EXPECT_LT((a_n - D[0].transpose() * lambda).norm(), 1e-10 * (1.0 + a_n.norm()));
  EXPECT_LT((a_nm1 - D[1].transpose() * lambda).norm(), 1e-10 * (1.0 + a_nm1.norm()));
  const VecX dq_n = test::randomVector(n, 1.0, 32), dq_nm1 = test::randomVector(n, 1.0, 33);
  const VecX jvp = sim.getGradientPreviousStatesJVP(dq_n, dq_nm1);
  const VecX expected = D[0] * dq_n + D[1] * dq_nm1;
  EXPECT_LT((jvp - expected).norm(), 1e-10 * (1.0 + expected.norm()));
  // Derivative calls leave the state and the step as they found them.
  EXPECT_EQ((sim.getState() - q0).norm(), 0.0);
  EXPECT_EQ((totalGradient(sim) - g0).norm(), 0.0);
}

class SoftPreviousStateDerivatives : public ::testing::TestWithParam<SoftModel> {};

TEST_P(SoftPreviousStateDerivatives, MatchFiniteDifferences) {
  auto sim = test::softTermScenario(GetParam());
  totalGradient(*sim);
  ASSERT_GT(sim->stats().active_contacts, 0);
  expectPreviousStateDerivatives(*sim, 1e-5);
}

// Static, only the held pose blend couples a step to q_n (through gravity and contact, with no
// inertia to dwarf it): the rotation columns of ∂g/∂q_n alone, and nothing from q_{n−1}. Its
// entries (~1e-2) are small beside the gradient's (~1e3), whose round-off a 1e-6 difference
// would amplify to ~1e-7: steps of 1e-4 rad (the gradient is smooth in R_n: P is linear in
// R_pᵀ R_b).
TEST_P(SoftPreviousStateDerivatives, StaticKeepsThePoseBlendShare) {
  auto sim = test::softTermScenario(GetParam());
  sim->setStatic(true);
  const MatX D1 = sim->getGradientPreviousStateJacobian(1);
  const int nb = sim->numBoneDofs();
  double rotations = 0.0, others = 0.0;
  for (int col = 0; col < sim->numDofs(); ++col)
    (col < nb && col % 6 >= 3 ? rotations : others) += D1.col(col).squaredNorm();
  ASSERT_GT(rotations, 0.0);
  EXPECT_EQ(others, 0.0);
  EXPECT_TRUE(sim->getGradientPreviousStateJacobian(2).isZero(0.0));
  expectPreviousStateDerivatives(*sim, 1e-6, {1}, 1e-4);
}

// The surface's cotangents (getNodesCotangents) against differences of μ · getNodes(): in the
// state (against getNodesStateJacobian), in q_n (its rotations hold the pose blend) and in the
// rest joints.
TEST_P(SoftPreviousStateDerivatives, SurfaceCotangentsMatchDifferences) {
  auto sim = test::softTermScenario(GetParam());
  const int n = sim->numDofs();
  const SimulableStep base = sim->saveStep();
  const MatX3 nodes = sim->getNodes();
  const VecX m = test::randomVector(int(nodes.size()), 1.0, 51);
  const MatX3 mu = Eigen::Map<const MatX3>(m.data(), nodes.rows(), 3);
  VecX state, previous, joints;
  sim->getNodesCotangents(mu, &state, &previous, &joints);
  const Eigen::Map<const VecX> flat(mu.data(), mu.size());
  const VecX expected_state = sim->getNodesStateJacobian().transpose() * flat;
  ASSERT_GT(state.norm(), 0.0);
  EXPECT_LT((state - expected_state).norm(), 1e-10 * state.norm());
  const auto pairing = [&] { return (sim->getNodes().array() * mu.array()).sum(); };
  const VecX d = test::randomVector(n, 1.0, 52);
  const double eps = 1e-6;
  sim->restoreStep(movedHistory(base, 1, eps * d));
  const double plus = pairing();
  sim->restoreStep(movedHistory(base, 1, -eps * d));
  const double minus = pairing();
  sim->restoreStep(base);
  ASSERT_GT(std::abs(previous.dot(d)), 0.0);
  EXPECT_NEAR(previous.dot(d), (plus - minus) / (2 * eps), 1e-6 * std::abs(previous.dot(d)));
  const VecX J0 = sim->getParameter(SimParameter::RestJoints), dJ = test::randomVector(72, 1.0, 53);
  sim->setParameter(SimParameter::RestJoints, J0 + eps * dJ);
  const double joints_plus = pairing();
  sim->setParameter(SimParameter::RestJoints, J0 - eps * dJ);
  const double joints_minus = pairing();
  sim->setParameter(SimParameter::RestJoints, J0);
  ASSERT_GT(std::abs(joints.dot(dJ)), 0.0);
  EXPECT_NEAR(joints.dot(dJ), (joints_plus - joints_minus) / (2 * eps),
              1e-6 * std::abs(joints.dot(dJ)));
}

// getNodesOfFrames and getNodesCotangentsOfFrames (many states in one pass) against getNodes and
// getNodesCotangents of each state: the same values to rounding; bad frames are InputErrors.
TEST_P(SoftPreviousStateDerivatives, SurfaceOfFramesMatchesEachState) {
  auto sim = test::softTermScenario(GetParam());
  const int n = sim->numDofs();
  const SimulableStep base = sim->saveStep();
  const int V = int(sim->getNodes().rows());
  SimulableStep moved = movedHistory(base, 1, 0.05 * test::randomVector(n, 1.0, 61));
  moved.u += 0.5 * moved.u;  // and another soft state
  const std::vector<SimulableStep> steps = {base, moved};
  std::vector<SurfaceFrame> frames;
  RowMatX nodes(2, 3 * V), dL(2, 3 * V), state(2, n), previous(2, n);
  VecX joints = VecX::Zero(72), shape;
  for (int k = 0; k < 2; ++k) {
    sim->restoreStep(steps[size_t(k)]);
    frames.push_back(sim->getSurfaceFrame());
    const MatX3 x = sim->getNodes();
    nodes.row(k) = Eigen::Map<const Eigen::RowVectorXd>(x.data(), 3 * V);
    dL.row(k) = test::randomVector(3 * V, 1.0, 62 + k).transpose();
    VecX s, p, j, b;
    sim->getNodesCotangents(Eigen::Map<const MatX3>(dL.row(k).data(), V, 3), &s, &p, &j, &b);
    state.row(k) = s.transpose();
    previous.row(k) = p.transpose();
    joints += j;
    shape = k == 0 ? b : VecX(shape + b);
  }
  sim->restoreStep(base);
  ASSERT_FALSE(frames[0].held_R[1].isApprox(frames[1].held_R[1], 1e-6));
  ASSERT_GT(frames[1].soft.norm(), 0.0);
  const auto close = [](const auto& a, const auto& b) {
    return a.size() > 0 && a.size() == b.size() && b.cwiseAbs().maxCoeff() > 0.0 &&
           (a - b).cwiseAbs().maxCoeff() <= 1e-12 * b.cwiseAbs().maxCoeff();
  };
  EXPECT_TRUE(close(sim->getNodesOfFrames(frames), nodes));
  RowMatX state_f, previous_f;
  VecX joints_f, shape_f;
  sim->getNodesCotangentsOfFrames(frames, dL, &state_f, &previous_f, &joints_f, &shape_f);
  EXPECT_TRUE(close(state_f, state));
  EXPECT_TRUE(close(previous_f, previous));
  EXPECT_TRUE(close(joints_f, joints));
  EXPECT_TRUE(close(shape_f, shape));
  std::vector<SurfaceFrame> bad = frames;
  bad[1].soft.resize(3);
  EXPECT_THROW(sim->getNodesOfFrames(bad), InputError);
  bad = frames;
  bad[0].held_R.pop_back();
  EXPECT_THROW(sim->getNodesOfFrames(bad), InputError);
  EXPECT_THROW(sim->getNodesCotangentsOfFrames(frames, RowMatX::Zero(2, 3 * V - 3), &state_f,
                                               nullptr, nullptr, nullptr),
               InputError);
  EXPECT_THROW(sim->getNodesCotangentsOfFrames(frames, RowMatX::Zero(1, 3 * V), &state_f, nullptr,
                                               nullptr, nullptr),
               InputError);
}

INSTANTIATE_TEST_SUITE_P(Models, SoftPreviousStateDerivatives,
                         ::testing::Values(SoftModel::Fem, SoftModel::Rom, SoftModel::RomModes),
                         test::modelName);

}  // namespace
}  // namespace flsh
