// Simulable (skeleton model): whole-model derivatives against finite differences through
// updateState, state handling, mocap initialization and small dynamics checks, on a small
// synthetic body.
#include "flsh/sim/simulable.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <limits>
#include <memory>
#include <random>

#include "flsh/body/body_forward.h"
#include "flsh/body/motion.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::jacobianMatchesFiniteDifferences;
using test::randomVector;
using test::atMovedState;

MatX dense(const std::vector<Triplet>& H, int n) { return test::denseFromTriplets(H, n); }
using test::messageOf;

// One small synthetic body, avatar and walk for the whole binary (800 vertices).
const test::SmallScene& shared() { return test::smallScene(800, 1.0); }

double lowestNodeHeight(const Simulable& sim) { return sim.getNodes().col(1).minCoeff(); }

// A walking avatar one step in, moved off the prediction, with a ground plane 1.5 cm above its
// lowest vertex so that contacts are active.
std::unique_ptr<Simulable> walkingAvatarOnGround(unsigned seed) {
  auto sim = std::make_unique<Simulable>(shared().avatar, shared().walk);
  sim->initialize();
  sim->preUpdate();
  VecX d = randomVector(sim->numDofs(), 0.03, seed);
  sim->updateState(d);
  sim->setColliders({Collider::plane(Vec3(0, lowestNodeHeight(*sim) + 0.015, 0), Vec3::UnitY())});
  return sim;
}

// ---- whole-model derivatives ---------------------------------------------------------------

TEST(Simulable, DynamicEnergyDerivativesMatchFiniteDifferences) {
  auto sim = walkingAvatarOnGround(1);
  const int n = sim->numDofs();
  VecX g = VecX::Zero(n);
  sim->getDynamicGradientVector(g);
  std::vector<Triplet> H;
  sim->getDynamicHessianTripletVector(H, 0, false);
  const auto energy = [&](const VecX& d) {
    return atMovedState(*sim, d, [&] { return VecX::Constant(1, sim->getDynamicEnergyScalar()); });
  };
  const auto gradient = [&](const VecX& d) {
    return atMovedState(*sim, d, [&] {
      VecX gd = VecX::Zero(n);
      sim->getDynamicGradientVector(gd);
      return test::pullBackRotationGradient(gd, d);
    });
  };
  const auto r1 = jacobianMatchesFiniteDifferences(energy, VecX::Zero(n), g.transpose(), 1e-6);
  EXPECT_TRUE(r1);
  const auto r2 = jacobianMatchesFiniteDifferences(gradient, VecX::Zero(n), dense(H, n), 1e-6);
  EXPECT_TRUE(r2);
  std::cout << "[dynamic] gradient: " << r1.message() << "; exact Hessian: " << r2.message()
            << "\n";
}

TEST(Simulable, PotentialEnergyDerivativesWithGroundContactMatchFiniteDifferences) {
  auto sim = walkingAvatarOnGround(2);
  const int n = sim->numDofs();
  VecX g = VecX::Zero(n);
  sim->getPotentialGradientVector(g);
  ASSERT_GT(sim->stats().active_contacts, 3) << "the ground plane must touch the feet";
  std::vector<Triplet> H;
  sim->getPotentialHessianTripletVector(H, 0, false);
  const auto energy = [&](const VecX& d) {
    return atMovedState(*sim, d, [&] { return VecX::Constant(1, sim->getPotentialEnergyScalar()); });
  };
  const auto gradient = [&](const VecX& d) {
    return atMovedState(*sim, d, [&] {
      VecX gd = VecX::Zero(n);
      sim->getPotentialGradientVector(gd);
      return test::pullBackRotationGradient(gd, d);
    });
  };
  const auto r1 = jacobianMatchesFiniteDifferences(energy, VecX::Zero(n), g.transpose(), 1e-6);
  EXPECT_TRUE(r1);
  const auto r2 = jacobianMatchesFiniteDifferences(gradient, VecX::Zero(n), dense(H, n), 1e-6);
  EXPECT_TRUE(r2);
  std::cout << "[potential+contact] gradient: " << r1.message()
            << "; exact Hessian: " << r2.message() << "\n";
}

TEST(Simulable, ContactOnlyDerivativesMatchFiniteDifferences) {
  // The contact term alone (everything else switched off), so that its error is not hidden
  // under the stiffer springs.
  SimulableOptions options;
  options.gravity.setZero();
  options.joint_stiffness = 0.0;
  options.track_mocap = false;
  options.contact.stiffness = 1e7;
  Simulable sim(shared().avatar, shared().walk, options);
  sim.initialize();
  sim.updateState(randomVector(sim.numDofs(), 0.03, 3));
  sim.setColliders({Collider::plane(Vec3(0, lowestNodeHeight(sim) + 0.02, 0), Vec3::UnitY()),
                    Collider::sphere(sim.bonePositions().row(20).transpose() + Vec3(0, 0.03, 0),
                                     0.06)});
  const int n = sim.numDofs();
  VecX g = VecX::Zero(n);
  sim.getPotentialGradientVector(g);
  EXPECT_GT(sim.stats().active_contacts, 3);
  for (bool psd : {false, true}) {
    std::vector<Triplet> H;
    sim.getPotentialHessianTripletVector(H, 0, psd);
    const MatX Hd = dense(H, n);
    if (psd) {
      EXPECT_GE(Eigen::SelfAdjointEigenSolver<MatX>(Hd).eigenvalues().minCoeff(),
                -1e-9 * Hd.norm());
      continue;
    }
    const auto gradient = [&](const VecX& d) {
      return atMovedState(sim, d, [&] {
        VecX gd = VecX::Zero(n);
        sim.getPotentialGradientVector(gd);
        return test::pullBackRotationGradient(gd, d);
      });
    };
    const auto r = jacobianMatchesFiniteDifferences(gradient, VecX::Zero(n), Hd, 1e-6);
    EXPECT_TRUE(r);
    std::cout << "[contact only] exact Hessian: " << r.message() << "\n";
  }
}

// The energy and gradient from one pass (what Newton's line search asks of a Scene) equal the
// separate calls: both gradients added at an offset, the energy their sum, contact included.
TEST(Simulable, EnergyAndGradientInOnePassMatchTheSeparateCalls) {
  auto sim = walkingAvatarOnGround(4);
  sim->getPotentialEnergyScalar();
  ASSERT_GT(sim->stats().active_contacts, 0);
  const int n = sim->numDofs(), offset = 3;
  VecX parts = VecX::Zero(n + offset);
  sim->getDynamicGradientVector(parts, offset);
  sim->getPotentialGradientVector(parts, offset);
  ASSERT_GT(parts.cwiseAbs().maxCoeff(), 0.0);
  VecX fused = VecX::Constant(n + offset, 0.25);  // added to what is there
  const double energy = sim->getEnergyAndGradientVector(fused, offset);
  fused.array() -= 0.25;
  EXPECT_LE((fused - parts).cwiseAbs().maxCoeff(), 1e-13 * parts.cwiseAbs().maxCoeff());
  EXPECT_EQ(fused.head(offset).cwiseAbs().maxCoeff(), 0.0);
  const double dynamic = sim->getDynamicEnergyScalar(), potential = sim->getPotentialEnergyScalar();
  ASSERT_GT(std::abs(dynamic), 0.0);
  EXPECT_NEAR(energy, dynamic + potential, 1e-12 * (std::abs(dynamic) + std::abs(potential)));
  VecX both = VecX::Constant(n + offset, 0.25);
  sim->getGradientVector(both, offset);
  both.array() -= 0.25;
  EXPECT_TRUE(both == fused);  // the same passes
}

TEST(Simulable, PsdHessiansArePsd) {
  auto sim = walkingAvatarOnGround(4);
  const int n = sim->numDofs();
  std::vector<Triplet> H;
  sim->getDynamicHessianTripletVector(H, 0, true);
  sim->getPotentialHessianTripletVector(H, 0, true);
  const MatX Hd = dense(H, n);
  EXPECT_LT((Hd - Hd.transpose()).cwiseAbs().maxCoeff(), 1e-9 * Hd.cwiseAbs().maxCoeff());
  EXPECT_GE(Eigen::SelfAdjointEigenSolver<MatX>(Hd).eigenvalues().minCoeff(), -1e-9 * Hd.norm());
}

TEST(Simulable, StateJacobianMatchesFiniteDifferences) {
  auto sim = walkingAvatarOnGround(5);
  const MatX D = sim->getStateJacobian();
  ASSERT_EQ(D.rows(), 75);
  ASSERT_EQ(D.cols(), sim->numDofs());
  const auto poseTrans = [&](const VecX& d) {
    return atMovedState(*sim, d, [&] {
      VecX out(75);
      out << sim->getPose(), sim->getTrans();
      return out;
    });
  };
  const auto r = jacobianMatchesFiniteDifferences(poseTrans, VecX::Zero(sim->numDofs()), D, 1e-6);
  EXPECT_TRUE(r);
  std::cout << "[state Jacobian] " << r.message() << "\n";
}

TEST(Simulable, NodesJacobianMatchesFiniteDifferences) {
  auto sim = walkingAvatarOnGround(6);
  const SpMat D = sim->getNodesStateJacobian();
  ASSERT_EQ(D.rows(), 3 * shared().body->numVertices());
  const auto nodes = [&](const VecX& d) {
    return atMovedState(*sim, d, [&] {
      const MatX3 x = sim->getNodes();
      return VecX(Eigen::Map<const VecX>(x.data(), x.size()));
    });
  };
  const auto r =
      jacobianMatchesFiniteDifferences(nodes, VecX::Zero(sim->numDofs()), MatX(D), 1e-6);
  EXPECT_TRUE(r);
  std::cout << "[nodes Jacobian] " << r.message() << "\n";
}

// ---- broad phase ---------------------------------------------------------------------------

TEST(Simulable, BroadPhaseSkipsOnlyVerticesWithoutContact) {
  // Deep penetration and a sphere at a bent hand: the contact energy through the simulable
  // equals colliderContactEnergy over every node.
  auto sim = walkingAvatarOnGround(7);
  sim->updateState(randomVector(sim->numDofs(), 0.2, 8));  // strongly bent joints
  const std::vector<Collider> colliders = {
      Collider::plane(Vec3(0, lowestNodeHeight(*sim) + 0.25, 0), Vec3(0.1, 1, 0)),
      Collider::sphere(sim->getNodes().row(600).transpose(), 0.1),
      Collider::capsule(sim->getNodes().row(100).transpose(),
                        sim->getNodes().row(100).transpose() + Vec3(0.3, 0, 0), 0.05)};
  sim->setColliders({});
  const double without = sim->getPotentialEnergyScalar();
  sim->setColliders(colliders);
  const double with = sim->getPotentialEnergyScalar();
  const double all_nodes = colliderContactEnergy(sim->getNodes(), shared().avatar->vertexAreas(),
                                                 colliders, sim->time(), sim->options().contact);
  ASSERT_GT(all_nodes, 0.0);
  EXPECT_NEAR(with - without, all_nodes, 1e-9 * all_nodes);
}

// ---- state handling ------------------------------------------------------------------------

TEST(Simulable, DerivativeCallsDoNotChangeTheState) {
  auto sim = walkingAvatarOnGround(9);
  const VecX q = sim->getState();
  const MatX3 t = sim->bonePositions();
  const std::vector<Mat3> R = sim->boneRotations();
  const VecX v = sim->getVelocity();
  const double E = sim->getPotentialEnergyScalar() + sim->getDynamicEnergyScalar();
  VecX g = VecX::Zero(sim->numDofs());
  std::vector<Triplet> H;
  sim->getDynamicGradientVector(g);
  sim->getPotentialGradientVector(g);
  sim->getDynamicHessianTripletVector(H, 0, false);
  sim->getPotentialHessianTripletVector(H, 0, false);
  sim->getPotentialHessianTripletVector(H, 0, true);
  sim->getStateJacobian();
  sim->getNodesStateJacobian();
  sim->getVertices();
  sim->getNodes();
  sim->fixVectorKinematic(g);
  sim->fixMatrixKinematic(H);
  EXPECT_TRUE(sim->getState() == q);
  EXPECT_TRUE(sim->bonePositions() == t);
  for (int b = 0; b < 24; ++b) EXPECT_TRUE(sim->boneRotations()[b] == R[b]);
  EXPECT_TRUE(sim->getVelocity() == v);
  EXPECT_EQ(sim->getPotentialEnergyScalar() + sim->getDynamicEnergyScalar(), E);
}

TEST(Simulable, PushPopRoundTripsExactlyAndInvalidatesCaches) {
  auto sim = walkingAvatarOnGround(10);
  const VecX q = sim->getState();
  const std::vector<Mat3> R = sim->boneRotations();
  const double E = sim->getPotentialEnergyScalar();
  sim->pushState();
  sim->updateState(randomVector(sim->numDofs(), 0.1, 11));
  EXPECT_NE(sim->getPotentialEnergyScalar(), E);  // the contact cache follows the state
  sim->pushState();
  sim->setState(VecX::Zero(sim->numDofs()));
  sim->popState();
  sim->popState();
  EXPECT_TRUE(sim->getState() == q);
  for (int b = 0; b < 24; ++b) EXPECT_TRUE(sim->boneRotations()[b] == R[b]);
  EXPECT_EQ(sim->getPotentialEnergyScalar(), E);
  const std::string message = messageOf<Error>([&] { sim->popState(); });
  EXPECT_NE(message.find("empty"), std::string::npos) << message;
}

bool sameStep(const SimulableStep& a, const SimulableStep& b) {
  if (a.t != b.t || a.t_n != b.t_n || a.t_nm1 != b.t_nm1 || a.time != b.time ||
      a.target_t0 != b.target_t0 || a.is_static != b.is_static ||
      a.colliders.size() != b.colliders.size())
    return false;
  for (size_t k = 0; k < a.R.size(); ++k)
    if (a.R[k] != b.R[k] || a.R_n[k] != b.R_n[k] || a.R_nm1[k] != b.R_nm1[k] ||
        a.target_R[k] != b.target_R[k])
      return false;
  for (size_t k = 0; k < a.colliders.size(); ++k)
    if (a.colliders[k].path.offsets != b.colliders[k].path.offsets) return false;
  return true;
}

// The adjoint's tape puts a simulable back at any recorded step: a bitwise round trip of the
// states, time, targets and colliders, with the energies of that step.
TEST(Simulable, SaveStepRestoreStepRoundTripsExactly) {
  auto sim = walkingAvatarOnGround(12);
  const SimulableStep saved = sim->saveStep();
  const double E = sim->getPotentialEnergyScalar() + sim->getDynamicEnergyScalar();
  const int contacts = sim->stats().active_contacts;
  ASSERT_GT(contacts, 0);
  for (int k = 0; k < 3; ++k) {  // move everything on: states, time, targets
    sim->postUpdate();
    sim->preUpdate();
    sim->updateState(randomVector(sim->numDofs(), 0.05, 13 + k));
  }
  sim->setColliders({});
  EXPECT_FALSE(sameStep(sim->saveStep(), saved));
  sim->restoreStep(saved);
  EXPECT_TRUE(sameStep(sim->saveStep(), saved));
  EXPECT_EQ(sim->stats().active_contacts, contacts);
  EXPECT_EQ(sim->getPotentialEnergyScalar() + sim->getDynamicEnergyScalar(), E);
  SimulableStep bad = saved;
  bad.R_n.pop_back();
  const std::string msg = messageOf<InputError>([&] { sim->restoreStep(bad); });
  EXPECT_NE(msg.find("23"), std::string::npos) << msg;
  EXPECT_TRUE(sameStep(sim->saveStep(), saved));  // nothing half-restored
}

TEST(Simulable, DiscardStateKeepsTheCurrentStateAndDropsTheSavedOne) {
  auto sim = walkingAvatarOnGround(10);
  const VecX q0 = sim->getState();
  sim->pushState();  // saved: q0
  sim->updateState(randomVector(sim->numDofs(), 0.1, 12));
  const VecX q1 = sim->getState();
  sim->pushState();  // saved: q1
  sim->updateState(randomVector(sim->numDofs(), 0.1, 13));
  const VecX q2 = sim->getState();
  sim->discardState();  // drops q1, keeps q2 bit for bit
  EXPECT_TRUE(sim->getState() == q2);
  sim->popState();  // back to q0: the discarded level is gone
  EXPECT_TRUE(sim->getState() == q0);
  // Re-pushing reuses the storage of the dropped levels and still round-trips exactly.
  sim->setState(q1);
  sim->pushState();
  sim->setState(q2);
  sim->popState();
  for (int b = 0; b < 24; ++b)
    EXPECT_TRUE(sim->boneRotations()[b] == rodrigues(q1.segment<3>(6 * b + 3))) << "bone " << b;
  const std::string message = messageOf<Error>([&] { sim->discardState(); });
  EXPECT_NE(message.find("empty"), std::string::npos) << message;
}

TEST(Simulable, SetStateRejectsWrongSizesAndNonFiniteValues) {
  Simulable sim(shared().avatar);
  sim.initialize();
  std::string message = messageOf<InputError>([&] { sim.setState(VecX::Zero(10)); });
  EXPECT_NE(message.find("144"), std::string::npos) << message;
  EXPECT_NE(message.find("10"), std::string::npos) << message;
  VecX q = sim.getState();
  q[7] = std::nan("");
  message = messageOf<InputError>([&] { sim.setState(q); });
  EXPECT_NE(message.find("NaN"), std::string::npos) << message;
  message = messageOf<InputError>([&] { sim.updateState(VecX::Zero(3)); });
  EXPECT_NE(message.find("144"), std::string::npos) << message;
  message = messageOf<InputError>([&] { sim.setVelocity(VecX::Zero(143)); });
  EXPECT_NE(message.find("143"), std::string::npos) << message;
  // The state is untouched by the rejected calls.
  EXPECT_TRUE(sim.bonePositions() == shared().avatar->restJoints());
}

// Finite but absurd values are rejected where they enter, naming the entry and the bound
// (issue 23): a velocity of 1e300 used to leave the next step's state NaN.
TEST(Simulable, SettersRejectAbsurdMagnitudes) {
  Simulable sim(shared().avatar);
  sim.initialize();
  const VecX q0 = sim.getState();
  VecX q = q0;
  q[6 * 2 + 1] = 2e4;  // bone 2, t_y, m
  std::string message = messageOf<InputError>([&] { sim.setState(q); });
  for (const char* part : {"q[13]", "20000", "10000", "bone 2"})
    EXPECT_NE(message.find(part), std::string::npos) << message;
  q = q0;
  q.segment<3>(6 * 5 + 3) = Vec3(0, 0, 2e6);  // bone 5's rotation vector, rad
  message = messageOf<InputError>([&] { sim.setState(q); });
  for (const char* part : {"bone 5", "angle 2e+06 rad", "at most 1e+06"})
    EXPECT_NE(message.find(part), std::string::npos) << message;
  q.segment<3>(6 * 5 + 3) = Vec3(0, 0, 1e5);  // large but accepted: a rotation all the same
  sim.setState(q);
  EXPECT_TRUE(sim.getState().allFinite());
  EXPECT_LT(sim.getState().segment<3>(6 * 5 + 3).norm(), 3.15);

  VecX v = VecX::Zero(sim.numDofs());
  v[6 * 3 + 4] = 1e300;
  message = messageOf<InputError>([&] { sim.setVelocity(v); });
  for (const char* part : {"setVelocity", "v[22]", "1e+300", "10000", "bone 3"})
    EXPECT_NE(message.find(part), std::string::npos) << message;
  v[6 * 3 + 4] = -std::numeric_limits<double>::infinity();
  message = messageOf<InputError>([&] { sim.setVelocity(v); });
  EXPECT_NE(message.find("finite"), std::string::npos) << message;
  v[6 * 3 + 4] = 0.0;
  v[6 * 3 + 1] = kMaxStateVelocity;  // the bound itself is accepted (bone 3, t_y, m/s)
  sim.setVelocity(v);
  EXPECT_NEAR(sim.getVelocity()[6 * 3 + 1], kMaxStateVelocity, 1e-6 * kMaxStateVelocity);
}

TEST(Simulable, ConstructorRejectsAbsurdMocap) {
  auto motion = std::make_shared<Motion>(*shared().walk);
  motion->poses(2, 3 * 4 + 1) = 1e300;  // frame 2, left knee
  std::string message = messageOf<InputError>([&] { Simulable sim(shared().avatar, motion); });
  for (const char* part : {"frame 2", "joint 4 (left_knee)", "1e+300", "1e6 rad"})
    EXPECT_NE(message.find(part), std::string::npos) << message;
  motion = std::make_shared<Motion>(*shared().walk);
  motion->trans(1, 2) = -1e300;
  message = messageOf<InputError>([&] { Simulable sim(shared().avatar, motion); });
  EXPECT_NE(message.find("trans"), std::string::npos) << message;
  EXPECT_NE(message.find("10000"), std::string::npos) << message;
}

TEST(Simulable, SetStateGetStateRoundTrip) {
  auto sim = walkingAvatarOnGround(12);
  const VecX q = randomVector(sim->numDofs(), 1.5, 13);
  sim->setState(q);
  EXPECT_LT((sim->getState() - q).cwiseAbs().maxCoeff(), 1e-13);
}

TEST(Simulable, VelocityRoundTrip) {
  auto sim = walkingAvatarOnGround(14);
  const VecX v = randomVector(sim->numDofs(), 2.0, 15);
  sim->setVelocity(v);
  EXPECT_LT((sim->getVelocity() - v).cwiseAbs().maxCoeff(), 1e-11);
}

TEST(Simulable, ConstructorRejectsBadInputs) {
  std::string message = messageOf<InputError>([] { Simulable sim(nullptr); });
  EXPECT_NE(message.find("avatar"), std::string::npos) << message;
  auto fresh = std::make_shared<SoftAvatar>(shared().body, VecX());
  message = messageOf<InputError>([&] { Simulable sim(fresh); });
  EXPECT_NE(message.find("initVolumetricData"), std::string::npos) << message;
  SimulableOptions options;
  options.kinematic_bones = {3, 24};
  message = messageOf<InputError>([&] { Simulable sim(shared().avatar, nullptr, options); });
  EXPECT_NE(message.find("kinematic_bones"), std::string::npos) << message;
  options = {};
  options.time_step = 0.0;
  message = messageOf<InputError>([&] { Simulable sim(shared().avatar, nullptr, options); });
  EXPECT_NE(message.find("time_step"), std::string::npos) << message;
  auto other_body = std::make_shared<BodyModel>(*shared().body);
  message = messageOf<InputError>(
      [&] { Simulable sim(shared().avatar, other_body, shared().walk); });
  EXPECT_NE(message.find("body model"), std::string::npos) << message;
  auto bad_motion = std::make_shared<Motion>(*shared().walk);
  bad_motion->trans.conservativeResize(3, 3);
  message = messageOf<InputError>([&] { Simulable sim(shared().avatar, bad_motion); });
  EXPECT_NE(message.find("trans"), std::string::npos) << message;
}

// ---- mocap ---------------------------------------------------------------------------------

TEST(Simulable, InitializeReproducesTheMocapFirstFrame) {
  const test::SmallScene& s = shared();
  Simulable sim(s.avatar, s.body, s.walk);
  sim.initialize();
  const VecX pose0 = s.walk->poses.row(0).transpose();
  const Vec3 trans0 = s.walk->trans.row(0).transpose();
  const PosedBody posed = poseBody(*s.body, s.avatar->betas(), pose0, trans0);
  EXPECT_LT((sim.bonePositions() - posed.joints).cwiseAbs().maxCoeff(), 1e-12);
  for (int b = 0; b < 24; ++b) {
    EXPECT_LT((sim.boneRotations()[b] - posed.transforms[b].topLeftCorner<3, 3>()).norm(), 1e-12);
    EXPECT_LT((rodrigues(sim.getPose().segment<3>(3 * b)) - rodrigues(pose0.segment<3>(3 * b)))
                  .norm(),
              1e-12);
  }
  EXPECT_LT((sim.getTrans() - trans0).norm(), 1e-12);
  EXPECT_LT((sim.getVertices() - posed.vertices).cwiseAbs().maxCoeff(), 1e-10);
  // The initial velocity is the mocap's first finite difference.
  const PosedBody posed1 = poseBody(*s.body, s.avatar->betas(), s.walk->poses.row(1).transpose(),
                                    s.walk->trans.row(1).transpose());
  const VecX v = sim.getVelocity();
  for (int b = 0; b < 24; ++b)
    EXPECT_LT((v.segment<3>(6 * b) - (posed1.joints.row(b) - posed.joints.row(b)).transpose() *
                                         s.walk->fps)
                  .norm(),
              1e-9);
  EXPECT_GT(v.norm(), 0.0);
  EXPECT_EQ(sim.time(), 0.0);
}

TEST(Simulable, KinematicRootFollowsTheInterpolatedMocap) {
  SimulableOptions options;
  options.kinematic_bones = {0};
  options.time_step = 0.01;  // 0.3 of a mocap frame at 30 fps: interpolation is exercised
  Simulable sim(shared().avatar, shared().walk, options);
  sim.initialize();
  sim.preUpdate();
  sim.preUpdate();
  const Motion& walk = *shared().walk;
  const double alpha = 0.02 * walk.fps;  // between frames 0 and 1
  const Vec3 trans = (1 - alpha) * walk.trans.row(0).transpose() + alpha * walk.trans.row(1).transpose();
  const Vec3 root = slerpRotationVector(walk.poses.row(0).head<3>().transpose(),
                                        walk.poses.row(1).head<3>().transpose(), alpha);
  EXPECT_NEAR(sim.time(), 0.02, 1e-15);
  EXPECT_LT((sim.getTrans() - trans).norm(), 1e-12);
  EXPECT_LT((sim.boneRotations()[0] - rodrigues(root)).norm(), 1e-12);
  VecX g = VecX::Ones(sim.numDofs());
  sim.fixVectorKinematic(g, 0);
  EXPECT_EQ(g.head<6>().norm(), 0.0);
  EXPECT_EQ(g.tail(sim.numDofs() - 6).minCoeff(), 1.0);
  std::vector<Triplet> H;
  sim.getPotentialHessianTripletVector(H);
  sim.fixMatrixKinematic(H);
  const MatX Hd = dense(H, sim.numDofs());
  EXPECT_TRUE(Hd.topLeftCorner(6, 6).isIdentity(0.0));
  EXPECT_EQ(Hd.block(0, 6, 6, sim.numDofs() - 6).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_EQ(Hd.block(6, 0, sim.numDofs() - 6, 6).cwiseAbs().maxCoeff(), 0.0);
}

// ---- small dynamics checks with a dense Newton loop ----------------------------------------

struct StepResult {
  int iterations = 0;
  bool converged = false;
  double initial_gradient = 0.0, final_gradient = 0.0;  // ‖g‖∞ of the free DoFs
};

// Minimizes the backward-Euler energy of one step (dense, PSD Hessian, backtracking).
StepResult solveStep(Simulable& sim, int max_iterations = 50) {
  const int n = sim.numDofs();
  auto energy = [&] { return sim.getDynamicEnergyScalar() + sim.getPotentialEnergyScalar(); };
  StepResult result;
  for (int it = 0; it <= max_iterations; ++it) {
    VecX g = VecX::Zero(n);
    sim.getDynamicGradientVector(g);
    sim.getPotentialGradientVector(g);
    sim.fixVectorKinematic(g);
    const double gnorm = g.cwiseAbs().maxCoeff();
    if (it == 0) result.initial_gradient = gnorm;
    result.iterations = it;
    result.final_gradient = gnorm;
    const double scale = std::max(1.0, result.initial_gradient);
    if (gnorm <= 1e-8 * scale || it == max_iterations) {
      result.converged = gnorm <= 1e-8 * scale;
      return result;
    }
    std::vector<Triplet> H;
    sim.getDynamicHessianTripletVector(H);
    sim.getPotentialHessianTripletVector(H);
    sim.fixMatrixKinematic(H);
    const VecX dq = -dense(H, n).ldlt().solve(g);
    const double E0 = energy();
    double step = 1.0;
    bool accepted = false;
    for (int ls = 0; ls < 30 && !accepted; ++ls, step *= 0.5) {
      sim.pushState();
      sim.updateState(step * dq);
      accepted = energy() <= E0 + 1e-4 * step * g.dot(dq);
      sim.popState();
      if (accepted) sim.updateState(step * dq);
    }
    if (!accepted) {
      // No measurable decrease left: converged to round-off if the gradient is small.
      result.converged = gnorm <= 1e-6 * scale;
      return result;
    }
  }
  return result;
}

TEST(Simulable, RestAvatarWithPinnedRootHangsUnderGravity) {
  const test::SmallScene& s = shared();
  SimulableOptions options;
  options.kinematic_bones = {0};
  Simulable sim(s.avatar, nullptr, options);
  sim.initialize();
  const MatX3& J = s.avatar->restJoints();
  const std::vector<int>& parents = s.body->parents;
  for (int step = 0; step < 12; ++step) {
    sim.preUpdate();
    EXPECT_TRUE(solveStep(sim).converged);
    sim.postUpdate();
  }
  // The pinned root stays exactly at rest; the rest hangs from it, joints held together.
  EXPECT_TRUE(sim.boneRotations()[0] == Mat3::Identity());
  EXPECT_TRUE(sim.bonePositions().row(0) == J.row(0));
  double max_gap = 0.0;
  for (int b = 1; b < 24; ++b) {
    const int p = parents[b];
    const Vec3 carried = sim.boneRotations()[p] * (J.row(b) - J.row(p)).transpose() +
                         sim.bonePositions().row(p).transpose();
    max_gap = std::max(max_gap, (carried - sim.bonePositions().row(b).transpose()).norm());
  }
  EXPECT_LT(max_gap, 5e-3);  // M g / k_J is millimetres
  EXPECT_GT(max_gap, 0.0);
  // The legs hang below the hips and only settle (the shank's and foot's centres of mass lie a
  // few cm in front of the knee and ankle); the unsupported arms swing down.
  const int left_ankle = 7, left_wrist = 20;
  EXPECT_LT((sim.bonePositions().row(left_ankle) - J.row(left_ankle)).norm(), 0.1);
  EXPECT_LT(sim.bonePositions()(left_wrist, 1), J(left_wrist, 1) - 0.05);
  EXPECT_TRUE(sim.getState().allFinite());
}

TEST(Simulable, FreeFallMovesTheCentreOfMassExactly) {
  // Joint springs are internal forces: backward Euler moves the centre of mass by
  // COM_k = COM_0 + h² g k(k+1)/2 from rest, whatever the bones do.
  const test::SmallScene& s = shared();
  Simulable sim(s.avatar);
  sim.initialize();
  auto centreOfMass = [&] {
    Vec3 moment = Vec3::Zero();
    double mass = 0.0;
    for (int b = 0; b < 24; ++b) {
      const BoneInertia& I = s.avatar->boneInertia()[b];
      moment += I.mass * sim.bonePositions().row(b).transpose() +
                sim.boneRotations()[b] * I.first_moment;
      mass += I.mass;
    }
    return Vec3(moment / mass);
  };
  const Vec3 com0 = centreOfMass();
  const int steps = 10;
  for (int step = 0; step < steps; ++step) {
    sim.preUpdate();
    EXPECT_TRUE(solveStep(sim).converged);
    sim.postUpdate();
  }
  const double h = sim.options().time_step;
  const Vec3 expected = com0 + h * h * sim.options().gravity * steps * (steps + 1) / 2.0;
  EXPECT_LT((centreOfMass() - expected).norm(), 1e-9);
  EXPECT_GT((centreOfMass() - com0).norm(), 0.1);
}

TEST(Simulable, TracksTheMocapOnTheGround) {
  // Stiff tracking (6 Hz): the sag under gravity, g/ω², is below a centimetre. (With the
  // defaults, 2 Hz at the root, a body whose feet do not carry it sags about 6 cm.)
  const test::SmallScene& s = shared();
  SimulableOptions options;
  options.tracking_stiffness = options.root_stiffness = std::pow(2.0 * M_PI * 6.0, 2);
  Simulable sim(s.avatar, s.body, s.walk, options);
  sim.initialize();
  sim.setColliders({Collider::plane(Vec3(0, lowestNodeHeight(sim) - 0.005, 0), Vec3::UnitY())});
  int contacts = 0;
  for (int step = 0; step < 20; ++step) {
    sim.preUpdate();
    EXPECT_TRUE(solveStep(sim).converged);
    sim.postUpdate();
    contacts = std::max(contacts, sim.stats().active_contacts);
  }
  const Motion& walk = *s.walk;
  const double frame = sim.time() * walk.fps;
  const int f0 = int(frame);
  const double alpha = frame - f0;
  VecX pose(72);
  for (int b = 0; b < 24; ++b)
    pose.segment<3>(3 * b) = slerpRotationVector(walk.poses.row(f0).segment<3>(3 * b).transpose(),
                                                 walk.poses.row(f0 + 1).segment<3>(3 * b).transpose(),
                                                 alpha);
  const Vec3 trans =
      (1 - alpha) * walk.trans.row(f0).transpose() + alpha * walk.trans.row(f0 + 1).transpose();
  const PosedBody target = poseBody(*s.body, s.avatar->betas(), pose, trans);
  const double error = (sim.bonePositions() - target.joints).rowwise().norm().maxCoeff();

  EXPECT_LT(error, 0.03) << "joints drift from the mocap";
  EXPECT_GT(contacts, 0);
  EXPECT_GT(lowestNodeHeight(sim), sim.colliders()[0].p0().y() - 0.02);  // no sinking
}

TEST(Simulable, TrackingStiffnessAddsTheInertiaFloorToEveryBoneButTheRoot) {
  // At the mocap's first frame every tracking spring is at rest, so its Hessian block over the
  // bone's rotation is k_b I₃ (the joint springs do not depend on a bone's own rotation and
  // gravity is off). Raising the floor by ΔI adds ω_T² ΔI to each bone's own block, and to its
  // parent's (the spring's other end); the root's spring has no floor.
  const test::SmallScene& s = shared();
  auto rotationBlocks = [&](double floor) {
    SimulableOptions options;
    options.gravity.setZero();
    options.tracking_inertia_floor = floor;
    Simulable sim(s.avatar, s.body, s.walk, options);
    sim.initialize();
    std::vector<Triplet> H;
    sim.getPotentialHessianTripletVector(H, 0, false);
    const MatX dense_H = dense(H, sim.numDofs());
    std::vector<Mat3> blocks(24);
    for (int b = 0; b < 24; ++b) blocks[b] = dense_H.block<3, 3>(6 * b + 3, 6 * b + 3);
    return blocks;
  };
  const SimulableOptions defaults;
  EXPECT_EQ(defaults.tracking_inertia_floor, 0.01);
  const double delta = 0.05;
  const std::vector<Mat3> without = rotationBlocks(0.0), with = rotationBlocks(delta);
  int children_of[24] = {};
  for (int b = 1; b < 24; ++b) ++children_of[kSmplParents[b]];
  const double omega2 = defaults.tracking_stiffness;
  for (int b = 0; b < 24; ++b) {
    const double springs = (b == 0 ? 0 : 1) + children_of[b];
    EXPECT_LT((with[b] - without[b] - springs * omega2 * delta * Mat3::Identity()).norm(),
              1e-9 * with[b].norm())
        << "bone " << b;
  }
  // Without the floor a toe (a leaf, SMPL bone 10) is nearly free: its block is its own spring.
  EXPECT_GT(without[10].trace(), 0.0);
  EXPECT_LT(without[10](0, 0), 0.2 * omega2 * delta);
  EXPECT_LT((without[10] - without[10](0, 0) * Mat3::Identity()).norm(), 1e-9 * without[10].norm());
}

TEST(Simulable, ToesFollowTheirTargetsOnTheGround) {
  // The walk keeps the toes straight (target 0 relative to the foot) while the foot rolls over
  // the ground: the contact pushes the toe tips. With the pure inertia scaling a toe's spring
  // is ~0.16 N·m/rad and the toes fold (0.74 rad on this body; 2 rad on the FEM walk of
  // docs/benchmarks.md); with the default floor they stay within ~0.11 rad.
  const test::SmallScene& s = shared();
  auto largestToeError = [&](double floor) {
    SimulableOptions options;
    options.time_step = 1.0 / 30.0;
    options.tracking_inertia_floor = floor;
    Simulable sim(s.avatar, s.body, s.walk, options);
    sim.initialize();
    sim.setColliders({Collider::plane(Vec3(0, lowestNodeHeight(sim) - 0.002, 0), Vec3::UnitY())});
    double largest = 0.0;
    for (int step = 0; step < 29; ++step) {
      sim.preUpdate();
      EXPECT_TRUE(solveStep(sim).converged);
      sim.postUpdate();
      const std::vector<Mat3>& R = sim.boneRotations();
      for (int toe : {10, 11})
        largest = std::max(largest, logSO3(R[kSmplParents[toe]].transpose() * R[toe]).norm());
    }
    return largest;
  };
  const double floored = largestToeError(SimulableOptions().tracking_inertia_floor);
  const double pure = largestToeError(0.0);
  EXPECT_LT(floored, 0.2);
  EXPECT_GT(pure, 2.0 * floored);
}

TEST(Simulable, NegativeTrackingInertiaFloorIsAnInputError) {
  SimulableOptions options;
  options.tracking_inertia_floor = -1e-3;
  EXPECT_THROW(Simulable(shared().avatar, shared().body, shared().walk, options), InputError);
  options.tracking_inertia_floor = std::nan("");
  EXPECT_THROW(Simulable(shared().avatar, shared().body, shared().walk, options), InputError);
}

TEST(Simulable, StaysFiniteAtExtremeSettingsAndDeepPenetration) {
  // Time steps 1e-4…0.1 s, tracking very soft…very stiff, the avatar starting 30 cm deep in
  // the ground with a fast initial spin: every step converges, the state stays finite and the
  // body is pushed up, not through.
  const test::SmallScene& s = shared();
  for (double h : {1e-4, 1.0 / 60.0, 0.1}) {
    for (double tracking : {1e-2, 355.0, 1e5}) {
      SimulableOptions options;
      options.time_step = h;
      options.tracking_stiffness = options.root_stiffness = tracking;
      Simulable sim(s.avatar, s.body, s.walk, options);
      sim.initialize();
      VecX v = sim.getVelocity();
      for (int b = 0; b < 24; ++b) v.segment<3>(6 * b + 3) += Vec3(0, 20.0, 0);  // rad/s
      sim.setVelocity(v);
      const double ground = lowestNodeHeight(sim) + 0.3;
      sim.setColliders({Collider::plane(Vec3(0, ground, 0), Vec3::UnitY())});
      for (int step = 0; step < 3; ++step) {
        sim.preUpdate();
        // Deep contact makes the first steps hard (the active set keeps changing): ask for
        // steady progress, not full convergence, within 50 iterations.
        const StepResult r = solveStep(sim);
        EXPECT_LT(r.final_gradient, 1e-3 * r.initial_gradient)
            << "h " << h << " tracking " << tracking << " step " << step;
        sim.postUpdate();
      }
      EXPECT_TRUE(sim.getState().allFinite()) << "h " << h << " tracking " << tracking;
      EXPECT_TRUE(sim.getNodes().allFinite());
      EXPECT_GT(lowestNodeHeight(sim), ground - 0.5) << "h " << h << " tracking " << tracking;
    }
  }
}

TEST(Simulable, StaticModeHasNoDynamicTerm) {
  auto sim = walkingAvatarOnGround(16);
  EXPECT_GT(sim->getDynamicEnergyScalar(), 0.0);
  sim->setStatic(true);
  EXPECT_TRUE(sim->isStatic());
  EXPECT_EQ(sim->getDynamicEnergyScalar(), 0.0);
  VecX g = VecX::Zero(sim->numDofs());
  sim->getDynamicGradientVector(g);
  std::vector<Triplet> H;
  sim->getDynamicHessianTripletVector(H);
  EXPECT_EQ(g.norm(), 0.0);
  EXPECT_TRUE(H.empty());
}

}  // namespace
}  // namespace flsh
