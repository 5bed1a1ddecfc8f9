// Simulable::restoreStep refuses snapshots holding NaN or Inf (issue 23). Every setter of the
// state refuses non-finite values, but restoreStep put back any snapshot as it was, so a NaN in
// a snapshot (e.g. a tape edited by hand, or filled from a bad file) was stepped on.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>
#include <memory>

#include "flsh/core/error.h"
#include "flsh/sim/simulable.h"
#include "flsh/volume/soft_avatar.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::messageOf;
using ::testing::HasSubstr;

const test::SmallScene& shared() { return test::smallScene(800, 1.0); }

std::unique_ptr<Simulable> steppedSimulable() {
  auto sim = std::make_unique<Simulable>(shared().avatar, shared().walk);
  sim->initialize();
  sim->preUpdate();
  sim->updateState(test::randomVector(sim->numDofs(), 0.03, 5));
  Collider ball = Collider::sphere(Vec3(0, 0, 0.5), 0.1);
  ball.path = ColliderPath::constantVelocity(Vec3(0, 0, -1), 1.0);
  sim->setColliders({Collider::plane(Vec3(0, -1, 0), Vec3::UnitY()), ball});
  return sim;
}

struct Poison {
  const char* name;  ///< what the message must name
  std::function<void(SimulableStep&, double)> apply;
};

TEST(SimulableRestoreStep, NonFiniteSnapshotsAreRefusedNamingTheValue) {
  auto sim = steppedSimulable();
  const SimulableStep good = sim->saveStep();
  const std::vector<Poison> poisons = {
      {"R[4](1, 2)", [](SimulableStep& s, double x) { s.R[4](1, 2) = x; }},
      {"R_n[0](0, 0)", [](SimulableStep& s, double x) { s.R_n[0](0, 0) = x; }},
      {"R_nm1[23](2, 1)", [](SimulableStep& s, double x) { s.R_nm1[23](2, 1) = x; }},
      {"target_R[7](0, 1)", [](SimulableStep& s, double x) { s.target_R[7](0, 1) = x; }},
      {"t(2, 0)", [](SimulableStep& s, double x) { s.t(2, 0) = x; }},
      {"t_n(10, 2)", [](SimulableStep& s, double x) { s.t_n(10, 2) = x; }},
      {"t_nm1(3, 1)", [](SimulableStep& s, double x) { s.t_nm1(3, 1) = x; }},
      {"target_t0[1]", [](SimulableStep& s, double x) { s.target_t0[1] = x; }},
      {"time is", [](SimulableStep& s, double x) { s.time = x; }},
      {"colliders[1].path.offsets[1][2]",
       [](SimulableStep& s, double x) { s.colliders[1].path.offsets[1][2] = x; }},
      {"colliders[1].path.times[0]",
       [](SimulableStep& s, double x) { s.colliders[1].path.times[0] = x; }},
  };
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  for (const Poison& p : poisons) {
    for (const double bad : {nan, inf, -inf}) {
      // Change the simulable first, so that a (partial) restore would show.
      sim->restoreStep(good);
      sim->preUpdate();
      sim->updateState(test::randomVector(sim->numDofs(), 0.02, 9));
      const VecX q_before = sim->getState();
      const VecX v_before = sim->getVelocity();
      const double time_before = sim->time();

      SimulableStep poisoned = good;
      p.apply(poisoned, bad);
      const std::string message = messageOf<InputError>([&] { sim->restoreStep(poisoned); });
      EXPECT_THAT(message,
                  HasSubstr("Simulable::restoreStep: the snapshot's " + std::string(p.name)))
          << bad;
      EXPECT_THAT(message, HasSubstr(std::isnan(bad) ? "nan" : "inf")) << p.name;
      EXPECT_THAT(message, HasSubstr("nothing restored")) << p.name;
      // Nothing half-restored.
      EXPECT_EQ(sim->getState(), q_before) << p.name;
      EXPECT_EQ(sim->getVelocity(), v_before) << p.name;
      EXPECT_EQ(sim->time(), time_before) << p.name;
      EXPECT_TRUE(sim->getState().allFinite()) << p.name;
    }
  }
  // The unpoisoned snapshot still restores.
  sim->restoreStep(good);
  EXPECT_EQ(sim->saveStep().t, good.t);
  EXPECT_EQ(sim->time(), good.time);
}

TEST(SimulableRestoreStep, NonFiniteSoftTissueValuesAreRefused) {
  // The FEM soft skeleton of the 800-vertex body (coarse interior): displacements of q, q_n,
  // q_{n-1} and the held pose blend offsets are checked too.
  auto avatar = std::make_shared<SoftAvatar>(
      test::smallScene(800).body, VecX(),
      test::smallSoftAvatarSettings(test::freshTempDir("restore_step_soft_cache")));
  avatar->enableSoftTissue();
  avatar->initVolumetricData();
  Simulable sim(avatar, shared().walk);
  sim.initialize();
  sim.preUpdate();
  sim.updateState(test::randomVector(sim.numDofs(), 0.001, 3));
  const SimulableStep good = sim.saveStep();
  ASSERT_GT(good.u.size(), 0);
  const VecX q_before = sim.getState();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const Eigen::Index last = good.u.size() - 1;
  const std::vector<std::pair<std::string, std::function<void(SimulableStep&)>>> poisons = {
      {"u[0]", [&](SimulableStep& s) { s.u[0] = nan; }},
      {"u_n[" + std::to_string(last) + "]", [&](SimulableStep& s) { s.u_n[last] = nan; }},
      {"u_nm1[7]",
       [&](SimulableStep& s) { s.u_nm1[7] = -std::numeric_limits<double>::infinity(); }},
      {"pose_blend(5, 2)", [&](SimulableStep& s) { s.pose_blend(5, 2) = nan; }},
  };
  for (const auto& [name, apply] : poisons) {
    SimulableStep poisoned = good;
    apply(poisoned);
    EXPECT_THAT(messageOf<InputError>([&] { sim.restoreStep(poisoned); }),
                HasSubstr("the snapshot's " + name + " is "));
    EXPECT_EQ(sim.getState(), q_before) << name;
  }
  sim.restoreStep(good);
  EXPECT_EQ(sim.getState(), q_before);
}

// The ROM's snapshot keeps the rotations its held pose blend comes from (no #N × 3 offsets per
// step): restored after the body moved on, every node is where it was, also when the snapshot
// was taken after postUpdate (as Scene::step takes it), where the held blend is not R_n's;
// offsets set one by one are kept.
TEST(SimulableRestoreStep, RomSnapshotsHoldThePoseBlendOfTheirPose) {
  auto avatar = std::make_shared<SoftAvatar>(
      test::smallScene(800).body, VecX(),
      test::smallSoftAvatarSettings(test::freshTempDir("restore_step_rom_cache")));
  avatar->enableSoftTissue();
  avatar->enableReducedModel();
  avatar->initVolumetricData();
  Simulable sim(avatar, shared().walk);
  sim.initialize();
  sim.preUpdate();
  sim.updateState(test::randomVector(sim.numDofs(), 0.01, 4));
  const SimulableStep good = sim.saveStep();
  EXPECT_EQ(good.pose_blend.rows(), 0);
  EXPECT_EQ(good.pose_blend_R.size(), size_t(24));
  const MatX3 nodes = sim.getVolumeNodes();
  for (int k = 0; k < 3; ++k) {  // walk on: other poses, other held blends
    sim.postUpdate();
    sim.preUpdate();
    sim.updateState(test::randomVector(sim.numDofs(), 0.01, 10 + k));
  }
  ASSERT_NE(sim.getVolumeNodes(), nodes);
  sim.restoreStep(good);
  EXPECT_EQ(sim.getVolumeNodes(), nodes);
  // After postUpdate: q_n is the new state, the blend still the previous q_n's.
  sim.postUpdate();
  const SimulableStep after_post = sim.saveStep();
  EXPECT_EQ(after_post.pose_blend.rows(), 0);
  EXPECT_NE(after_post.pose_blend_R, after_post.R_n);
  const MatX3 nodes_after_post = sim.getVolumeNodes();
  sim.preUpdate();
  sim.updateState(test::randomVector(sim.numDofs(), 0.01, 20));
  ASSERT_NE(sim.getVolumeNodes(), nodes_after_post);
  sim.restoreStep(after_post);
  EXPECT_EQ(sim.getVolumeNodes(), nodes_after_post);
  // Bad rotations are refused by name, nothing restored.
  SimulableStep short_R = after_post;
  short_R.pose_blend_R.pop_back();
  EXPECT_THAT(messageOf<InputError>([&] { sim.restoreStep(short_R); }),
              HasSubstr("23 pose blend rotations, expected 24 bones"));
  SimulableStep nan_R = after_post;
  nan_R.pose_blend_R[3](1, 2) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THAT(messageOf<InputError>([&] { sim.restoreStep(nan_R); }),
              HasSubstr("the snapshot's pose_blend_R[3](1, 2) is "));
  EXPECT_EQ(sim.getVolumeNodes(), nodes_after_post);
  // The offsets the step had evaluated come along and are taken as they are: restored with or
  // without them, the same nodes and the same gradient, bit for bit. Bad ones are refused.
  ASSERT_FALSE(after_post.pose_blend_nodes.empty());
  ASSERT_EQ(after_post.pose_blend_rows.rows(), Eigen::Index(after_post.pose_blend_nodes.size()));
  EXPECT_FALSE(after_post.pose_blend_rows.isZero(0.0));
  SimulableStep unseeded = after_post;
  unseeded.pose_blend_nodes.clear();
  unseeded.pose_blend_rows.resize(0, 3);
  sim.restoreStep(unseeded);
  const MatX3 nodes_unseeded = sim.getVolumeNodes();
  VecX gradient_unseeded = VecX::Zero(sim.numDofs()), gradient = VecX::Zero(sim.numDofs());
  const double energy_unseeded = sim.getEnergyAndGradientVector(gradient_unseeded);
  sim.restoreStep(after_post);
  EXPECT_EQ(sim.getVolumeNodes(), nodes_unseeded);
  EXPECT_EQ(sim.getEnergyAndGradientVector(gradient), energy_unseeded);
  EXPECT_EQ(gradient, gradient_unseeded);
  SimulableStep short_rows = after_post;
  short_rows.pose_blend_rows.conservativeResize(short_rows.pose_blend_rows.rows() - 1, 3);
  EXPECT_THAT(messageOf<InputError>([&] { sim.restoreStep(short_rows); }),
              HasSubstr("rows of pose_blend_rows for"));
  SimulableStep far_node = after_post;
  far_node.pose_blend_nodes[1] = avatar->volumetricData().numNodes();
  EXPECT_THAT(messageOf<InputError>([&] { sim.restoreStep(far_node); }),
              HasSubstr("the snapshot's pose_blend_nodes[1] is "));
  SimulableStep nan_row = after_post;
  nan_row.pose_blend_rows(2, 0) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THAT(messageOf<InputError>([&] { sim.restoreStep(nan_row); }),
              HasSubstr("the snapshot's pose_blend_rows(2, 0) is "));
  EXPECT_EQ(sim.getVolumeNodes(), nodes_after_post);
  // Offsets of one's own are saved as they are.
  SimulableStep own = good;
  own.pose_blend = MatX3::Constant(avatar->volumetricData().numNodes(), 3, 0.001);
  sim.restoreStep(own);
  const SimulableStep saved = sim.saveStep();
  ASSERT_EQ(saved.pose_blend.rows(), own.pose_blend.rows());
  EXPECT_EQ(saved.pose_blend, own.pose_blend);
}

}  // namespace
}  // namespace flsh
