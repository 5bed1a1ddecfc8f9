// Rollout through the soft skeletons (FEM and ROM): for every input group (the material through
// SoftAvatar::withMaterial avatars, β through withShape avatars), the directional
// derivative of a whole-rollout loss (joint positions, the state vectors with their soft part,
// and the simulated surface at every step, which moves with the pose blend held from the
// previous state) against a central difference of re-run rollouts, with and without contact (a
// ground plane the walk touches and a sphere), also across steps that needed line-search cuts and
// PSD directions (the body thrown at the ground); forward sensitivities against the reverse
// pass; backward leaves the simulable bitwise unchanged; unconverged steps are refused.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <tuple>

#include "flsh/core/error.h"
#include "flsh/diff/rollout.h"
#include "flsh/diff/simulable_adjoint.h"
#include "support/small_soft_avatar.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::randomVector;
using test::SoftModel;

constexpr int kSteps = 6;

const test::SmallScene& scene() { return test::smallScene(800); }

// The soft models' Newton (the scene's: exact Hessian with a PSD fallback, the lagged factor),
// converged tightly: the gradients are exact for the converged rollout.
RolloutOptions tightOptions(bool coarse_correction = true) {
  RolloutOptions o;
  for (NewtonOptions* newton : {&o.soft_tissue_newton, &o.reduced_newton}) {
    newton->gradient_tolerance = 1e-11;
    newton->max_iterations = 100;
    newton->lagged.coarse_correction = coarse_correction;
  }
  return o;
}

// A ground plane 1 cm above the lowest surface node of the initial state and a sphere pressing
// 1 cm into the frontmost one (placed once per model).
std::vector<Collider> sceneColliders(SoftModel model) {
  Simulable sim(test::smallSoftAvatar(model), scene().walk);
  sim.initialize();
  const MatX3 nodes = sim.getNodes();
  Eigen::Index lowest, front;
  nodes.col(1).minCoeff(&lowest);
  nodes.col(2).maxCoeff(&front);
  const Vec3 tip = nodes.row(front).transpose();
  return {Collider::plane(Vec3(0, nodes(lowest, 1) + 0.01, 0), Vec3::UnitY()),
          Collider::sphere(tip + Vec3(0, 0, 0.04), 0.05)};
}

// Bitwise equal step data (states, soft states, pose blend, time, targets).
bool sameStep(const SimulableStep& a, const SimulableStep& b) {
  bool same = a.t == b.t && a.t_n == b.t_n && a.t_nm1 == b.t_nm1 && a.time == b.time &&
              a.target_t0 == b.target_t0 && a.u == b.u && a.u_n == b.u_n && a.u_nm1 == b.u_nm1 &&
              a.pose_blend == b.pose_blend && a.pose_blend_R == b.pose_blend_R;
  for (size_t k = 0; k < a.R.size(); ++k)
    same = same && a.R[k] == b.R[k] && a.R_n[k] == b.R_n[k] && a.R_nm1[k] == b.R_nm1[k] &&
           a.target_R[k] == b.target_R[k];
  return same;
}

struct Case {
  SoftModel model;
  bool contact;
  bool explicit_initial = false;  // the initial state and velocity as inputs
  double drop = 0.0;              // m/s added downward to the root's initial velocity (an input)
  bool coarse_correction = true;  // LaggedFactorOptions::coarse_correction (the defaults: on)
};

std::shared_ptr<Simulable> makeSimulable(const Case& c,
                                         std::shared_ptr<const SoftAvatar> avatar = nullptr) {
  if (!avatar) avatar = test::smallSoftAvatar(c.model);
  auto sim = std::make_shared<Simulable>(avatar, scene().walk);
  if (c.contact) sim->setColliders(sceneColliders(c.model));
  return sim;
}

RolloutInputs baseInputs(const Case& c) {
  RolloutInputs in;
  Simulable sim(test::smallSoftAvatar(c.model), scene().walk);
  sim.initialize();
  const Vec3 J0 = sim.getParameter(SimParameter::RestJoints).head<3>();
  if (c.explicit_initial) {
    // Soft tissue already moving: the state and velocity three steps into the walk.
    static const auto walked = [](SoftModel model) {
      auto moving = std::make_shared<Simulable>(test::smallSoftAvatar(model), scene().walk);
      Rollout warm_up(moving, tightOptions());
      warm_up.run(3);
      return std::pair{moving->getState(), moving->getVelocity()};
    };
    static const auto fem = walked(SoftModel::Fem), rom = walked(SoftModel::Rom),
                      modes = walked(SoftModel::RomModes);
    const auto& start = c.model == SoftModel::Fem ? fem : c.model == SoftModel::Rom ? rom : modes;
    in.initial_state = start.first;
    in.initial_velocity = start.second;
  }
  if (c.drop != 0.0) {  // thrown at the ground: hard contact from the first step
    if (in.initial_velocity.size() == 0) in.initial_velocity = sim.getVelocity();
    in.initial_velocity[1] -= c.drop;
  }
  in.pose_targets.resize(kSteps, 72);
  in.root_targets.resize(kSteps, 3);
  for (int t = 0; t < kSteps; ++t) {
    sim.preUpdate();
    in.pose_targets.row(t) = sim.getParameter(SimParameter::PoseTargets).transpose();
    in.root_targets.row(t) =
        (sim.getParameter(SimParameter::RootTranslationTarget) - J0).transpose();
    sim.postUpdate();
  }
  return in;
}

// L = Σ_t w_t ‖joints_t − target_t‖² + Σ_t a_t · q_t (rotations and the soft state) +
//     Σ_t c_t · vertices_t (the simulated surface).
struct Loss {
  RowMatX joint_targets, state_weights, vertex_weights;  // T × 72, T × n, T × 3V
  VecX weights;

  Loss(int n, int nb, int nv) {
    joint_targets.resize(kSteps, 72);
    state_weights = RowMatX::Zero(kSteps, n);
    vertex_weights.resize(kSteps, 3 * nv);
    weights.resize(kSteps);
    for (int t = 0; t < kSteps; ++t) {
      joint_targets.row(t) = (randomVector(72, 0.5, 100 + t) + VecX::Constant(72, 0.4)).transpose();
      weights[t] = 1.0 + 0.1 * t;
      const VecX a = randomVector(n, 1.0, 200 + t);
      for (int b = 0; b < nb / 6; ++b)
        state_weights.row(t).segment<3>(6 * b + 3) = a.segment<3>(6 * b + 3).transpose();
      state_weights.row(t).tail(n - nb) = 30.0 * a.tail(n - nb).transpose();
      vertex_weights.row(t) = randomVector(3 * nv, 1.0, 300 + t).transpose();
    }
  }

  double value(const Rollout& r) const {
    const RowMatX joints = r.joints();
    double L = 0.0;
    for (int t = 0; t < kSteps; ++t) {
      L += weights[t] * (joints.row(t) - joint_targets.row(t)).squaredNorm();
      L += state_weights.row(t).dot(r.states().row(t));
      const MatX3 v = r.vertices(t + 1);
      L += vertex_weights.row(t).dot(Eigen::Map<const Eigen::RowVectorXd>(v.data(), v.size()));
    }
    return L;
  }

  RolloutVariables gradient(Rollout& r) const {
    const RowMatX joints = r.joints();
    RowMatX dL_djoints(kSteps, 72);
    for (int t = 0; t < kSteps; ++t)
      dL_djoints.row(t) = 2.0 * weights[t] * (joints.row(t) - joint_targets.row(t));
    Rollout::TrajectoryCotangent c = r.trajectoryCotangent(dL_djoints, vertex_weights);
    return r.backward(c.states + state_weights, c.direct);
  }
};

const Loss& lossFor(SoftModel model) {
  static const auto make = [](SoftModel m) {
    Simulable sim(test::smallSoftAvatar(m));
    return Loss(sim.numDofs(), sim.numBoneDofs(), scene().body->numVertices());
  };
  static const Loss fem = make(SoftModel::Fem), rom = make(SoftModel::Rom),
                    modes = make(SoftModel::RomModes);
  return model == SoftModel::Fem ? fem : model == SoftModel::Rom ? rom : modes;
}

// The avatar with the material parameters moved by `step` (the same discretization).
std::shared_ptr<const SoftAvatar> avatarWithMaterial(SoftModel model, const VecX& step) {
  const auto avatar = test::smallSoftAvatar(model);
  MaterialModel m = avatar->volumetricData().material_model;
  m.setParameters(m.parameters() + step);
  return avatar->withMaterial(m);
}

double lossAlong(const Case& c, const RolloutVariables& d, double eps) {
  std::shared_ptr<const SoftAvatar> avatar;
  if (d.material.size()) avatar = avatarWithMaterial(c.model, eps * d.material);
  if (d.shape.size()) {
    const auto base = test::smallSoftAvatar(c.model);
    avatar = base->withShape(base->betas() + eps * d.shape);
  }
  auto sim = makeSimulable(c, avatar);
  if (d.rest_joints.size())
    sim->setParameter(SimParameter::RestJoints,
                      sim->getParameter(SimParameter::RestJoints) + eps * d.rest_joints);
  if (d.bone_inertia.size())
    sim->setParameter(SimParameter::BoneInertia,
                      sim->getParameter(SimParameter::BoneInertia) + eps * d.bone_inertia);
  RolloutInputs in = baseInputs(c);
  if (d.pose_targets.size()) in.pose_targets += eps * d.pose_targets;
  if (d.root_targets.size()) in.root_targets += eps * d.root_targets;
  if (d.stiffnesses.size())
    in.stiffnesses = sim->getParameter(SimParameter::Stiffnesses) + eps * d.stiffnesses;
  if (d.collider_offsets.size()) in.collider_offsets = eps * d.collider_offsets;
  if (d.initial_state.size()) in.initial_state += eps * d.initial_state;
  if (d.initial_velocity.size()) in.initial_velocity += eps * d.initial_velocity;
  Rollout rollout(sim, tightOptions(c.coarse_correction));
  rollout.run(kSteps, in);
  for (int t = 1; t <= kSteps; ++t)
    EXPECT_TRUE(rollout.tape().stepInfo(t).converged) << "eps " << eps << ", step " << t;
  return lossFor(c.model).value(rollout);
}

// dot(∇L, d) against (L(+ε) − L(−ε)) / 2ε: relative error ≤ 1e-6 (ROM), 1e-5 (FEM). The modal
// ROM's losses curve more along these directions (its stiff static-correction coordinates): the
// fourth-order difference (8 (L(ε) − L(−ε)) − (L(2ε) − L(−2ε))) / 12ε, at `modes_eps` when given.
// Measured (second / fourth order): Shape with contact 1.3e-6 / 7.7e-9 at ε = 1e-4; InitialState
// without contact 2.3e-6 / 9.7e-7 at 1e-3 and 2.7e-5 / 2.0e-7 at 3e-3; InitialVelocity without
// contact 8e-7 to 2.2e-6 between 1e-4 and 1e-3 (the loss's noise: the same with Newton stopping at
// 1e-13), 1.3e-8 / 2.5e-9 at 3e-3.
void expectDirectionalDerivative(const Case& c, const RolloutVariables& d, double eps,
                                 double modes_eps = 0.0, bool modes_fourth_order = true) {
  if (c.model == SoftModel::RomModes && modes_eps > 0.0) eps = modes_eps;
  auto sim = makeSimulable(c);
  Rollout rollout(sim, tightOptions(c.coarse_correction));
  rollout.run(kSteps, baseInputs(c));
  int contacts = 0;
  for (int t = 1; t <= kSteps; ++t) {
    ASSERT_TRUE(rollout.tape().stepInfo(t).converged) << t;
    if (c.contact) {
      SimulableAdjointModel model(sim);
      const auto saved = model.saveStep();
      model.restoreStep(rollout.tape().stepSnapshot(t));
      contacts += sim->stats().active_contacts;
      model.restoreStep(*saved);
    }
  }
  if (c.contact) {
    ASSERT_GT(contacts, kSteps) << "contact is active along the rollout";
  }
  const SimulableStep before = sim->saveStep();
  const RolloutVariables grad = lossFor(c.model).gradient(rollout);
  const SimulableStep after = sim->saveStep();
  EXPECT_TRUE(sameStep(before, after)) << "backward() changed the simulable";
  EXPECT_EQ(grad.shape.size(), sim->parameterSize(SimParameter::Shape));
  const double analytic = dot(grad, d);
  ASSERT_GT(std::abs(analytic), 1e-8) << "the directional derivative is zero: vacuous check";
  const double central = lossAlong(c, d, eps) - lossAlong(c, d, -eps);
  const double fd =
      c.model == SoftModel::RomModes && modes_fourth_order
          ? (8.0 * central - (lossAlong(c, d, 2 * eps) - lossAlong(c, d, -2 * eps))) / (12.0 * eps)
          : central / (2.0 * eps);
  const double error = std::abs(analytic - fd) / std::abs(fd);
  const double tol = c.model == SoftModel::Fem ? 1e-5 : 1e-6;
  EXPECT_LE(error, tol) << "analytic " << analytic << ", central difference " << fd;
  char text[32];
  std::snprintf(text, sizeof(text), "%.3g", error);
  ::testing::Test::RecordProperty("relative_error", text);
}

class SoftRolloutGradient : public ::testing::TestWithParam<std::tuple<SoftModel, bool>> {
 protected:
  Case scenario(bool explicit_initial = false) const {
    return {std::get<0>(GetParam()), std::get<1>(GetParam()), explicit_initial};
  }
};

TEST_P(SoftRolloutGradient, RestJoints) {
  RolloutVariables d;
  d.rest_joints = randomVector(72, 0.01, 2);
  expectDirectionalDerivative(scenario(), d, 1e-4);
}

TEST_P(SoftRolloutGradient, BoneInertia) {
  RolloutVariables d;
  const Case c = scenario();
  const VecX p0 =
      Simulable(test::smallSoftAvatar(c.model)).getParameter(SimParameter::BoneInertia).cwiseAbs();
  d.bone_inertia = randomVector(240, 0.1, 3).cwiseProduct(p0);
  // The inertias reach the loss only through the tracking stiffnesses: a small derivative, so
  // a longer step (1e-4 of each inertia) keeps the difference above the solves' rounding. The
  // modal ROM with contact is noisier still (its loss moves by ~5e-12 with the rollout's
  // convergence: relative error 4e-5 at ε = 1e-4, 3e-6 at 3e-4, 0.7–1.4e-6 at 1e-3 as the
  // forward states' rounding moves, below 1e-6 at 3e-3): the modal cases at 3e-3.
  expectDirectionalDerivative(c, d, 1e-3, 3e-3);
}

TEST_P(SoftRolloutGradient, PoseTargets) {
  RolloutVariables d;
  const VecX v = randomVector(kSteps * 72, 0.1, 4);
  d.pose_targets = Eigen::Map<const RowMatX>(v.data(), kSteps, 72);
  expectDirectionalDerivative(scenario(), d, 1e-5);
}

TEST_P(SoftRolloutGradient, RootTargets) {
  RolloutVariables d;
  const VecX v = randomVector(kSteps * 3, 0.01, 5);
  d.root_targets = Eigen::Map<const RowMatX>(v.data(), kSteps, 3);
  expectDirectionalDerivative(scenario(), d, 1e-4);
}

TEST_P(SoftRolloutGradient, Stiffnesses) {
  RolloutVariables d;
  const Case c = scenario();
  const VecX k = makeSimulable(c)->getParameter(SimParameter::Stiffnesses);
  d.stiffnesses = randomVector(4, 0.1, 6).cwiseProduct(k);
  expectDirectionalDerivative(c, d, 1e-4);
}

// The material file's coefficients (log-values and log-slopes; at β = 0 the slopes do not act):
// a rollout of SoftAvatar::withMaterial avatars.
TEST_P(SoftRolloutGradient, Material) {
  const Case c = scenario();
  RolloutVariables d;
  d.material = randomVector(makeSimulable(c)->parameterSize(SimParameter::Material), 0.1, 10);
  expectDirectionalDerivative(c, d, 1e-4);
}

// β: rollouts of SoftAvatar::withShape avatars (the same discretization at β′); the loss sees β
// through the rest nodes, masses, materials, joints and the simulated surface.
TEST_P(SoftRolloutGradient, Shape) {
  const Case c = scenario();
  RolloutVariables d;
  d.shape = randomVector(int(test::smallSoftAvatar(c.model)->betas().size()), 1.0, 18);
  expectDirectionalDerivative(c, d, 1e-4);
}

TEST_P(SoftRolloutGradient, InitialState) {
  const Case c = scenario(true);
  const int n = makeSimulable(c)->numDofs();
  RolloutVariables d;
  d.initial_state = randomVector(n, 0.01, 8);
  d.initial_state.tail(n - 144) *= 0.1;  // soft state: mm
  // ε = 1e-3, not 1e-4: here the central difference's error is the rollout's convergence noise
  // (Newton stops at a 1e-11 gradient), which grows as 1/ε — RomWithContact 7e-8 at 1e-4,
  // 5e-7 at 1e-5, 8e-9 at 1e-3 (GCC -O3), but 1.7e-6 at 1e-4 in the clang -O1 sanitizer build —
  // while the truncation error is still ≤ 4e-8 at 1e-3 in all four cases. The modal ROM: the
  // second-order difference at 4e-4. Its loss along d bends between 5e-4 and 1e-3 (with the
  // basis compressed with rotation_weight 0.3: at ε = 1e-3 the central difference is 0.3 % off,
  // from 3e-4 down to 2e-4 within 3.6e-8 without contact and 1.3e-7 with it); a fourth-order
  // stencil reaching 2ε would straddle it. The bend is a cubature sample crossing the rest
  // split's branch switch (restSplitExcess, C¹ there, its Hessian jumps): without contact, step
  // 1's bounded samples go 9 → 8 between ε = 5e-4 and 7e-4 (2026-12-03).
  expectDirectionalDerivative(c, d, 1e-3, 4e-4, false);
}

TEST_P(SoftRolloutGradient, InitialVelocity) {
  const Case c = scenario(true);
  RolloutVariables d;
  d.initial_velocity = randomVector(makeSimulable(c)->numDofs(), 0.1, 9);
  expectDirectionalDerivative(c, d, 1e-4, 3e-3);
}

INSTANTIATE_TEST_SUITE_P(Models, SoftRolloutGradient,
                         ::testing::Combine(::testing::Values(SoftModel::Fem, SoftModel::Rom,
                                                              SoftModel::RomModes),
                                            ::testing::Values(true, false)),
                         [](const auto& info) {
                           const SoftModel m = std::get<0>(info.param);
                           return std::string(m == SoftModel::Fem   ? "Fem"
                                              : m == SoftModel::Rom ? "Rom"
                                                                    : "RomModes") +
                                  (std::get<1>(info.param) ? "WithContact" : "WithoutContact");
                         });

class SoftRollout : public ::testing::TestWithParam<SoftModel> {};

// The adjoint's exact Hessian (assembled from the fixed block lists on a kept pattern) is the
// sum of the simulable's exact triplets, at a first state and, slots cached, at a second one
// deeper in contact.
TEST_P(SoftRollout, ExactHessianIsTheTripletsSum) {
  auto sim = std::make_shared<Simulable>(test::smallSoftAvatar(GetParam()), scene().walk);
  sim->initialize();
  sim->setColliders(sceneColliders(GetParam()));
  const SimulableAdjointModel model(sim);
  const int n = model.numDofs();
  for (int pass = 0; pass < 2; ++pass) {
    if (pass == 1) sim->updateState(randomVector(n, 2e-3, 11));
    std::vector<Triplet> triplets;
    sim->getDynamicHessianTripletVector(triplets, 0, false);
    sim->getPotentialHessianTripletVector(triplets, 0, false);
    SpMat expected(n, n);
    expected.setFromTriplets(triplets.begin(), triplets.end());
    SpMat H;
    model.exactHessian(H);
    ASSERT_EQ(H.rows(), n);
    ASSERT_EQ(H.cols(), n);
    const MatX E(expected), A(H);
    ASSERT_GT(E.cwiseAbs().maxCoeff(), 0.0);
    EXPECT_LT((A - E).cwiseAbs().maxCoeff(), 1e-12 * E.cwiseAbs().maxCoeff()) << "pass " << pass;
  }
}

// Collider offsets exist only with colliders, so not in the contact-or-free grid.
TEST_P(SoftRollout, ColliderOffsetsGradient) {
  RolloutVariables d;
  d.collider_offsets = randomVector(6, 0.01, 7);
  expectDirectionalDerivative({GetParam(), true}, d, 1e-4);
}

// Thrown at the ground at 8 m/s: Newton needs PSD directions (and, for the FEM, line-search cuts;
// the handle ROM's reduced Newton took none even at 20 m/s; the modal ROM takes ~35 cuts and no
// PSD direction at 8 m/s) on the way to the converged states; the gradient is that of the
// converged rollout all the same.
TEST_P(SoftRollout, GradientAcrossLineSearchCutsAndPsdDirections) {
  Case c{GetParam(), true};
  c.drop = 8.0;
  // With the bones as PCG's coarse level the FEM takes no line-search cuts in this fall: off,
  // it does (the case this test is for).
  c.coarse_correction = false;
  {
    auto sim = makeSimulable(c);
    Rollout rollout(sim, tightOptions(c.coarse_correction));
    rollout.run(kSteps, baseInputs(c));
    int cuts = 0, psd = 0;
    for (int t = 1; t <= kSteps; ++t) {
      cuts += rollout.tape().stepInfo(t).line_search_steps;
      psd += rollout.tape().stepInfo(t).psd_fallbacks;
    }
    if (c.model != SoftModel::RomModes) {
      ASSERT_GT(psd, 0);
    }
    if (c.model != SoftModel::Rom) {
      ASSERT_GT(cuts, 0);
    }
  }
  RolloutVariables d;
  const VecX v = randomVector(kSteps * 72, 0.1, 24);
  d.pose_targets = Eigen::Map<const RowMatX>(v.data(), kSteps, 72);
  d.shape = randomVector(int(test::smallSoftAvatar(c.model)->betas().size()), 1.0, 25);
  // The modal ROM at 3e-5: on an AVX-512 machine (2026-12-02) its loss along d took a different
  // line-search path between some of the ±ε, ±2ε rollouts at ε ≤ 1e-5 (relative error 1.1e-5 at
  // 3e-6, 3.0e-6 at 1e-5) and is smooth at 3e-5 (1.7e-9) and 1e-4 (3.4e-7).
  expectDirectionalDerivative(c, d, 1e-5, 3e-5);
}

// backward(…, groups) returns the groups asked for, as the full backward has them, and no others.
TEST_P(SoftRollout, BackwardOfSomeGroupsIsTheirShareOfAll) {
  const Case c{GetParam(), true};
  auto sim = makeSimulable(c);
  Rollout rollout(sim, tightOptions());
  rollout.run(kSteps, baseInputs(c));
  const VecX values = randomVector(kSteps * sim->numDofs(), 1.0, 31);
  const RowMatX cotangent = Eigen::Map<const RowMatX>(values.data(), kSteps, sim->numDofs());
  const RolloutVariables all = rollout.backward(cotangent);
  const auto close = [](const auto& a, const auto& b) {
    return a.size() > 0 && a.size() == b.size() &&
           (a - b).cwiseAbs().maxCoeff() <= 1e-12 * b.cwiseAbs().maxCoeff();
  };
  const RolloutVariables some =
      rollout.backward(cotangent, {}, {SimParameter::PoseTargets, SimParameter::Material});
  ASSERT_GT(all.material.cwiseAbs().maxCoeff(), 0.0);
  EXPECT_TRUE(close(some.pose_targets, all.pose_targets));
  EXPECT_TRUE(close(some.material, all.material));
  EXPECT_TRUE(close(some.initial_state, all.initial_state));
  EXPECT_EQ(some.shape.size(), 0);
  EXPECT_EQ(some.stiffnesses.size(), 0);
  EXPECT_EQ(some.root_targets.size(), 0);
  const RolloutVariables shape = rollout.backward(cotangent, {}, {SimParameter::Shape});
  ASSERT_GT(all.shape.cwiseAbs().maxCoeff(), 0.0);
  EXPECT_TRUE(close(shape.shape, all.shape));
  EXPECT_EQ(shape.material.size(), 0);
  EXPECT_EQ(shape.rest_joints.size(), 0);
  // All groups again afterwards.
  EXPECT_TRUE(close(rollout.backward(cotangent).stiffnesses, all.stiffnesses));
}

// trajectoryCotangent (the pose blend's share of all steps in one pass) is the sum of each
// step's verticesCotangent, and leaves the simulable's step as it was.
TEST_P(SoftRollout, TrajectoryCotangentIsTheSumOfEachStep) {
  const Case c{GetParam(), true};
  auto sim = makeSimulable(c);
  Rollout rollout(sim, tightOptions());
  rollout.run(kSteps, baseInputs(c));
  const Loss& loss = lossFor(c.model);
  const long nv = scene().body->numVertices();
  const VecX before = sim->getState();
  const Rollout::TrajectoryCotangent all =
      rollout.trajectoryCotangent(RowMatX(), loss.vertex_weights);
  EXPECT_TRUE(sim->getState() == before);
  RowMatX states = RowMatX::Zero(kSteps, sim->numDofs());
  RolloutVariables direct;
  for (int t = 1; t <= kSteps; ++t) {
    const Rollout::VerticesCotangent v = rollout.verticesCotangent(
        t, Eigen::Map<const MatX3>(loss.vertex_weights.row(t - 1).data(), nv, 3));
    states.row(t - 1) += v.state.transpose();
    ASSERT_GT(v.previous_state.norm(), 0.0);
    if (t > 1)
      states.row(t - 2) += v.previous_state.transpose();
    else
      direct.initial_state = v.previous_state;
    accumulate(direct, v.direct);
  }
  const auto close = [](const auto& a, const auto& b) {
    return a.size() > 0 && a.size() == b.size() &&
           (a - b).cwiseAbs().maxCoeff() <= 1e-12 * b.cwiseAbs().maxCoeff();
  };
  ASSERT_GT(states.cwiseAbs().maxCoeff(), 0.0);
  EXPECT_TRUE(close(all.states, states));
  EXPECT_TRUE(close(all.direct.initial_state, direct.initial_state));
  EXPECT_TRUE(close(all.direct.rest_joints, direct.rest_joints));
  EXPECT_TRUE(close(all.direct.shape, direct.shape));
}

// vertexTrajectory (all steps' surfaces in one pass) holds each step's vertices(t).
TEST_P(SoftRollout, VertexTrajectoryHoldsEachStepsVertices) {
  const Case c{GetParam(), true};
  auto sim = makeSimulable(c);
  Rollout rollout(sim, tightOptions());
  rollout.run(kSteps, baseInputs(c));
  const VecX before = sim->getState();
  const RowMatX all = rollout.vertexTrajectory();
  EXPECT_TRUE(sim->getState() == before);
  const long nv = scene().body->numVertices();
  ASSERT_EQ(all.rows(), kSteps);
  ASSERT_EQ(all.cols(), 3 * nv);
  for (int t = 1; t <= kSteps; ++t) {
    const MatX3 v = rollout.vertices(t);
    const Eigen::Map<const Eigen::RowVectorXd> row(v.data(), 3 * nv);
    EXPECT_LT((all.row(t - 1) - row).cwiseAbs().maxCoeff(), 1e-12 * row.cwiseAbs().maxCoeff())
        << "step " << t;
  }
}

// A step Newton leaves unconverged is reported, never differentiated.
TEST_P(SoftRollout, UnconvergedStepsAreRefused) {
  auto sim = makeSimulable({GetParam(), true});
  RolloutOptions options = tightOptions();
  for (NewtonOptions* newton : {&options.soft_tissue_newton, &options.reduced_newton})
    newton->max_iterations = 1;
  Rollout rollout(sim, options);
  rollout.run(2);
  ASSERT_FALSE(rollout.tape().stepInfo(1).converged);
  const std::string message =
      test::messageOf<Error>([&] { rollout.backward(RowMatX::Zero(2, sim->numDofs())); });
  EXPECT_NE(message.find("step 1 did not converge"), std::string::npos) << message;
  EXPECT_THROW(rollout.forwardSensitivities({RolloutVariables()}), Error);
}

// vᵀ(dL/dp) by the reverse pass equals Σ_t a_t · (dq_t/dp v) by forward sensitivities (the
// loss linear in the states: a_t = its state weights), for a direction in several groups. The
// FEM's sweeps solve by PCG (TapeSolveOptions), whose residual bounds the agreement: measured
// 2e-10 to 1.2e-9 at the default 1e-12 (it moves with the rounding of the forward states),
// 1.6e-11 at 1e-14, 5e-12 with every step factored. The check runs at 1e-14.
TEST_P(SoftRollout, ForwardSensitivitiesAgreeWithTheReversePass) {
  const Case c{GetParam(), true, true};
  auto sim = makeSimulable(c);
  const int n = sim->numDofs();
  RolloutOptions options = tightOptions();
  options.tape_solve.relative_tolerance = 1e-14;
  Rollout rollout(sim, options);
  rollout.run(kSteps, baseInputs(c));
  const RowMatX& a = lossFor(c.model).state_weights;
  const RolloutVariables grad = rollout.backward(a);
  RolloutVariables d;
  d.rest_joints = randomVector(72, 0.01, 11);
  const VecX v = randomVector(kSteps * 72, 0.1, 12);
  d.pose_targets = Eigen::Map<const RowMatX>(v.data(), kSteps, 72);
  d.stiffnesses =
      randomVector(4, 0.1, 13).cwiseProduct(sim->getParameter(SimParameter::Stiffnesses));
  d.collider_offsets = randomVector(6, 0.01, 14);
  d.initial_state = randomVector(n, 0.001, 15);
  d.initial_velocity = randomVector(n, 0.01, 16);
  d.material = randomVector(sim->parameterSize(SimParameter::Material), 0.1, 17);
  d.shape = randomVector(sim->parameterSize(SimParameter::Shape), 1.0, 18);
  const std::vector<RowMatX> dq = rollout.forwardSensitivities({d});
  ASSERT_EQ(dq.size(), 1u);
  const double forward = (a.array() * dq[0].array()).sum();
  const double reverse = dot(grad, d);
  ASSERT_GT(std::abs(reverse), 1e-8);
  EXPECT_NEAR(forward, reverse, 1e-9 * std::abs(reverse));
}

// A tape that keeps only the snapshots gives the gradients and sensitivities of one that keeps
// the factors, and says how each step was solved: with the FEM's systems (~2 600 DoFs) by PCG
// with a nearby step's factor (TapeSolveOptions, the default), or, not iterative, each step by
// its own factor; the ROMs' (a few hundred DoFs) always by their own factors.
TEST_P(SoftRollout, SnapshotTapeMatchesTheFactorTape) {
  const Case c{GetParam(), true, true};
  RolloutVariables results[3];
  RowMatX sensitivities[3];
  RolloutVariables d;
  d.initial_velocity = randomVector(makeSimulable(c)->numDofs(), 0.1, 61);
  const bool fem = c.model == SoftModel::Fem;
  for (int k = 0; k < 3; ++k) {
    RolloutOptions options = tightOptions();
    options.tape_storage =
        k == 0 ? RolloutOptions::TapeStorage::Factors : RolloutOptions::TapeStorage::Snapshots;
    options.tape_solve.iterative = k == 2;
    Rollout rollout(makeSimulable(c), options);
    rollout.run(kSteps, baseInputs(c));
    EXPECT_EQ(rollout.tape().stepInfo(1).factorization == "deferred", k > 0);
    results[k] = lossFor(c.model).gradient(rollout);
    int pcg_steps = 0, cg_iterations = 0;
    for (int t = 1; t <= kSteps; ++t) {
      const TapeStepInfo& info = rollout.tape().stepInfo(t);
      EXPECT_NE(info.factorization, "deferred") << "step " << t;
      pcg_steps += info.factorization == "pcg";
      cg_iterations += info.cg_iterations;
    }
    // The reverse sweep factors its first step (T) and solves the others by PCG, but for a step
    // after a slow solve (here 13–26 iterations per step: a step after one of 26 factors).
    if (fem && k == 2) {
      EXPECT_GE(pcg_steps, kSteps / 2);
      EXPECT_GE(cg_iterations, 5 * pcg_steps);
      EXPECT_EQ(rollout.tape().stepInfo(kSteps).factorization, "llt");
    } else {
      EXPECT_EQ(pcg_steps, 0) << "tape " << k;
    }
    sensitivities[k] = rollout.forwardSensitivities({d}).front();
  }
  ASSERT_GT(results[0].initial_velocity.norm(), 0.0);
  for (int k = 1; k < 3; ++k) {
    EXPECT_LT((results[0].initial_velocity - results[k].initial_velocity).norm(),
              1e-9 * results[0].initial_velocity.norm())
        << "tape " << k;
    EXPECT_LT((results[0].pose_targets - results[k].pose_targets).norm(),
              1e-9 * results[0].pose_targets.norm())
        << "tape " << k;
    EXPECT_LT((results[0].material - results[k].material).norm(), 1e-9 * results[0].material.norm())
        << "tape " << k;
    EXPECT_LT((sensitivities[0] - sensitivities[k]).norm(), 1e-9 * sensitivities[0].norm())
        << "tape " << k;
  }
}

INSTANTIATE_TEST_SUITE_P(Models, SoftRollout,
                         ::testing::Values(SoftModel::Fem, SoftModel::Rom, SoftModel::RomModes),
                         test::modelName);

// The PCG's fallbacks on the FEM: a PCG that cannot converge (one iteration allowed) makes its
// step factor its own exact Hessian; a slow one (more than 0 iterations) makes the next step
// factor. Either way the gradients are those of the tape that keeps every factor.
TEST(SoftRolloutPcg, FallbacksFactorAndKeepTheGradients) {
  const Case c{SoftModel::Fem, true, true};
  const RowMatX& a = lossFor(c.model).state_weights;
  RolloutOptions reference_options = tightOptions();
  reference_options.tape_storage = RolloutOptions::TapeStorage::Factors;
  Rollout reference(makeSimulable(c), reference_options);
  reference.run(kSteps, baseInputs(c));
  const RolloutVariables expected = reference.backward(a);
  ASSERT_GT(expected.pose_targets.norm(), 0.0);
  for (const bool no_convergence : {true, false}) {
    RolloutOptions options = tightOptions();
    options.tape_storage = RolloutOptions::TapeStorage::Snapshots;
    if (no_convergence)
      options.tape_solve.max_iterations = 1;
    else
      options.tape_solve.refactor_after_iterations = 0;
    Rollout rollout(makeSimulable(c), options);
    rollout.run(kSteps, baseInputs(c));
    const RolloutVariables got = rollout.backward(a);
    int pcg_steps = 0, cg_iterations = 0;
    for (int t = 1; t <= kSteps; ++t) {
      pcg_steps += rollout.tape().stepInfo(t).factorization == "pcg";
      cg_iterations += rollout.tape().stepInfo(t).cg_iterations;
    }
    // No convergence: every step tried PCG (one iteration), then factored. Refactor after 0:
    // PCG and a factor alternate from step T (factored) down.
    EXPECT_EQ(pcg_steps, no_convergence ? 0 : kSteps / 2) << no_convergence;
    EXPECT_EQ(cg_iterations > 0, true) << no_convergence;
    if (no_convergence) {
      EXPECT_EQ(cg_iterations, kSteps - 1);
    }
    EXPECT_LT((got.pose_targets - expected.pose_targets).norm(),
              1e-9 * expected.pose_targets.norm())
        << no_convergence;
    EXPECT_LT((got.initial_state - expected.initial_state).norm(),
              1e-9 * expected.initial_state.norm())
        << no_convergence;
  }
}

// A forward sweep of more directions than TapeSolveOptions::max_right_hand_sides factors every
// step (PCG would solve once per direction); of up to that many, it solves by PCG. Both give the
// sensitivities of the tape that keeps every factor.
TEST(SoftRolloutPcg, ForwardSweepsOfManyDirectionsFactor) {
  const Case c{SoftModel::Fem, true, true};
  const int n = makeSimulable(c)->numDofs();
  std::vector<RolloutVariables> directions(4);
  for (int d = 0; d < 4; ++d) directions[size_t(d)].initial_velocity = randomVector(n, 0.1, 70 + d);
  RolloutOptions factors = tightOptions();
  factors.tape_storage = RolloutOptions::TapeStorage::Factors;
  Rollout reference(makeSimulable(c), factors);
  reference.run(kSteps, baseInputs(c));
  const std::vector<RowMatX> expected = reference.forwardSensitivities(directions);
  RolloutOptions snapshots = tightOptions();
  snapshots.tape_storage = RolloutOptions::TapeStorage::Snapshots;
  Rollout rollout(makeSimulable(c), snapshots);
  rollout.run(kSteps, baseInputs(c));
  for (const int count : {4, 3}) {
    const std::vector<RolloutVariables> some(directions.begin(), directions.begin() + count);
    const std::vector<RowMatX> got = rollout.forwardSensitivities(some);
    int pcg_steps = 0;
    for (int t = 1; t <= kSteps; ++t)
      pcg_steps += rollout.tape().stepInfo(t).factorization == "pcg";
    if (count > snapshots.tape_solve.max_right_hand_sides) {
      EXPECT_EQ(pcg_steps, 0) << count << " directions";
    } else {
      EXPECT_GT(pcg_steps, 0) << count << " directions";
    }
    ASSERT_EQ(got.size(), size_t(count));
    for (int d = 0; d < count; ++d) {
      ASSERT_GT(expected[size_t(d)].norm(), 0.0);
      EXPECT_LT((got[size_t(d)] - expected[size_t(d)]).norm(), 1e-9 * expected[size_t(d)].norm())
          << count << " directions, direction " << d;
    }
  }
}

TEST(SoftRolloutPcg, BadSolveOptionsAreInputErrors) {
  // The Rollout refuses `change`d options with an InputError whose message holds `expected`.
  const auto expectRefused = [](auto change, const std::string& expected) {
    RolloutOptions options;
    change(options.tape_solve);
    const std::string message = test::messageOf<InputError>([&] {
      Rollout(makeSimulable({SoftModel::Fem, false}), options);
    });
    EXPECT_NE(message.find(expected), std::string::npos) << message;
  };
  expectRefused([](TapeSolveOptions& o) { o.relative_tolerance = 0.0; },
                "TapeSolveOptions::relative_tolerance must be in (0, 1), got 0");
  expectRefused([](TapeSolveOptions& o) { o.max_iterations = 0; },
                "TapeSolveOptions::max_iterations must be ≥ 1, got 0");
  expectRefused([](TapeSolveOptions& o) { o.refactor_after_iterations = -1; },
                "TapeSolveOptions::refactor_after_iterations must be ≥ 0, got -1");
  expectRefused([](TapeSolveOptions& o) { o.max_right_hand_sides = 0; },
                "TapeSolveOptions::max_right_hand_sides must be ≥ 1, got 0");
}

}  // namespace
}  // namespace flsh
