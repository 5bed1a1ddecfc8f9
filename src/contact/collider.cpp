#include "flsh/contact/collider.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <sstream>

#include "contact/collider_detail.h"
#include "flsh/core/error.h"

namespace flsh {

namespace {

std::string vecText(const Vec3& v) {
  std::ostringstream s;
  s << "(" << v.x() << ", " << v.y() << ", " << v.z() << ")";
  return s.str();
}

void requireFinite(const Vec3& v, const std::string& what) {
  if (!v.allFinite()) throw InputError(what + " must be finite, got " + vecText(v));
}

void requirePositiveRadius(double radius, const std::string& what) {
  if (!(std::isfinite(radius) && radius > 0.0))
    throw InputError(what + " must be positive and finite, got " + detail::numberText(radius));
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// ColliderPath

Vec3 ColliderPath::offsetAt(double t) const {
  if (times.empty()) return Vec3::Zero();
  // A size mismatch would read past the end of `offsets`: refuse instead (validate() explains).
  if (times.size() != offsets.size())
    throw InputError("ColliderPath: times has " + std::to_string(times.size()) +
                     " entries but offsets has " + std::to_string(offsets.size()));
  if (!std::isfinite(t))
    throw InputError("ColliderPath::offsetAt: time must be finite, got " + detail::numberText(t));
  if (t <= times.front()) return offsets.front();
  if (t >= times.back()) return offsets.back();
  // First key strictly after t; t lies in [times[k-1], times[k]).
  const size_t k = std::upper_bound(times.begin(), times.end(), t) - times.begin();
  const double w = (t - times[k - 1]) / (times[k] - times[k - 1]);
  return (1.0 - w) * offsets[k - 1] + w * offsets[k];
}

Vec3 ColliderPath::velocityAt(double t) const {
  if (times.size() < 2) return Vec3::Zero();
  if (times.size() != offsets.size())
    throw InputError("ColliderPath: times has " + std::to_string(times.size()) +
                     " entries but offsets has " + std::to_string(offsets.size()));
  if (!std::isfinite(t))
    throw InputError("ColliderPath::velocityAt: time must be finite, got " + detail::numberText(t));
  // Held constant outside the keys; right derivative at a key = slope of the segment after it.
  if (t < times.front() || t >= times.back()) return Vec3::Zero();
  const size_t k = std::upper_bound(times.begin(), times.end(), t) - times.begin();
  return (offsets[k] - offsets[k - 1]) / (times[k] - times[k - 1]);
}

ColliderPath ColliderPath::constantVelocity(const Vec3& velocity, double duration) {
  requireFinite(velocity, "ColliderPath::constantVelocity: velocity");
  if (!(std::isfinite(duration) && duration > 0.0))
    throw InputError("ColliderPath::constantVelocity: duration must be positive and finite, got " +
                     detail::numberText(duration));
  ColliderPath path;
  path.times = {0.0, duration};
  path.offsets = {Vec3::Zero(), velocity * duration};
  return path;
}

void ColliderPath::validate(const std::string& what) const {
  if (times.size() != offsets.size())
    throw InputError(what + ": path times has " + std::to_string(times.size()) +
                     " entries but offsets has " + std::to_string(offsets.size()) +
                     " (expected equal sizes)");
  for (size_t k = 0; k < times.size(); ++k) {
    if (!std::isfinite(times[k]))
      throw InputError(what + ": path time " + std::to_string(k) + " must be finite, got " +
                       detail::numberText(times[k]));
    if (k > 0 && !(times[k] > times[k - 1]))
      throw InputError(what + ": path times must be strictly increasing, but time " +
                       std::to_string(k) + " = " + detail::numberText(times[k]) + " follows " +
                       detail::numberText(times[k - 1]));
    if (!offsets[k].allFinite())
      throw InputError(what + ": path offset " + std::to_string(k) + " must be finite, got " +
                       vecText(offsets[k]));
  }
}

// ---------------------------------------------------------------------------------------------
// Collider

Collider Collider::plane(const Vec3& point, const Vec3& normal) {
  requireFinite(point, "Collider::plane: point");
  requireFinite(normal, "Collider::plane: normal");
  const double length = normal.norm();
  if (!(length > 1e-12))
    throw InputError("Collider::plane: normal must be nonzero, got " + vecText(normal));
  Collider c;
  c.shape_ = ColliderShape::Plane;
  c.p0_ = point;
  c.p1_ = normal / length;
  c.name = "plane";
  return c;
}

Collider Collider::sphere(const Vec3& center, double radius) {
  requireFinite(center, "Collider::sphere: center");
  requirePositiveRadius(radius, "Collider::sphere: radius");
  Collider c;
  c.shape_ = ColliderShape::Sphere;
  c.p0_ = center;
  c.p1_ = center;
  c.radius_ = radius;
  c.name = "sphere";
  return c;
}

Collider Collider::capsule(const Vec3& a, const Vec3& b, double radius) {
  requireFinite(a, "Collider::capsule: a");
  requireFinite(b, "Collider::capsule: b");
  requirePositiveRadius(radius, "Collider::capsule: radius");
  Collider c;
  c.shape_ = ColliderShape::Capsule;
  c.p0_ = a;
  c.p1_ = b;
  c.radius_ = radius;
  c.name = "capsule";
  return c;
}

double Collider::signedDistance(const Vec3& x, double t, Vec3* gradient, Mat3* hessian) const {
  const Vec3 offset = path.offsetAt(t);
  switch (shape_) {
    case ColliderShape::Plane: {
      // p1_ holds the unit normal.
      if (gradient) *gradient = p1_;
      if (hessian) hessian->setZero();
      return (x - p0_ - offset).dot(p1_);
    }
    case ColliderShape::Sphere:
      return detail::pointDistance(x, p0_ + offset, radius_, Vec3::UnitY(), gradient, hessian);
    case ColliderShape::Capsule:
      return detail::capsuleDistanceX(x, p0_ + offset, p1_ + offset, radius_, gradient, hessian);
  }
  return 0.0;  // unreachable: every shape is handled above
}

Vec3 Collider::distanceGradientOffset(const Vec3& x, double t) const {
  Vec3 gradient;
  signedDistance(x, t, &gradient, nullptr);
  return -gradient;
}

// ---------------------------------------------------------------------------------------------
// Capsule distance with derivatives w.r.t. (x, a, b)

namespace detail {

std::string numberText(double value) {
  std::ostringstream s;
  s << value;
  return s.str();
}

Vec3 perpendicularUnit(const Vec3& u) {
  // Cross with the coordinate axis least aligned with u: never parallel, deterministic.
  Eigen::Index axis = 0;
  u.cwiseAbs().minCoeff(&axis);
  const Vec3 p = u.cross(Vec3::Unit(axis));
  const double n = p.norm();
  return n > 0.0 ? Vec3(p / n) : Vec3(Vec3::UnitY());
}

double pointDistance(const Vec3& x, const Vec3& c, double r, const Vec3& fallback_direction,
                     Vec3* gradient, Mat3* hessian) {
  const Vec3 e = x - c;
  const double D = e.norm();
  if (D < kCoreDistanceTolerance) {
    // On the centre: any unit vector is a subgradient; the Hessian blows up, return zero.
    if (gradient) *gradient = fallback_direction;
    if (hessian) hessian->setZero();
    return D - r;
  }
  const Vec3 n = e / D;
  if (gradient) *gradient = n;
  if (hessian) *hessian = (Mat3::Identity() - n * n.transpose()) / D;
  return D - r;
}

double capsuleDistanceX(const Vec3& x, const Vec3& a, const Vec3& b, double r, Vec3* gradient,
                        Mat3* hessian) {
  const Vec3 u = b - a;
  const double L2 = u.squaredNorm();
  if (L2 < kDegenerateSegmentLength2)
    return pointDistance(x, 0.5 * (a + b), r, Vec3::UnitY(), gradient, hessian);
  const double s = (x - a).dot(u) / L2;
  const double L = std::sqrt(L2);
  if (s <= 0.0) return pointDistance(x, a, r, -u / L, gradient, hessian);
  if (s >= 1.0) return pointDistance(x, b, r, u / L, gradient, hessian);
  const Vec3 e = x - a - s * u;
  const double D = e.norm();
  if (D < kCoreDistanceTolerance) {
    if (gradient) *gradient = perpendicularUnit(u);
    if (hessian) hessian->setZero();
    return D - r;
  }
  const Vec3 n = e / D;
  if (gradient) *gradient = n;
  // Cylinder curvature: zero along the normal and along the axis.
  if (hessian) *hessian = (Mat3::Identity() - n * n.transpose() - u * u.transpose() / L2) / D;
  return D - r;
}

}  // namespace detail

double capsuleDistance(const Vec3& x, const Vec3& a, const Vec3& b, double r,
                       Eigen::Matrix<double, 9, 1>* gradient,
                       Eigen::Matrix<double, 9, 9>* hessian) {
  if (!(x.allFinite() && a.allFinite() && b.allFinite() && std::isfinite(r)))
    throw InputError("capsuleDistance: inputs must be finite, got x = " + vecText(x) + ", a = " +
                     vecText(a) + ", b = " + vecText(b) + ", r = " + detail::numberText(r));
  const Vec3 u = b - a;
  const double L2 = u.squaredNorm();

  // Point regions (cap a, cap b, or a zero-length segment at its midpoint): d = |x − c| − r
  // with c = w_a a + w_b b, so ∂d/∂(x, a, b) = (n, −w_a n, −w_b n).
  auto pointRegion = [&](double w_a, double w_b, const Vec3& fallback) {
    const Vec3 c = w_a * a + w_b * b;
    Vec3 n;
    Mat3 P;
    const double d = detail::pointDistance(x, c, r, fallback, &n, hessian ? &P : nullptr);
    const double coef[3] = {1.0, -w_a, -w_b};
    if (gradient)
      for (int i = 0; i < 3; ++i) gradient->segment<3>(3 * i) = coef[i] * n;
    if (hessian)
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) hessian->block<3, 3>(3 * i, 3 * j) = coef[i] * coef[j] * P;
    return d;
  };

  if (L2 < detail::kDegenerateSegmentLength2) return pointRegion(0.5, 0.5, Vec3::UnitY());
  const double s = (x - a).dot(u) / L2;
  const double L = std::sqrt(L2);
  if (s <= 0.0) return pointRegion(1.0, 0.0, -u / L);
  if (s >= 1.0) return pointRegion(0.0, 1.0, u / L);

  // Interior: e = x − (1 − s) a − s b with s = (x − a)·u / |u|² the closest-point parameter.
  // Envelope theorem: ∇d = Bᵀ n with B = [I, −(1 − s) I, −s I]; differentiating s as well gives
  // ∇²d = Bᵀ (I − nnᵀ) B / D − (|u|² / D) ∇s ∇sᵀ.
  const Vec3 e = x - a - s * u;
  const double D = e.norm();
  const double coef[3] = {1.0, -(1.0 - s), -s};
  if (D < detail::kCoreDistanceTolerance) {
    // On the axis: a unit vector perpendicular to it is a subgradient; Hessian set to zero.
    const Vec3 n = detail::perpendicularUnit(u);
    if (gradient)
      for (int i = 0; i < 3; ++i) gradient->segment<3>(3 * i) = coef[i] * n;
    if (hessian) hessian->setZero();
    return D - r;
  }
  const Vec3 n = e / D;
  if (gradient)
    for (int i = 0; i < 3; ++i) gradient->segment<3>(3 * i) = coef[i] * n;
  if (hessian) {
    const Mat3 P = (Mat3::Identity() - n * n.transpose()) / D;
    // ∂s/∂x = u/|u|², ∂s/∂a = (−e − (1 − s) u)/|u|², ∂s/∂b = (e − s u)/|u|².
    Eigen::Matrix<double, 9, 1> ds;
    ds.segment<3>(0) = u / L2;
    ds.segment<3>(3) = (-e - (1.0 - s) * u) / L2;
    ds.segment<3>(6) = (e - s * u) / L2;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) hessian->block<3, 3>(3 * i, 3 * j) = coef[i] * coef[j] * P;
    hessian->noalias() -= (L2 / D) * ds * ds.transpose();
  }
  return D - r;
}

}  // namespace flsh
