// Internal distance kernels shared by the colliders and the contact energies (not public API).
#pragma once

#include <string>

#include "flsh/core/types.h"

namespace flsh::detail {

/// Closer than this (m) to a sphere centre or capsule axis, the normal is undefined: a fixed
/// unit subgradient and a zero Hessian are returned instead of dividing by ~0.
constexpr double kCoreDistanceTolerance = 1e-12;
/// Segments shorter than 1e-10 m (squared: 1e-20 m²) are treated as a point (their midpoint).
constexpr double kDegenerateSegmentLength2 = 1e-20;

/// A number for error messages (%g-style: keeps 1e-9 and 1e+12 readable, unlike to_string).
std::string numberText(double value);

/// A unit vector perpendicular to u (u nonzero), chosen deterministically.
Vec3 perpendicularUnit(const Vec3& u);

/// |x − c| − r with gradient/Hessian w.r.t. x; `fallback_direction` (unit) is the gradient at
/// x = c.
double pointDistance(const Vec3& x, const Vec3& c, double r, const Vec3& fallback_direction,
                     Vec3* gradient, Mat3* hessian);

/// Distance from x to segment ab minus r, derivatives w.r.t. x only (cheaper than the 9-input
/// capsuleDistance). No input checks: the caller guarantees finite values.
double capsuleDistanceX(const Vec3& x, const Vec3& a, const Vec3& b, double r, Vec3* gradient,
                        Mat3* hessian);

}  // namespace flsh::detail
