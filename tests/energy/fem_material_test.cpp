// The FEM material kernel (orthotropic StVK with Fung saturation) against closed forms and
// central finite differences, at random, nearly flat, inverted and very large deformations,
// for several Fung exponents and random material frames.
#include "flsh/energy/fem_material.h"

#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::jacobianMatchesFiniteDifferences;
using test::messageOf;
using Mat9x12 = Eigen::Matrix<double, 9, 12>;

// Default skin and soft-tissue coefficients of docs/materials.md.
const Vec3 kSkinYoung(120e3, 80e3, 40e3), kSkinPoisson(0.42, 0.45, 0.45),
    kSkinShear(34e3, 24e3, 19e3);
const Vec3 kTissueYoung(15e3, 10e3, 10e3), kTissuePoisson(0.45, 0.45, 0.45),
    kTissueShear(4.2e3, 4.2e3, 3.4e3);
const std::vector<double> kGammas = {0.0, 1e-8, 3.0, 8.0};

class Random {
 public:
  explicit Random(unsigned seed) : engine_(seed) {}
  double uniform(double a, double b) {
    return std::uniform_real_distribution<double>(a, b)(engine_);
  }
  Vec3 vec(double scale) { return Vec3(uniform(-1, 1), uniform(-1, 1), uniform(-1, 1)) * scale; }
  Mat3 mat(double scale) {
    Mat3 M;
    for (int i = 0; i < 9; ++i) M.data()[i] = uniform(-scale, scale);
    return M;
  }
  Mat3 rotation() { return rodrigues(vec(3.0)); }

 private:
  std::mt19937 engine_;
};

FemMaterialPoint skin(const Mat3& frame, double gamma) {
  return makeFemMaterialPoint(kSkinYoung, kSkinPoisson, kSkinShear, frame, gamma);
}
FemMaterialPoint tissue(const Mat3& frame, double gamma) {
  return makeFemMaterialPoint(kTissueYoung, kTissuePoisson, kTissueShear, frame, gamma);
}

/// Deformation gradients of every regime: random moderate, nearly flat (det ≈ 1e-4) and
/// inverted (det < 0).
struct NamedF {
  std::string name;
  Mat3 F;
};
std::vector<NamedF> testDeformations(Random& random) {
  std::vector<NamedF> out;
  out.push_back({"random", Mat3::Identity() + random.mat(0.3)});
  out.push_back(
      {"near-flat", random.rotation() * Vec3(1.2, 0.9, 1e-4).asDiagonal() * random.rotation()});
  out.push_back(
      {"inverted", random.rotation() * Vec3(1.1, 0.8, -0.3).asDiagonal() * random.rotation()});
  return out;
}

VecX vecOf(const Mat3& M) { return Eigen::Map<const VecX>(M.data(), 9); }
Mat3 matOf(const VecX& v) { return Eigen::Map<const Mat3>(v.data()); }

double psiOf(const Mat3& F, const FemMaterialPoint& m) { return fungEnergyDensity(F, m); }
Mat3 stressOf(const Mat3& F, const FemMaterialPoint& m) {
  Mat3 P;
  fungEnergyDensity(F, m, &P);
  return P;
}
Mat9 tangentOf(const Mat3& F, const FemMaterialPoint& m, bool psd) {
  Mat3 P;
  Mat9 D;
  fungEnergyDensity(F, m, &P, &D, psd);
  return D;
}

/// Ψ_S computed independently in the frame: Ê = Aᵀ E A, ε̂ (engineering shear), ½ ε̂ᵀ C ε̂.
double frameStVK(const Mat3& F, const FemMaterialPoint& m) {
  const Mat3 E = 0.5 * (F.transpose() * F - Mat3::Identity());
  const Mat3 Eh = m.frame.transpose() * E * m.frame;
  Vec6 e;
  e << Eh(0, 0), Eh(1, 1), Eh(2, 2), 2 * Eh(1, 2), 2 * Eh(0, 2), 2 * Eh(0, 1);
  return 0.5 * e.dot(m.C * e);
}

double minEigenvalue(const MatX& M) {
  return Eigen::SelfAdjointEigenSolver<MatX>(0.5 * (M + M.transpose())).eigenvalues().minCoeff();
}

/// ∂vec(F)/∂u (9 × 12, node-major u) of a tet: ∂F_ij/∂u_{a,k} = δ_ik g_aj.
Mat9x12 deformationMap(const TetElementRest& rest) {
  Eigen::Matrix<double, 3, 4> G;
  G.rightCols<3>() = rest.Dm_inv.transpose();
  G.col(0) = -G.rightCols<3>().rowwise().sum();
  Mat9x12 B = Mat9x12::Zero();
  for (int a = 0; a < 4; ++a)
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) B(i + 3 * j, 3 * a + i) = G(j, a);
  return B;
}

/// A ~2 cm tet (the default body resolution), positively oriented.
Mat34 restTet(Random& random) {
  Mat34 X;
  X << 0, 0.02, 0, 0,  //
      0, 0, 0.02, 0,   //
      0, 0, 0, 0.02;
  for (int a = 0; a < 4; ++a) X.col(a) += random.vec(0.003);
  return X;
}

/// Nodal displacements of a rest tet: a moderate strain (random, ~4 mm) and one that inverts
/// it (node 3 pushed through the opposite face).
struct TetDisplacements {
  Mat34 moderate, inverting;
};
TetDisplacements tetDisplacements(Random& random) {
  TetDisplacements d{Mat34::Zero(), Mat34::Zero()};
  for (int a = 0; a < 4; ++a) d.moderate.col(a) = random.vec(0.004);
  d.inverting.col(3) = Vec3(0.002, 0.001, -0.03);
  return d;
}

VecX flatten(const Mat34& u) { return Eigen::Map<const VecX>(u.data(), 12); }
Mat34 unflatten(const VecX& v) { return Eigen::Map<const Mat34>(v.data()); }

TEST(OrthotropicStiffness, InvertsTheComplianceWithShearInVoigtOrder) {
  const Mat6 C = orthotropicStiffness(kSkinYoung, kSkinPoisson, kSkinShear);
  Mat6 S = Mat6::Zero();
  const Vec3& E = kSkinYoung;
  const Vec3& nu = kSkinPoisson;
  S.topLeftCorner<3, 3>() << 1 / E[0], -nu[0] / E[0], -nu[1] / E[0],  //
      -nu[0] / E[0], 1 / E[1], -nu[2] / E[1],                         //
      -nu[1] / E[0], -nu[2] / E[1], 1 / E[2];
  S(3, 3) = 1 / kSkinShear[2];  // 23
  S(4, 4) = 1 / kSkinShear[1];  // 13
  S(5, 5) = 1 / kSkinShear[0];  // 12
  EXPECT_LT((C * S - Mat6::Identity()).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((C - C.transpose()).cwiseAbs().maxCoeff(), 1e-9 * C.cwiseAbs().maxCoeff());
  EXPECT_GT(minEigenvalue(C), 0.0);
  // Uniaxial stress along a1 gives strain 1/E1 along a1 and −ν12/E1, −ν13/E1 across.
  Vec6 stress = Vec6::Zero();
  stress[0] = 1.0;
  const Vec6 strain = C.inverse() * stress;
  EXPECT_NEAR(strain[0] * E[0], 1.0, 1e-12);
  EXPECT_NEAR(-strain[1] / strain[0], nu[0], 1e-12);
  EXPECT_NEAR(-strain[2] / strain[0], nu[1], 1e-12);
}

TEST(OrthotropicStiffness, RejectsNonPhysicalInputWithAMessage) {
  const std::string indefinite = messageOf<InputError>(
      [] { orthotropicStiffness(Vec3(1e4, 1e4, 1e4), Vec3(0.9, 0.3, 0.3), Vec3(3e3, 3e3, 3e3)); });
  EXPECT_NE(indefinite.find("not positive definite"), std::string::npos) << indefinite;
  EXPECT_NE(indefinite.find("0.9"), std::string::npos) << indefinite;
  const std::string negative = messageOf<InputError>(
      [] { orthotropicStiffness(Vec3(1e4, -1e4, 1e4), Vec3(0.3, 0.3, 0.3), Vec3(3e3, 3e3, 3e3)); });
  EXPECT_NE(negative.find("young"), std::string::npos) << negative;
  EXPECT_NE(negative.find("positive"), std::string::npos) << negative;
  const std::string nan = messageOf<InputError>(
      [] { orthotropicStiffness(Vec3(1e4, 1e4, 1e4), Vec3(0.3, 0.3, 0.3), Vec3(3e3, NAN, 3e3)); });
  EXPECT_NE(nan.find("finite"), std::string::npos) << nan;
}

TEST(FemMaterialPoint, WorldStiffnessGivesTheFrameEnergy) {
  Random random(3);
  for (int trial = 0; trial < 5; ++trial) {
    const FemMaterialPoint m = skin(random.rotation(), 0.0);
    const Mat3 F = Mat3::Identity() + random.mat(0.3);
    const double expected = frameStVK(F, m);
    ASSERT_GT(expected, 0.0);
    EXPECT_NEAR(psiOf(F, m), expected, 1e-12 * expected);
  }
}

TEST(FungEnergyDensity, StressAndTangentMatchFiniteDifferences) {
  Random random(5);
  for (double gamma : kGammas) {
    for (int material_index = 0; material_index < 2; ++material_index) {
      const Mat3 frame = random.rotation();
      const FemMaterialPoint m = material_index == 0 ? skin(frame, gamma) : tissue(frame, gamma);
      for (const NamedF& d : testDeformations(random)) {
        SCOPED_TRACE("gamma " + std::to_string(gamma) + ", material " +
                     std::to_string(material_index) + ", F " + d.name);
        Mat3 P;
        Mat9 dPdF;
        const double psi = fungEnergyDensity(d.F, m, &P, &dPdF, false);
        EXPECT_GT(psi, 0.0);
        EXPECT_NEAR(psi, psiOf(d.F, m), 0.0);
        const MatX P_row = vecOf(P).transpose();
        EXPECT_TRUE(jacobianMatchesFiniteDifferences(
            [&](const VecX& x) { return VecX::Constant(1, psiOf(matOf(x), m)); }, vecOf(d.F),
            P_row));
        EXPECT_TRUE(jacobianMatchesFiniteDifferences(
            [&](const VecX& x) { return vecOf(stressOf(matOf(x), m)); }, vecOf(d.F), dPdF));
        EXPECT_LT((dPdF - dPdF.transpose()).cwiseAbs().maxCoeff(),
                  1e-12 * dPdF.cwiseAbs().maxCoeff());
      }
    }
  }
}

TEST(FungEnergyDensity, BeyondTheExponentCapStaysConsistent) {
  Random random(6);
  const FemMaterialPoint m = skin(random.rotation(), 8.0);
  for (const Mat3& F : {Mat3(3.0 * Mat3::Identity()), Mat3(2.0 * random.rotation())}) {
    // The exponent x = γΨ_S/μ is past the cap: the continued branch is what is tested.
    ASSERT_GT(m.gamma * frameStVK(F, m) / m.modulus, kFungExponentCap);
    Mat3 P;
    Mat9 dPdF;
    const double psi = fungEnergyDensity(F, m, &P, &dPdF, false);
    ASSERT_TRUE(std::isfinite(psi) && P.allFinite() && dPdF.allFinite());
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(
        [&](const VecX& x) { return VecX::Constant(1, psiOf(matOf(x), m)); }, vecOf(F),
        MatX(vecOf(P).transpose()), 1e-6, 1e-6));
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(
        [&](const VecX& x) { return vecOf(stressOf(matOf(x), m)); }, vecOf(F), dPdF, 1e-6, 1e-6));
  }
  // Across the cap the value and slope are continuous: Ψ(s·F) for s crossing the cap.
  const Mat3 direction = Mat3::Identity() + random.mat(0.2);
  double s_low = 1.0, s_high = 4.0;  // bisect for the scale where x = cap
  const auto exponent = [&](double s) {
    return m.gamma * frameStVK(s * direction, m) / m.modulus - kFungExponentCap;
  };
  ASSERT_LT(exponent(s_low), 0.0);
  ASSERT_GT(exponent(s_high), 0.0);
  for (int it = 0; it < 200; ++it) {
    const double mid = 0.5 * (s_low + s_high);
    (exponent(mid) < 0 ? s_low : s_high) = mid;
  }
  const double below = psiOf(s_low * direction, m), above = psiOf(s_high * direction, m);
  EXPECT_NEAR(below, above, 1e-9 * std::abs(below));
  const Mat3 P_below = stressOf(s_low * direction, m), P_above = stressOf(s_high * direction, m);
  EXPECT_LT((P_below - P_above).cwiseAbs().maxCoeff(), 1e-9 * P_below.cwiseAbs().maxCoeff());
}

TEST(FungEnergyDensity, ZeroAtRestAndUnderRotations) {
  Random random(7);
  for (double gamma : kGammas) {
    const FemMaterialPoint m = skin(random.rotation(), gamma);
    for (const Mat3& F : {Mat3(Mat3::Identity()), random.rotation(), random.rotation()}) {
      Mat3 P;
      const double psi = fungEnergyDensity(F, m, &P);
      EXPECT_LE(std::abs(psi), 1e-20 * m.modulus);
      EXPECT_LE(P.cwiseAbs().maxCoeff(), 1e-10 * m.modulus);
    }
  }
}

TEST(FungEnergyDensity, InvariantUnderWorldRotations) {
  Random random(8);
  for (double gamma : kGammas) {
    const FemMaterialPoint m = tissue(random.rotation(), gamma);
    for (const NamedF& d : testDeformations(random)) {
      const Mat3 Q = random.rotation();
      Mat3 P, P_rotated;
      const double psi = fungEnergyDensity(d.F, m, &P);
      const double psi_rotated = fungEnergyDensity(Q * d.F, m, &P_rotated);
      ASSERT_GT(psi, 0.0);
      EXPECT_NEAR(psi_rotated, psi, 1e-12 * psi) << d.name;
      EXPECT_LT((P_rotated - Q * P).cwiseAbs().maxCoeff(), 1e-10 * P.cwiseAbs().maxCoeff())
          << d.name;
    }
  }
}

TEST(FungEnergyDensity, IsotropicModuliGiveTextbookStVK) {
  Random random(9);
  const double E = 20e3, nu = 0.3, G = E / (2 * (1 + nu));
  const double mu = G, lambda = E * nu / ((1 + nu) * (1 - 2 * nu));
  const FemMaterialPoint m = makeFemMaterialPoint(Vec3::Constant(E), Vec3::Constant(nu),
                                                  Vec3::Constant(G), random.rotation(), 0.0);
  for (const NamedF& d : testDeformations(random)) {
    if (d.F.determinant() < kInversionOnset) continue;  // the guard adds to StVK there
    const Mat3 Eg = 0.5 * (d.F.transpose() * d.F - Mat3::Identity());
    const double expected = mu * (Eg * Eg).trace() + 0.5 * lambda * Eg.trace() * Eg.trace();
    const Mat3 expected_P = d.F * (lambda * Eg.trace() * Mat3::Identity() + 2 * mu * Eg);
    Mat3 P;
    const double psi = fungEnergyDensity(d.F, m, &P);
    ASSERT_GT(expected, 0.0);
    EXPECT_NEAR(psi, expected, 1e-12 * expected) << d.name;
    EXPECT_LT((P - expected_P).cwiseAbs().maxCoeff(), 1e-10 * expected_P.cwiseAbs().maxCoeff())
        << d.name;
  }
}

TEST(FungEnergyDensity, FungMapAndItsZeroExponentLimit) {
  Random random(10);
  const Mat3 frame = random.rotation();
  for (const NamedF& d : testDeformations(random)) {
    if (d.F.determinant() < kInversionOnset) continue;  // the guard adds to the Fung law there
    const double psi_s = frameStVK(d.F, skin(frame, 0.0));
    ASSERT_GT(psi_s, 0.0);
    // γ = 0 is StVK exactly; tiny γ differs from it only at order γΨ_S/μ.
    EXPECT_NEAR(psiOf(d.F, skin(frame, 0.0)), psi_s, 1e-13 * psi_s) << d.name;
    const FemMaterialPoint tiny = skin(frame, 1e-14);
    EXPECT_NEAR(psiOf(d.F, tiny), psi_s, 1e-13 * psi_s) << d.name;
    const FemMaterialPoint small = skin(frame, 1e-8);
    const double x_small = small.gamma * psi_s / small.modulus;
    EXPECT_NEAR(psiOf(d.F, small), psi_s * (1 + 0.5 * x_small), 1e-13 * psi_s) << d.name;
    // The closed form (μ/γ)(exp(γΨ_S/μ) − 1) where it is well conditioned.
    const FemMaterialPoint stiff = skin(frame, 3.0);
    const double x = stiff.gamma * psi_s / stiff.modulus;
    ASSERT_LT(x, kFungExponentCap);
    const double expected = stiff.modulus / stiff.gamma * std::expm1(x);
    EXPECT_NEAR(psiOf(d.F, stiff), expected, 1e-12 * expected) << d.name;
    EXPECT_GT(psiOf(d.F, stiff), psi_s);
  }
}

TEST(FungEnergyDensity, ProjectedTangentIsPSDAndExactWhereStressIsPSD) {
  Random random(11);
  int projected_cases = 0, exact_cases = 0, negative_definite_cases = 0;
  for (double gamma : kGammas) {
    const Mat3 frame = random.rotation();
    const FemMaterialPoint m = skin(frame, gamma);
    std::vector<NamedF> cases = testDeformations(random);
    cases.push_back({"compressed", random.rotation() * Vec3(0.8, 0.85, 0.9).asDiagonal()});
    cases.push_back({"random 2", Mat3::Identity() + random.mat(0.4)});
    // Stretch along the frame axes: Ŝ = C_normal ε̂ > 0 entrywise, so S ⪰ 0.
    cases.push_back(
        {"stretched", random.rotation() * Vec3(1.3, 1.2, 1.25).asDiagonal() * frame.transpose()});
    for (const NamedF& d : cases) {
      SCOPED_TRACE("gamma " + std::to_string(gamma) + ", F " + d.name);
      const Mat9 exact = tangentOf(d.F, m, false), psd = tangentOf(d.F, m, true);
      const double scale = exact.cwiseAbs().maxCoeff();
      ASSERT_GT(scale, 0.0);
      EXPECT_GE(minEigenvalue(psd), -1e-10 * scale);
      EXPECT_LT((psd - psd.transpose()).cwiseAbs().maxCoeff(), 1e-12 * scale);
      if (d.F.determinant() < kInversionOnset) continue;  // guarded: InversionGuard tests
      const Mat3 S = d.F.inverse() * stressOf(d.F, m);
      const Vec3 s_eigen =
          Eigen::SelfAdjointEigenSolver<Mat3>(0.5 * (S + S.transpose())).eigenvalues();
      const double s_min = s_eigen.minCoeff(), s_size = S.cwiseAbs().maxCoeff();
      if (s_min >= 1e-9 * s_size) {
        ++exact_cases;
        EXPECT_LT((psd - exact).cwiseAbs().maxCoeff(), 1e-12 * scale);
      } else if (s_min < -1e-6 * s_size) {
        ++projected_cases;
        // The projection removes exactly the negative part of S from S ⊗ I₃: exact − psd is
        // negative semidefinite with S's most negative eigenvalue as its smallest.
        const Eigen::VectorXd removed =
            Eigen::SelfAdjointEigenSolver<MatX>(MatX(exact - psd)).eigenvalues();
        EXPECT_NEAR(removed.minCoeff(), s_min, 1e-10 * scale);
        EXPECT_LE(removed.maxCoeff(), 1e-10 * scale);
        // S ≺ 0: the exact tangent has negative curvature along infinitesimal rotations.
        if (s_eigen.maxCoeff() < 0) {
          ++negative_definite_cases;
          EXPECT_LT(minEigenvalue(exact), -1e-6 * scale);
        }
      }
    }
  }
  // Both branches of the projection were exercised.
  EXPECT_GE(exact_cases, 4);
  EXPECT_GE(projected_cases, 4);
  EXPECT_GE(negative_definite_cases, 1);
}

// The inversion guard: nothing above the onset, (κ/2)(J₀ − J)² below it, so that a reflected
// tet (zero StVK energy) costs energy; its derivatives are in the finite-difference tests above
// (the near-flat and inverted cases).
TEST(FungEnergyDensity, InversionGuardMakesReflectionsCostEnergy) {
  Random random(21);
  const Mat3 frame = random.rotation();
  const FemMaterialPoint m = skin(frame, 0.0);
  const double kappa = kInversionStiffness * m.modulus;
  const Mat3 Q = random.rotation(), R = random.rotation();
  // A reflection: StVK is exactly zero there, the guard is not.
  const Mat3 reflection = Q * Vec3(1.0, 1.0, -1.0).asDiagonal() * R;
  EXPECT_NEAR(frameStVK(reflection, m), 0.0, 1e-9 * m.modulus);
  const double depth = kInversionOnset + 1.0;
  EXPECT_NEAR(psiOf(reflection, m), 0.5 * kappa * depth * depth, 1e-9 * kappa);
  // Pushing a flat tet further through costs more: the guard grows as J falls.
  double previous = -1.0;
  for (double z : {0.4, 0.1, -0.2, -0.5}) {
    const double psi = psiOf(Q * Vec3(1.0, 1.0, z).asDiagonal() * R, m);
    EXPECT_GT(psi, previous) << "J = " << z;
    previous = psi;
  }
  // Above the onset the law is StVK exactly (γ = 0), at the onset the guard starts from 0.
  for (double z : {kInversionOnset, 0.7, 1.0, 1.3}) {
    const Mat3 F = Q * Vec3(1.0, 1.0, z).asDiagonal() * R;
    EXPECT_NEAR(psiOf(F, m), frameStVK(F, m), 1e-12 * std::max(1.0, frameStVK(F, m))) << z;
  }
  // Element level: an inverted tet's energy and the PSD Hessian stay PSD.
  Mat34 X;
  X << 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1;
  const TetElementRest rest = tetElementRest(X, 0);
  Mat34 u = Mat34::Zero();
  u(2, 3) = -1.5;  // node 3 through the opposite face: J = −0.5
  Mat12 H;
  Vec12 g;
  const double E = tetElasticEnergy(rest, m, u, &g, &H, true);
  EXPECT_GT(E, rest.volume * 0.5 * kappa * std::pow(kInversionOnset + 0.5, 2) * 0.999);
  EXPECT_GT(g.norm(), 0.0);
  EXPECT_GE(Eigen::SelfAdjointEigenSolver<Mat12>(H).eigenvalues().minCoeff(),
            -1e-9 * H.cwiseAbs().maxCoeff());
  // The gradient pushes node 3 back up (towards a positive volume).
  EXPECT_LT(g[11], 0.0);
}

TEST(FungEnergyDensity, FiniteAtVeryLargeStrain) {
  Random random(12);
  for (double gamma : kGammas) {
    const FemMaterialPoint m = skin(random.rotation(), gamma);
    for (const Mat3& F :
         {Mat3(10.0 * Mat3::Identity()), random.mat(1e3), Mat3(1e3 * Mat3::Ones())}) {
      for (bool psd : {false, true}) {
        Mat3 P;
        Mat9 dPdF;
        const double psi = fungEnergyDensity(F, m, &P, &dPdF, psd);
        EXPECT_TRUE(std::isfinite(psi) && psi > 0);
        EXPECT_TRUE(P.allFinite());
        EXPECT_TRUE(dPdF.allFinite());
      }
    }
  }
  EXPECT_THROW(fungEnergyDensity(Mat3::Constant(NAN), skin(Mat3::Identity(), 3.0)), InputError);
}

TEST(TetElement, RestGeometryAndDeformationGradient) {
  Random random(13);
  const Mat34 X = restTet(random);
  const TetElementRest rest = tetElementRest(X, 0);
  Mat3 Dm;
  Dm << X.col(1) - X.col(0), X.col(2) - X.col(0), X.col(3) - X.col(0);
  EXPECT_NEAR(rest.volume, Dm.determinant() / 6.0, 1e-18);
  EXPECT_GT(rest.volume, 0.0);
  // A linear displacement field u = M X + c has F = I + M.
  const Mat3 M = random.mat(0.3);
  const Vec3 c = random.vec(0.1);
  Mat34 u;
  for (int a = 0; a < 4; ++a) u.col(a) = M * X.col(a) + c;
  EXPECT_LT((tetDeformationGradient(rest, u) - (Mat3::Identity() + M)).cwiseAbs().maxCoeff(),
            1e-12);
}

TEST(TetElement, DegenerateOrInvertedRestTetIsAnInputError) {
  Mat34 flat;
  flat << 0, 0.02, 0, 0.01,  //
      0, 0, 0.02, 0.01,      //
      0, 0, 0, 0;
  const std::string degenerate = messageOf<InputError>([&] { tetElementRest(flat, 7); });
  EXPECT_NE(degenerate.find("tet 7"), std::string::npos) << degenerate;
  EXPECT_NE(degenerate.find("degenerate"), std::string::npos) << degenerate;
  Mat34 inverted;
  inverted << 0, 0, 0.02, 0,  //
      0, 0.02, 0, 0,          //
      0, 0, 0, 0.02;
  const std::string flipped = messageOf<InputError>([&] { tetElementRest(inverted, 3); });
  EXPECT_NE(flipped.find("tet 3"), std::string::npos) << flipped;
  EXPECT_NE(flipped.find("inverted"), std::string::npos) << flipped;
  Mat34 collapsed = Mat34::Zero();
  EXPECT_NE(messageOf<InputError>([&] { tetElementRest(collapsed, 1); }).find("degenerate"),
            std::string::npos);
  Mat34 nan = inverted;
  nan(1, 2) = NAN;
  EXPECT_NE(messageOf<InputError>([&] { tetElementRest(nan, 2); }).find("not finite"),
            std::string::npos);
}

TEST(TetElement, GradientAndHessianMatchFiniteDifferences) {
  Random random(14);
  for (double gamma : kGammas) {
    const FemMaterialPoint m = skin(random.rotation(), gamma);
    const TetElementRest rest = tetElementRest(restTet(random), 0);
    // Moderate strain, and a displacement that inverts the tet (node 3 pushed through).
    const auto [moderate, inverting] = tetDisplacements(random);
    for (const bool inverts : {false, true}) {
      const Mat34& u = inverts ? inverting : moderate;
      SCOPED_TRACE("gamma " + std::to_string(gamma));
      Vec12 gradient;
      Mat12 hessian;
      const double energy = tetElasticEnergy(rest, m, u, &gradient, &hessian, false);
      ASSERT_GT(gradient.norm(), 0.0);
      ASSERT_GT(hessian.norm(), 0.0);
      const Mat3 F = tetDeformationGradient(rest, u);
      // The inverting case must exercise the inversion guard's derivatives too.
      if (inverts) {
        ASSERT_LT(F.determinant(), kInversionOnset);
      }
      EXPECT_NEAR(energy, rest.volume * psiOf(F, m), 1e-12 * energy);
      // Quantities of a 2 cm tet are small in J: tighten the absolute tolerance accordingly.
      EXPECT_TRUE(jacobianMatchesFiniteDifferences(
          [&](const VecX& x) { return VecX::Constant(1, tetElasticEnergy(rest, m, unflatten(x))); },
          flatten(u), MatX(gradient.transpose()), 1e-9, 1e-7));
      EXPECT_TRUE(jacobianMatchesFiniteDifferences(
          [&](const VecX& x) {
            Vec12 g;
            tetElasticEnergy(rest, m, unflatten(x), &g);
            return VecX(g);
          },
          flatten(u), hessian, 1e-7, 1e-7));
      // The same as the density's tangent mapped through ∂vec(F)/∂u, exact and projected.
      const Mat9x12 B = deformationMap(rest);
      for (bool psd : {false, true}) {
        Mat12 h;
        tetElasticEnergy(rest, m, u, nullptr, &h, psd);
        const Mat12 expected = rest.volume * B.transpose() * tangentOf(F, m, psd) * B;
        EXPECT_LT((h - expected).cwiseAbs().maxCoeff(), 1e-10 * expected.cwiseAbs().maxCoeff());
      }
      Mat3 P;
      fungEnergyDensity(F, m, &P);
      EXPECT_LT((gradient - rest.volume * B.transpose() * vecOf(P)).cwiseAbs().maxCoeff(),
                1e-10 * gradient.cwiseAbs().maxCoeff());
    }
  }
}

// The packed tet (what FemElasticityTerm's loop reads) is the same element: weight 1 gives the
// same numbers bit for bit, a cubature weight scales them (up to the weight's rounding); the
// inverting case exercises the guard.
TEST(TetElement, PackedTetIsTheSameElement) {
  Random random(15);
  for (double gamma : kGammas) {
    const FemMaterialPoint m = tissue(random.rotation(), gamma);
    const TetElementRest rest = tetElementRest(restTet(random), 0);
    const auto [moderate, inverting] = tetDisplacements(random);
    for (const Mat34* u : {&moderate, &inverting})
      for (const bool psd : {false, true})
        for (const double weight : {1.0, 0.37}) {
          SCOPED_TRACE("gamma " + std::to_string(gamma) + ", weight " + std::to_string(weight));
          Vec12 g, g_packed;
          Mat12 H, H_packed;
          const double E = tetElasticEnergy(rest, m, *u, &g, &H, psd);
          const PackedTet packed = packTet(rest, m, weight);
          EXPECT_EQ(packed.volume, weight * rest.volume);
          const double E_packed = tetElasticEnergy(packed, *u, &g_packed, &H_packed, psd);
          ASSERT_GT(g.norm(), 0.0);
          ASSERT_GT(H.norm(), 0.0);
          if (weight == 1.0) {
            EXPECT_EQ(E_packed, E);
            EXPECT_EQ(g_packed, g);
            EXPECT_EQ(H_packed, H);
          } else {
            EXPECT_NEAR(E_packed, weight * E, 1e-13 * weight * E);
            EXPECT_LT((g_packed - weight * g).cwiseAbs().maxCoeff(),
                      1e-13 * weight * g.cwiseAbs().maxCoeff());
            EXPECT_LT((H_packed - weight * H).cwiseAbs().maxCoeff(),
                      1e-13 * weight * H.cwiseAbs().maxCoeff());
          }
          // Energy alone and gradient alone are the same numbers as with the Hessian.
          Vec12 g_alone;
          EXPECT_EQ(tetElasticEnergy(packed, *u), E_packed);
          tetElasticEnergy(packed, *u, &g_alone);
          EXPECT_EQ(g_alone, g_packed);
        }
    Mat34 bad = Mat34::Zero();
    bad(1, 2) = std::numeric_limits<double>::quiet_NaN();
    EXPECT_THROW(tetElasticEnergy(packTet(rest, m, 1.0), bad), InputError);
  }
}

// The reduced tet (ROM): Z (3 × n) with u = Z Φᵀ gives the tet's energy, and its gradient and
// Hessian chained through Φ, for n handles below and above the stack-storage bound; the inverting
// case exercises the inversion guard.
TEST(ReducedTetElement, IsTheTetChainedThroughTheBasis) {
  Random random(21);
  const FemMaterialPoint m = tissue(random.rotation(), 3.0);
  const TetElementRest rest = tetElementRest(restTet(random), 0);
  for (const int n : {4, 7, kMaxBoundedReducedColumns + 4}) {
    Mat4X Phi(4, n);
    for (int i = 0; i < Phi.size(); ++i) Phi.data()[i] = random.uniform(0.0, 1.0);
    // Z = U (Φ Φᵀ)⁻¹ Φ reproduces any nodal U (Φ has full row rank).
    const MatX right = (Phi * Phi.transpose()).inverse() * Phi;  // 4 × n, Φᵀ on its right is I
    const auto [moderate, inverting] = tetDisplacements(random);
    const Mat3X G = reducedShapeGradients(rest, Phi);
    // (Φ ⊗ I₃): ∂u/∂z, node-major rows, handle-major columns.
    MatX P = MatX::Zero(12, 3 * n);
    for (int a = 0; a < 4; ++a)
      for (int s = 0; s < n; ++s) P.block<3, 3>(3 * a, 3 * s) = Phi(a, s) * Mat3::Identity();
    for (const bool inverts : {false, true}) {
      SCOPED_TRACE("n " + std::to_string(n) + (inverts ? ", inverting" : ", moderate"));
      const Mat34 U = inverts ? inverting : moderate;
      const Mat3X Z = U * right;
      ASSERT_LT((Z * Phi.transpose() - U).cwiseAbs().maxCoeff(), 1e-12);
      if (inverts) {
        ASSERT_LT(tetDeformationGradient(rest, U).determinant(), kInversionOnset);
      }
      for (const bool psd : {false, true}) {
        Vec12 g;
        Mat12 h;
        const double E = tetElasticEnergy(rest, m, U, &g, &h, psd);
        VecX gz(3 * n);
        MatX hz(3 * n, 3 * n);
        Eigen::Ref<VecX> gz_view = gz;
        Eigen::Ref<MatX> hz_view = hz;
        const double Ez = reducedTetElasticEnergy(rest.volume, m, G, Z, &gz_view, &hz_view, psd);
        ASSERT_GT(gz.cwiseAbs().maxCoeff(), 0.0);
        ASSERT_GT(hz.cwiseAbs().maxCoeff(), 0.0);
        EXPECT_NEAR(Ez, E, 1e-9 * E);  // Z Φᵀ reproduces U to rounding only
        const VecX g_expected = P.transpose() * g;
        const MatX h_expected = P.transpose() * h * P;
        EXPECT_LT((gz - g_expected).cwiseAbs().maxCoeff(),
                  1e-10 * g_expected.cwiseAbs().maxCoeff());
        EXPECT_LT((hz - h_expected).cwiseAbs().maxCoeff(),
                  1e-10 * h_expected.cwiseAbs().maxCoeff());
        EXPECT_LT((hz - hz.transpose()).cwiseAbs().maxCoeff(), 1e-12 * hz.cwiseAbs().maxCoeff());
      }
    }
  }
}

TEST(ReducedTetElement, GradientAndHessianMatchFiniteDifferences) {
  Random random(22);
  const FemMaterialPoint m = skin(random.rotation(), 8.0);
  const TetElementRest rest = tetElementRest(restTet(random), 0);
  const int n = 6;
  Mat4X Phi(4, n);
  for (int i = 0; i < Phi.size(); ++i) Phi.data()[i] = random.uniform(0.0, 1.0);
  const Mat3X G = reducedShapeGradients(rest, Phi);
  Mat3X Z(3, n);
  for (int s = 0; s < n; ++s) Z.col(s) = random.vec(0.002);
  const auto flat = [](const Mat3X& z) { return VecX(Eigen::Map<const VecX>(z.data(), z.size())); };
  const auto unflat = [](const VecX& x) { return Mat3X(Eigen::Map<const Mat3X>(x.data(), 3, n)); };
  VecX gradient(3 * n);
  MatX hessian(3 * n, 3 * n);
  Eigen::Ref<VecX> g_view = gradient;
  Eigen::Ref<MatX> h_view = hessian;
  reducedTetElasticEnergy(rest.volume, m, G, Z, &g_view, &h_view, false);
  ASSERT_GT(gradient.cwiseAbs().maxCoeff(), 0.0);
  ASSERT_GT(hessian.cwiseAbs().maxCoeff(), 0.0);
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(
      [&](const VecX& x) {
        return VecX::Constant(1, reducedTetElasticEnergy(rest.volume, m, G, unflat(x)));
      },
      flat(Z), MatX(gradient.transpose()), 1e-9, 1e-7));
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(
      [&](const VecX& x) {
        VecX g(3 * n);
        Eigen::Ref<VecX> view = g;
        reducedTetElasticEnergy(rest.volume, m, G, unflat(x), &view);
        return g;
      },
      flat(Z), hessian, 1e-7, 1e-7));
}

// The rest-stiffness split of a cubature sample tet (restSplitExcess): w (Ψ − q) while that is
// ≥ −q, a bounded C¹ continuation below. Value, gradient and Hessian against finite differences in
// both branches (a moderate state at unit and heavy weight; a compressed tet at heavy weight,
// which takes the bounded branch, with the default floor 2, with 1.5 and with 25), the bound
// f ≥ −c q, and PSD forms that are PSD.
TEST(ReducedTetElement, RestSplitExcessMatchesFiniteDifferencesInBothBranches) {
  Random random(24);
  const FemMaterialPoint m = tissue(random.rotation(), 3.0);
  const Mat34 X = restTet(random);
  const TetElementRest rest = tetElementRest(X, 0);
  const int n = 5;
  Mat4X Phi(4, n);
  for (int i = 0; i < Phi.size(); ++i) Phi.data()[i] = random.uniform(0.0, 1.0);
  const MatX right = (Phi * Phi.transpose()).inverse() * Phi;  // U ↦ Z with Z Φᵀ = U
  const Mat3X G = reducedShapeGradients(rest, Phi);
  MatX K(3 * n, 3 * n);
  {
    Eigen::Ref<MatX> view = K;
    reducedTetElasticEnergy(rest.volume, m, G, Mat3X::Zero(3, n), nullptr, &view, false);
  }
  ASSERT_GT(K.cwiseAbs().maxCoeff(), 0.0);
  const auto unflat = [](const VecX& x) { return Mat3X(Eigen::Map<const Mat3X>(x.data(), 3, n)); };
  // f, and its gradient / Hessian when asked, at flattened z.
  const auto excess = [&](const VecX& z, double w, VecX* g, MatX* H, bool psd, bool* bounded,
                          double lowest) {
    VecX gradient(3 * n);
    MatX hessian(3 * n, 3 * n);
    Eigen::Ref<VecX> g_view = gradient;
    Eigen::Ref<MatX> h_view = hessian;
    const double psi = reducedTetElasticEnergy(
        rest.volume, m, G, unflat(z), g || H ? &g_view : nullptr, H ? &h_view : nullptr, psd);
    const double f = restSplitExcess(psi, z, K, w, g || H ? &g_view : nullptr,
                                     H ? &h_view : nullptr, psd, bounded, lowest);
    if (g) *g = gradient;
    if (H) *H = hessian;
    return f;
  };
  Mat34 moderate, compressed;
  for (int a = 0; a < 4; ++a) moderate.col(a) = random.vec(0.003);
  const Vec3 centroid = X.rowwise().mean(), axis = random.vec(1.0).normalized();
  for (int a = 0; a < 4; ++a)  // 35 % shorter along `axis`
    compressed.col(a) = -0.35 * axis * axis.dot(X.col(a) - centroid);
  // The compressed tet is softer than its rest quadratic (r = Ψ − q < 0; StVK softens in
  // compression): at weight w, x = −w r / q; the heavy weight puts x at 2.5 (bounded branch).
  const Mat3X Zc = compressed * right;
  const VecX zc = Eigen::Map<const VecX>(Zc.data(), Zc.size());
  const double qc = 0.5 * zc.dot(K * zc);
  const double x_unit = -(reducedTetElasticEnergy(rest.volume, m, G, Zc) - qc) / qc;
  ASSERT_GT(x_unit, 0.0);
  ASSERT_LT(x_unit, 1.0);
  struct Case {
    const char* name;
    Mat34 U;
    double weight;
    bool bounded;
    double lowest;  // the floor c: f ≥ −c q
  };
  for (const Case& c :
       {Case{"moderate, w = 1", moderate, 1.0, false, 2.0},
        Case{"moderate, w = 200", moderate, 200.0, false, 2.0},
        Case{"compressed, w = 1", compressed, 1.0, false, 2.0},
        Case{"compressed, heavy", compressed, 2.5 / x_unit, true, 2.0},
        Case{"compressed, heavy, floor 1.5", compressed, 2.5 / x_unit, true, 1.5},
        // restSplitFloors' floors grow with the weight (1 + s w).
        Case{"compressed, heavy, floor 25", compressed, 2.5 / x_unit, true, 25.0}}) {
    SCOPED_TRACE(c.name);
    const Mat3X Z = c.U * right;
    const VecX z = Eigen::Map<const VecX>(Z.data(), Z.size());
    const double q = 0.5 * z.dot(K * z);
    VecX g;
    MatX H;
    bool bounded = !c.bounded;
    const double f = excess(z, c.weight, &g, &H, false, &bounded, c.lowest);
    EXPECT_EQ(bounded, c.bounded);
    const double psi = reducedTetElasticEnergy(rest.volume, m, G, Z);
    if (c.bounded) {
      EXPECT_LT(c.weight * (psi - q), -q);  // the plain excess would go below −q …
      EXPECT_GT(f, -c.lowest * q);          // … the bounded one stays above −c q
      EXPECT_NEAR(f, -q * (c.lowest - (c.lowest - 1.0) * std::exp(-1.5 / (c.lowest - 1.0))),
                  1e-9 * q);
      EXPECT_LT(f, -q);
    } else {
      EXPECT_NEAR(f, c.weight * (psi - q), 1e-12 * c.weight * (psi + q));
    }
    ASSERT_GT(g.cwiseAbs().maxCoeff(), 0.0);
    ASSERT_GT(H.cwiseAbs().maxCoeff(), 0.0);
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(
        [&](const VecX& x) {
          return VecX::Constant(1, excess(x, c.weight, nullptr, nullptr, false, nullptr, c.lowest));
        },
        z, MatX(g.transpose()), 1e-6, 1e-7));
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(
        [&](const VecX& x) {
          VecX gx;
          excess(x, c.weight, &gx, nullptr, false, nullptr, c.lowest);
          return gx;
        },
        z, H, 1e-6, 1e-7));
    MatX H_psd;
    excess(z, c.weight, nullptr, &H_psd, true, nullptr, c.lowest);
    EXPECT_GE(Eigen::SelfAdjointEigenSolver<MatX>(H_psd).eigenvalues().minCoeff(),
              -1e-10 * H_psd.cwiseAbs().maxCoeff());
  }
  EXPECT_NE(messageOf<InputError>([&] {
              restSplitExcess(0.0, VecX::Zero(3 * n), K, 0.0);
            }).find("weight must be finite and > 0"),
            std::string::npos);
  EXPECT_NE(messageOf<InputError>([&] {
              restSplitExcess(0.0, VecX::Zero(3 * n - 1), K, 1.0);
            }).find("expected " + std::to_string(3 * n - 1) + " square"),
            std::string::npos);
  EXPECT_NE(messageOf<InputError>([&] {
              restSplitExcess(0.0, VecX::Zero(3 * n), K, 1.0, nullptr, nullptr, false, nullptr,
                              1.0);
            }).find("lowest (the floor c) must be finite and > 1"),
            std::string::npos);
}

// restSplitFloors on a random subspace: rest Hessians K̃_e of sample "tets" on 2–4 of 8 handles
// (random PSD, 3n × 3n) with weights from 1 to 300; K half their weighted sum plus three times
// their unit-weight sum plus a random SPD rest. The floors are 1 + s w_e with
// s = (1 − α − λ₁) / λ_w, λ₁ and λ_w recomputed here as generalized eigenvalues;
// Σ c_e K̃_e ≼ (1 − α) K, so ½ zᵀ K z − Σ c_e q_e ≥ α ½ zᵀ K z; the fallback when the
// unweighted samples hold more than 1 − α of K; errors.
TEST(ReducedTetElement, RestSplitFloorsKeepTheAskedShareOfTheRestStiffness) {
  Random random(31);
  const int H = 8, m = 3 * H, count = 12;
  struct Sample {
    std::vector<int> handles;
    MatX K;
  };
  std::vector<Sample> samples;
  VecX weights(count);
  for (int e = 0; e < count; ++e) {
    Sample s;
    const int n = 2 + e % 3;
    while (int(s.handles.size()) < n) {
      const int h = int(random.uniform(0.0, H - 1e-9));
      if (std::find(s.handles.begin(), s.handles.end(), h) == s.handles.end())
        s.handles.push_back(h);
    }
    MatX A(3 * n, 3 * n);
    for (int i = 0; i < A.size(); ++i) A.data()[i] = random.uniform(-1.0, 1.0);
    s.K = A * A.transpose() / 3.0;
    samples.push_back(s);
    weights[e] = random.uniform(1.0, 300.0);
  }
  const auto assemble = [&](const VecX& scale) {
    MatX out = MatX::Zero(m, m);
    for (int e = 0; e < count; ++e)
      for (size_t a = 0; a < samples[e].handles.size(); ++a)
        for (size_t b = 0; b < samples[e].handles.size(); ++b)
          out.block<3, 3>(3 * samples[e].handles[a], 3 * samples[e].handles[b]) +=
              scale[e] * samples[e].K.block<3, 3>(3 * a, 3 * b);
    return out;
  };
  const MatX unit = assemble(VecX::Ones(count)), weighted = assemble(weights);
  MatX B(m, m);
  for (int i = 0; i < B.size(); ++i) B.data()[i] = random.uniform(-1.0, 1.0);
  // As a fitted cubature: the weighted sum about K, but above it in some directions.
  const MatX K = 0.5 * weighted + 3.0 * unit + B * B.transpose() + MatX::Identity(m, m);
  const auto largest = [&](const MatX& A) {
    return Eigen::GeneralizedSelfAdjointEigenSolver<MatX>(A, K, Eigen::EigenvaluesOnly)
        .eigenvalues()
        .maxCoeff();
  };
  const double alpha = 0.5, lambda_unit = largest(unit), lambda_weighted = largest(weighted);
  ASSERT_GT(lambda_unit, 0.01);
  ASSERT_LT(lambda_unit, 1.0 - alpha);
  ASSERT_GT(lambda_weighted, 1.0);  // the weights alone would overshoot K
  const VecX floors = restSplitFloors(K, unit, weighted, weights, alpha);
  ASSERT_EQ(floors.size(), count);
  const double s = (1.0 - alpha - lambda_unit) / lambda_weighted;
  for (int e = 0; e < count; ++e) EXPECT_NEAR(floors[e], 1.0 + s * weights[e], 1e-9 * floors[e]);
  EXPECT_GT(floors.maxCoeff(), 2.0);  // heavy samples get more than the former fixed floor 2
  // The guarantee: Σ c_e K̃_e ≼ (1 − α) K, hence the bound on random states.
  EXPECT_LE(largest(assemble(floors)), 1.0 - alpha + 1e-9);
  for (int trial = 0; trial < 20; ++trial) {
    VecX z(m);
    for (int i = 0; i < m; ++i) z[i] = random.uniform(-1.0, 1.0);
    double lowest = 0.5 * z.dot(K * z);
    for (int e = 0; e < count; ++e) {
      VecX ze(samples[e].K.rows());
      for (size_t a = 0; a < samples[e].handles.size(); ++a)
        ze.segment<3>(3 * a) = z.segment<3>(3 * samples[e].handles[a]);
      lowest -= floors[e] * 0.5 * ze.dot(samples[e].K * ze);
    }
    EXPECT_GE(lowest, alpha * 0.5 * z.dot(K * z) * (1.0 - 1e-9));
  }
  // The unweighted samples hold more than 1 − α of K: every floor max(1.05, 0.95 / λ₁).
  const MatX K_small = unit + 0.2 * MatX::Identity(m, m);
  const double lambda_small =
      Eigen::GeneralizedSelfAdjointEigenSolver<MatX>(unit, K_small, Eigen::EigenvaluesOnly)
          .eigenvalues()
          .maxCoeff();
  ASSERT_GT(lambda_small, 1.0 - alpha);
  const VecX fallback = restSplitFloors(K_small, unit, weighted, weights, alpha);
  for (int e = 0; e < count; ++e)
    EXPECT_NEAR(fallback[e], std::max(1.05, 0.95 / lambda_small), 1e-9);
  // Errors.
  EXPECT_NE(messageOf<InputError>([&] {
              restSplitFloors(K, unit.topLeftCorner(m - 3, m - 3), weighted, weights);
            }).find("K_unit is " + std::to_string(m - 3)),
            std::string::npos);
  VecX bad = weights;
  bad[3] = 0.0;
  EXPECT_NE(messageOf<InputError>([&] {
              restSplitFloors(K, unit, weighted, bad);
            }).find("weights[3] = 0"),
            std::string::npos);
  EXPECT_NE(messageOf<InputError>([&] {
              restSplitFloors(K, unit, weighted, weights, 1.0);
            }).find("kept (α) must be in (0, 1)"),
            std::string::npos);
  EXPECT_NE(messageOf<InputError>([&] {
              restSplitFloors(-K, unit, weighted, weights);
            }).find("not symmetric positive definite"),
            std::string::npos);
}

TEST(ReducedTetElement, SizeMismatchAndNonFiniteInputAreInputErrors) {
  Random random(23);
  const FemMaterialPoint m = tissue(Mat3::Identity(), 0.0);
  const TetElementRest rest = tetElementRest(restTet(random), 0);
  const Mat3X G = reducedShapeGradients(rest, Mat4X::Constant(4, 3, 0.5));
  const Mat3X Z = Mat3X::Zero(3, 3);
  EXPECT_NE(messageOf<InputError>([&] {
              reducedTetElasticEnergy(rest.volume, m, G, Mat3X::Zero(3, 2));
            }).find("expected as many as G (3)"),
            std::string::npos);
  VecX small(4);
  Eigen::Ref<VecX> small_view = small;
  EXPECT_NE(messageOf<InputError>([&] {
              reducedTetElasticEnergy(rest.volume, m, G, Z, &small_view);
            }).find("gradient has size 4, expected 3 · 3"),
            std::string::npos);
  MatX wrong(9, 8);
  Eigen::Ref<MatX> wrong_view = wrong;
  EXPECT_NE(messageOf<InputError>([&] {
              reducedTetElasticEnergy(rest.volume, m, G, Z, nullptr, &wrong_view);
            }).find("Hessian is 9 × 8"),
            std::string::npos);
  Mat3X nan = Z;
  nan(1, 2) = NAN;
  EXPECT_NE(messageOf<InputError>([&] {
              reducedTetElasticEnergy(rest.volume, m, G, nan);
            }).find("non-finite"),
            std::string::npos);
  // At Z = 0 the tet is at rest: zero energy and gradient.
  VecX g(9);
  Eigen::Ref<VecX> g_view = g;
  EXPECT_EQ(reducedTetElasticEnergy(rest.volume, m, G, Z, &g_view), 0.0);
  EXPECT_EQ(g.cwiseAbs().maxCoeff(), 0.0);
}

TEST(TetElement, ProjectedHessianIsPSD) {
  Random random(15);
  for (double gamma : kGammas) {
    const FemMaterialPoint m = tissue(random.rotation(), gamma);
    const TetElementRest rest = tetElementRest(restTet(random), 0);
    for (double scale : {0.002, 0.006, 0.015}) {
      Mat34 u;
      for (int a = 0; a < 4; ++a) u.col(a) = random.vec(scale);
      Mat12 exact, psd;
      tetElasticEnergy(rest, m, u, nullptr, &exact, false);
      tetElasticEnergy(rest, m, u, nullptr, &psd, true);
      const double size = exact.cwiseAbs().maxCoeff();
      ASSERT_GT(size, 0.0);
      EXPECT_GE(minEigenvalue(psd), -1e-10 * size) << "gamma " << gamma << ", scale " << scale;
    }
  }
}

TEST(TetElement, InvariantUnderRigidTranslation) {
  Random random(16);
  const FemMaterialPoint m = skin(random.rotation(), 8.0);
  const TetElementRest rest = tetElementRest(restTet(random), 0);
  Mat34 u;
  for (int a = 0; a < 4; ++a) u.col(a) = random.vec(0.004);
  Vec12 gradient;
  Mat12 hessian;
  const double energy = tetElasticEnergy(rest, m, u, &gradient, &hessian);
  ASSERT_GT(gradient.cwiseAbs().maxCoeff(), 0.0);
  const Mat34 shifted = u.colwise() + Vec3(0.3, -0.2, 0.5);
  EXPECT_NEAR(tetElasticEnergy(rest, m, shifted), energy, 1e-12 * energy);
  // Net force and every translation column of the Hessian vanish.
  const Vec3 net = gradient.reshaped(3, 4).rowwise().sum();
  EXPECT_LT(net.cwiseAbs().maxCoeff(), 1e-12 * gradient.cwiseAbs().maxCoeff());
  for (int k = 0; k < 3; ++k) {
    Vec12 translation = Vec12::Zero();
    for (int a = 0; a < 4; ++a) translation[3 * a + k] = 1.0;
    EXPECT_LT((hessian * translation).cwiseAbs().maxCoeff(), 1e-10 * hessian.cwiseAbs().maxCoeff());
  }
}

TEST(TetElement, FiniteAtVeryLargeDisplacement) {
  Random random(17);
  const FemMaterialPoint m = skin(random.rotation(), 8.0);
  const TetElementRest rest = tetElementRest(restTet(random), 0);
  Mat34 u;
  for (int a = 0; a < 4; ++a) u.col(a) = random.vec(20.0);  // |F − I| ~ 1e3
  ASSERT_GT(tetDeformationGradient(rest, u).cwiseAbs().maxCoeff(), 100.0);
  for (bool psd : {false, true}) {
    Vec12 gradient;
    Mat12 hessian;
    const double energy = tetElasticEnergy(rest, m, u, &gradient, &hessian, psd);
    EXPECT_TRUE(std::isfinite(energy) && energy > 0);
    EXPECT_TRUE(gradient.allFinite());
    EXPECT_TRUE(hessian.allFinite());
  }
  Mat34 bad = u;
  bad(2, 1) = INFINITY;
  EXPECT_THROW(tetElasticEnergy(rest, m, bad), InputError);
}

}  // namespace
}  // namespace flsh
