// Analytic colliders (plane, sphere, capsule), static or moving along a scripted path
// (ARCHITECTURE.md §5). Signed distance d(x) is positive outside, negative inside.
#pragma once

#include <string>
#include <vector>

#include "flsh/core/types.h"

namespace flsh {

/// Piecewise-linear keyframed translation of a collider. Empty = static. Before the first key
/// and after the last the offset is held constant.
struct ColliderPath {
  std::vector<double> times;  ///< strictly increasing, s
  std::vector<Vec3> offsets;  ///< translation at each time, m
  Vec3 offsetAt(double t) const;
  Vec3 velocityAt(double t) const;  ///< m/s (right derivative at keys)
  /// A straight path with constant velocity from `start` (offset 0 at t = 0) for `duration` s.
  static ColliderPath constantVelocity(const Vec3& velocity, double duration);
  void validate(const std::string& what) const;  ///< throws InputError naming `what`
};

enum class ColliderShape { Plane, Sphere, Capsule };

class Collider {
 public:
  /// Half-space below the plane through `point` with outward `normal` (normalized here).
  static Collider plane(const Vec3& point, const Vec3& normal);
  static Collider sphere(const Vec3& center, double radius);
  static Collider capsule(const Vec3& a, const Vec3& b, double radius);

  ColliderShape shape() const { return shape_; }
  /// Plane: point and unit normal; sphere: center (p1 unused); capsule: segment a, b.
  const Vec3& p0() const { return p0_; }
  const Vec3& p1() const { return p1_; }
  double radius() const { return radius_; }
  ColliderPath path;
  std::string name;  ///< for messages and outputs

  /// Signed distance of x at time t; optional gradient ∂d/∂x and Hessian ∂²d/∂x² (zero for the
  /// plane; the sphere's and capsule's are singular on their centre/axis, where a finite
  /// subgradient is returned instead of NaN).
  double signedDistance(const Vec3& x, double t, Vec3* gradient = nullptr,
                        Mat3* hessian = nullptr) const;
  /// Derivative of d with respect to the collider's translation offset: ∂d/∂o = −∂d/∂x.
  /// (Collider positions are parameters of the adjoint.)
  Vec3 distanceGradientOffset(const Vec3& x, double t) const;

 private:
  ColliderShape shape_ = ColliderShape::Plane;
  Vec3 p0_ = Vec3::Zero(), p1_ = Vec3::Zero();
  double radius_ = 0.0;
};

/// Signed distance from x to the capsule (a, b, r) and its derivatives with respect to
/// y = (x, a, b) ∈ R⁹: gradient (9) and Hessian (9 × 9). Used for colliders and for
/// avatar–avatar contact where a, b move with the other avatar's bone.
double capsuleDistance(const Vec3& x, const Vec3& a, const Vec3& b, double r,
                       Eigen::Matrix<double, 9, 1>* gradient = nullptr,
                       Eigen::Matrix<double, 9, 9>* hessian = nullptr);

}  // namespace flsh
