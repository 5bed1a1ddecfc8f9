// Rotations: Rodrigues, left Jacobian (and inverse), log map and slerp, including the
// degenerate angles 0 and π.
#include "flsh/core/rotation.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <random>

#include "support/test_support.h"

namespace flsh {
namespace {

const double kPi = 3.14159265358979323846;

Vec3 randomUnit(std::mt19937& rng) {
  std::normal_distribution<double> g(0.0, 1.0);
  return Vec3(g(rng), g(rng), g(rng)).normalized();
}

VecX flatten(const Mat3& R) { return Eigen::Map<const VecX>(R.data(), 9); }

TEST(Rotation, SkewIsCrossProduct) {
  const Vec3 a(0.3, -1.2, 2.0), b(-0.7, 0.4, 1.1);
  EXPECT_LT((skew(a) * b - a.cross(b)).norm(), 1e-15);
}

TEST(Rotation, RodriguesMatchesEigenAngleAxis) {
  std::mt19937 rng(3);
  for (double angle : {0.0, 1e-12, 1e-6, 1e-4, 0.3, 1.0, 2.5, kPi - 1e-6, kPi}) {
    const Vec3 axis = randomUnit(rng);
    const Mat3 expected = Eigen::AngleAxisd(angle, axis).toRotationMatrix();
    EXPECT_LT((rodrigues(angle * axis) - expected).cwiseAbs().maxCoeff(), 1e-14)
        << "angle " << angle;
  }
}

// Huge finite angles (issue 23): |θ|² overflows above 1e154, which made R all NaN. R must be a
// rotation about θ's axis. (Its angle is |θ| as float64 gives it: one ulp of 1e300 is ~1e284
// rad, so beyond ~1e15 rad the angle modulo 2π carries no information, only validity.)
TEST(Rotation, RodriguesOfHugeFiniteAnglesIsARotation) {
  std::mt19937 rng(8);
  for (double angle : {1e6, 1e100, 1e154, 1e155, 1e200, 1e300, 1.7e308}) {
    const Vec3 axis = randomUnit(rng);
    const Vec3 theta = angle * axis;
    const Mat3 R = rodrigues(theta);
    ASSERT_TRUE(R.allFinite()) << "angle " << angle;
    EXPECT_LT((R.transpose() * R - Mat3::Identity()).cwiseAbs().maxCoeff(), 1e-14) << angle;
    EXPECT_NEAR(R.determinant(), 1.0, 1e-14) << angle;
    EXPECT_LT((R * axis - axis).norm(), 1e-13) << "the axis is fixed, angle " << angle;
    // The angle: the one of |θ| as computed, here within an ulp of the stable norm's.
    const double t = theta.stableNorm();
    if (angle <= 1e6) {
      EXPECT_NEAR(R.trace(), 1.0 + 2.0 * std::cos(t), 1e-9) << angle;
    }
  }
  // NaN in, NaN out: callers check (toSmplPose, Simulable::setState).
  EXPECT_FALSE(rodrigues(Vec3(std::nan(""), 0, 0)).allFinite());
}

// dR/dθ_a = [J_l(θ) e_a]× R, checked against central differences of rodrigues.
void expectLeftJacobianMatchesFiniteDifferences(const Vec3& theta) {
  Mat3 dR[3];
  rodriguesDerivatives(theta, dR);
  const Mat3 R = rodrigues(theta), J = leftJacobianSO3(theta);
  MatX analytic(9, 3);
  for (int a = 0; a < 3; ++a) {
    EXPECT_LT((dR[a] - skew(J.col(a)) * R).cwiseAbs().maxCoeff(), 1e-15);
    analytic.col(a) = flatten(dR[a]);
  }
  const auto f = [](const VecX& t) { return flatten(rodrigues(Vec3(t))); };
  EXPECT_TRUE(test::jacobianMatchesFiniteDifferences(f, theta, analytic, 1e-8))
      << "theta = " << theta.transpose();
}

TEST(Rotation, LeftJacobianMatchesFiniteDifferencesNearZero) {
  expectLeftJacobianMatchesFiniteDifferences(Vec3::Zero());
  expectLeftJacobianMatchesFiniteDifferences(Vec3(1e-9, -2e-9, 0.5e-9));
  expectLeftJacobianMatchesFiniteDifferences(Vec3(3e-5, 1e-5, -2e-5));  // Taylor branch
}

TEST(Rotation, LeftJacobianMatchesFiniteDifferencesGeneric) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> angle(0.1, 3.0);
  for (int n = 0; n < 10; ++n)
    expectLeftJacobianMatchesFiniteDifferences(angle(rng) * randomUnit(rng));
}

TEST(Rotation, LeftJacobianMatchesFiniteDifferencesNearPi) {
  std::mt19937 rng(7);
  for (double angle : {kPi - 1e-3, kPi - 1e-6, kPi})
    expectLeftJacobianMatchesFiniteDifferences(angle * randomUnit(rng));
}

TEST(Rotation, LeftJacobianInverseIsInverse) {
  std::mt19937 rng(11);
  for (double angle : {0.0, 1e-8, 5e-5, 0.2, 1.5, 3.0, kPi - 1e-6}) {
    const Vec3 theta = angle * randomUnit(rng);
    const Mat3 product = leftJacobianInverseSO3(theta) * leftJacobianSO3(theta);
    EXPECT_LT((product - Mat3::Identity()).cwiseAbs().maxCoeff(), 1e-9) << "angle " << angle;
  }
}

TEST(Rotation, LogInvertsRodrigues) {
  std::mt19937 rng(13);
  for (double angle : {0.0, 1e-9, 1e-6, 1e-3, 0.7, 2.0, 3.0, kPi - 1e-3, kPi - 1e-6}) {
    const Vec3 theta = angle * randomUnit(rng);
    const Vec3 back = logSO3(rodrigues(theta));
    // Near π the log map is ill-conditioned (dθ ≈ dR / (π − |θ|)): scale the tolerance.
    const double tol = 1e-13 + 1e-15 / (kPi - angle);
    EXPECT_LT((back - theta).norm(), tol) << "angle " << angle;
  }
}

TEST(Rotation, LogAtPiIsEitherAxisDirection) {
  std::mt19937 rng(17);
  for (int n = 0; n < 5; ++n) {
    const Vec3 theta = kPi * randomUnit(rng);
    const Vec3 back = logSO3(rodrigues(theta));
    EXPECT_NEAR(back.norm(), kPi, 1e-7);
    EXPECT_LT(std::min((back - theta).norm(), (back + theta).norm()), 1e-7);
    EXPECT_LT((rodrigues(back) - rodrigues(theta)).cwiseAbs().maxCoeff(), 1e-12);
  }
}

TEST(Rotation, SlerpEndpointsAndMidpoint) {
  const Vec3 a(0.2, -0.4, 0.1), b(-0.5, 0.3, 0.9);
  EXPECT_LT((slerpRotationVector(a, b, 0.0) - a).norm(), 1e-12);
  EXPECT_LT((slerpRotationVector(a, b, 1.0) - b).norm(), 1e-12);
  // The midpoint M satisfies M = A·exp(½ log(Aᵀ B)): half of the relative rotation.
  const Mat3 A = rodrigues(a), B = rodrigues(b);
  const Mat3 expected = A * rodrigues(0.5 * logSO3(A.transpose() * B));
  EXPECT_LT((rodrigues(slerpRotationVector(a, b, 0.5)) - expected).cwiseAbs().maxCoeff(), 1e-12);
  // Same axis: slerp interpolates the angle linearly.
  const Vec3 axis = Vec3(1, 2, 2).normalized();
  EXPECT_LT((slerpRotationVector(0.4 * axis, 1.2 * axis, 0.5) - 0.8 * axis).norm(), 1e-12);
  // From the identity.
  EXPECT_LT((slerpRotationVector(Vec3::Zero(), b, 0.25) - 0.25 * b).norm(), 1e-12);
}

}  // namespace
}  // namespace flsh
