#include "flsh/energy/skeleton_energies.h"

#include "flsh/core/rotation.h"

namespace flsh {

Mat3 rotationCurvature(const Vec3& r, const Vec3& y) {
  return 0.5 * (r * y.transpose() + y * r.transpose()) - r.dot(y) * Mat3::Identity();
}

double rigidInertiaEnergy(const Vec3& t, const Mat3& R, const Vec3& t_n, const Mat3& R_n,
                          const Vec3& t_nm1, const Mat3& R_nm1, const BoneInertia& inertia,
                          double h, Vec6* gradient, Mat6* hessian, bool psd) {
  const double inv_h2 = 1.0 / (h * h);
  const Mat3& S = inertia.second_moment;
  const Vec3& m1 = inertia.first_moment;
  const double M = inertia.mass;
  const Mat3 A = 2.0 * R_n - R_nm1;  // predicted "rotation" (not orthogonal in general)
  const Vec3 c = 2.0 * t_n - t_nm1;  // predicted joint position
  const Mat3 D = R - A;
  const Vec3 u = t - c;
  const Vec3 Dm = D * m1;
  const double energy =
      0.5 * inv_h2 * ((D * S * D.transpose()).trace() + 2.0 * u.dot(Dm) + M * u.squaredNorm());
  if (gradient) {
    const Mat3 RSAt = R * S * A.transpose();
    gradient->head<3>() = inv_h2 * (Dm + M * u);
    gradient->tail<3>() = inv_h2 * ((R * m1).cross(u) + vee(RSAt - RSAt.transpose()));
  }
  if (hessian) {
    const Vec3 Rm = R * m1;
    const Mat3 RSRt = R * S * R.transpose();
    hessian->setZero();
    hessian->topLeftCorner<3, 3>() = inv_h2 * M * Mat3::Identity();
    hessian->topRightCorner<3, 3>() = -inv_h2 * skew(Rm);
    hessian->bottomLeftCorner<3, 3>() = inv_h2 * skew(Rm);
    Mat3 Hww = S.trace() * Mat3::Identity() - RSRt;  // Σ m [y]×ᵀ[y]×, y = R(X − J)
    if (!psd) {
      // Σ m r·∂²y: P = Σ m y rᵀ with r = x − x̂ = y + u − A(X − J).
      const Mat3 P = RSRt + Rm * u.transpose() - R * S * A.transpose();
      Hww += 0.5 * (P + P.transpose()) - P.trace() * Mat3::Identity();
    }
    hessian->bottomRightCorner<3, 3>() = inv_h2 * Hww;
  }
  return energy;
}

void rigidInertiaGradientPreviousStates(const Vec3& t, const Mat3& R, const Vec3& t_n,
                                        const Mat3& R_n, const Vec3& t_nm1, const Mat3& R_nm1,
                                        const BoneInertia& inertia, double h, Mat6* dg_dq_n,
                                        Mat6* dg_dq_nm1) {
  const double inv_h2 = 1.0 / (h * h);
  const Vec3 Rm = R * inertia.first_moment;
  // x̂ = 2 x_n − x_{n−1}: the previous state k enters A and c with weight κ (2 or −1).
  auto fill = [&](const Mat3& R_k, double kappa, Mat6* out) {
    const Mat3 Y = R_k * inertia.second_moment * R.transpose();
    out->topLeftCorner<3, 3>() = -kappa * inv_h2 * inertia.mass * Mat3::Identity();
    out->bottomLeftCorner<3, 3>() = -kappa * inv_h2 * skew(Rm);
    out->topRightCorner<3, 3>() = kappa * inv_h2 * skew(R_k * inertia.first_moment);
    out->bottomRightCorner<3, 3>() = -kappa * inv_h2 * (Y.trace() * Mat3::Identity() - Y);
  };
  if (dg_dq_n) fill(R_n, 2.0, dg_dq_n);
  if (dg_dq_nm1) fill(R_nm1, -1.0, dg_dq_nm1);
}

double gravityEnergy(const Vec3& t, const Mat3& R, const BoneInertia& inertia, const Vec3& g,
                     Vec6* gradient, Mat6* hessian, bool psd) {
  const Vec3 y = R * inertia.first_moment;
  if (gradient) {
    gradient->head<3>() = -inertia.mass * g;
    gradient->tail<3>() = g.cross(y);
  }
  if (hessian) {
    hessian->setZero();
    const Mat3 Hww = rotationCurvature(-g, y);
    hessian->bottomRightCorner<3, 3>() = psd ? projectToPSD<3>(Hww) : Hww;
  }
  return -g.dot(inertia.mass * t + y);
}

double jointSpringEnergy(const Vec3& t_p, const Mat3& R_p, const Vec3& t_b, const Mat3& R_b,
                         const Vec3& J_p, const Vec3& J_b, double k, Vec12* gradient,
                         Mat12* hessian, bool psd) {
  // R_b does not enter: the bone's joint centre is its origin t_b.
  const Vec3 y = R_p * (J_b - J_p);
  const Vec3 d = y + t_p - t_b;  // gap between the parent's and the bone's joint centre
  if (gradient) {
    gradient->segment<3>(0) = k * d;
    gradient->segment<3>(3) = k * y.cross(d);
    gradient->segment<3>(6) = -k * d;
    gradient->segment<3>(9).setZero();
  }
  if (hessian) {
    Eigen::Matrix<double, 3, 12> Jd = Eigen::Matrix<double, 3, 12>::Zero();
    Jd.block<3, 3>(0, 0) = Mat3::Identity();
    Jd.block<3, 3>(0, 3) = -skew(y);
    Jd.block<3, 3>(0, 6) = -Mat3::Identity();
    *hessian = k * Jd.transpose() * Jd;
    const Mat3 curvature = k * rotationCurvature(d, y);
    hessian->block<3, 3>(3, 3) += psd ? projectToPSD<3>(curvature) : curvature;
  }
  return 0.5 * k * d.squaredNorm();
}

double trackingSpringEnergy(const Mat3& R_p, const Mat3& R_b, const Mat3& R_target, double k,
                            Vec6* gradient, Mat6* hessian, bool psd) {
  const Mat3 B = R_target.transpose() * R_p.transpose();
  const Vec3 e = logSO3(B * R_b);
  // J_l(e)ᵀ e = e, so the gradient needs no Jacobian: g_b = k Bᵀe = −g_p.
  const Vec3 w = B.transpose() * e;
  if (gradient) {
    gradient->head<3>() = -k * w;
    gradient->tail<3>() = k * w;
  }
  if (hessian) {
    const Mat3 Jinv = leftJacobianInverseSO3(e);  // finite up to |e| = π
    if (psd) {
      const Mat3 G = k * B.transpose() * Jinv.transpose() * Jinv * B;
      hessian->topLeftCorner<3, 3>() = G;
      hessian->bottomRightCorner<3, 3>() = G;
      hessian->topRightCorner<3, 3>() = -G;
      hessian->bottomLeftCorner<3, 3>() = -G;
    } else {
      // Differentiating g_b = k Bᵀe: de = J_l(e)⁻¹ B δω_b − J_l(e)⁻¹ B δω_p and dBᵀ = [δω_p]× Bᵀ;
      // the chart term ½[g]× of each diagonal block leaves the symmetric part Q of J_l(e)⁻¹.
      const Mat3 Q = 0.5 * (Jinv + Jinv.transpose());
      const Mat3 BtQB = k * B.transpose() * Q * B;
      hessian->topLeftCorner<3, 3>() = BtQB;
      hessian->bottomRightCorner<3, 3>() = BtQB;
      hessian->topRightCorner<3, 3>() = -k * B.transpose() * Jinv * B;
      hessian->bottomLeftCorner<3, 3>() = -k * B.transpose() * Jinv.transpose() * B;
    }
  }
  return 0.5 * k * e.squaredNorm();
}

double rootSpringEnergy(const Vec3& t_0, const Mat3& R_0, const Vec3& t_target,
                        const Mat3& R_target, double k_pos, double k_rot, Vec6* gradient,
                        Mat6* hessian, bool psd) {
  // The rotation part is a tracking spring whose parent is the world frame.
  Vec6 g_rot;
  Mat6 H_rot;
  const double rotation_energy =
      trackingSpringEnergy(Mat3::Identity(), R_0, R_target, k_rot, gradient ? &g_rot : nullptr,
                           hessian ? &H_rot : nullptr, psd);
  const Vec3 d = t_0 - t_target;
  if (gradient) {
    gradient->head<3>() = k_pos * d;
    gradient->tail<3>() = g_rot.tail<3>();
  }
  if (hessian) {
    hessian->setZero();
    hessian->topLeftCorner<3, 3>() = k_pos * Mat3::Identity();
    hessian->bottomRightCorner<3, 3>() = H_rot.bottomRightCorner<3, 3>();
  }
  return 0.5 * k_pos * d.squaredNorm() + rotation_energy;
}

}  // namespace flsh
