// A ROM scene stepped with Newton's directions from the constant soft–soft block
// (NewtonOptions::approximate_hessian, on in SceneOptions::reduced_newton) ends each step where
// the exact directions end it, with the ground in contact.
#include <gtest/gtest.h>

#include <memory>

#include "flsh/solve/scene.h"
#include "support/small_soft_avatar.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::SoftModel;

std::unique_ptr<Scene> walkingOnTheGround(SoftModel model, bool approximate) {
  SceneOptions options;
  options.reduced_newton.gradient_tolerance = 1e-10;
  options.reduced_newton.approximate_hessian = approximate;
  auto scene = std::make_unique<Scene>(options);
  auto sim = std::make_shared<Simulable>(test::smallSoftAvatar(model), test::smallScene(800).walk);
  scene->addSimulable(sim);
  scene->initialize();
  scene->addCollider(
      Collider::plane(Vec3(0, sim->getNodes().col(1).minCoeff() + 0.01, 0), Vec3::UnitY()));
  return scene;
}

TEST(SceneApproximateHessian, IsOnForTheRomByDefault) {
  EXPECT_TRUE(SceneOptions().reduced_newton.approximate_hessian);
  EXPECT_FALSE(SceneOptions().soft_tissue_newton.approximate_hessian);
  EXPECT_FALSE(SceneOptions().newton.approximate_hessian);
}

TEST(SceneApproximateHessian, StepsEndWhereTheExactDirectionsEndThem) {
  for (SoftModel model : {SoftModel::Rom, SoftModel::RomModes}) {
    SCOPED_TRACE(model == SoftModel::Rom ? "handles" : "modes and handles");
    auto approximate = walkingOnTheGround(model, true);
    auto exact = walkingOnTheGround(model, false);
    NewtonResult with, without;
    int contacts = 0;
    double largest_u = 0.0;
    for (int step = 0; step < 6; ++step) {
      const StepStats a = approximate->step(), b = exact->step();
      ASSERT_TRUE(a.newton.converged) << "step " << step << ": " << a.newton.message;
      ASSERT_TRUE(b.newton.converged) << "step " << step << ": " << b.newton.message;
      with.addCounts(a.newton);
      without.addCounts(b.newton);
      contacts = std::max(contacts, a.active_contacts);
      const Simulable& sa = *approximate->simulables()[0];
      const Simulable& sb = *exact->simulables()[0];
      largest_u = std::max(largest_u, sa.getSoftTissueDisplacements().cwiseAbs().maxCoeff());
      EXPECT_LE((sa.getState() - sb.getState()).lpNorm<Eigen::Infinity>(), 1e-8) << "step " << step;
    }
    EXPECT_GT(contacts, 0);
    EXPECT_GT(largest_u, 1e-4);  // the soft tissue moves (m)
    EXPECT_EQ(without.approximate_directions, 0);
    if (model == SoftModel::Rom) {  // the handle basis has none: the same solves
      EXPECT_EQ(with.approximate_directions, 0);
      EXPECT_EQ(with.iterations, without.iterations);
      continue;
    }
    EXPECT_GT(with.approximate_directions, 0);
    EXPECT_LT(with.hessian_evaluations, without.hessian_evaluations);
  }
}

}  // namespace
}  // namespace flsh
