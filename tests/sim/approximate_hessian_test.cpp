// Simulable::getApproximateHessianTripletVector, the ROM's Hessian for Newton's directions with
// a constant soft–soft block K_r + Σ_j (m_j / h²) B_jᵀ B_j: at the rest pose it is the exact
// Hessian; elsewhere it has the exact Hessian's bone rows and columns and a soft–soft block that
// does not move with the state; models without one (the FEM, the handle basis, a static
// simulable) refuse it.
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <memory>
#include <string>
#include <vector>

#include "flsh/sim/simulable.h"
#include "support/small_soft_avatar.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::SoftModel;

constexpr int kBoneDofs = 144;

MatX exactHessian(const Simulable& sim) {
  std::vector<Triplet> H;
  std::vector<FixedHessianBlocks> blocks;
  sim.getHessianTripletVector(H, blocks, 0, false);
  for (const Triplet& t : test::expanded(blocks)) H.push_back(t);
  return test::denseFromTriplets(H, sim.numDofs());
}

MatX approximateHessian(const Simulable& sim) {
  std::vector<Triplet> H;
  std::vector<FixedHessianBlocks> blocks;
  size_t potential_start = 0;
  EXPECT_TRUE(sim.getApproximateHessianTripletVector(H, blocks, 0, &potential_start));
  EXPECT_GT(potential_start, 0u);
  EXPECT_LE(potential_start, H.size());
  for (const Triplet& t : test::expanded(blocks)) H.push_back(t);
  return test::denseFromTriplets(H, sim.numDofs());
}

double largest(const MatX& A) { return A.cwiseAbs().maxCoeff(); }

// The modal basis alone (the ROM with modes and no handles) and with handles.
std::shared_ptr<const SoftAvatar> modalAvatar(bool handles) {
  if (handles) return test::smallSoftAvatar(SoftModel::RomModes);
  static const std::shared_ptr<const SoftAvatar> modes = [] {
    SoftAvatarSettings s = test::smallSoftAvatarSettings(test::freshTempDir("approximate_cache"));
    test::useSmallModes(s, ReducedBasisKind::Modes);
    return std::shared_ptr<const SoftAvatar>(test::makeSmallSoftAvatar(s, true));
  }();
  return modes;
}

class ApproximateHessian : public ::testing::TestWithParam<bool> {};

// At rest (every R_b = I, so M_j = Σ_b w_jb R_b = I for every node, and u = 0, where the
// elastic cubature's rest-split excess has no curvature) the constant block is the exact one.
TEST_P(ApproximateHessian, IsTheExactHessianAtRest) {
  Simulable sim(modalAvatar(GetParam()));  // no motion: the rest pose
  sim.initialize();
  sim.preUpdate();
  ASSERT_TRUE(sim.hasApproximateHessian());
  const MatX E = exactHessian(sim), A = approximateHessian(sim);
  ASSERT_GT(largest(E.bottomRightCorner(E.rows() - kBoneDofs, E.cols() - kBoneDofs)), 0.0);
  ASSERT_GT(largest(E.topRightCorner(kBoneDofs, E.cols() - kBoneDofs)), 0.0);
  EXPECT_LE(largest(A - E), 1e-9 * largest(E));
  EXPECT_LE(largest(A - A.transpose()), 1e-12 * largest(A));
}

// Moved (bones and soft state): the bone rows and columns are the exact Hessian's; the
// soft–soft block is the rest pose's (a constant), and differs from the exact one there; the
// approximation is positive definite in the soft state; nothing of the state changes.
TEST_P(ApproximateHessian, KeepsTheBonesExactAndTheSoftBlockConstant) {
  Simulable rest(modalAvatar(GetParam()));
  rest.initialize();
  rest.preUpdate();
  const MatX A_rest = approximateHessian(rest);

  Simulable sim(modalAvatar(GetParam()), test::smallScene(800).walk);
  sim.initialize();
  sim.preUpdate();
  const int n = sim.numDofs(), m = n - kBoneDofs;
  VecX d = test::randomVector(n, 0.05, 3);
  d.tail(m) = test::randomVector(m, 0.02, 4);
  sim.updateState(d);
  const VecX q = sim.getState();
  const MatX E = exactHessian(sim), A = approximateHessian(sim);
  EXPECT_EQ(sim.getState(), q);
  EXPECT_LE(largest(A.topRows(kBoneDofs) - E.topRows(kBoneDofs)), 1e-12 * largest(E));
  EXPECT_LE(largest(A.leftCols(kBoneDofs) - E.leftCols(kBoneDofs)), 1e-12 * largest(E));
  const MatX A_zz = A.bottomRightCorner(m, m), E_zz = E.bottomRightCorner(m, m);
  EXPECT_LE(largest(A_zz - A_rest.bottomRightCorner(m, m)), 1e-12 * largest(A_zz));
  EXPECT_GT(largest(A_zz - E_zz), 1e-6 * largest(E_zz));  // an approximation here
  EXPECT_EQ(Eigen::LLT<MatX>(A_zz).info(), Eigen::Success);
}

INSTANTIATE_TEST_SUITE_P(Bases, ApproximateHessian, ::testing::Bool(),
                         [](const ::testing::TestParamInfo<bool>& info) {
                           return std::string(info.param ? "ModesAndHandles" : "Modes");
                         });

TEST(ApproximateHessianModels, TheFemTheHandlesAndStaticSimulablesHaveNone) {
  Simulable fem(test::smallSoftAvatar(SoftModel::Fem), test::smallScene(800).walk);
  fem.initialize();
  Simulable handles(test::smallSoftAvatar(SoftModel::Rom), test::smallScene(800).walk);
  handles.initialize();
  Simulable still(modalAvatar(false), test::smallScene(800).walk);
  still.initialize();
  ASSERT_TRUE(still.hasApproximateHessian());
  still.setStatic(true);
  for (const Simulable* sim : {&fem, &handles, &still}) {
    EXPECT_FALSE(sim->hasApproximateHessian());
    std::vector<Triplet> H = {Triplet(0, 0, 1.0)};
    std::vector<FixedHessianBlocks> blocks;
    EXPECT_FALSE(sim->getApproximateHessianTripletVector(H, blocks, 0));
    EXPECT_EQ(H.size(), 1u);
    EXPECT_TRUE(blocks.empty());
  }
}

}  // namespace
}  // namespace flsh
