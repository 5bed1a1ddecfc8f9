#include "flsh/core/rotation.h"

#include <Eigen/Geometry>
#include <cmath>
#include <limits>

namespace flsh {

namespace {
// Below this angle the trigonometric coefficients use their Taylor series (error < 1e-16).
constexpr double kSmallAngle = 1e-4;
}  // namespace

Mat3 skew(const Vec3& v) {
  Mat3 S;
  S << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return S;
}

Mat3 rodrigues(const Vec3& theta) {
  const double t2 = theta.squaredNorm();
  const double t = std::sqrt(t2);
  double a, b;  // R = I + a K + b K², K = [θ]×
  if (t < kSmallAngle) {
    a = 1.0 - t2 / 6.0 + t2 * t2 / 120.0;
    b = 0.5 - t2 / 24.0 + t2 * t2 / 720.0;
  } else if (std::isfinite(t2)) {
    a = std::sin(t) / t;
    b = (1.0 - std::cos(t)) / t2;
  } else if (theta.allFinite()) {
    // |θ|² overflows (|θ| > 1e154): the same formula on the unit axis, with |θ| from a
    // norm that does not overflow; sin and cos reduce the angle exactly.
    const double angle = theta.stableNorm();
    const Mat3 K = skew(theta / angle);
    return Mat3::Identity() + std::sin(angle) * K + (1.0 - std::cos(angle)) * K * K;
  } else {
    a = b = std::numeric_limits<double>::quiet_NaN();  // NaN in, NaN out (callers check)
  }
  const Mat3 K = skew(theta);
  return Mat3::Identity() + a * K + b * K * K;
}

Mat3 leftJacobianSO3(const Vec3& theta) {
  const double t2 = theta.squaredNorm();
  const double t = std::sqrt(t2);
  double b, c;  // J = I + b K + c K²
  if (t < kSmallAngle) {
    b = 0.5 - t2 / 24.0 + t2 * t2 / 720.0;
    c = 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0;
  } else {
    b = (1.0 - std::cos(t)) / t2;
    c = (t - std::sin(t)) / (t2 * t);
  }
  const Mat3 K = skew(theta);
  return Mat3::Identity() + b * K + c * K * K;
}

Mat3 leftJacobianInverseSO3(const Vec3& theta) {
  const double t2 = theta.squaredNorm();
  const double t = std::sqrt(t2);
  double c;  // J⁻¹ = I − ½ K + c K²
  if (t < kSmallAngle) {
    c = 1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0;
  } else {
    c = (1.0 - t * std::sin(t) / (2.0 * (1.0 - std::cos(t)))) / t2;
  }
  const Mat3 K = skew(theta);
  return Mat3::Identity() - 0.5 * K + c * K * K;
}

void rodriguesDerivatives(const Vec3& theta, Mat3 dR[3]) {
  const Mat3 R = rodrigues(theta);
  const Mat3 J = leftJacobianSO3(theta);
  for (int a = 0; a < 3; ++a) dR[a] = skew(J.col(a)) * R;
}

Vec3 logSO3(const Mat3& R) {
  // Quaternion route: stable for all angles, including near π where the matrix formula
  // (R − Rᵀ)/(2 sin θ) loses all precision.
  Eigen::Quaterniond q(R);
  q.normalize();
  if (q.w() < 0) q.coeffs() = -q.coeffs();
  const Vec3 v = q.vec();
  const double s = v.norm();
  if (s < 1e-12) return 2.0 * v;  // θ ≈ 2 v, exact to O(|v|³)
  const double angle = 2.0 * std::atan2(s, q.w());
  return v * (angle / s);
}

Vec3 slerpRotationVector(const Vec3& a, const Vec3& b, double t) {
  const double na = a.norm(), nb = b.norm();
  const Eigen::Quaterniond qa(Eigen::AngleAxisd(na, na > 0 ? Vec3(a / na) : Vec3::UnitX()));
  const Eigen::Quaterniond qb(Eigen::AngleAxisd(nb, nb > 0 ? Vec3(b / nb) : Vec3::UnitX()));
  return logSO3(qa.slerp(t, qb).toRotationMatrix());
}

}  // namespace flsh
