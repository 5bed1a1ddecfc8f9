// Rollout (the adjoint on the articulated skeleton): for every input group, the directional
// derivative of a whole-rollout loss (joint positions, rotation vectors and SMPL vertices)
// against a central finite difference of re-run rollouts, with and without contact (a ground
// plane the walk touches and a sphere); forward sensitivities against the reverse pass; the
// simulable left bitwise unchanged by backward(); bad inputs.
#include "flsh/diff/rollout.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>

#include "flsh/core/error.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::messageOf;
using test::randomVector;

constexpr int kSteps = 10;

const test::SmallScene& shared() { return test::smallScene(600, 1.0); }

RolloutOptions tightOptions() {
  RolloutOptions o;
  o.newton.gradient_tolerance = 1e-12;  // gradients are exact for the converged rollout
  return o;
}

// Colliders placed once from the base avatar's initial state: a ground plane 1 cm above the
// lowest vertex and a sphere pressing 1 cm into the frontmost vertex.
std::vector<Collider> sceneColliders() {
  static const std::vector<Collider> colliders = [] {
    Simulable sim(shared().avatar, shared().walk);
    sim.initialize();
    const MatX3 nodes = sim.getNodes();
    Eigen::Index lowest, front;
    nodes.col(1).minCoeff(&lowest);
    nodes.col(2).maxCoeff(&front);
    const Vec3 tip = nodes.row(front).transpose();
    return std::vector<Collider>{
        Collider::plane(Vec3(0, nodes(lowest, 1) + 0.01, 0), Vec3::UnitY()),
        Collider::sphere(tip + Vec3(0, 0, 0.04), 0.05)};
  }();
  return colliders;
}

// The mocap's targets at the rollout's steps (the base of the target inputs).
struct Targets {
  RowMatX pose, root;  // T × 72, T × 3 (SMPL trans)
};
const Targets& mocapTargets() {
  static const Targets targets = [] {
    Targets t;
    t.pose.resize(kSteps, 72);
    t.root.resize(kSteps, 3);
    Simulable sim(shared().avatar, shared().walk);
    sim.initialize();
    const Vec3 J0 = sim.getParameter(SimParameter::RestJoints).head<3>();
    for (int s = 0; s < kSteps; ++s) {
      sim.preUpdate();
      t.pose.row(s) = sim.getParameter(SimParameter::PoseTargets).transpose();
      t.root.row(s) = (sim.getParameter(SimParameter::RootTranslationTarget) - J0).transpose();
      sim.postUpdate();
    }
    return t;
  }();
  return targets;
}

// L = Σ_t w_t ‖joints_t − target_t‖² + Σ_t a_t · (rotation entries of q_t) + c · vertices_T.
struct Loss {
  RowMatX joint_targets;     // T × 72
  VecX weights;              // T
  RowMatX rotation_weights;  // T × numDofs, zero on translations
  MatX3 vertex_weights;      // #V × 3

  Loss() {
    const int n = 144;
    joint_targets = RowMatX::Zero(kSteps, 72);
    weights.resize(kSteps);
    rotation_weights = RowMatX::Zero(kSteps, n);
    for (int t = 0; t < kSteps; ++t) {
      joint_targets.row(t) = randomVector(72, 0.5, 100 + t).transpose();
      joint_targets.row(t) += VecX::Constant(72, 0.4).transpose();
      weights[t] = 1.0 + 0.1 * t;
      const VecX a = randomVector(n, 1.0, 200 + t);
      for (int b = 0; b < 24; ++b)
        rotation_weights.row(t).segment<3>(6 * b + 3) = a.segment<3>(6 * b + 3).transpose();
    }
    const int nv = shared().body->numVertices();
    const VecX c = randomVector(3 * nv, 1.0, 300);
    vertex_weights = Eigen::Map<const MatX3>(c.data(), nv, 3);
  }

  double value(const Rollout& r) const {
    const RowMatX joints = r.joints();
    double L = 0.0;
    for (int t = 0; t < kSteps; ++t) {
      L += weights[t] * (joints.row(t) - joint_targets.row(t)).squaredNorm();
      L += rotation_weights.row(t).dot(r.states().row(t));
    }
    L += (vertex_weights.array() * r.vertices(kSteps).array()).sum();
    return L;
  }

  // dL/dstates (T × numDofs) and the direct terms (β and J_0 in the vertices).
  std::pair<RowMatX, RolloutVariables> cotangent(const Rollout& r) const {
    const RowMatX joints = r.joints();
    RowMatX a = rotation_weights;
    for (int t = 0; t < kSteps; ++t) {
      const VecX dj = 2.0 * weights[t] * (joints.row(t) - joint_targets.row(t)).transpose();
      a.row(t) += r.jointsCotangent(Eigen::Map<const MatX3>(dj.data(), 24, 3)).transpose();
    }
    const Rollout::VerticesCotangent v = r.verticesCotangent(kSteps, vertex_weights);
    a.row(kSteps - 1) += v.state.transpose();
    return {a, v.direct};
  }
};

const Loss& loss() {
  static const Loss l;
  return l;
}

// Base inputs of a scenario: explicit targets (the mocap's); the initial state and velocity
// explicit only when their own gradient is checked (otherwise initialize()'s, whose dependence
// on J(β) the shape and rest-joint gradients then include).
struct Scenario {
  bool contact = false;
  bool explicit_initial = false;
};

RolloutInputs baseInputs(const Scenario& s) {
  RolloutInputs in;
  in.pose_targets = mocapTargets().pose;
  in.root_targets = mocapTargets().root;
  if (s.explicit_initial) {
    Simulable sim(shared().avatar, shared().walk);
    sim.initialize();
    in.initial_state = sim.getState();
    in.initial_velocity = sim.getVelocity();
  }
  return in;
}

// Runs the rollout with the model and inputs moved by ε·direction and returns the loss.
double lossAlong(const Scenario& s, const RolloutVariables& d, double eps) {
  std::shared_ptr<const SoftAvatar> avatar = shared().avatar;
  if (d.shape.size()) {
    auto shaped = std::make_shared<SoftAvatar>(shared().body, avatar->betas() + eps * d.shape,
                                               avatar->settings());
    shaped->initVolumetricData();
    avatar = shaped;
  }
  auto sim = std::make_shared<Simulable>(avatar, shared().walk);
  if (s.contact) sim->setColliders(sceneColliders());
  if (d.rest_joints.size())
    sim->setParameter(SimParameter::RestJoints,
                      sim->getParameter(SimParameter::RestJoints) + eps * d.rest_joints);
  if (d.bone_inertia.size())
    sim->setParameter(SimParameter::BoneInertia,
                      sim->getParameter(SimParameter::BoneInertia) + eps * d.bone_inertia);
  RolloutInputs in = baseInputs(s);
  if (d.pose_targets.size()) in.pose_targets += eps * d.pose_targets;
  if (d.root_targets.size()) in.root_targets += eps * d.root_targets;
  if (d.stiffnesses.size())
    in.stiffnesses = sim->getParameter(SimParameter::Stiffnesses) + eps * d.stiffnesses;
  if (d.collider_offsets.size()) in.collider_offsets = eps * d.collider_offsets;
  if (d.initial_state.size()) in.initial_state += eps * d.initial_state;
  if (d.initial_velocity.size()) in.initial_velocity += eps * d.initial_velocity;
  Rollout rollout(sim, tightOptions());
  rollout.run(kSteps, in);
  return loss().value(rollout);
}

struct Recorded {
  std::shared_ptr<Simulable> sim;
  std::unique_ptr<Rollout> rollout;
};

Recorded recordBase(const Scenario& s) {
  Recorded r;
  r.sim = std::make_shared<Simulable>(shared().avatar, shared().walk);
  if (s.contact) r.sim->setColliders(sceneColliders());
  r.rollout = std::make_unique<Rollout>(r.sim, tightOptions());
  r.rollout->run(kSteps, baseInputs(s));
  return r;
}

RolloutVariables gradientOf(Rollout& rollout) {
  const auto [a, direct] = loss().cotangent(rollout);
  return rollout.backward(a, direct);
}

// The directional derivative dot(∇L, d) against (L(+ε) − L(−ε)) / 2ε.
void expectDirectionalDerivative(const Scenario& s, const RolloutVariables& d, double eps,
                                 double tol = 1e-6) {
  Recorded base = recordBase(s);
  for (int t = 1; t <= kSteps; ++t) ASSERT_TRUE(base.rollout->tape().stepInfo(t).converged) << t;
  if (s.contact) {
    int contacts = 0;
    // Contacts are active along the rollout (checked on the recorded steps).
    SimulableAdjointModel model(base.sim);
    const auto saved = model.saveStep();
    for (int t = 1; t <= kSteps; ++t) {
      model.restoreStep(base.rollout->tape().stepSnapshot(t));
      contacts += base.sim->stats().active_contacts;
    }
    model.restoreStep(*saved);
    ASSERT_GT(contacts, kSteps);
  }
  const RolloutVariables grad = gradientOf(*base.rollout);
  const double analytic = dot(grad, d);
  ASSERT_GT(std::abs(analytic), 1e-8)
      << "the directional derivative is zero: the check would be vacuous";
  const double fd = (lossAlong(s, d, eps) - lossAlong(s, d, -eps)) / (2.0 * eps);
  const double error = std::abs(analytic - fd) / std::abs(fd);
  EXPECT_LE(error, tol) << "analytic " << analytic << ", central difference " << fd;
  char text[32];
  std::snprintf(text, sizeof(text), "%.3g", error);
  ::testing::Test::RecordProperty("relative_error", text);
}

class RolloutGradient : public ::testing::TestWithParam<bool> {
 protected:
  Scenario scenario(bool explicit_initial = false) const { return {GetParam(), explicit_initial}; }
};

TEST_P(RolloutGradient, Shape) {
  RolloutVariables d;
  d.shape = randomVector(10, 1.0, 1);
  expectDirectionalDerivative(scenario(), d, 1e-4);
}

TEST_P(RolloutGradient, RestJoints) {
  RolloutVariables d;
  d.rest_joints = randomVector(72, 0.01, 2);
  expectDirectionalDerivative(scenario(), d, 1e-4);
}

TEST_P(RolloutGradient, BoneInertia) {
  RolloutVariables d;
  const VecX p0 = Simulable(shared().avatar).getParameter(SimParameter::BoneInertia).cwiseAbs();
  d.bone_inertia = randomVector(240, 0.1, 3).cwiseProduct(p0);
  expectDirectionalDerivative(scenario(), d, 1e-4);
}

TEST_P(RolloutGradient, PoseTargets) {
  RolloutVariables d;
  const VecX v = randomVector(kSteps * 72, 0.1, 4);
  d.pose_targets = Eigen::Map<const RowMatX>(v.data(), kSteps, 72);
  expectDirectionalDerivative(scenario(), d, 1e-5);
}

TEST_P(RolloutGradient, RootTargets) {
  RolloutVariables d;
  const VecX v = randomVector(kSteps * 3, 0.01, 5);
  d.root_targets = Eigen::Map<const RowMatX>(v.data(), kSteps, 3);
  expectDirectionalDerivative(scenario(), d, 1e-4);
}

TEST_P(RolloutGradient, Stiffnesses) {
  RolloutVariables d;
  const VecX k = Simulable(shared().avatar, shared().walk).getParameter(SimParameter::Stiffnesses);
  d.stiffnesses = randomVector(4, 0.1, 6).cwiseProduct(k);
  expectDirectionalDerivative(scenario(), d, 1e-4);
}

// Collider offsets exist only in the scenario with colliders (contact), so not parameterized.
TEST(RolloutGradientWithContact, ColliderOffsets) {
  RolloutVariables d;
  d.collider_offsets = randomVector(6, 0.01, 7);
  expectDirectionalDerivative(Scenario{true, false}, d, 1e-4);
}

TEST_P(RolloutGradient, InitialState) {
  RolloutVariables d;
  d.initial_state = randomVector(144, 0.01, 8);
  expectDirectionalDerivative(scenario(true), d, 1e-4);
}

TEST_P(RolloutGradient, InitialVelocity) {
  RolloutVariables d;
  d.initial_velocity = randomVector(144, 0.1, 9);
  expectDirectionalDerivative(scenario(true), d, 1e-4);
}

INSTANTIATE_TEST_SUITE_P(ContactAndFree, RolloutGradient, ::testing::Values(true, false),
                         [](const auto& info) {
                           return info.param ? "WithContact" : "WithoutContact";
                         });

// vᵀ(dL/dp) by the reverse pass equals Σ_t a_t · (dq_t/dp v) by forward sensitivities, for a
// direction in every group at once (and each group alone).
TEST(Rollout, ForwardSensitivitiesAgreeWithTheReversePass) {
  const Scenario s{true, false};
  Recorded base = recordBase(s);
  const auto [a, direct] = loss().cotangent(*base.rollout);
  const RolloutVariables grad = base.rollout->backward(a, direct);
  RolloutVariables all;
  all.shape = randomVector(10, 1.0, 11);
  all.rest_joints = randomVector(72, 0.01, 12);
  all.bone_inertia = randomVector(240, 0.1, 13);
  all.pose_targets =
      RowMatX(Eigen::Map<const RowMatX>(randomVector(kSteps * 72, 0.1, 14).data(), kSteps, 72));
  all.root_targets =
      RowMatX(Eigen::Map<const RowMatX>(randomVector(kSteps * 3, 0.01, 15).data(), kSteps, 3));
  all.stiffnesses = randomVector(4, 1.0, 16);
  all.collider_offsets = randomVector(6, 0.01, 17);
  all.initial_state = randomVector(144, 0.01, 18);
  all.initial_velocity = randomVector(144, 0.1, 19);
  std::vector<RolloutVariables> directions = {all};
  RolloutVariables only;
  only.pose_targets = all.pose_targets;
  directions.push_back(only);
  only = {};
  only.shape = all.shape;
  directions.push_back(only);
  const std::vector<RowMatX> dq = base.rollout->forwardSensitivities(directions);
  ASSERT_EQ(dq.size(), directions.size());
  for (size_t k = 0; k < directions.size(); ++k) {
    ASSERT_EQ(dq[k].rows(), kSteps);
    ASSERT_EQ(dq[k].cols(), 144);
    const double forward = (a.array() * dq[k].array()).sum() + dot(direct, directions[k]);
    const double reverse = dot(grad, directions[k]);
    ASSERT_GT(std::abs(reverse), 1e-8) << k;
    EXPECT_NEAR(forward, reverse, 1e-9 * std::abs(reverse)) << k;
  }
}

// The sweeps' products (no matrices) equal the transposed / plain Jacobian products at every
// recorded step of a rollout with contact, and Shape deferred to finishParameterVJPs matches.
TEST(Rollout, ProductsMatchTheJacobians) {
  Recorded base = recordBase({true, false});
  Simulable& sim = *base.sim;
  SimulableAdjointModel model(base.sim);
  const auto saved = model.saveStep();
  const std::vector<ParameterGroupInfo> groups = model.parameterGroups();
  const std::vector<SimParameter> all = {SimParameter::Shape,
                                         SimParameter::RestJoints,
                                         SimParameter::BoneInertia,
                                         SimParameter::PoseTargets,
                                         SimParameter::RootTranslationTarget,
                                         SimParameter::Stiffnesses,
                                         SimParameter::ColliderOffsets,
                                         SimParameter::Material};
  auto close = [](const VecX& a, const VecX& b) {
    return (a - b).norm() <= 1e-10 * std::max(1.0, b.norm());
  };
  int contacts = 0;
  for (int t = 1; t <= kSteps; ++t) {
    model.restoreStep(base.rollout->tape().stepSnapshot(t));
    contacts += sim.stats().active_contacts;
    const VecX lambda = randomVector(model.numDofs(), 1.0, 100 + t);
    std::vector<MatX> jacobians;
    model.parameterJacobians(jacobians);
    const std::vector<VecX> full = sim.getGradientParameterVJPs(lambda, all);
    std::vector<VecX> deferred;
    model.parameterVJPs(lambda, deferred);
    model.finishParameterVJPs(deferred);
    for (size_t g = 0; g < groups.size(); ++g) {
      if (groups[g].size == 0) {  // the skeleton has no material
        EXPECT_EQ(groups[g].name, std::string("material"));
        continue;
      }
      const VecX expected = jacobians[g].transpose() * lambda;
      ASSERT_GT(expected.norm(), 0.0) << groups[g].name << " step " << t;
      EXPECT_TRUE(close(full[g], expected)) << groups[g].name << " step " << t;
      EXPECT_TRUE(close(deferred[g], expected)) << groups[g].name << " step " << t;
    }
    // Tangents: one direction over every group.
    std::vector<VecX> dirs(groups.size());
    std::vector<std::vector<const VecX*>> directions(1);
    VecX expected = VecX::Zero(model.numDofs());
    for (size_t g = 0; g < groups.size(); ++g) {
      dirs[g] = randomVector(groups[g].size, 1.0, 200 + unsigned(g));
      directions[0].push_back(&dirs[g]);
      expected += jacobians[g] * dirs[g];
    }
    std::vector<VecX> jvp;
    model.parameterJVPs(directions, jvp);
    EXPECT_TRUE(close(jvp[0], expected)) << "step " << t;
    // Previous states.
    const SpMat G1 = model.previousStateJacobian(1), G2 = model.previousStateJacobian(2);
    VecX a_n, a_nm1;
    model.previousStatesVJP(lambda, a_n, a_nm1);
    ASSERT_GT(a_n.norm(), 0.0);
    ASSERT_GT(a_nm1.norm(), 0.0);
    EXPECT_TRUE(close(a_n, G1.transpose() * lambda));
    EXPECT_TRUE(close(a_nm1, G2.transpose() * lambda));
    const VecX dq_n = randomVector(model.numDofs(), 1.0, 300 + t);
    const VecX dq_nm1 = randomVector(model.numDofs(), 1.0, 400 + t);
    EXPECT_TRUE(close(model.previousStatesJVP(dq_n, dq_nm1), G1 * dq_n + G2 * dq_nm1));
  }
  model.restoreStep(*saved);
  ASSERT_GT(contacts, kSteps);
  EXPECT_THROW(sim.getGradientParameterVJPs(VecX::Zero(3), all), InputError);
  EXPECT_THROW(sim.getGradientPreviousStatesJVP(VecX::Zero(3), VecX::Zero(3)), InputError);
}

TEST(Rollout, BackwardLeavesTheSimulableUnchangedAndRepeats) {
  Recorded base = recordBase({true, false});
  Simulable& sim = *base.sim;
  const SimulableStep before = sim.saveStep();
  const VecX q = sim.getState(), v = sim.getVelocity();
  const VecX targets = sim.getParameter(SimParameter::PoseTargets);
  const VecX root = sim.getParameter(SimParameter::RootTranslationTarget);
  const VecX offsets = sim.getParameter(SimParameter::ColliderOffsets);
  const double time = sim.time();
  const int contacts = sim.stats().active_contacts;
  const auto [a, direct] = loss().cotangent(*base.rollout);
  const RolloutVariables g1 = base.rollout->backward(a, direct);
  const RolloutVariables g2 = base.rollout->backward(a, direct);
  base.rollout->forwardSensitivities({g1});
  const SimulableStep after = sim.saveStep();
  EXPECT_TRUE(after.t == before.t && after.t_n == before.t_n && after.t_nm1 == before.t_nm1);
  for (int b = 0; b < 24; ++b) {
    EXPECT_TRUE(after.R[b] == before.R[b]);
    EXPECT_TRUE(after.R_n[b] == before.R_n[b]);
    EXPECT_TRUE(after.R_nm1[b] == before.R_nm1[b]);
    EXPECT_TRUE(after.target_R[b] == before.target_R[b]);
  }
  EXPECT_EQ(sim.getState(), q);
  EXPECT_EQ(sim.getVelocity(), v);
  EXPECT_EQ(sim.time(), time);
  EXPECT_EQ(sim.getParameter(SimParameter::PoseTargets), targets);
  EXPECT_EQ(sim.getParameter(SimParameter::RootTranslationTarget), root);
  EXPECT_EQ(sim.getParameter(SimParameter::ColliderOffsets), offsets);
  EXPECT_EQ(sim.stats().active_contacts, contacts);
  EXPECT_EQ(g1.shape, g2.shape);
  EXPECT_EQ(g1.pose_targets, g2.pose_targets);
  EXPECT_EQ(g1.initial_state, g2.initial_state);
  EXPECT_EQ(g1.stiffnesses, g2.stiffnesses);
  EXPECT_EQ(g1.collider_offsets, g2.collider_offsets);
  EXPECT_EQ(g1.bone_inertia, g2.bone_inertia);
}

TEST(Rollout, RejectsBadInputsWithClearMessages) {
  auto sim = std::make_shared<Simulable>(shared().avatar, shared().walk);
  Rollout rollout(sim, tightOptions());
  EXPECT_NE(messageOf<Error>([&] { rollout.backward(RowMatX::Zero(1, 144)); }).find("run()"),
            std::string::npos);
  RolloutInputs in;
  in.pose_targets = RowMatX::Zero(3, 72);
  std::string msg = messageOf<InputError>([&] { rollout.run(4, in); });
  EXPECT_NE(msg.find("pose_targets"), std::string::npos) << msg;
  EXPECT_NE(msg.find("(3, 72)"), std::string::npos) << msg;
  EXPECT_NE(msg.find("(4, 72)"), std::string::npos) << msg;
  in = {};
  in.root_targets = RowMatX::Zero(4, 3);
  in.root_targets(2, 1) = std::nan("");
  msg = messageOf<InputError>([&] { rollout.run(4, in); });
  EXPECT_NE(msg.find("root_targets"), std::string::npos) << msg;
  EXPECT_NE(msg.find("NaN"), std::string::npos) << msg;
  in = {};
  in.initial_state = VecX::Zero(7);
  msg = messageOf<InputError>([&] { rollout.run(4, in); });
  EXPECT_NE(msg.find("initial_state"), std::string::npos) << msg;
  EXPECT_NE(msg.find("144"), std::string::npos) << msg;
  in = {};
  in.collider_offsets = VecX::Zero(3);
  msg = messageOf<InputError>([&] { rollout.run(4, in); });
  EXPECT_NE(msg.find("0 colliders"), std::string::npos) << msg;
  EXPECT_THROW(rollout.run(0), InputError);
  EXPECT_EQ(rollout.numSteps(), 0);  // nothing recorded by the failed runs

  rollout.run(3);
  msg = messageOf<InputError>([&] { rollout.backward(RowMatX::Zero(2, 144)); });
  EXPECT_NE(msg.find("dL_dstates"), std::string::npos) << msg;
  EXPECT_NE(msg.find("(3, 144)"), std::string::npos) << msg;
  RowMatX nan = RowMatX::Zero(3, 144);
  nan(1, 5) = std::nan("");
  EXPECT_NE(messageOf<InputError>([&] { rollout.backward(nan); }).find("NaN"), std::string::npos);
  RolloutVariables bad;
  bad.pose_targets = RowMatX::Zero(2, 72);
  msg = messageOf<InputError>([&] { rollout.forwardSensitivities({bad}); });
  EXPECT_NE(msg.find("pose_targets"), std::string::npos) << msg;
  EXPECT_NE(messageOf<InputError>([&] {
              rollout.verticesCotangent(3, MatX3::Zero(5, 3));
            }).find("(5, 3)"),
            std::string::npos);

  // Targets without tracking springs would do nothing: an error, not a silent no-op.
  auto passive = std::make_shared<Simulable>(shared().avatar);
  Rollout passive_rollout(passive);
  in = {};
  in.pose_targets = RowMatX::Zero(2, 72);
  msg = messageOf<InputError>([&] { passive_rollout.run(2, in); });
  EXPECT_NE(msg.find("tracking"), std::string::npos) << msg;
}

TEST(Rollout, KinematicBonesAreRejected) {
  SimulableOptions options;
  options.kinematic_bones = {0};
  auto sim = std::make_shared<Simulable>(shared().avatar, shared().walk, options);
  const std::string msg = messageOf<Error>([&] { Rollout r(sim); });
  EXPECT_NE(msg.find("kinematic"), std::string::npos) << msg;
}

}  // namespace
}  // namespace flsh
