// A soft skeleton's (FEM and ROM) parameter derivatives, the whole simulable: ∂g/∂p for the
// groups its terms differentiate so far (rest joints, pose and root targets, bone inertias,
// stiffnesses, collider offsets, the material) against central differences of the total gradient
// under setParameter, the products against the Jacobians, and a clear error for what is not written
// yet (issue 25: β).
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
  EXPECT_EQ(sum.rest_outer.size() > 0, model == SoftModel::Rom);
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
TEST(SoftMaterialDerivatives, RomRestSplitBoundedBranch) {
  auto sim = test::softTermScenario(SoftModel::Rom);
  const int n = sim->numDofs(), nb = sim->numBoneDofs();
  VecX q = sim->getState();
  const VecX push = test::randomVector(n - nb, 1.0, 51);
  int bounded = 0;
  for (double amplitude = 0.01; amplitude <= 0.16 && bounded == 0; amplitude *= 2) {
    q.tail(n - nb) = amplitude * push;
    sim->setState(q);
    bounded = sim->restSplitBoundedSamples();
  }
  ASSERT_GT(bounded, 0) << "no sample reached the bounded branch";
  RecordProperty("bounded_samples", bounded);
  expectMaterialDerivatives(*sim, SoftModel::Rom);
}

TEST_P(SoftParameterDerivatives, GroupsNotWrittenYetThrowNamingThem) {
  auto sim = test::softTermScenario(GetParam());
  for (SimParameter p : {SimParameter::Shape}) {
    const std::string message =
        test::messageOf<Error>([&] { sim->getGradientParameterJacobian(p); });
    EXPECT_NE(message.find(simParameterInfo(p).enum_name), std::string::npos) << message;
    EXPECT_NE(message.find("soft-tissue avatar"), std::string::npos) << message;
    EXPECT_THROW(sim->getGradientParameterVJPs(VecX::Zero(sim->numDofs()), {p}), Error);
    const VecX d = VecX::Ones(sim->parameterSize(p));
    ParameterDirection along{};
    along[size_t(p)] = &d;
    EXPECT_THROW(sim->getGradientParameterJVPs({along}), Error);
  }
}

INSTANTIATE_TEST_SUITE_P(Models, SoftParameterDerivatives,
                         ::testing::Values(SoftModel::Fem, SoftModel::Rom), test::modelName);

}  // namespace
}  // namespace flsh
