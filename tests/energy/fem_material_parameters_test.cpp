// The elastic law's derivatives with respect to a material point's parameters (C_world, μ, γ;
// the adjoint's Material group): the energy density's and the stress's product with a direction
// against central differences, in every regime (small and large strain, γ = 0, past the Fung
// exponent cap, with the inversion guard active), and the two consistent with each other.
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <string>
#include <vector>

#include "flsh/core/rotation.h"
#include "flsh/energy/fem_material.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::jacobianMatchesFiniteDifferences;
using test::randomVector;

const Vec3 kYoung(120e3, 80e3, 40e3), kPoisson(0.42, 0.45, 0.45), kShear(34e3, 24e3, 19e3);

Mat3 randomMatrix(double scale, unsigned seed) {
  const VecX v = randomVector(9, scale, seed);
  return Eigen::Map<const Mat3>(v.data());
}

struct Regime {
  std::string name;
  Mat3 F;
  double gamma;
};

std::vector<Regime> regimes() {
  const Mat3 Q = rodrigues(Vec3(0.3, -0.7, 0.5)), R = rodrigues(Vec3(-1.1, 0.2, 0.4));
  return {
      {"small strain, StVK", Mat3::Identity() + randomMatrix(0.05, 1), 0.0},
      {"small strain, tiny γ", Mat3::Identity() + randomMatrix(0.05, 2), 1e-8},
      {"moderate strain", Mat3::Identity() + randomMatrix(0.3, 3), 3.0},
      {"past the exponent cap", 3.0 * Q, 8.0},
      {"inversion guard", Q * Vec3(1.1, 0.9, 0.2).asDiagonal() * R, 3.0},
      {"inverted", Q * Vec3(1.1, 0.8, -0.3).asDiagonal() * R, 8.0},
  };
}

// The parameters as a vector scaled to O(1): C_world = C₀ + μ₀ X (36 entries, column-major), μ =
// μ₀ (1 + x_μ), γ = γ₀ + x_γ.
constexpr int kParams = 38;

FemMaterialPoint perturbed(const FemMaterialPoint& m0, const VecX& x) {
  FemMaterialPoint m = m0;
  m.C_world += m0.modulus * Eigen::Map<const Mat6>(x.data());
  m.modulus = m0.modulus * (1.0 + x[36]);
  m.gamma = m0.gamma + x[37];
  return m;
}

MatX asRow(const FemMaterialDerivative& d, double modulus) {
  MatX row(1, kParams);
  row.leftCols(36) = modulus * Eigen::Map<const Eigen::RowVectorXd>(d.C_world.data(), 36);
  row(0, 36) = modulus * d.modulus;
  row(0, 37) = d.gamma;
  return row;
}

TEST(FemMaterialParameters, EnergyDensityGradientMatchesFiniteDifferences) {
  for (const Regime& r : regimes()) {
    SCOPED_TRACE(r.name);
    const FemMaterialPoint m =
        makeFemMaterialPoint(kYoung, kPoisson, kShear, rodrigues(Vec3(0.2, 0.9, -0.4)), r.gamma);
    FemMaterialDerivative d;
    addEnergyDensityMaterialGradient(r.F, m, 1.0, d);
    ASSERT_GT(fungEnergyDensity(r.F, m), 0.0);
    ASSERT_GT(MatX(asRow(d, m.modulus)).cwiseAbs().maxCoeff(), 0.0);
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(
        [&](const VecX& x) { return VecX::Constant(1, fungEnergyDensity(r.F, perturbed(m, x))); },
        VecX::Zero(kParams), asRow(d, m.modulus), 1e-6, 1e-7));
  }
}

TEST(FemMaterialParameters, StressProductGradientMatchesFiniteDifferences) {
  const Mat3 dF = randomMatrix(1.0, 7);
  for (const Regime& r : regimes()) {
    SCOPED_TRACE(r.name);
    const FemMaterialPoint m =
        makeFemMaterialPoint(kYoung, kPoisson, kShear, rodrigues(Vec3(-0.6, 0.1, 0.8)), r.gamma);
    const auto product = [&](const FemMaterialPoint& point) {
      Mat3 P;
      fungEnergyDensity(r.F, point, &P);
      return P.cwiseProduct(dF).sum();
    };
    FemMaterialDerivative d;
    addStressMaterialGradient(r.F, m, dF, 1.0, d);
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(
        [&](const VecX& x) { return VecX::Constant(1, product(perturbed(m, x))); },
        VecX::Zero(kParams), asRow(d, m.modulus), 1e-6, 1e-7));
  }
}

// The stress product's derivative is the energy gradient's derivative along dF: the two kernels
// agree through a difference of the energy's in F.
TEST(FemMaterialParameters, StressProductIsTheEnergyGradientAlongTheDirection) {
  const Mat3 dF = randomMatrix(1.0, 11);
  for (const Regime& r : regimes()) {
    SCOPED_TRACE(r.name);
    const FemMaterialPoint m =
        makeFemMaterialPoint(kYoung, kPoisson, kShear, rodrigues(Vec3(0.5, 0.5, 0.1)), r.gamma);
    const double h = 1e-6;
    FemMaterialDerivative plus, minus, stress;
    addEnergyDensityMaterialGradient(r.F + h * dF, m, 0.5 / h, plus);
    addEnergyDensityMaterialGradient(r.F - h * dF, m, 0.5 / h, minus);
    addStressMaterialGradient(r.F, m, dF, 1.0, stress);
    // On C_world's symmetric part: P uses σ = C_world ε, Ψ the quadratic form ½ εᵀ C_world ε.
    const Mat6 difference = plus.C_world - minus.C_world, along = stress.C_world;
    const Mat6 mismatch = (difference + difference.transpose()) - (along + along.transpose());
    const double scale = along.cwiseAbs().maxCoeff();
    ASSERT_GT(scale, 0.0);
    EXPECT_LT(mismatch.cwiseAbs().maxCoeff(), 1e-5 * scale);
    EXPECT_NEAR(plus.modulus - minus.modulus, stress.modulus,
                1e-5 * std::max(std::abs(stress.modulus), 1e-3));
    EXPECT_NEAR(plus.gamma - minus.gamma, stress.gamma,
                1e-5 * std::max(std::abs(stress.gamma), 1e-3 * m.modulus));
  }
}

TEST(FemMaterialParameters, ScaleAddsAndLinearStrainIsTheSymmetricPart) {
  const Mat3 F = Mat3::Identity() + randomMatrix(0.2, 5), dF = randomMatrix(1.0, 6);
  const FemMaterialPoint m = makeFemMaterialPoint(kYoung, kPoisson, kShear, Mat3::Identity(), 3.0);
  FemMaterialDerivative once, twice;
  addStressMaterialGradient(F, m, dF, 2.0, once);
  addStressMaterialGradient(F, m, dF, 1.0, twice);
  addStressMaterialGradient(F, m, dF, 1.0, twice);
  EXPECT_LT((once.C_world - twice.C_world).norm(), 1e-12 * once.C_world.norm());
  const Mat3 H = randomMatrix(1.0, 8);
  const Vec6 e = voigtLinearStrain(H);
  EXPECT_DOUBLE_EQ(e[0], H(0, 0));
  EXPECT_DOUBLE_EQ(e[3], H(1, 2) + H(2, 1));
  EXPECT_DOUBLE_EQ(e[5], H(0, 1) + H(1, 0));
}

// The rest shape's derivative of λᵀ g (addTetGradientRestCotangent) against central
// differences of the element gradient's product with λ under moved rest nodes, in every regime
// of the law (the displacements chosen so that F is the regime's).
TEST(FemMaterialParameters, GradientRestCotangentMatchesFiniteDifferences) {
  Mat34 X;
  X << 0.0, 0.03, 0.004, 0.006, 0.0, 0.002, 0.025, 0.003, 0.0, 0.001, 0.004, 0.028;
  const VecX lambda_values = randomVector(12, 1.0, 31);
  const Mat34 lambda = Eigen::Map<const Mat34>(lambda_values.data());
  for (const Regime& r : regimes()) {
    SCOPED_TRACE(r.name);
    const FemMaterialPoint m =
        makeFemMaterialPoint(kYoung, kPoisson, kShear, rodrigues(Vec3(0.2, 0.9, -0.4)), r.gamma);
    const TetElementRest rest = tetElementRest(X, 0);
    // u with F(u) = r.F at the rest X: u_a = (F − I)(X_a − X_0).
    Mat34 u;
    for (int a = 0; a < 4; ++a) u.col(a) = (r.F - Mat3::Identity()) * (X.col(a) - X.col(0));
    Mat34 X_bar = Mat34::Zero();
    addTetGradientRestCotangent(rest, m, u, lambda, 2.0, X_bar);
    ASSERT_GT(X_bar.norm(), 0.0);
    const double scale = 0.01;  // steps in units of 1 cm
    const auto product = [&](const VecX& d) {
      Vec12 g;
      tetElasticEnergy(tetElementRest(X + scale * Eigen::Map<const Mat34>(d.data()), 0), m, u, &g);
      return VecX::Constant(1, 2.0 * Eigen::Map<const Vec12>(lambda.data()).dot(g));
    };
    const MatX analytic = scale * Eigen::Map<const MatX>(X_bar.data(), 1, 12);
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(product, VecX::Zero(12), analytic, 1e-6, 1e-6));
  }
}

// The element energy's and the rest bilinear form's rest-shape derivatives
// (addTetEnergyRestCotangent, addTetLinearFormRestCotangent): against central differences of
// volume · Ψ and of λᵀ H₀ u (H₀ the exact element Hessian at zero displacement, the tet's rest
// stiffness) under moved rest nodes.
TEST(FemMaterialParameters, EnergyAndRestFormCotangentsMatchFiniteDifferences) {
  Mat34 X;
  X << 0.0, 0.03, 0.004, 0.006, 0.0, 0.002, 0.025, 0.003, 0.0, 0.001, 0.004, 0.028;
  const VecX lambda_values = randomVector(12, 1.0, 32), v_values = randomVector(12, 0.004, 33);
  const Mat34 lambda = Eigen::Map<const Mat34>(lambda_values.data());
  const Mat34 v = Eigen::Map<const Mat34>(v_values.data());
  const double scale = 0.01;  // steps in units of 1 cm
  const auto moved = [&](const VecX& d) {
    return tetElementRest(X + scale * Eigen::Map<const Mat34>(d.data()), 0);
  };
  for (const Regime& r : regimes()) {
    SCOPED_TRACE(r.name);
    const FemMaterialPoint m =
        makeFemMaterialPoint(kYoung, kPoisson, kShear, rodrigues(Vec3(0.2, 0.9, -0.4)), r.gamma);
    Mat34 u;
    for (int a = 0; a < 4; ++a) u.col(a) = (r.F - Mat3::Identity()) * (X.col(a) - X.col(0));
    Mat34 X_bar = Mat34::Zero();
    addTetEnergyRestCotangent(tetElementRest(X, 0), m, u, 1.5, X_bar);
    ASSERT_GT(X_bar.norm(), 0.0);
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(
        [&](const VecX& d) { return VecX::Constant(1, 1.5 * tetElasticEnergy(moved(d), m, u)); },
        VecX::Zero(12), scale * Eigen::Map<const MatX>(X_bar.data(), 1, 12), 1e-6, 1e-6));
  }
  const FemMaterialPoint m =
      makeFemMaterialPoint(kYoung, kPoisson, kShear, rodrigues(Vec3(-0.6, 0.1, 0.8)), 3.0);
  Mat34 X_bar = Mat34::Zero();
  addTetLinearFormRestCotangent(tetElementRest(X, 0), m.C_world, v, lambda, 0.5, X_bar);
  ASSERT_GT(X_bar.norm(), 0.0);
  const auto form = [&](const VecX& d) {
    Vec12 g;
    Mat12 H;
    tetElasticEnergy(moved(d), m, Mat34::Zero(), &g, &H);
    return VecX::Constant(
        1, 0.5 * Eigen::Map<const Vec12>(lambda.data()).dot(H * Eigen::Map<const Vec12>(v.data())));
  };
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(
      form, VecX::Zero(12), scale * Eigen::Map<const MatX>(X_bar.data(), 1, 12), 1e-6, 1e-6));
}

}  // namespace
}  // namespace flsh
