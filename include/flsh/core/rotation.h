// Rotations: axis-angle (rotation vector) ⇄ matrix and the derivatives flsh needs.
//
// Convention: R = exp([θ]×) (Rodrigues). The left Jacobian J_l(θ) relates a change of the
// rotation vector to a spatial (world-frame) angular increment: dR = [J_l(θ) dθ]× R.
// All functions are exact to round-off at θ = 0 (Taylor branches) and valid up to |θ| = π;
// rodrigues() is valid for every finite θ. They do not check their input (they run inside
// parallel loops): a NaN in gives NaN out. Rotation vectors are checked where they enter flsh
// (poses, states): finite and |θ| ≤ kMaxRotationAngle, else InputError.
#pragma once

#include "flsh/core/types.h"

namespace flsh {

/// Largest angle |θ| (rad) accepted where rotation vectors enter flsh: poses (toSmplPose),
/// simulation states (Simulable::setState). Beyond it an angle means no rotation anyone meant
/// (at 1e16 rad consecutive float64 values are 2 rad apart); 1e6 rad still resolves the
/// angle modulo 2π to 1e-10 rad.
constexpr double kMaxRotationAngle = 1e6;

/// [v]×, the cross-product matrix: skew(v) w = v × w.
Mat3 skew(const Vec3& v);

/// skew's inverse on skew-symmetric matrices: vee(M) = (M21, M02, M10), so vee([w]×) = w.
/// Of M − Mᵀ it is twice the axial vector; Σ_k a_k × b_k = vee(Mᵀ − M) for M = Σ_k a_k b_kᵀ.
inline Vec3 vee(const Mat3& M) { return {M(2, 1), M(0, 2), M(1, 0)}; }

/// Rodrigues' formula R = exp([θ]×). Exact for every finite θ, however large: the angle is
/// reduced modulo 2π by sin/cos (no overflow of |θ|² above 1e154).
Mat3 rodrigues(const Vec3& theta);

/// Left Jacobian of SO(3): d/dε exp([θ + ε]×) = [J_l(θ) ε]× exp([θ]×) to first order.
Mat3 leftJacobianSO3(const Vec3& theta);

/// Inverse of the left Jacobian (defined for |θ| < 2π).
Mat3 leftJacobianInverseSO3(const Vec3& theta);

/// dR/dθ_a for a = 0, 1, 2 (three 3 × 3 matrices), i.e. [J_l(θ) e_a]× R.
void rodriguesDerivatives(const Vec3& theta, Mat3 dR[3]);

/// Rotation vector of R with |θ| ≤ π; robust near 0 and near π.
Vec3 logSO3(const Mat3& R);

/// Spherical interpolation between two rotation vectors, t in [0, 1], along the shortest arc.
Vec3 slerpRotationVector(const Vec3& a, const Vec3& b, double t);

}  // namespace flsh
