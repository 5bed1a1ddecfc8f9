// A soft skeleton's (FEM and ROM) parameter derivatives, the whole simulable: ∂g/∂p for every
// group (rest joints, pose and root targets, bone inertias, stiffnesses, collider offsets, the
// material, β) against central differences of the total gradient under setParameter (or of
// simulables on SoftAvatar::withMaterial / withShape avatars), the products against the
// Jacobians.
#include "flsh/core/error.h"
#include "sim/soft/soft_term_checks.h"

namespace flsh {
namespace {

using test::SoftModel;
using test::totalGradient;

class SoftParameterDerivatives : public ::testing::TestWithParam<SoftModel> {};

TEST_P(SoftParameterDerivatives, SupportedGroupsMatchFiniteDifferences) {
  auto sim = test::softTermScenario(GetParam());
  const int n = sim->numDofs();
  const VecX q0 = sim->getState();
  for (const auto& [group, relative_scale] :
       {std::pair{SimParameter::RestJoints, false}, std::pair{SimParameter::PoseTargets, false},
        std::pair{SimParameter::RootTranslationTarget, false},
        std::pair{SimParameter::BoneInertia, true}, std::pair{SimParameter::Stiffnesses, true},
        std::pair{SimParameter::ColliderOffsets, false}}) {
    // Copies: a lambda may not capture a structured binding before C++20 (clang rejects it).
    const SimParameter p = group;
    const bool relative = relative_scale;
    SCOPED_TRACE(simParameterInfo(p).name);
    const VecX p0 = sim->getParameter(p);
    VecX scale = relative ? VecX(p0.cwiseAbs()) : VecX::Ones(p0.size());
    for (Eigen::Index k = 0; k < scale.size(); ++k)
      if (scale[k] == 0.0) scale[k] = 1.0;  // e.g. the products of inertia of a symmetric bone
    const MatX J = sim->getGradientParameterJacobian(p);
    ASSERT_EQ(J.rows(), n);
    ASSERT_EQ(J.cols(), p0.size());
    const MatX analytic = J * scale.asDiagonal();
    const auto gradient = [&](const VecX& d) {
      sim->setParameter(p, p0 + scale.cwiseProduct(d));
      const VecX g = totalGradient(*sim);
      sim->setParameter(p, p0);
      return g;
    };
    EXPECT_TRUE(
        test::jacobianMatchesFiniteDifferences(gradient, VecX::Zero(p0.size()), analytic, 1e-5));
    const VecX lambda = test::randomVector(n, 1.0, 21);
    const VecX vjp = sim->getGradientParameterVJPs(lambda, {p}).front();
    EXPECT_LT((vjp - J.transpose() * lambda).norm(), 1e-10 * (1.0 + vjp.norm()));
    const VecX direction = test::randomVector(int(p0.size()), 1.0, 22);
    ParameterDirection along{};
    along[size_t(p)] = &direction;
    const VecX jvp = sim->getGradientParameterJVPs({along}).front();
    EXPECT_LT((jvp - J * direction).norm(), 1e-10 * (1.0 + jvp.norm()));
  }
  EXPECT_EQ((sim->getState() - q0).norm(), 0.0) << "derivative calls changed the state";
}

// The material (the file's coefficients): ∂g/∂p against central differences of the total
// gradient of simulables on SoftAvatar::withMaterial avatars at the same step (restoreStep), in
// the log-values a (at β = 0 the log-slopes do not act); the products against the Jacobian in
// every entry.
void expectMaterialDerivatives(Simulable& sim, SoftModel model) {
  const int n = sim.numDofs();
  const VecX q0 = sim.getState();
  const SimulableStep step = sim.saveStep();
  const std::shared_ptr<const SoftAvatar> avatar = test::smallSoftAvatar(model);
  const MaterialModel material = avatar->volumetricData().material_model;
  const VecX p0 = sim.getParameter(SimParameter::Material);
  ASSERT_EQ(p0.size(), sim.parameterSize(SimParameter::Material));
  ASSERT_EQ(p0.size(), material.numParameters());
  const MatX J = sim.getGradientParameterJacobian(SimParameter::Material);
  ASSERT_EQ(J.rows(), n);
  ASSERT_EQ(J.cols(), p0.size());
  const int K = int(avatar->betas().size()), C = MaterialModel::numCoefficients();
  std::vector<int> log_values;
  for (int i = 0; i < C; ++i) log_values.push_back(i * (1 + K));
  const auto gradient = [&](const VecX& d) {
    VecX p = p0;
    for (int i = 0; i < C; ++i) p[log_values[size_t(i)]] += d[i];
    MaterialModel m = material;
    m.setParameters(p);
    Simulable other(avatar->withMaterial(m), test::smallScene(800).walk);
    other.setColliders(sim.colliders());
    other.restoreStep(step);
    return totalGradient(other);
  };
  // Every layer's moduli and densities act (the soft tissue's most).
  for (const char* q : {"density", "E1", "G23", "fung_gamma"})
    EXPECT_GT(J.col(material.parameterOffset(q, MaterialModel::kSoftTissue)).norm(), 0.0) << q;
  EXPECT_TRUE(test::jacobianMatchesFiniteDifferences(gradient, VecX::Zero(C),
                                                     J(Eigen::all, log_values), 1e-5));
  const VecX lambda = test::randomVector(n, 1.0, 41);
  const VecX vjp = sim.getGradientParameterVJPs(lambda, {SimParameter::Material}).front();
  EXPECT_LT((vjp - J.transpose() * lambda).norm(), 1e-10 * (1.0 + vjp.norm()));
  // The reverse sweep's form (summed over steps, chained once) gives the same, and is linear.
  Simulable::MaterialProducts sum;
  sim.accumulateMaterialProducts(lambda, sum);
  EXPECT_EQ(sum.rest_outer.size() > 0, model != SoftModel::Fem);
  EXPECT_LT((sim.finishMaterialProducts(sum) - vjp).norm(), 1e-10 * (1.0 + vjp.norm()));
  const VecX lambda2 = test::randomVector(n, 1.0, 43);
  sim.accumulateMaterialProducts(lambda2, sum);
  const VecX both =
      sim.getGradientParameterVJPs(lambda + lambda2, {SimParameter::Material}).front();
  EXPECT_LT((sim.finishMaterialProducts(sum) - both).norm(), 1e-10 * (1.0 + both.norm()));
  const VecX direction = test::randomVector(int(p0.size()), 1.0, 42);
  ParameterDirection along{};
  along[size_t(SimParameter::Material)] = &direction;
  const VecX jvp = sim.getGradientParameterJVPs({along}).front();
  EXPECT_LT((jvp - J * direction).norm(), 1e-10 * (1.0 + jvp.norm()));
  EXPECT_EQ((sim.getState() - q0).norm(), 0.0) << "derivative calls changed the state";
}

TEST_P(SoftParameterDerivatives, MaterialMatchesFiniteDifferences) {
  auto sim = test::softTermScenario(GetParam());
  expectMaterialDerivatives(*sim, GetParam());
  const std::string message = test::messageOf<InputError>([&] {
    sim->setParameter(SimParameter::Material, sim->getParameter(SimParameter::Material));
  });
  EXPECT_NE(message.find("withMaterial"), std::string::npos) << message;
}

// The ROM's rest split in its bounded branch (a sample's energy far below its rest quadratic,
// the floor acting): the soft state pushed until some samples get there.
int pushIntoTheBoundedBranch(Simulable& sim) {
  const int n = sim.numDofs(), nb = sim.numBoneDofs();
  VecX q = sim.getState();
  const VecX push = test::randomVector(n - nb, 1.0, 51);
  int bounded = 0;
  for (double amplitude = 0.01; amplitude <= 0.16 && bounded == 0; amplitude *= 2) {
    q.tail(n - nb) = amplitude * push;
    sim.setState(q);
    bounded = sim.restSplitBoundedSamples();
  }
  return bounded;
}

// The ROMs (handles; modes and handles) with samples in the rest split's bounded branch.
class RestSplitBoundedBranch : public ::testing::TestWithParam<SoftModel> {};

TEST_P(RestSplitBoundedBranch, Material) {
  auto sim = test::softTermScenario(GetParam());
  const int bounded = pushIntoTheBoundedBranch(*sim);
  ASSERT_GT(bounded, 0) << "no sample reached the bounded branch";
  RecordProperty("bounded_samples", bounded);
  expectMaterialDerivatives(*sim, GetParam());
}

// β: ∂g/∂β against central differences of the total gradient of simulables on
// SoftAvatar::withShape avatars at the same step, at a β away from the mean shape (so that the
// materials' log-slopes act), with ground and sphere contact; the products against the Jacobian.
VecX testBeta(int K) {
  VecX beta = VecX::Zero(K);
  beta.head(3) << 0.4, -0.3, 0.2;
  return beta;
}

void expectShapeDerivatives(Simulable& simulable, const std::shared_ptr<const SoftAvatar>& base,
                            const VecX& beta) {
  Simulable* sim = &simulable;
  const int K = int(beta.size());
  const int n = sim->numDofs();
  const VecX q0 = sim->getState();
  const SimulableStep step = sim->saveStep();
  const MatX J = sim->getGradientParameterJacobian(SimParameter::Shape);
  ASSERT_EQ(J.rows(), n);
  ASSERT_EQ(J.cols(), K);
  ASSERT_GT(J.norm(), 0.0);
  // The soft tissue's own rows (elasticity, masses, rest nodes) act, not only the bones'.
  EXPECT_GT(J.bottomRows(n - sim->numBoneDofs()).norm(), 0.0);
  // The bones' rows and the soft tissue's each on their own scale (the elastic rows, through the
  // materials' log-slopes on β₀ and β₁, are 10³ times the bones').
  const int nb = sim->numBoneDofs();
  const double bone_scale = J.topRows(nb).norm(), soft_scale = J.bottomRows(n - nb).norm();
  ASSERT_GT(bone_scale, 0.0);
  const auto scaled = [&](const MatX& m) {
    MatX out = m;
    out.topRows(nb) /= bone_scale;
    out.bottomRows(n - nb) /= soft_scale;
    return out;
  };
  const auto gradient = [&](const VecX& d) {
    Simulable other(base->withShape(beta + d), test::smallScene(800).walk);
    other.setColliders(sim->colliders());
    // The step's states and targets, the root target moved with J_0(β) as preUpdate moves it
    // (target = J_0 + the motion's translation).
    other.restoreStep(step);
    other.setParameter(
        SimParameter::RootTranslationTarget,
        sim->getParameter(SimParameter::RootTranslationTarget) +
            (other.avatar().restJoints().row(0) - sim->avatar().restJoints().row(0)).transpose());
    return VecX(scaled(totalGradient(other)));
  };
  EXPECT_TRUE(
      test::jacobianMatchesFiniteDifferences(gradient, VecX::Zero(K), scaled(J), 1e-6, 1e-4));
  // β₂ moves no material coefficient (the default log-slopes act on β₀ and β₁): its soft rows
  // are the rest nodes' (elastic rest shape, inertia, gravity, contact) and the masses', checked
  // on their own scale.
  const double h = 1e-4;
  const VecX step2 = h * VecX::Unit(K, 2);
  const auto unscaled = [&](const VecX& g) {
    MatX m = g;
    m.topRows(nb) *= bone_scale;
    m.bottomRows(n - nb) *= soft_scale;
    return VecX(m);
  };
  const VecX fd2 = (unscaled(gradient(step2)) - unscaled(gradient(-step2))) / (2 * h);
  ASSERT_GT(J.col(2).tail(n - nb).norm(), 0.0);
  EXPECT_LT((fd2 - J.col(2)).tail(n - nb).norm(), 1e-6 * J.col(2).tail(n - nb).norm());
  const VecX lambda = test::randomVector(n, 1.0, 61);
  const VecX vjp = sim->getGradientParameterVJPs(lambda, {SimParameter::Shape}).front();
  EXPECT_LT((vjp - J.transpose() * lambda).norm(), 1e-10 * (1.0 + vjp.norm()));
  // The reverse sweep's form (the materials' and the ROM's K share summed over the steps and
  // finished once) gives the same, and is linear in λ.
  const VecX lambda2 = test::randomVector(n, 1.0, 63);
  Simulable::MaterialProducts sum;
  VecX steps = VecX::Zero(K);
  for (const VecX* l : {&lambda, &lambda2})
    steps += sim->getGradientParameterVJPs(*l, {SimParameter::Shape, SimParameter::Material}, false,
                                           &sum)
                 .front();
  ASSERT_TRUE(sum.shape);
  VecX share;
  sim->finishMaterialProducts(sum, &share);
  ASSERT_GT(share.norm(), 0.0);
  const VecX both = J.transpose() * (lambda + lambda2);
  EXPECT_LT((steps + share - both).norm(), 1e-10 * (1.0 + both.norm()));
  const VecX direction = test::randomVector(K, 1.0, 62);
  ParameterDirection along{};
  along[size_t(SimParameter::Shape)] = &direction;
  const VecX jvp = sim->getGradientParameterJVPs({along}).front();
  EXPECT_LT((jvp - J * direction).norm(), 1e-10 * (1.0 + jvp.norm()));
  EXPECT_EQ((sim->getState() - q0).norm(), 0.0) << "derivative calls changed the state";
}

TEST_P(SoftParameterDerivatives, ShapeMatchesFiniteDifferences) {
  const std::shared_ptr<const SoftAvatar> base = test::smallSoftAvatar(GetParam());
  const VecX beta = testBeta(int(base->betas().size()));
  auto sim = test::softTermScenario(base->withShape(beta));
  expectShapeDerivatives(*sim, base, beta);
}

// The ROM's rest split in its bounded branch for β too.
TEST_P(RestSplitBoundedBranch, Shape) {
  const std::shared_ptr<const SoftAvatar> base = test::smallSoftAvatar(GetParam());
  const VecX beta = testBeta(int(base->betas().size()));
  auto sim = test::softTermScenario(base->withShape(beta));
  const int bounded = pushIntoTheBoundedBranch(*sim);
  ASSERT_GT(bounded, 0) << "no sample reached the bounded branch";
  expectShapeDerivatives(*sim, base, beta);
}

// The material and shape chains (the material map, ∂m/∂c, ∂m/∂β) are built once per avatar and
// mass cubature and shared by its Simulables: a FEM after a ROM on the same avatar object (the
// reduced model switched off: lumped masses instead of the inertial cubature's) gets the same
// products as on an avatar of its own.
TEST(SoftParameterChains, FollowTheMassCubature) {
  const std::string cache = test::freshTempDir("soft_chain_cache");
  const auto make = [&] {
    return test::makeSmallSoftAvatar(test::smallSoftAvatarSettings(cache), true);
  };
  const std::shared_ptr<SoftAvatar> shared = make(), own = make();
  const std::vector<SimParameter> groups = {SimParameter::Material, SimParameter::Shape};
  const auto products = [&](const std::shared_ptr<SoftAvatar>& avatar) {
    auto sim = test::softTermScenario(avatar);
    return sim->getGradientParameterVJPs(test::randomVector(sim->numDofs(), 1.0, 71), groups);
  };
  const std::vector<VecX> rom = products(shared);  // builds the inertial cubature's chains
  ASSERT_GT(rom[0].norm(), 0.0);
  shared->enableReducedModel(false);
  own->enableReducedModel(false);
  const std::vector<VecX> fem = products(shared), fem_own = products(own);
  for (size_t g = 0; g < groups.size(); ++g) {
    ASSERT_GT(fem_own[g].norm(), 0.0);
    EXPECT_LE((fem[g] - fem_own[g]).norm(), 1e-12 * fem_own[g].norm()) << "group " << g;
  }
}

INSTANTIATE_TEST_SUITE_P(Models, SoftParameterDerivatives,
                         ::testing::Values(SoftModel::Fem, SoftModel::Rom, SoftModel::RomModes),
                         test::modelName);
INSTANTIATE_TEST_SUITE_P(Roms, RestSplitBoundedBranch,
                         ::testing::Values(SoftModel::Rom, SoftModel::RomModes), test::modelName);

}  // namespace
}  // namespace flsh
