// Local energy kernels of the articulated skeleton (ARCHITECTURE.md §4), as free functions on
// fixed-size Eigen types. Simulable assembles them; the adjoint reuses them.
//
// Chart: every bone has 6 increments [δt, δω] with t ← t + δt and R ← exp([δω]×) R (a
// world-frame rotation increment). Each kernel returns the energy and, when the pointers are
// not null, writes its gradient and Hessian with respect to the increments of the bones it
// involves, in the order the arguments list them (e.g. [δt_p, δω_p, δt_b, δω_b]).
//
// Hessians are the second derivatives of E(t + δt, exp([δω]×) R) at δ = 0, which are
// symmetric (with ∂²R/∂δω_a∂δω_b = ½([e_a]×[e_b]× + [e_b]×[e_a]×) R). Note that the derivative of
// the gradient along updateState differs from this by −½[g_ω]× in each bone's rotation block
// (the chart moves with the state); the two agree where the total gradient vanishes, which is
// where the adjoint linearizes. `psd` = true gives the positive-semidefinite form Newton uses:
// Gauss–Newton where it is natural (inertia, tracking), plus the PSD projection of the
// rotation-curvature block where that block is large away from rest (joint springs pulled by
// contact), and an eigenvalue-clamped projection otherwise (gravity).
#pragma once

#include <Eigen/Core>
#include <Eigen/Eigenvalues>

#include "flsh/core/types.h"
#include "flsh/energy/bone_inertia.h"

namespace flsh {

// Vec6, Mat6, Vec12, Mat12: flsh/core/types.h.

/// Inertia of one rigid bone in backward Euler: E = 1/(2h²) Σ m ‖x − x̂‖² over its mass points,
/// x = R (X − J) + t, x̂ = 2 x_n − x_{n−1}; in closed form with A = 2R_n − R_{n−1},
/// c = 2t_n − t_{n−1}: 1/(2h²)[tr((R−A) S (R−A)ᵀ) + 2(t−c)ᵀ(R−A) m̄ + M‖t−c‖²] (J).
/// Gradient/Hessian over [δt, δω] (6). psd: Gauss–Newton (Σ m JᵀJ), exact otherwise.
double rigidInertiaEnergy(const Vec3& t, const Mat3& R, const Vec3& t_n, const Mat3& R_n,
                          const Vec3& t_nm1, const Mat3& R_nm1, const BoneInertia& inertia,
                          double h, Vec6* gradient = nullptr, Mat6* hessian = nullptr,
                          bool psd = false);

/// Mixed derivatives of the inertia gradient (6, at state t, R) with respect to the increments
/// of the previous states, for the adjoint: ∂g/∂q_n (6 × 6, increments of t_n, R_n) and
/// ∂g/∂q_{n−1} (6 × 6). Either pointer may be null.
void rigidInertiaGradientPreviousStates(const Vec3& t, const Mat3& R, const Vec3& t_n,
                                        const Mat3& R_n, const Vec3& t_nm1, const Mat3& R_nm1,
                                        const BoneInertia& inertia, double h, Mat6* dg_dq_n,
                                        Mat6* dg_dq_nm1);

/// Gravity potential of one bone: −g·(M t + R m̄) (J), g in m/s². Over [δt, δω] (6).
/// psd: the rotation block projected on the PSD cone.
double gravityEnergy(const Vec3& t, const Mat3& R, const BoneInertia& inertia, const Vec3& g,
                     Vec6* gradient = nullptr, Mat6* hessian = nullptr, bool psd = false);

/// Joint spring between bone b and its parent p: ½k‖R_p(J_b − J_p) + t_p − t_b‖² (J), k in
/// N/m, J_p, J_b rest joint centres. Over [δt_p, δω_p, δt_b, δω_b] (12). psd: Gauss–Newton
/// k JᵀJ plus the PSD projection of the curvature k d·∂²(R_p(J_b − J_p)) (3 × 3, δω_p).
double jointSpringEnergy(const Vec3& t_p, const Mat3& R_p, const Vec3& t_b, const Mat3& R_b,
                         const Vec3& J_p, const Vec3& J_b, double k, Vec12* gradient = nullptr,
                         Mat12* hessian = nullptr, bool psd = false);

/// Tracking spring of a joint: ½k‖e‖², e = log(R_targetᵀ R_pᵀ R_b) (|e| ≤ π), k in N·m/rad².
/// R_target is the target rotation of b relative to its parent p. Over [δω_p, δω_b] (6).
/// Exact Hessian: k [Q, −J⁻ᵀ; −J⁻¹, Q] in the frame B = R_targetᵀR_pᵀ (J⁻¹ = J_l(e)⁻¹, Q its
/// symmetric part); psd: Gauss–Newton k [−B, B]ᵀ J⁻ᵀ J⁻¹ [−B, B]. Finite for e → 0 and |e| → π.
double trackingSpringEnergy(const Mat3& R_p, const Mat3& R_b, const Mat3& R_target, double k,
                            Vec6* gradient = nullptr, Mat6* hessian = nullptr, bool psd = false);

/// Root spring: ½k_pos‖t_0 − t_target‖² + ½k_rot‖log(R_targetᵀ R_0)‖² (J), k_pos in N/m,
/// k_rot in N·m/rad². Over [δt_0, δω_0] (6). psd: Gauss–Newton rotation block.
double rootSpringEnergy(const Vec3& t_0, const Mat3& R_0, const Vec3& t_target,
                        const Mat3& R_target, double k_pos, double k_rot,
                        Vec6* gradient = nullptr, Mat6* hessian = nullptr, bool psd = false);

/// Σ r·∂²y/∂δω_a∂δω_b for a point y rotating with the bone (y = R p) against a fixed vector r:
/// ½(r yᵀ + y rᵀ) − (r·y) I. The curvature term of every energy of rotated points.
Mat3 rotationCurvature(const Vec3& r, const Vec3& y);

/// Projects a symmetric matrix onto the PSD cone (eigenvalues clamped at 0).
template <int N>
Eigen::Matrix<double, N, N> projectToPSD(const Eigen::Matrix<double, N, N>& M) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, N, N>> eig;
  if constexpr (N == 3)
    eig.computeDirect(M);  // closed form: the 3 × 3 projections sit in every evaluation
  else
    eig.compute(M);
  return eig.eigenvectors() * eig.eigenvalues().cwiseMax(0.0).asDiagonal() *
         eig.eigenvectors().transpose();
}

}  // namespace flsh
