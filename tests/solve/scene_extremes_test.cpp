// Scene stepping (the real newtonSolve) at the extremes of the issue: time steps 1e-4 and 0.1 s,
// very soft and very stiff tracking, a joint held near π, a fast motion, and an avatar starting
// deep inside the ground. Each run must stay finite and bounded (root within a few metres of
// where it started, no NaN) and Newton must keep returning a usable state.
#include <gtest/gtest.h>

#include <cmath>
#include <memory>

#include "flsh/body/motion.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/core/error.h"
#include "flsh/solve/scene.h"
#include "support/test_support.h"

namespace flsh {
namespace {

// One small synthetic body, avatar and walk for the whole binary (600 vertices).
const test::SmallScene& shared() { return test::smallScene(600, 4.0); }

struct Outcome {
  double max_root_travel = 0.0;  // m, largest distance of the root from its start
  double lowest_final = 0.0;     // m, lowest node height relative to the ground at the end
  bool finite = true;
  int steps_run = 0;
  VecX final_pose;  // 72, SMPL pose at the end
};

/// Runs `steps` scene steps of one avatar tracking `motion` over a ground plane placed `depth`
/// metres above the avatar's lowest vertex (depth > 0: the avatar starts inside the ground).
Outcome run(const SimulableOptions& options, std::shared_ptr<const Motion> motion, int steps,
            double depth = -0.005) {
  auto sim = std::make_shared<Simulable>(shared().avatar, std::move(motion), options);
  Scene scene;
  scene.addSimulable(sim);
  scene.initialize();
  const double ground = sim->getNodes().col(1).minCoeff() + depth;
  scene.addCollider(Collider::plane(Vec3(0, ground, 0), Vec3::UnitY()));
  const Vec3 root0 = sim->bonePositions().row(0).transpose();
  Outcome out;
  for (int k = 0; k < steps; ++k) {
    scene.step();
    ++out.steps_run;
    const VecX q = sim->getState();
    if (!q.allFinite()) {
      out.finite = false;
      return out;
    }
    out.max_root_travel =
        std::max(out.max_root_travel, (sim->bonePositions().row(0).transpose() - root0).norm());
  }
  const MatX3 nodes = sim->getNodes();
  out.finite = out.finite && nodes.allFinite();
  out.lowest_final = nodes.col(1).minCoeff() - ground;
  out.final_pose = sim->getPose();
  return out;
}

SimulableOptions withTimeStep(double h) {
  SimulableOptions options;
  options.time_step = h;
  return options;
}

void expectBounded(const Outcome& out, double max_travel, const char* what) {
  EXPECT_TRUE(out.finite) << what << ": NaN/Inf after " << out.steps_run << " steps";
  EXPECT_LT(out.max_root_travel, max_travel) << what;
  EXPECT_GT(out.lowest_final, -0.3) << what << ": sank through the ground";
}

TEST(SceneExtremes, TinyTimeStep) {
  const Outcome out = run(withTimeStep(1e-4), shared().walk, 5);
  expectBounded(out, 0.05, "h = 1e-4 s");  // 0.5 ms of walking moves the root millimetres
}

TEST(SceneExtremes, LargeTimeStep) {
  const Outcome out = run(withTimeStep(0.1), shared().walk, 30);  // 3 s of the walk
  expectBounded(out, 6.0, "h = 0.1 s");
}

TEST(SceneExtremes, VerySoftAndVeryStiffTracking) {
  for (double stiffness : {1e-3, 1e5}) {
    SimulableOptions options;
    options.tracking_stiffness = stiffness;
    options.root_stiffness = stiffness;
    const Outcome out = run(options, shared().walk, 30);
    expectBounded(out, 3.0, stiffness < 1.0 ? "soft tracking" : "stiff tracking");
  }
}

TEST(SceneExtremes, ElbowTargetNearPi) {
  auto motion = std::make_shared<Motion>(*shared().walk);
  const int elbow = smplJointIndex("left_elbow");
  for (int f = 0; f < motion->numFrames(); ++f)
    motion->poses.row(f).segment<3>(3 * elbow) << 0.0, 3.1, 0.0;
  const Outcome out = run(SimulableOptions(), motion, 30);
  expectBounded(out, 3.0, "elbow at 3.1 rad");
  ASSERT_EQ(out.final_pose.size(), 72);
  EXPECT_GT(out.final_pose.segment<3>(3 * elbow).norm(), 2.8) << "the elbow must reach near π";
}

TEST(SceneExtremes, FastArmSwing) {
  // The walk played 5× faster: same poses, frame rate × 5.
  auto motion = std::make_shared<Motion>(*shared().walk);
  motion->fps *= 5.0;
  const Outcome out = run(SimulableOptions(), motion, 30);
  expectBounded(out, 4.0, "walk at 5x speed");
}

TEST(SceneExtremes, StartingDeepInsideTheGround) {
  const Outcome out = run(SimulableOptions(), shared().walk, 30, 0.3);
  expectBounded(out, 3.0, "0.3 m inside the ground");
  EXPECT_GT(out.lowest_final, -0.3 + 0.05) << "the ground must push the avatar out";
}

TEST(SceneExtremes, LargestAcceptedVelocityKeepsTheStateFinite) {
  // Every DoF at kMaxStateVelocity (10 km/s, 10^4 rad/s): nothing converges, but no step may
  // produce NaN (the prediction's rotations go through rodrigues at 167 rad per step).
  auto sim = std::make_shared<Simulable>(shared().avatar, shared().walk);
  Scene scene;
  scene.addSimulable(sim);
  scene.initialize();
  sim->setVelocity(VecX::Constant(sim->numDofs(), kMaxStateVelocity));
  for (int k = 0; k < 3; ++k) {
    scene.step();
    ASSERT_TRUE(sim->getState().allFinite()) << "step " << k;
  }
}

TEST(SceneExtremes, NonFiniteSnapshotIsRefusedAndTheSceneStepsOn) {
  // The setters keep NaN out, and so does restoreStep now (issue 23; it used to put back any
  // snapshot as is, and a NaN previous state then made the whole step NaN, which Scene::step's
  // guard caught, restored and reported). The snapshot is refused naming the value, nothing is
  // restored, and the scene steps on normally. Scene::step's guard against a non-finite state
  // after Newton stays as a defence; no input through the API is known to reach it now.
  auto sim = std::make_shared<Simulable>(shared().avatar, shared().walk);
  SceneOptions options;
  options.lower_energy_start = false;
  Scene scene(options);
  scene.addSimulable(sim);
  scene.initialize();
  scene.step();
  SimulableStep poisoned = sim->saveStep();
  poisoned.t_nm1(3, 1) = std::nan("");
  const VecX q_before = sim->getState();
  const double t_before = sim->time();
  const std::string message = test::messageOf<InputError>([&] { sim->restoreStep(poisoned); });
  EXPECT_NE(message.find("t_nm1(3, 1) is nan"), std::string::npos) << message;
  EXPECT_EQ(sim->getState(), q_before);
  EXPECT_EQ(sim->time(), t_before);
  scene.step();
  EXPECT_TRUE(sim->getState().allFinite());
}

TEST(SceneStatic, EquilibriumUnderGravityIsOneConvergedSolve) {
  // Static mode drops inertia: one step solves the equilibrium of gravity, joint and tracking
  // springs. Standing still with the ground under the feet, the body sags a little below the
  // mocap pose and the converged gradient is (relatively) zero.
  auto stand = std::make_shared<Motion>(makeBuiltinMotion("stand", 1.0, 30.0));
  auto sim = std::make_shared<Simulable>(shared().avatar, stand);
  Scene scene;
  scene.addSimulable(sim);
  scene.initialize();
  const double ground = sim->getNodes().col(1).minCoeff() - 0.005;
  scene.addCollider(Collider::plane(Vec3(0, ground, 0), Vec3::UnitY()));
  const double root_start = sim->bonePositions()(0, 1);
  scene.setStatic(true);
  const StepStats stats = scene.step();
  ASSERT_TRUE(stats.newton.converged) << stats.newton.message;
  EXPECT_DOUBLE_EQ(sim->getDynamicEnergyScalar(), 0.0);
  VecX g = VecX::Zero(sim->numDofs());
  sim->getPotentialGradientVector(g);
  sim->fixVectorKinematic(g);
  VecX weight = VecX::Zero(sim->numDofs());
  for (int b = 0; b < kNumJoints; ++b)
    weight[6 * b + 1] = shared().avatar->boneInertia()[b].mass * 9.81;
  ASSERT_GT(weight.lpNorm<Eigen::Infinity>(), 1.0);
  EXPECT_LT(g.lpNorm<Eigen::Infinity>(), 1e-4 * weight.lpNorm<Eigen::Infinity>());
  // Gravity pulls the root down, but by less than 3 cm (springs and ground carry the body).
  const double sag = root_start - sim->bonePositions()(0, 1);
  EXPECT_GT(sag, 0.0);
  EXPECT_LT(sag, 0.03);
  // A second static solve from the equilibrium changes nothing.
  const VecX q = sim->getState();
  const StepStats again = scene.step();
  EXPECT_TRUE(again.newton.converged);
  EXPECT_LT((sim->getState() - q).lpNorm<Eigen::Infinity>(), 1e-6);
}

}  // namespace
}  // namespace flsh
