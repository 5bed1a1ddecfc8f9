// Simulable::getGradientParameterJacobian / getGradientPreviousStateJacobian against central
// finite differences of the total gradient, on a walking avatar with active ground and sphere
// contact and mocap tracking (600-vertex synthetic body).
#include <gtest/gtest.h>

#include <memory>
#include <random>

#include "flsh/core/error.h"
#include "flsh/sim/simulable.h"
#include "sim/terms/term_checks.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::jacobianMatchesFiniteDifferences;
using test::randomVector;
using test::messageOf;

const test::SmallScene& shared() { return test::smallScene(600, 1.0); }

VecX totalGradient(const Simulable& sim) {
  VecX g = VecX::Zero(sim.numDofs());
  sim.getDynamicGradientVector(g);
  sim.getPotentialGradientVector(g);
  return g;
}

// Sets q_{n−1} = M ⊕ dM, q_n = N ⊕ dN (state vectors plus increments) and the current state Q.
void setHistory(Simulable& sim, const VecX& N, const VecX& dN, const VecX& M, const VecX& dM,
                const VecX& Q) {
  sim.setState(M);
  sim.updateState(dM);
  sim.postUpdate();
  sim.setState(N);
  sim.updateState(dN);
  sim.postUpdate();
  sim.setState(Q);
}

// A walking avatar one step in with a distinct velocity history, moved off the prediction, a
// ground plane 1.5 cm above its lowest vertex and a sphere pressing 1 cm into its frontmost
// vertex (curved collider: nonzero distance Hessian).
struct Scenario {
  std::unique_ptr<Simulable> sim;
  VecX N, M, Q;
};

Scenario walkingAvatarInContact() {
  Scenario s;
  s.sim = std::make_unique<Simulable>(shared().avatar, shared().walk);
  Simulable& sim = *s.sim;
  sim.initialize();
  sim.preUpdate();
  const int n = sim.numDofs();
  const VecX predicted = sim.getState();
  s.N = predicted + randomVector(n, 0.02, 3);
  s.M = s.N + randomVector(n, 0.02, 4);
  s.Q = predicted + randomVector(n, 0.03, 5);
  setHistory(sim, s.N, VecX::Zero(n), s.M, VecX::Zero(n), s.Q);
  test::placeGroundAndSphere(sim);
  return s;
}

// ∂g/∂p against finite differences of g under setParameter (p = p0 + scale ⊙ δ).
void expectParameterJacobian(SimParameter p, double tol, bool relative_scale = false) {
  Scenario s = walkingAvatarInContact();
  Simulable& sim = *s.sim;
  totalGradient(sim);
  ASSERT_GT(sim.stats().active_contacts, 1);
  const VecX p0 = sim.getParameter(p);
  ASSERT_EQ(p0.size(), sim.parameterSize(p));
  const VecX scale = relative_scale ? VecX(p0.cwiseAbs()) : VecX::Ones(p0.size());
  const MatX analytic = sim.getGradientParameterJacobian(p) * scale.asDiagonal();
  ASSERT_EQ(analytic.rows(), sim.numDofs());
  ASSERT_EQ(analytic.cols(), p0.size());
  const auto gradient = [&](const VecX& d) {
    sim.setParameter(p, p0 + scale.cwiseProduct(d));
    const VecX g = totalGradient(sim);
    sim.setParameter(p, p0);
    return g;
  };
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(gradient, VecX::Zero(p0.size()), analytic, tol));
}

TEST(ParameterDerivatives, RestJointsMatchFiniteDifferences) {
  expectParameterJacobian(SimParameter::RestJoints, 1e-5);
}

TEST(ParameterDerivatives, BoneInertiaMatchFiniteDifferences) {
  expectParameterJacobian(SimParameter::BoneInertia, 1e-5);
}

TEST(ParameterDerivatives, PoseTargetsMatchFiniteDifferences) {
  expectParameterJacobian(SimParameter::PoseTargets, 1e-5);
}

TEST(ParameterDerivatives, RootTranslationTargetMatchFiniteDifferences) {
  expectParameterJacobian(SimParameter::RootTranslationTarget, 1e-5);
}

TEST(ParameterDerivatives, StiffnessesMatchFiniteDifferences) {
  expectParameterJacobian(SimParameter::Stiffnesses, 1e-5, true);
}

TEST(ParameterDerivatives, ColliderOffsetsMatchFiniteDifferences) {
  expectParameterJacobian(SimParameter::ColliderOffsets, 1e-5);
}

// The stiffness columns against a Simulable rebuilt with the changed options at the same state
// (independent of setParameter).
TEST(ParameterDerivatives, StiffnessesMatchRebuiltSimulables) {
  Scenario s = walkingAvatarInContact();
  const MatX analytic = s.sim->getGradientParameterJacobian(SimParameter::Stiffnesses);
  const SimulableOptions base = s.sim->options();
  const auto gradient = [&](const VecX& d) {
    SimulableOptions o = base;
    o.joint_stiffness *= 1.0 + d[0];
    o.tracking_stiffness *= 1.0 + d[1];
    o.root_stiffness *= 1.0 + d[2];
    o.contact.stiffness *= 1.0 + d[3];
    Simulable rebuilt(shared().avatar, shared().walk, o);
    rebuilt.initialize();
    rebuilt.preUpdate();
    setHistory(rebuilt, s.N, VecX::Zero(s.N.size()), s.M, VecX::Zero(s.N.size()), s.Q);
    rebuilt.setColliders(s.sim->colliders());
    return totalGradient(rebuilt);
  };
  const Eigen::Vector4d scale(base.joint_stiffness, base.tracking_stiffness, base.root_stiffness,
                              base.contact.stiffness);
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(gradient, VecX::Zero(4),
                                               analytic * scale.asDiagonal(), 1e-5));
}

// ∂g/∂β against central differences of simulables built on avatars at β ± ε, at the same
// states and colliders (through J(β), bone inertias, the contact surface and vertex areas).
TEST(ParameterDerivatives, ShapeMatchesRebuiltAvatars) {
  Scenario s = walkingAvatarInContact();
  Simulable& sim = *s.sim;
  totalGradient(sim);
  ASSERT_GT(sim.stats().active_contacts, 1);
  const VecX beta0 = sim.getParameter(SimParameter::Shape);
  ASSERT_EQ(beta0.size(), sim.parameterSize(SimParameter::Shape));
  const MatX analytic = sim.getGradientParameterJacobian(SimParameter::Shape);
  ASSERT_EQ(analytic.rows(), sim.numDofs());
  ASSERT_EQ(analytic.cols(), beta0.size());
  const auto gradient = [&](const VecX& beta) {
    auto avatar = std::make_shared<SoftAvatar>(shared().body, beta, shared().avatar->settings());
    avatar->initVolumetricData();
    Simulable rebuilt(avatar, shared().walk, sim.options());
    rebuilt.initialize();
    rebuilt.preUpdate();
    setHistory(rebuilt, s.N, VecX::Zero(s.N.size()), s.M, VecX::Zero(s.N.size()), s.Q);
    rebuilt.setColliders(sim.colliders());
    return totalGradient(rebuilt);
  };
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(gradient, beta0, analytic, 1e-5, 1e-5));
}

TEST(ParameterDerivatives, SeveralGroupsAtOnceMatchOneByOne) {
  Scenario s = walkingAvatarInContact();
  const std::vector<SimParameter> groups = {SimParameter::Shape, SimParameter::Stiffnesses,
                                            SimParameter::RestJoints, SimParameter::BoneInertia};
  const std::vector<MatX> together = s.sim->getGradientParameterJacobians(groups);
  ASSERT_EQ(together.size(), groups.size());
  for (size_t k = 0; k < groups.size(); ++k)
    EXPECT_TRUE(together[k].isApprox(s.sim->getGradientParameterJacobian(groups[k]), 1e-14)) << k;
}

// The three forms of ∂g/∂p: the Jacobian–vector products of several directions at once (with
// β's chain through the rest joints and bone inertias) and the vector–Jacobian products equal
// the Jacobians applied to the same vectors.
TEST(ParameterDerivatives, ProductsOfSeveralDirectionsMatchTheJacobians) {
  Scenario s = walkingAvatarInContact();
  const Simulable& sim = *s.sim;
  const int n = sim.numDofs();
  std::vector<SimParameter> groups;
  for (const SimParameterInfo& info : simParameters()) groups.push_back(info.id);
  const std::vector<MatX> jacobians = sim.getGradientParameterJacobians(groups);
  std::vector<VecX> values;  // direction d, group g at values[d * groups + g]
  std::vector<ParameterDirection> directions(2);
  values.reserve(2 * groups.size());
  std::vector<VecX> expected(2, VecX::Zero(n));
  for (size_t d = 0; d < 2; ++d) {
    directions[d].fill(nullptr);
    for (size_t g = 0; g < groups.size(); ++g) {
      if (d == 1 && g % 2 == 0) continue;  // the second direction leaves every other group alone
      values.push_back(randomVector(sim.parameterSize(groups[g]), 1.0, int(40 + 10 * d + g)));
      directions[d][size_t(groups[g])] = &values.back();
      expected[d] += jacobians[g] * values.back();
    }
  }
  const std::vector<VecX> jvps = sim.getGradientParameterJVPs(directions);
  ASSERT_EQ(jvps.size(), 2u);
  for (size_t d = 0; d < 2; ++d) {
    ASSERT_GT(jvps[d].norm(), 0.0) << d;
    EXPECT_LT((jvps[d] - expected[d]).norm(), 1e-10 * expected[d].norm()) << d;
  }
  const VecX lambda = randomVector(n, 1.0, 60);
  const std::vector<VecX> vjps = sim.getGradientParameterVJPs(lambda, groups);
  for (size_t g = 0; g < groups.size(); ++g) {
    const VecX reference = jacobians[g].transpose() * lambda;
    EXPECT_LT((vjps[g] - reference).norm(), 1e-10 * (1.0 + reference.norm())) << g;
  }
  const VecX wrong = VecX::Zero(5);
  ParameterDirection bad{};
  bad[size_t(SimParameter::Stiffnesses)] = &wrong;
  const std::string msg = messageOf<InputError>([&] { sim.getGradientParameterJVPs({bad}); });
  EXPECT_NE(msg.find("stiffnesses has 5 values, expected parameterSize() = 4"), std::string::npos)
      << msg;
}

TEST(ParameterDerivatives, ShapeIsFixedByTheAvatar) {
  Scenario s = walkingAvatarInContact();
  const std::string msg = messageOf<InputError>(
      [&] { s.sim->setParameter(SimParameter::Shape, VecX::Zero(10)); });
  EXPECT_NE(msg.find("SoftAvatar"), std::string::npos) << msg;
  EXPECT_EQ(s.sim->getParameter(SimParameter::Shape), shared().avatar->betas());
}

// What initialize() sets, as a function of the rest joints: against setParameter(RestJoints)
// followed by initialize().
TEST(ParameterDerivatives, InitialStateRestJointsJacobianMatchesFiniteDifferences) {
  Simulable sim(shared().avatar, shared().walk);
  sim.initialize();
  const VecX J0 = sim.getParameter(SimParameter::RestJoints);
  const VecX q0 = sim.getState();
  MatX dq, dv;
  sim.getInitialStateRestJointsJacobian(&dq, &dv);
  const auto state = [&](const VecX& J) {
    sim.setParameter(SimParameter::RestJoints, J);
    sim.initialize();
    // Increments relative to q0 (rotations do not move: compare the translations directly).
    VecX d = sim.getState() - q0;
    sim.setParameter(SimParameter::RestJoints, J0);
    return d;
  };
  const auto velocity = [&](const VecX& J) {
    sim.setParameter(SimParameter::RestJoints, J);
    sim.initialize();
    const VecX v = sim.getVelocity();
    sim.setParameter(SimParameter::RestJoints, J0);
    return v;
  };
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(state, J0, dq, 1e-7));
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(velocity, J0, dv, 1e-6));
}

TEST(ParameterDerivatives, PreviousStatesMatchFiniteDifferences) {
  Scenario s = walkingAvatarInContact();
  Simulable& sim = *s.sim;
  const int n = sim.numDofs();
  const VecX zero = VecX::Zero(n);
  for (int which : {1, 2}) {
    const MatX analytic = sim.getGradientPreviousStateJacobian(which);
    ASSERT_EQ(analytic.rows(), n);
    ASSERT_EQ(analytic.cols(), n);
    const auto gradient = [&](const VecX& d) {
      setHistory(sim, s.N, which == 1 ? d : zero, s.M, which == 2 ? d : zero, s.Q);
      const VecX g = totalGradient(sim);
      setHistory(sim, s.N, zero, s.M, zero, s.Q);
      return g;
    };
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(gradient, zero, analytic, 1e-5)) << which;
  }
}

TEST(ParameterDerivatives, StaticHasNoPreviousStateDependence) {
  Scenario s = walkingAvatarInContact();
  s.sim->setStatic(true);
  EXPECT_TRUE(s.sim->getGradientPreviousStateJacobian(1).isZero(0.0));
  EXPECT_TRUE(s.sim->getGradientPreviousStateJacobian(2).isZero(0.0));
}

TEST(ParameterDerivatives, DerivativeCallsDoNotChangeTheState) {
  Scenario s = walkingAvatarInContact();
  Simulable& sim = *s.sim;
  const VecX q = sim.getState(), v = sim.getVelocity(), g = totalGradient(sim);
  const int contacts = sim.stats().active_contacts;
  for (SimParameter p : {SimParameter::RestJoints, SimParameter::BoneInertia,
                         SimParameter::PoseTargets, SimParameter::RootTranslationTarget,
                         SimParameter::Stiffnesses, SimParameter::ColliderOffsets,
                         SimParameter::Shape})
    sim.getGradientParameterJacobian(p);
  const VecX targets = VecX::Ones(sim.parameterSize(SimParameter::PoseTargets));
  ParameterDirection along{};
  along[size_t(SimParameter::PoseTargets)] = &targets;
  sim.getGradientParameterJVPs({along});
  sim.getGradientParameterVJPs(VecX::Ones(sim.numDofs()), {SimParameter::Shape});
  sim.getGradientPreviousStateJacobian(1);
  sim.getGradientPreviousStateJacobian(2);
  EXPECT_EQ(sim.getState(), q);
  EXPECT_EQ(sim.getVelocity(), v);
  EXPECT_EQ(totalGradient(sim), g);
  EXPECT_EQ(sim.stats().active_contacts, contacts);
}

TEST(ParameterDerivatives, BadArgumentsThrowWithTheirShapes) {
  Scenario s = walkingAvatarInContact();
  Simulable& sim = *s.sim;
  EXPECT_THROW(sim.getGradientPreviousStateJacobian(3), InputError);
  const std::string size_message =
      messageOf<InputError>([&] { sim.setParameter(SimParameter::RestJoints, VecX::Zero(5)); });
  EXPECT_NE(size_message.find("5"), std::string::npos) << size_message;
  EXPECT_NE(size_message.find("72"), std::string::npos) << size_message;
  VecX inertia = sim.getParameter(SimParameter::BoneInertia);
  const VecX original = inertia;
  inertia[30] = -1.0;  // bone 3's mass
  EXPECT_THROW(sim.setParameter(SimParameter::BoneInertia, inertia), InputError);
  EXPECT_EQ(sim.getParameter(SimParameter::BoneInertia), original);  // nothing half-written
  VecX stiff = sim.getParameter(SimParameter::Stiffnesses);
  stiff[1] = -1.0;
  EXPECT_THROW(sim.setParameter(SimParameter::Stiffnesses, stiff), InputError);
  EXPECT_EQ(sim.options().tracking_stiffness, 355.0);
}

}  // namespace
}  // namespace flsh
