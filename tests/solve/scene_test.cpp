// Scene: merged state and offsets, merged gradient and exact Hessian against finite differences
// (two avatars in contact with each other and with the ground), avatar–avatar contact alone,
// push/pop and kinematic DoFs, and short simulations (standing on the ground; two overlapping
// avatars pushed apart).
#include "flsh/solve/scene.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <memory>
#include <random>

#include "flsh/body/motion.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/contact/contact_energy.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::jacobianMatchesFiniteDifferences;
using test::randomVector;

// One small synthetic body, avatar and walk for the whole binary (600 vertices).
const test::SmallScene& shared() { return test::smallScene(600, 1.0); }

MatX dense(const std::vector<Triplet>& H, int n) {
  MatX D = MatX::Zero(n, n);
  for (const Triplet& t : H) D(t.row(), t.col()) += t.value();
  return D;
}

using test::translateBones;

double lowestNodeHeight(const Simulable& sim) { return sim.getNodes().col(1).minCoeff(); }

/// Evaluates f at the merged state moved by d, restoring the state afterwards.
template <class F>
auto atMoved(Scene& scene, const VecX& d, F&& f) {
  scene.push();
  scene.step(d);
  auto result = f();
  scene.pop();
  return result;
}

/// Two avatars: A walking (mocap), B a ragdoll at rest placed `overlap` metres deeper into A
/// (along z) than where their capsules first touch; both in one scene.
struct TwoAvatars {
  std::shared_ptr<Simulable> a, b;
  std::unique_ptr<Scene> scene;
};

TwoAvatars twoAvatarsInContact(double overlap, const SimulableOptions& options = {},
                               bool with_mocap = true, const SceneOptions& scene_options = {}) {
  TwoAvatars out;
  const test::SmallScene& s = shared();
  out.a = std::make_shared<Simulable>(s.avatar, with_mocap ? s.walk : nullptr, options);
  out.b = std::make_shared<Simulable>(s.avatar, nullptr, options);
  out.scene = std::make_unique<Scene>(scene_options);
  out.scene->addSimulable(out.a);
  out.scene->addSimulable(out.b);
  out.scene->initialize();
  // Back B off along z until no vertex of either touches the other's capsules, then move it
  // `overlap` closer again.
  const double step = 0.01;
  translateBones(*out.b, Vec3(0, 0, -0.05));
  int active = 1;
  double moved = 0.0;
  while (active > 0 && moved < 2.0) {
    translateBones(*out.b, Vec3(0, 0, step));
    moved += step;
    out.scene->avatarContactEnergy(nullptr, nullptr, true, &active);
  }
  translateBones(*out.b, Vec3(0, 0, -overlap));
  return out;
}

TEST(Scene, OffsetsFollowTheSimulablesAndTimeStepsMustAgree) {
  const test::SmallScene& s = shared();
  Scene scene;
  EXPECT_EQ(scene.numDofs(), 0);
  scene.addSimulable(std::make_shared<Simulable>(s.avatar));
  scene.addSimulable(std::make_shared<Simulable>(s.avatar));
  EXPECT_EQ(scene.offset(0), 0);
  EXPECT_EQ(scene.offset(1), 144);
  EXPECT_EQ(scene.numDofs(), 288);
  SimulableOptions other;
  other.time_step = 1.0 / 120.0;
  const std::string message = test::messageOf<InputError>(
      [&] { scene.addSimulable(std::make_shared<Simulable>(s.avatar, nullptr, other)); });
  EXPECT_NE(message.find("time_step"), std::string::npos) << message;
  EXPECT_EQ(scene.numDofs(), 288);
  EXPECT_THROW(scene.addSimulable(nullptr), InputError);
  EXPECT_THROW(scene.step(VecX::Zero(5)), InputError);
  EXPECT_THROW(scene.pop(), Error);
  EXPECT_THROW(Scene().step(), Error);
}

TEST(Scene, CollidersReachEverySimulable) {
  const test::SmallScene& s = shared();
  Scene scene;
  auto a = std::make_shared<Simulable>(s.avatar);
  scene.addSimulable(a);
  scene.addCollider(Collider::plane(Vec3::Zero(), Vec3::UnitY()));
  auto b = std::make_shared<Simulable>(s.avatar);
  scene.addSimulable(b);  // added after the collider: still sees it
  EXPECT_EQ(a->colliders().size(), 1u);
  EXPECT_EQ(b->colliders().size(), 1u);
}

TEST(Scene, MergedStateGradientAndStepUseTheOffsets) {
  SceneOptions no_avatar_contact;
  no_avatar_contact.avatar_contact = false;
  TwoAvatars two = twoAvatarsInContact(0.05, {}, true, no_avatar_contact);
  Scene& scene = *two.scene;
  const int n = scene.numDofs();
  // step(dq) moves simulable i by its slice only.
  const VecX qa = two.a->getState(), qb = two.b->getState();
  VecX dq = VecX::Zero(n);
  dq[scene.offset(1) + 1] = 0.25;  // B's root, y
  scene.step(dq);
  EXPECT_EQ(two.a->getState(), qa);
  EXPECT_NEAR(two.b->getState()[1] - qb[1], 0.25, 1e-15);
  // Without avatar contact, the merged gradient is the simulables' gradients side by side.
  for (auto& s : scene.simulables()) s->preUpdate();
  VecX g;
  scene.gradient(g);
  for (int i = 0; i < 2; ++i) {
    const Simulable& sim = *scene.simulables()[i];
    VecX own = VecX::Zero(sim.numDofs());
    sim.getDynamicGradientVector(own);
    sim.getPotentialGradientVector(own);
    EXPECT_LT((g.segment(scene.offset(i), sim.numDofs()) - own).norm(), 1e-12 * own.norm())
        << "simulable " << i;
  }
}

TEST(Scene, AvatarContactDerivativesMatchFiniteDifferences) {
  TwoAvatars two = twoAvatarsInContact(0.04);
  Scene& scene = *two.scene;
  const int n = scene.numDofs();
  scene.step(randomVector(n, 0.02, 3));  // a generic configuration
  int active = 0;
  const double e0 = scene.avatarContactEnergy(nullptr, nullptr, true, &active);
  ASSERT_GT(active, 10) << "the avatars must overlap";
  ASSERT_GT(e0, 0.0);
  VecX g = VecX::Zero(n);
  std::vector<Triplet> exact, psd;
  scene.avatarContactEnergy(&g, &exact, false);
  scene.avatarContactEnergy(nullptr, &psd, true);
  // Both avatars feel the contact.
  EXPECT_GT(g.head(144).norm(), 0.0);
  EXPECT_GT(g.tail(144).norm(), 0.0);

  const auto energy = [&](const VecX& d) {
    return atMoved(scene, d, [&] {
      return VecX::Constant(1, scene.avatarContactEnergy(nullptr, nullptr, true));
    });
  };
  const auto gradient = [&](const VecX& d) {
    return atMoved(scene, d, [&] {
      VecX gd = VecX::Zero(n);
      scene.avatarContactEnergy(&gd, nullptr, true);
      return test::pullBackRotationGradient(gd, d);
    });
  };
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(energy, VecX::Zero(n), g.transpose(), 1e-6));
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(gradient, VecX::Zero(n), dense(exact, n), 1e-5));

  // Gauss–Newton form: symmetric positive semidefinite, and different from the exact one.
  const MatX Hpsd = dense(psd, n);
  EXPECT_LT((Hpsd - Hpsd.transpose()).norm(), 1e-12 * Hpsd.norm());
  const double lowest = Eigen::SelfAdjointEigenSolver<MatX>(Hpsd).eigenvalues()[0];
  EXPECT_GT(lowest, -1e-9 * Hpsd.norm());
  EXPECT_GT((Hpsd - dense(exact, n)).norm(), 1e-6 * Hpsd.norm());
}

// The broad phase and the scene's own skinning against brute force: every vertex of each
// avatar (Simulable::getNodes) against every capsule of the other.
TEST(Scene, AvatarContactEnergyEqualsTheBruteForceSum) {
  TwoAvatars two = twoAvatarsInContact(0.05);
  Scene& scene = *two.scene;
  scene.step(randomVector(scene.numDofs(), 0.05, 12));
  const ContactOptions& options = scene.options().avatar_contact_options;
  double brute = 0.0;
  int brute_active = 0;
  for (int ia = 0; ia < 2; ++ia) {
    const Simulable& A = *scene.simulables()[ia];
    const Simulable& B = *scene.simulables()[1 - ia];
    const MatX3 nodes = A.getNodes();
    const VecX& areas = A.avatar().vertexAreas();
    for (const BoneCapsule& c : B.avatar().boneCapsules()) {
      if (c.radius <= 0.0) continue;
      const Mat3& R = B.boneRotations()[c.bone];
      const Vec3 t = B.bonePositions().row(c.bone).transpose();
      const Vec3 J = B.avatar().restJoints().row(c.bone).transpose();
      const Vec3 a = R * (c.a - J) + t, b = R * (c.b - J) + t;
      for (int v = 0; v < nodes.rows(); ++v) {
        const double e = vertexCapsulePenalty(nodes.row(v).transpose(), a, b, c.radius,
                                              options.stiffness * areas[v], options);
        brute += e;
        brute_active += e > 0.0;
      }
    }
  }
  int active = 0;
  const double energy = scene.avatarContactEnergy(nullptr, nullptr, true, &active);
  ASSERT_GT(brute_active, 20);
  EXPECT_EQ(active, brute_active);
  EXPECT_NEAR(energy, brute, 1e-12 * brute);
}

TEST(Scene, MergedGradientAndExactHessianMatchFiniteDifferences) {
  TwoAvatars two = twoAvatarsInContact(0.03);
  Scene& scene = *two.scene;
  const int n = scene.numDofs();
  const double ground = std::min(lowestNodeHeight(*two.a), lowestNodeHeight(*two.b)) + 0.015;
  scene.addCollider(Collider::plane(Vec3(0, ground, 0), Vec3::UnitY()));
  for (auto& s : scene.simulables()) s->preUpdate();
  scene.step(randomVector(n, 0.02, 5));  // off the inertial prediction
  int active = 0;
  scene.avatarContactEnergy(nullptr, nullptr, true, &active);
  ASSERT_GT(active, 5);

  const VecX q_before = VecX(two.a->getState()), qb_before = two.b->getState();
  VecX g;
  scene.gradient(g);
  ASSERT_GT(two.a->stats().active_contacts + two.b->stats().active_contacts, 0);
  SpMat H;
  scene.hessian(H, false);
  // Derivative calls leave the state alone.
  EXPECT_EQ(two.a->getState(), q_before);
  EXPECT_EQ(two.b->getState(), qb_before);

  const auto energy = [&](const VecX& d) {
    return atMoved(scene, d, [&] { return VecX::Constant(1, scene.energy()); });
  };
  const auto gradient = [&](const VecX& d) {
    return atMoved(scene, d, [&] {
      VecX gd;
      scene.gradient(gd);
      return test::pullBackRotationGradient(gd, d);
    });
  };
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(energy, VecX::Zero(n), g.transpose(), 1e-6));
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(gradient, VecX::Zero(n), MatX(H), 1e-5));
  // The Newton (psd) Hessian is symmetric positive semidefinite.
  SpMat Hpsd;
  scene.hessian(Hpsd, true);
  const MatX D = MatX(Hpsd);
  EXPECT_LT((D - D.transpose()).norm(), 1e-12 * D.norm());
  EXPECT_GT(Eigen::SelfAdjointEigenSolver<MatX>(D).eigenvalues()[0], -1e-9 * D.norm());
}

TEST(Scene, PushPopRoundTripsExactlyAndKinematicDofsAreFixed) {
  SimulableOptions options;
  options.kinematic_bones = {0};
  TwoAvatars two = twoAvatarsInContact(0.02, options);
  Scene& scene = *two.scene;
  const int n = scene.numDofs();
  const VecX qa = two.a->getState(), qb = two.b->getState();
  scene.push();
  scene.step(randomVector(n, 0.1, 8));
  EXPECT_NE(two.a->getState(), qa);
  scene.pop();
  EXPECT_EQ(two.a->getState(), qa);
  EXPECT_EQ(two.b->getState(), qb);

  VecX g;
  scene.gradient(g);
  SpMat H;
  scene.hessian(H, true);
  ASSERT_GT(g.segment<6>(0).norm() + g.segment<6>(144).norm(), 0.0);
  scene.fixKinematic(g, &H);
  const MatX D = MatX(H);
  for (int offset : {0, 144}) {
    EXPECT_EQ(g.segment<6>(offset).norm(), 0.0);
    for (int k = offset; k < offset + 6; ++k) {
      for (int j = 0; j < n; ++j) {
        EXPECT_EQ(D(k, j), k == j ? 1.0 : 0.0);
        EXPECT_EQ(D(j, k), k == j ? 1.0 : 0.0);
      }
    }
  }
  EXPECT_GT(g.segment<6>(6).norm(), 0.0);  // free bones keep their gradient
}

TEST(Scene, AvatarStandingOnTheGroundConverges) {
  const test::SmallScene& s = shared();
  auto sim = std::make_shared<Simulable>(s.avatar, s.walk);
  Scene scene;
  scene.addSimulable(sim);
  scene.initialize();
  const double ground = lowestNodeHeight(*sim) - 0.005;
  scene.addCollider(Collider::plane(Vec3(0, ground, 0), Vec3::UnitY()));
  int max_contacts = 0;
  for (int step = 0; step < 15; ++step) {
    const StepStats stats = scene.step();
    EXPECT_TRUE(stats.newton.converged) << "step " << step << ": " << stats.newton.message;
    EXPECT_GE(stats.seconds, 0.0);
    max_contacts = std::max(max_contacts, stats.active_contacts);
  }
  EXPECT_NEAR(scene.time(), 15.0 / 60.0, 1e-12);
  EXPECT_GT(max_contacts, 0);
  EXPECT_TRUE(sim->getState().allFinite());
  EXPECT_GT(lowestNodeHeight(*sim), ground - 0.02);  // stands on the plane, does not sink
  // One symbolic analysis for all steps: the scene's Hessian pattern is fixed.
  ASSERT_NE(scene.linearSolver(), nullptr);
  EXPECT_EQ(scene.linearSolver()->numAnalyses(), 1);
  EXPECT_GT(scene.linearSolver()->numFactorizations(), 15);
}

TEST(Scene, AvatarContactPushesOverlappingAvatarsApart) {
  SimulableOptions options;
  options.gravity = Vec3::Zero();  // floating: only the contact acts between the two
  TwoAvatars two = twoAvatarsInContact(0.06, options, false);
  Scene& scene = *two.scene;
  int active0 = 0;
  const double e0 = scene.avatarContactEnergy(nullptr, nullptr, true, &active0);
  ASSERT_GT(active0, 10);
  const double za0 = two.a->bonePositions()(0, 2), zb0 = two.b->bonePositions()(0, 2);
  const double gap0 = zb0 - za0;
  double e = e0;
  for (int step = 0; step < 8; ++step) {
    const StepStats stats = scene.step();
    EXPECT_TRUE(stats.newton.converged) << "step " << step << ": " << stats.newton.message;
    e = scene.avatarContactEnergy(nullptr, nullptr, true);
  }
  const double gap = two.b->bonePositions()(0, 2) - two.a->bonePositions()(0, 2);
  EXPECT_LT(e, 0.2 * e0) << "the overlap must shrink";
  EXPECT_GT(std::abs(gap), std::abs(gap0) + 0.01) << "the roots must move apart";
  // Action and reaction: the roots move in opposite directions along z.
  const double moved_a = two.a->bonePositions()(0, 2) - za0;
  const double moved_b = two.b->bonePositions()(0, 2) - zb0;
  EXPECT_LT(moved_a * moved_b, 0.0) << moved_a << " " << moved_b;
  EXPECT_TRUE(two.a->getState().allFinite() && two.b->getState().allFinite());
}

}  // namespace
}  // namespace flsh
