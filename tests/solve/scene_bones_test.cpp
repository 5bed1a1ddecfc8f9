// The scene's objective on its avatars' bones with the soft tissue held (src/solve/
// scene_bones.cpp), which Newton's coarse presolve minimizes: it is the whole objective restricted
// to the bones (gradient, Hessian block, energy differences), its derivatives agree with finite
// differences, and the presolve reaches the same states with fewer iterations on every DoF.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <limits>
#include <memory>

#include "flsh/solve/scene.h"
#include "support/small_soft_avatar.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::SoftModel;

/// A walking soft avatar on the ground (5 mm into it) and a skeleton avatar 3 cm into it:
/// every kind of contact the bones' objective has.
std::unique_ptr<Scene> sceneOf(SoftModel model, const SceneOptions& options = {},
                               bool second_avatar = true) {
  auto scene = std::make_unique<Scene>(options);
  scene->addSimulable(
      std::make_shared<Simulable>(test::smallSoftAvatar(model), test::smallScene(800).walk));
  if (second_avatar) scene->addSimulable(std::make_shared<Simulable>(test::smallScene(800).avatar));
  scene->initialize();
  double lowest = std::numeric_limits<double>::infinity();
  for (const auto& sim : scene->simulables())
    lowest = std::min(lowest, sim->getNodes().col(1).minCoeff());
  scene->addCollider(Collider::plane(Vec3(0, lowest + 0.005, 0), Vec3::UnitY()));
  if (second_avatar) test::touchAlongZ(*scene, 1, 0.03);
  return scene;
}

/// A generic state: every DoF moved at random, the bones by up to 1 cm / 0.01 rad, the soft
/// state by up to 0.5 mm (the small body's tets are ~2 cm: more and the Fung exponential takes
/// the energy to ~1e28 J).
void moveToGenericState(Scene& scene, unsigned seed) {
  VecX d = test::randomVector(scene.numDofs(), 0.01, seed);
  for (size_t i = 0; i < scene.simulables().size(); ++i) {
    const Simulable& sim = *scene.simulables()[i];
    d.segment(scene.offset(int(i)) + sim.numBoneDofs(), sim.numDofs() - sim.numBoneDofs()) *= 0.05;
  }
  scene.step(d);
}

VecX restricted(const VecX& g, const std::vector<int>& dofs) {
  VecX out(Eigen::Index(dofs.size()));
  for (size_t k = 0; k < dofs.size(); ++k) out[Eigen::Index(k)] = g[dofs[k]];
  return out;
}

/// A step of the bones alone: `coarse` at the coarse DoFs, zero elsewhere.
VecX boneStep(const Scene& scene, const std::vector<int>& dofs, const VecX& coarse) {
  VecX d = VecX::Zero(scene.numDofs());
  for (size_t k = 0; k < dofs.size(); ++k) d[dofs[k]] = coarse[Eigen::Index(k)];
  return d;
}

class SceneBones : public ::testing::TestWithParam<SoftModel> {};

// At a generic state in contact: the bones' gradient is the whole gradient's bone entries, their
// Hessian the whole Hessian's bone block (exact and PSD), and their energy changes as the whole
// energy does when only bones move (what it leaves out, the elasticity, is constant there).
TEST_P(SceneBones, IsTheWholeObjectiveOnTheBones) {
  auto scene = sceneOf(GetParam());
  for (auto& sim : scene->simulables()) sim->preUpdate();
  moveToGenericState(*scene, 7);
  int active = 0;
  scene->avatarContactEnergy(nullptr, nullptr, true, &active);
  ASSERT_GT(active, 0) << "the avatars must touch";
  std::vector<int> dofs;
  scene->coarseDofs(dofs);
  double E_coarse = 0.0;
  VecX g_coarse, g;
  ASSERT_TRUE(scene->coarseEnergyAndGradient(E_coarse, g_coarse));
  scene->gradient(g);
  ASSERT_GT(scene->simulables()[0]->stats().active_contacts, 0) << "the ground must touch";
  scene->fixKinematic(g, nullptr);
  const VecX expected = restricted(g, dofs);
  ASSERT_GT(expected.cwiseAbs().maxCoeff(), 0.0);
  EXPECT_LE((g_coarse - expected).cwiseAbs().maxCoeff(), 1e-11 * expected.cwiseAbs().maxCoeff());

  for (bool psd : {false, true}) {
    SpMat H;
    scene->hessian(H, psd);
    scene->fixKinematic(g, &H);
    const MatX dense = MatX(H);
    MatX block(dofs.size(), dofs.size());
    for (size_t r = 0; r < dofs.size(); ++r)
      for (size_t c = 0; c < dofs.size(); ++c) block(r, c) = dense(dofs[r], dofs[c]);
    MatX H_coarse;
    scene->coarseHessian(H_coarse, psd);
    ASSERT_GT(block.cwiseAbs().maxCoeff(), 0.0);
    EXPECT_LE((H_coarse - block).cwiseAbs().maxCoeff(), 1e-11 * block.cwiseAbs().maxCoeff())
        << "psd = " << psd;
  }

  const VecX d = boneStep(*scene, dofs, test::randomVector(int(dofs.size()), 0.02, 11));
  const double whole_before = scene->energy();
  scene->push();
  scene->step(d);
  const double whole_after = scene->energy();
  double coarse_after = 0.0;
  VecX unused;
  scene->coarseEnergyAndGradient(coarse_after, unused);
  scene->pop();
  ASSERT_NE(whole_after, whole_before);
  EXPECT_NEAR(coarse_after - E_coarse, whole_after - whole_before,
              1e-9 * std::abs(whole_after - whole_before));
}

// Central differences along the bones: the gradient from the energy, the exact Hessian block from
// the gradient pulled back to the chart at the state (pullBackRotationGradient). Steps of 1e-7:
// the contact penalties are C¹, and at 1e-6 a vertex of the ROM's case crosses its contact
// border (the error grows with the step: 1.6e-3 at 1e-6, 3.9e-3 at 1e-5).
TEST_P(SceneBones, DerivativesMatchFiniteDifferences) {
  auto scene = sceneOf(GetParam());
  for (auto& sim : scene->simulables()) sim->preUpdate();
  moveToGenericState(*scene, 8);
  std::vector<int> dofs;
  scene->coarseDofs(dofs);
  const int n = int(dofs.size());
  const auto at = [&](const VecX& coarse, double* energy) {
    scene->push();
    scene->step(boneStep(*scene, dofs, coarse));
    double E = 0.0;
    VecX g;
    scene->coarseEnergyAndGradient(E, g);
    scene->pop();
    if (energy) *energy = E;
    return g;
  };
  const VecX g = at(VecX::Zero(n), nullptr);
  MatX H;
  scene->coarseHessian(H, false);
  ASSERT_GT(g.cwiseAbs().maxCoeff(), 0.0);
  ASSERT_GT(H.cwiseAbs().maxCoeff(), 0.0);
  const VecX direction = test::randomVector(n, 1.0, 12);
  const double eps = 1e-6;
  double E_plus = 0.0, E_minus = 0.0;
  at(eps * direction, &E_plus);
  at(-eps * direction, &E_minus);
  const double slope = (E_plus - E_minus) / (2 * eps);
  EXPECT_NEAR(g.dot(direction), slope, 1e-6 * std::max(1.0, std::abs(slope)));
  EXPECT_TRUE(test::jacobianMatchesFiniteDifferences(
      [&](const VecX& d) { return test::pullBackRotationGradient(at(d, nullptr), d); },
      VecX::Zero(n), H, 1e-5, 1e-7));
}

// Kinematic bones: zero gradient, identity rows and columns.
TEST_P(SceneBones, KinematicBonesAreHeld) {
  SceneOptions options;
  auto scene = std::make_unique<Scene>(options);
  SimulableOptions sim_options;
  sim_options.kinematic_bones = {0, 4};
  scene->addSimulable(std::make_shared<Simulable>(test::smallSoftAvatar(GetParam()),
                                                  test::smallScene(800).walk, sim_options));
  scene->initialize();
  for (auto& sim : scene->simulables()) sim->preUpdate();
  double E = 0.0;
  VecX g;
  ASSERT_TRUE(scene->coarseEnergyAndGradient(E, g));
  MatX H;
  scene->coarseHessian(H, true);
  ASSERT_GT(g.cwiseAbs().maxCoeff(), 0.0);
  for (int b : {0, 4})
    for (int k = 6 * b; k < 6 * b + 6; ++k) {
      EXPECT_EQ(g[k], 0.0);
      for (int c = 0; c < H.cols(); ++c) {
        EXPECT_EQ(H(k, c), c == k ? 1.0 : 0.0);
        EXPECT_EQ(H(c, k), c == k ? 1.0 : 0.0);
      }
    }
}

// Newton's coarse presolve on a walking avatar in contact: the same states as without it (both
// at a tight tolerance); fewer iterations on every DoF where the directions are Newton's (the
// FEM, the ROM with handles; the modal ROM's approximate directions converge linearly whatever
// the start, and its default keeps the presolve off).
TEST_P(SceneBones, PresolveReachesTheSameStatesInFewerWholeIterations) {
  const auto run = [&](int presolve, int& whole, int& coarse) {
    SceneOptions options;
    for (NewtonOptions* newton : {&options.soft_tissue_newton, &options.reduced_newton}) {
      newton->coarse_presolve.max_iterations = presolve;
      newton->gradient_tolerance = 1e-9;
    }
    auto scene = sceneOf(GetParam(), options, false);
    whole = coarse = 0;
    for (int step = 0; step < 6; ++step) {
      const StepStats stats = scene->step();
      EXPECT_TRUE(stats.newton.converged) << "step " << step << ": " << stats.newton.message;
      whole += stats.newton.iterations;
      coarse += stats.newton.coarse_iterations;
    }
    return scene->simulables()[0]->getNodes();
  };
  int whole_with = 0, coarse_with = 0, whole_without = 0, coarse_without = 0;
  const MatX3 a = run(8, whole_with, coarse_with), b = run(0, whole_without, coarse_without);
  EXPECT_EQ(coarse_without, 0);
  EXPECT_GT(coarse_with, 0);
  if (GetParam() != SoftModel::RomModes) {
    EXPECT_LT(whole_with, whole_without);
  }
  EXPECT_LE((a - b).cwiseAbs().maxCoeff(), 1e-7);
}

INSTANTIATE_TEST_SUITE_P(Models, SceneBones,
                         ::testing::Values(SoftModel::Fem, SoftModel::Rom, SoftModel::RomModes),
                         test::modelName);

// Skeleton-only scenes have no cheaper bones' objective: no presolve there.
TEST(SceneBonesSkeleton, HasNoCoarseForm) {
  Scene scene;
  scene.addSimulable(
      std::make_shared<Simulable>(test::smallScene(800).avatar, test::smallScene(800).walk));
  scene.initialize();
  double E = 0.0;
  VecX g;
  EXPECT_FALSE(scene.coarseEnergyAndGradient(E, g));
}

}  // namespace
}  // namespace flsh
