// ∂g/∂p and ∂g/∂q_{n}, ∂g/∂q_{n−1} of the Simulable's total gradient, analytic, term by term
// (the same kernels as simulable.cpp's assembly): inertia, gravity, joint springs, tracking and
// root springs, collider contact on the skinned surface.
#include "sim/parameter_derivatives.h"

#include <string>

#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "flsh/sim/skeleton_energies.h"

namespace flsh::detail {

std::vector<std::vector<int>> boneSubtrees(const std::vector<int>& parents) {
  std::vector<std::vector<int>> sub(parents.size());
  for (int c = 0; c < int(parents.size()); ++c)
    for (int b = c; b >= 0; b = parents[size_t(b)]) sub[size_t(b)].push_back(c);
  return sub;
}

double trackingMoment(const MatX3& J, const std::vector<BoneInertia>& inertia,
                      const SimulableOptions& options, const std::vector<int>& subtree, int b) {
  double I = b == 0 ? 0.0 : options.tracking_inertia_floor;
  for (int c : subtree) {
    const Vec3 d = (J.row(c) - J.row(b)).transpose();
    const BoneInertia& in = inertia[size_t(c)];
    I += in.second_moment.trace() + 2.0 * in.first_moment.dot(d) + in.mass * d.squaredNorm();
  }
  return I;
}

namespace {

constexpr int kInertiaValues = 10;  // mass, first moment (3), second moment (6)

Vec3 vee(const Mat3& M) { return Vec3(M(2, 1), M(0, 2), M(1, 0)); }

// Symmetric basis of the second moment in the order xx, yy, zz, xy, xz, yz.
Mat3 secondMomentBasis(int k) {
  static const int rows[6] = {0, 1, 2, 0, 0, 1}, cols[6] = {0, 1, 2, 1, 2, 2};
  Mat3 E = Mat3::Zero();
  E(rows[k], cols[k]) = 1.0;
  E(cols[k], rows[k]) = 1.0;
  return E;
}

// Gradient of a tracking spring with unit stiffness, over [δω_p, δω_b] (root: [−, δω_0]).
Vec6 unitTracking(const SimulableParameterView& v, int b) {
  Vec6 g;
  const int p = v.parents[b];
  trackingSpringEnergy(p < 0 ? Mat3::Identity() : v.R[p], v.R[b], v.target_R[b], 1.0, &g);
  return g;
}

// Adds the unit tracking gradient of bone b times a row vector (∂k_b/∂p) into D.
void addTrackingColumns(const SimulableParameterView& v, int b, const Eigen::RowVectorXd& dk,
                        int col0, MatX& D) {
  const Vec6 g = unitTracking(v, b);
  const int p = v.parents[b];
  if (p >= 0) D.middleRows<3>(6 * p + 3).middleCols(col0, dk.size()) += g.head<3>() * dk;
  D.middleRows<3>(6 * b + 3).middleCols(col0, dk.size()) += g.tail<3>() * dk;
}

// Exact contact node Hessians (3 × 3 per candidate) against the given colliders.
std::vector<Mat3> contactNodeHessians(const SimulableParameterView& v,
                                      const std::vector<Collider>& colliders) {
  const int n = int(v.candidates.size());
  std::vector<Mat3> H(n, Mat3::Zero());
  if (n == 0) return H;
  ContactOptions options = v.options.contact;
  options.exact_hessian = true;
  std::vector<Triplet> triplets;
  colliderContactEnergy(v.contact_nodes, v.contact_areas, colliders, v.time, options, nullptr,
                        &triplets, 0, nullptr);
  for (const Triplet& e : triplets) {
    const int j = e.row() / 3;
    H[j](e.row() - 3 * j, e.col() - 3 * j) += e.value();
  }
  return H;
}

// Pulls a node-gradient derivative dgx (3 × P per candidate) back to the DoFs of the bones
// skinning each candidate: g_t,b += w gx, g_ω,b += w y × gx, y = R_b(X − J_b).
void addContactRows(const SimulableParameterView& v, int j, const MatX& dgx, int col0, MatX& D) {
  const int i = v.candidates[j];
  for (int b = 0; b < v.num_bones; ++b) {
    const double w = v.weights(i, b);
    if (w == 0.0) continue;
    const Vec3 y = v.R[b] * (v.X.row(i) - v.J.row(b)).transpose();
    D.middleRows<3>(6 * b).middleCols(col0, dgx.cols()) += w * dgx;
    D.middleRows<3>(6 * b + 3).middleCols(col0, dgx.cols()) += w * skew(y) * dgx;
  }
}

MatX restJointsJacobian(const SimulableParameterView& v) {
  MatX D = MatX::Zero(6 * v.num_bones, 3 * v.num_bones);
  const double kj = v.options.joint_stiffness;
  // Joint springs: d = y + t_p − t_b with y = R_p(J_b − J_p); dy = dd = R_p (dJ_b − dJ_p), and
  // d(y × d) = [y − d]× R_p (dJ_b − dJ_p).
  for (int b = 0; b < v.num_bones; ++b) {
    const int p = v.parents[b];
    if (p < 0) continue;
    const Vec3 y = v.R[p] * (v.J.row(b) - v.J.row(p)).transpose();
    const Vec3 d = y + v.t.row(p).transpose() - v.t.row(b).transpose();
    const Mat3 dd = kj * v.R[p];
    const Mat3 dcross = kj * skew(y - d) * v.R[p];
    for (int s = 0; s < 2; ++s) {
      const int c = s == 0 ? b : p;
      const double sign = s == 0 ? 1.0 : -1.0;
      D.block<3, 3>(6 * p, 3 * c) += sign * dd;
      D.block<3, 3>(6 * p + 3, 3 * c) += sign * dcross;
      D.block<3, 3>(6 * b, 3 * c) -= sign * dd;
    }
  }
  if (v.tracking) {
    // k_b = stiffness · I_b: ∂I_b/∂J_c = 2(m̄_c + M_c d) for c in the subtree, minus their sum
    // for J_b itself. The root target t_0 = J_0 + trans moves with J_0.
    const auto sub = boneSubtrees(v.parents);
    for (int b = 0; b < v.num_bones; ++b) {
      const double scale = b == 0 ? v.options.root_stiffness : v.options.tracking_stiffness;
      Eigen::RowVectorXd dk = Eigen::RowVectorXd::Zero(3 * v.num_bones);
      for (int c : sub[b]) {
        const Vec3 d = (v.J.row(c) - v.J.row(b)).transpose();
        const Vec3 dI = 2.0 * (v.inertia[c].first_moment + v.inertia[c].mass * d);
        dk.segment<3>(3 * c) += scale * dI.transpose();
        dk.segment<3>(3 * b) -= scale * dI.transpose();
      }
      addTrackingColumns(v, b, dk, 0, D);
    }
    double mass = 0.0;
    for (const BoneInertia& in : v.inertia) mass += in.mass;
    D.block<3, 3>(0, 0) -= v.options.root_stiffness * mass * Mat3::Identity();
  }
  // Contact: dx_i/dJ_c = −w_ic R_c moves the node gradient by H_x dx; y_ib × g_x also turns
  // with dy_ib = −R_b dJ_b.
  const std::vector<Mat3> H = contactNodeHessians(v, v.colliders);
  for (size_t j = 0; j < v.candidates.size(); ++j) {
    const Vec3 gx = v.contact_gradient.segment<3>(3 * j);
    if (gx.isZero(0.0) && H[j].isZero(0.0)) continue;
    const int i = v.candidates[j];
    MatX dgx = MatX::Zero(3, 3 * v.num_bones);
    for (int c = 0; c < v.num_bones; ++c) {
      const double w = v.weights(i, c);
      if (w == 0.0) continue;
      dgx.middleCols<3>(3 * c) = -w * H[j] * v.R[c];
      D.block<3, 3>(6 * c + 3, 3 * c) += w * skew(gx) * v.R[c];
    }
    addContactRows(v, int(j), dgx, 0, D);
  }
  return D;
}

MatX boneInertiaJacobian(const SimulableParameterView& v) {
  MatX D = MatX::Zero(6 * v.num_bones, kInertiaValues * v.num_bones);
  const double inv_h2 = 1.0 / (v.options.time_step * v.options.time_step);
  const Vec3& gravity = v.options.gravity;
  for (int b = 0; b < v.num_bones; ++b) {
    const int col = kInertiaValues * b;
    const Vec3 t = v.t.row(b).transpose();
    if (!v.is_static) {
      // Inertia gradient inv_h2 [D m̄ + M u; (R m̄) × u + vee(R S Aᵀ − A S Rᵀ)], linear in M, m̄, S.
      const Mat3 A = 2.0 * v.R_n[b] - v.R_nm1[b];
      const Vec3 u = t - (2.0 * v.t_n.row(b) - v.t_nm1.row(b)).transpose();
      D.block<3, 1>(6 * b, col) += inv_h2 * u;
      D.block<3, 3>(6 * b, col + 1) += inv_h2 * (v.R[b] - A);
      D.block<3, 3>(6 * b + 3, col + 1) -= inv_h2 * skew(u) * v.R[b];
      for (int k = 0; k < 6; ++k) {
        const Mat3 RSAt = v.R[b] * secondMomentBasis(k) * A.transpose();
        D.block<3, 1>(6 * b + 3, col + 4 + k) += inv_h2 * vee(RSAt - RSAt.transpose());
      }
    }
    // Gravity: [−M g; g × R m̄].
    D.block<3, 1>(6 * b, col) -= gravity;
    D.block<3, 3>(6 * b + 3, col + 1) += skew(gravity) * v.R[b];
  }
  if (v.tracking) {
    const auto sub = boneSubtrees(v.parents);
    for (int b = 0; b < v.num_bones; ++b) {
      const double scale = b == 0 ? v.options.root_stiffness : v.options.tracking_stiffness;
      Eigen::RowVectorXd dk = Eigen::RowVectorXd::Zero(kInertiaValues * v.num_bones);
      for (int c : sub[b]) {
        const Vec3 d = (v.J.row(c) - v.J.row(b)).transpose();
        const int col = kInertiaValues * c;
        dk[col] = scale * d.squaredNorm();
        dk.segment<3>(col + 1) = 2.0 * scale * d.transpose();
        dk.segment<3>(col + 4).setConstant(scale);  // tr(S) = S_xx + S_yy + S_zz
      }
      addTrackingColumns(v, b, dk, 0, D);
    }
    // Root position spring k_pos = root_stiffness · Σ M.
    const Vec3 d0 = v.t.row(0).transpose() - v.target_t0;
    for (int c = 0; c < v.num_bones; ++c)
      D.block<3, 1>(0, kInertiaValues * c) += v.options.root_stiffness * d0;
  }
  return D;
}

// w = R_p log(M R_targetᵀ), M = R_pᵀR_b; a target change exp(θ + δ) = exp([J_l(θ)δ]×) exp(θ)
// gives dw = −R_p J_l(e)⁻ᵀ J_l(θ) δ with e = log(M R_targetᵀ).
MatX poseTargetsJacobian(const SimulableParameterView& v) {
  MatX D = MatX::Zero(6 * v.num_bones, 3 * v.num_bones);
  if (!v.tracking) return D;
  const auto sub = boneSubtrees(v.parents);
  for (int b = 0; b < v.num_bones; ++b) {
    const int p = v.parents[b];
    const Mat3 R_p = p < 0 ? Mat3::Identity() : v.R[p];
    const double stiffness =
        (b == 0 ? v.options.root_stiffness : v.options.tracking_stiffness) *
        trackingMoment(v.J, v.inertia, v.options, sub[b], b);
    const Vec3 theta = logSO3(v.target_R[b]);
    const Vec3 e = logSO3(R_p.transpose() * v.R[b] * v.target_R[b].transpose());
    const Mat3 dw = -stiffness * R_p * leftJacobianInverseSO3(e).transpose() *
                    leftJacobianSO3(theta);
    D.block<3, 3>(6 * b + 3, 3 * b) += dw;
    if (p >= 0) D.block<3, 3>(6 * p + 3, 3 * b) -= dw;
  }
  return D;
}

MatX stiffnessesJacobian(const SimulableParameterView& v) {
  MatX D = MatX::Zero(6 * v.num_bones, 4);
  Vec12 g12;
  for (int b = 0; b < v.num_bones; ++b) {
    const int p = v.parents[b];
    if (p < 0) continue;
    jointSpringEnergy(v.t.row(p).transpose(), v.R[p], v.t.row(b).transpose(), v.R[b],
                      v.J.row(p).transpose(), v.J.row(b).transpose(), 1.0, &g12);
    D.block<6, 1>(6 * p, 0) += g12.head<6>();
    D.block<6, 1>(6 * b, 0) += g12.tail<6>();
  }
  if (v.tracking) {
    const auto sub = boneSubtrees(v.parents);
    for (int b = 0; b < v.num_bones; ++b) {
      Eigen::RowVectorXd dk = Eigen::RowVectorXd::Zero(1);
      dk[0] = trackingMoment(v.J, v.inertia, v.options, sub[b], b);
      addTrackingColumns(v, b, dk, b == 0 ? 2 : 1, D);
    }
    double mass = 0.0;
    for (const BoneInertia& in : v.inertia) mass += in.mass;
    D.block<3, 1>(0, 2) += mass * (v.t.row(0).transpose() - v.target_t0);
  }
  // Contact is linear in its stiffness: the node gradient at unit stiffness.
  const int n = int(v.candidates.size());
  if (n > 0) {
    ContactOptions unit = v.options.contact;
    unit.stiffness = 1.0;
    VecX gx = VecX::Zero(3 * n);
    colliderContactEnergy(v.contact_nodes, v.contact_areas, v.colliders, v.time, unit, &gx);
    for (int j = 0; j < n; ++j)
      if (!gx.segment<3>(3 * j).isZero(0.0)) addContactRows(v, j, gx.segment<3>(3 * j), 3, D);
  }
  return D;
}

// The contact energy depends on x − o_k for collider k: ∂g_x/∂o_k = −H_x,k.
MatX colliderOffsetsJacobian(const SimulableParameterView& v) {
  const int nc = int(v.colliders.size());
  MatX D = MatX::Zero(6 * v.num_bones, 3 * nc);
  for (int k = 0; k < nc; ++k) {
    const std::vector<Mat3> H = contactNodeHessians(v, {v.colliders[k]});
    for (size_t j = 0; j < H.size(); ++j)
      if (!H[j].isZero(0.0)) addContactRows(v, int(j), -H[j], 3 * k, D);
  }
  return D;
}

// ∂g/∂β = ∂g/∂J dJ/dβ + ∂g/∂I dI/dβ + the contact terms of the rest surface: X_i moves by
// shapedirs_i dβ, so the node by Σ_c w_ic R_c dX_i and y_ib = R_b(X_i − J_b) by R_b dX_i; the
// node gradient is linear in the vertex area a_i (∂g_x/∂a_i = g_x / a_i).
// The contact-surface part (X(β), a(β)) of ∂g/∂β; the J and inertia parts are chained by the
// callers from the RestJoints and BoneInertia Jacobians.
MatX shapeSurfaceJacobian(const SimulableParameterView& v) {
  MatX D = MatX::Zero(6 * v.num_bones, v.shapedirs.cols());
  const std::vector<Mat3> H = contactNodeHessians(v, v.colliders);
  for (size_t j = 0; j < v.candidates.size(); ++j) {
    const Vec3 gx = v.contact_gradient.segment<3>(3 * j);
    if (gx.isZero(0.0) && H[j].isZero(0.0)) continue;
    const int i = v.candidates[j];
    const auto S_i = v.shapedirs.middleRows<3>(3 * i);  // 3 × K
    Mat3 dx_dX = Mat3::Zero();
    for (int c = 0; c < v.num_bones; ++c) {
      const double w = v.weights(i, c);
      if (w == 0.0) continue;
      dx_dX += w * v.R[c];
      D.middleRows<3>(6 * c + 3) -= w * skew(gx) * v.R[c] * S_i;
    }
    MatX dgx = H[j] * dx_dX * S_i;
    if (v.contact_areas[j] > 0.0)
      dgx += (gx / v.contact_areas[j]) * v.areas_shape_jacobian.row(i);
    addContactRows(v, int(j), dgx, 0, D);
  }
  return D;
}

// ---- vector–Jacobian products: the formulas above contracted with λ, no matrices -----------

// λ of bone b: translation and rotation parts.
Vec3 lambdaT(const VecX& lambda, int b) { return lambda.segment<3>(6 * b); }
Vec3 lambdaW(const VecX& lambda, int b) { return lambda.segment<3>(6 * b + 3); }

// λ contracted with the unit tracking gradient of bone b (the row ∂g/∂k_b of addTrackingColumns).
double trackingWeight(const SimulableParameterView& v, const VecX& lambda, int b) {
  const Vec6 g = unitTracking(v, b);
  const int p = v.parents[b];
  double s = lambdaW(lambda, b).dot(g.tail<3>());
  if (p >= 0) s += lambdaW(lambda, p).dot(g.head<3>());
  return s;
}

// Node cotangent μ_j = Σ_b w_ib (λt_b + λω_b × y_ib) per candidate (3 each): addContactRows
// contracted with λ is μ_jᵀ dgx.
Vec3 contactNodeCotangent(const SimulableParameterView& v, const VecX& lambda, size_t j) {
  const int i = v.candidates[j];
  Vec3 m = Vec3::Zero();
  for (int b = 0; b < v.num_bones; ++b) {
    const double w = v.weights(i, b);
    if (w == 0.0) continue;
    const Vec3 y = v.R[b] * (v.X.row(i) - v.J.row(b)).transpose();
    m += w * (lambdaT(lambda, b) + lambdaW(lambda, b).cross(y));
  }
  return m;
}

double totalMass(const SimulableParameterView& v) {
  double mass = 0.0;
  for (const BoneInertia& in : v.inertia) mass += in.mass;
  return mass;
}

// Per-step shared data of the products: tracking weights, node cotangents, contact Hessians.
struct VJPContext {
  const SimulableParameterView& v;
  const VecX& lambda;
  std::vector<std::vector<int>> sub;
  std::vector<double> tracking;  // trackingWeight per bone (tracking only)
  VecX mu;
  std::vector<Mat3> H;  // exact node Hessians against all colliders
  VJPContext(const SimulableParameterView& view, const VecX& l) : v(view), lambda(l) {
    if (v.tracking) {
      sub = boneSubtrees(v.parents);
      tracking.resize(v.num_bones);
      for (int b = 0; b < v.num_bones; ++b) tracking[b] = trackingWeight(v, lambda, b);
    }
    H = contactNodeHessians(v, v.colliders);
    // Only touching candidates (non-zero node gradient or Hessian) enter the contact products.
    mu = VecX::Zero(3 * v.candidates.size());
    for (size_t j = 0; j < v.candidates.size(); ++j)
      if (!skip(j)) mu.segment<3>(3 * j) = contactNodeCotangent(v, lambda, j);
  }
  bool skip(size_t j) const {
    return v.contact_gradient.segment<3>(3 * j).isZero(0.0) && H[j].isZero(0.0);
  }
};

VecX restJointsVJP(const VJPContext& c) {
  const SimulableParameterView& v = c.v;
  const VecX& l = c.lambda;
  VecX out = VecX::Zero(3 * v.num_bones);
  const double kj = v.options.joint_stiffness;
  for (int b = 0; b < v.num_bones; ++b) {
    const int p = v.parents[b];
    if (p < 0) continue;
    const Vec3 y = v.R[p] * (v.J.row(b) - v.J.row(p)).transpose();
    const Vec3 d = y + v.t.row(p).transpose() - v.t.row(b).transpose();
    // (kj R_p)ᵀ (λt_p − λt_b) + (kj [y − d]× R_p)ᵀ λω_p, +J_b and −J_p.
    const Vec3 w = kj * v.R[p].transpose() *
                   (lambdaT(l, p) - lambdaT(l, b) - (y - d).cross(lambdaW(l, p)));
    out.segment<3>(3 * b) += w;
    out.segment<3>(3 * p) -= w;
  }
  if (v.tracking) {
    for (int b = 0; b < v.num_bones; ++b) {
      const double scale = b == 0 ? v.options.root_stiffness : v.options.tracking_stiffness;
      const double s = scale * c.tracking[b];
      for (int k : c.sub[b]) {
        const Vec3 d = (v.J.row(k) - v.J.row(b)).transpose();
        const Vec3 dI = 2.0 * s * (v.inertia[k].first_moment + v.inertia[k].mass * d);
        out.segment<3>(3 * k) += dI;
        out.segment<3>(3 * b) -= dI;
      }
    }
    out.head<3>() -= v.options.root_stiffness * totalMass(v) * lambdaT(l, 0);
  }
  for (size_t j = 0; j < v.candidates.size(); ++j) {
    if (c.skip(j)) continue;
    const int i = v.candidates[j];
    const Vec3 gx = v.contact_gradient.segment<3>(3 * j);
    const Vec3 Hmu = c.H[j] * c.mu.segment<3>(3 * j);
    for (int k = 0; k < v.num_bones; ++k) {
      const double w = v.weights(i, k);
      if (w == 0.0) continue;
      out.segment<3>(3 * k) += w * v.R[k].transpose() * (lambdaW(l, k).cross(gx) - Hmu);
    }
  }
  return out;
}

VecX boneInertiaVJP(const VJPContext& c) {
  const SimulableParameterView& v = c.v;
  const VecX& l = c.lambda;
  VecX out = VecX::Zero(kInertiaValues * v.num_bones);
  const double inv_h2 = 1.0 / (v.options.time_step * v.options.time_step);
  const Vec3& gravity = v.options.gravity;
  for (int b = 0; b < v.num_bones; ++b) {
    const int col = kInertiaValues * b;
    const Vec3 lt = lambdaT(l, b), lw = lambdaW(l, b);
    if (!v.is_static) {
      const Mat3 A = 2.0 * v.R_n[b] - v.R_nm1[b];
      const Vec3 u = v.t.row(b).transpose() - (2.0 * v.t_n.row(b) - v.t_nm1.row(b)).transpose();
      out[col] += inv_h2 * u.dot(lt);
      out.segment<3>(col + 1) +=
          inv_h2 * ((v.R[b] - A).transpose() * lt + v.R[b].transpose() * u.cross(lw));
      for (int k = 0; k < 6; ++k) {
        const Mat3 RSAt = v.R[b] * secondMomentBasis(k) * A.transpose();
        out[col + 4 + k] += inv_h2 * lw.dot(vee(RSAt - RSAt.transpose()));
      }
    }
    out[col] -= gravity.dot(lt);
    out.segment<3>(col + 1) += v.R[b].transpose() * lw.cross(gravity);
  }
  if (v.tracking) {
    for (int b = 0; b < v.num_bones; ++b) {
      const double scale = b == 0 ? v.options.root_stiffness : v.options.tracking_stiffness;
      const double s = scale * c.tracking[b];
      for (int k : c.sub[b]) {
        const Vec3 d = (v.J.row(k) - v.J.row(b)).transpose();
        const int col = kInertiaValues * k;
        out[col] += s * d.squaredNorm();
        out.segment<3>(col + 1) += 2.0 * s * d;
        out.segment<3>(col + 4).array() += s;  // tr(S)
      }
    }
    const double root = v.options.root_stiffness *
                        (v.t.row(0).transpose() - v.target_t0).dot(lambdaT(l, 0));
    for (int k = 0; k < v.num_bones; ++k) out[kInertiaValues * k] += root;
  }
  return out;
}

VecX poseTargetsVJP(const VJPContext& c) {
  const SimulableParameterView& v = c.v;
  VecX out = VecX::Zero(3 * v.num_bones);
  if (!v.tracking) return out;
  for (int b = 0; b < v.num_bones; ++b) {
    const int p = v.parents[b];
    const Mat3 R_p = p < 0 ? Mat3::Identity() : v.R[p];
    const double stiffness =
        (b == 0 ? v.options.root_stiffness : v.options.tracking_stiffness) *
        trackingMoment(v.J, v.inertia, v.options, c.sub[b], b);
    const Vec3 theta = logSO3(v.target_R[b]);
    const Vec3 e = logSO3(R_p.transpose() * v.R[b] * v.target_R[b].transpose());
    const Mat3 dw = -stiffness * R_p * leftJacobianInverseSO3(e).transpose() *
                    leftJacobianSO3(theta);
    Vec3 lw = lambdaW(c.lambda, b);
    if (p >= 0) lw -= lambdaW(c.lambda, p);
    out.segment<3>(3 * b) = dw.transpose() * lw;
  }
  return out;
}

VecX stiffnessesVJP(const VJPContext& c) {
  const SimulableParameterView& v = c.v;
  const VecX& l = c.lambda;
  VecX out = VecX::Zero(4);
  Vec12 g12;
  for (int b = 0; b < v.num_bones; ++b) {
    const int p = v.parents[b];
    if (p < 0) continue;
    jointSpringEnergy(v.t.row(p).transpose(), v.R[p], v.t.row(b).transpose(), v.R[b],
                      v.J.row(p).transpose(), v.J.row(b).transpose(), 1.0, &g12);
    out[0] += g12.head<6>().dot(l.segment<6>(6 * p)) + g12.tail<6>().dot(l.segment<6>(6 * b));
  }
  if (v.tracking) {
    for (int b = 0; b < v.num_bones; ++b)
      out[b == 0 ? 2 : 1] += trackingMoment(v.J, v.inertia, v.options, c.sub[b], b) * c.tracking[b];
    out[2] += totalMass(v) * (v.t.row(0).transpose() - v.target_t0).dot(lambdaT(l, 0));
  }
  const int n = int(v.candidates.size());
  if (n > 0) {
    ContactOptions unit = v.options.contact;
    unit.stiffness = 1.0;
    VecX gx = VecX::Zero(3 * n);
    colliderContactEnergy(v.contact_nodes, v.contact_areas, v.colliders, v.time, unit, &gx);
    for (int j = 0; j < n; ++j) {
      const Vec3 g = gx.segment<3>(3 * j);
      if (g.isZero(0.0)) continue;
      // A zero contact stiffness leaves g_x = 0 (skipped in μ) but not the unit gradient.
      out[3] += g.dot(c.skip(j) ? contactNodeCotangent(v, c.lambda, j)
                                : Vec3(c.mu.segment<3>(3 * j)));
    }
  }
  return out;
}

VecX colliderOffsetsVJP(const VJPContext& c) {
  const SimulableParameterView& v = c.v;
  const int nc = int(v.colliders.size());
  VecX out = VecX::Zero(3 * nc);
  if (v.candidates.empty()) return out;
  if (nc == 1) {  // the all-collider Hessians are this collider's
    for (size_t j = 0; j < c.H.size(); ++j) out -= c.H[j] * c.mu.segment<3>(3 * j);
    return out;
  }
  for (int k = 0; k < nc; ++k) {
    const std::vector<Mat3> H = contactNodeHessians(v, {v.colliders[k]});
    for (size_t j = 0; j < H.size(); ++j) {
      if (H[j].isZero(0.0)) continue;
      const Vec3 mu = c.skip(j) ? contactNodeCotangent(v, c.lambda, j) : Vec3(c.mu.segment<3>(3 * j));
      out.segment<3>(3 * k) -= H[j] * mu;
    }
  }
  return out;
}

VecX shapeSurfaceVJP(const VJPContext& c) {
  const SimulableParameterView& v = c.v;
  VecX out = VecX::Zero(v.shapedirs.cols());
  for (size_t j = 0; j < v.candidates.size(); ++j) {
    if (c.skip(j)) continue;
    const int i = v.candidates[j];
    const Vec3 gx = v.contact_gradient.segment<3>(3 * j);
    const Vec3 mu = c.mu.segment<3>(3 * j);
    Mat3 dx_dX = Mat3::Zero();
    Vec3 turn = Vec3::Zero();  // Σ_c w R_cᵀ (λω_c × g_x): the rotating lever arms
    for (int k = 0; k < v.num_bones; ++k) {
      const double w = v.weights(i, k);
      if (w == 0.0) continue;
      dx_dX += w * v.R[k];
      turn += w * v.R[k].transpose() * lambdaW(c.lambda, k).cross(gx);
    }
    const Vec3 node = dx_dX.transpose() * (c.H[j] * mu) - turn;
    out.noalias() += v.shapedirs.middleRows<3>(3 * i).transpose().lazyProduct(node);
    if (v.contact_areas[j] > 0.0)
      out += (gx.dot(mu) / v.contact_areas[j]) * v.areas_shape_jacobian.row(i).transpose();
  }
  return out;
}

}  // namespace

std::vector<MatX> gradientParameterJacobians(const SimulableParameterView& v,
                                             const std::vector<SimParameter>& groups,
                                             bool shape_surface_only) {
  // RestJoints and BoneInertia are computed once even when Shape chains them too.
  MatX joints, inertia;
  bool have_joints = false, have_inertia = false;
  auto jointsJacobian = [&]() -> const MatX& {
    if (!have_joints) joints = restJointsJacobian(v), have_joints = true;
    return joints;
  };
  auto inertiaJacobian = [&]() -> const MatX& {
    if (!have_inertia) inertia = boneInertiaJacobian(v), have_inertia = true;
    return inertia;
  };
  std::vector<MatX> out;
  out.reserve(groups.size());
  for (SimParameter p : groups) {
    switch (p) {
      case SimParameter::RestJoints: out.push_back(jointsJacobian()); break;
      case SimParameter::BoneInertia: out.push_back(inertiaJacobian()); break;
      case SimParameter::Shape:
        if (shape_surface_only) {
          out.push_back(shapeSurfaceJacobian(v));
          break;
        }
        out.push_back(jointsJacobian() * v.joints_shape_jacobian +
                      inertiaJacobian() * v.inertia_shape_jacobian + shapeSurfaceJacobian(v));
        break;
      default: out.push_back(gradientParameterJacobian(v, p));
    }
  }
  return out;
}

int simParameterSize(SimParameter p, int num_colliders, int num_betas) {
  switch (p) {
    case SimParameter::RestJoints: return 3 * kNumJoints;
    case SimParameter::BoneInertia: return kInertiaValues * kNumJoints;
    case SimParameter::PoseTargets: return 3 * kNumJoints;
    case SimParameter::RootTranslationTarget: return 3;
    case SimParameter::Stiffnesses: return 4;
    case SimParameter::ColliderOffsets: return 3 * num_colliders;
    case SimParameter::Shape: return num_betas;
  }
  throw InputError("SimParameter: unknown parameter group " + std::to_string(int(p)));
}

MatX gradientParameterJacobian(const SimulableParameterView& v, SimParameter p) {
  switch (p) {
    case SimParameter::RestJoints: return restJointsJacobian(v);
    case SimParameter::BoneInertia: return boneInertiaJacobian(v);
    case SimParameter::PoseTargets: return poseTargetsJacobian(v);
    case SimParameter::RootTranslationTarget: {
      MatX D = MatX::Zero(6 * v.num_bones, 3);
      if (v.tracking) {
        double mass = 0.0;
        for (const BoneInertia& in : v.inertia) mass += in.mass;
        D.topRows<3>() = -v.options.root_stiffness * mass * Mat3::Identity();
      }
      return D;
    }
    case SimParameter::Stiffnesses: return stiffnessesJacobian(v);
    case SimParameter::ColliderOffsets: return colliderOffsetsJacobian(v);
    case SimParameter::Shape: return gradientParameterJacobians(v, {p}).front();
  }
  throw InputError("SimParameter: unknown parameter group " + std::to_string(int(p)));
}

MatX gradientPreviousStateJacobian(const SimulableParameterView& v, int which) {
  if (which != 1 && which != 2)
    throw InputError("Simulable::getGradientPreviousStateJacobian: which = " +
                     std::to_string(which) + ", expected 1 (q_n) or 2 (q_{n-1})");
  MatX D = MatX::Zero(6 * v.num_bones, 6 * v.num_bones);
  if (v.is_static) return D;
  Mat6 block;
  for (int b = 0; b < v.num_bones; ++b) {
    rigidInertiaGradientPreviousStates(v.t.row(b).transpose(), v.R[b], v.t_n.row(b).transpose(),
                                       v.R_n[b], v.t_nm1.row(b).transpose(), v.R_nm1[b],
                                       v.inertia[b], v.options.time_step,
                                       which == 1 ? &block : nullptr,
                                       which == 2 ? &block : nullptr);
    D.block<6, 6>(6 * b, 6 * b) = block;
  }
  return D;
}

}  // namespace flsh::detail

namespace flsh::detail {

std::vector<VecX> gradientParameterVJPs(const SimulableParameterView& v, const VecX& lambda,
                                        const std::vector<SimParameter>& groups,
                                        bool shape_surface_only) {
  if (lambda.size() != 6 * v.num_bones)
    throw InputError("Simulable::getGradientParameterVJPs: lambda has " +
                     std::to_string(lambda.size()) + " values, expected numDofs() = " +
                     std::to_string(6 * v.num_bones));
  const VJPContext c(v, lambda);
  VecX joints, inertia;
  auto jointsVJP = [&]() -> const VecX& {
    if (joints.size() == 0) joints = restJointsVJP(c);
    return joints;
  };
  auto inertiaVJP = [&]() -> const VecX& {
    if (inertia.size() == 0) inertia = boneInertiaVJP(c);
    return inertia;
  };
  std::vector<VecX> out;
  out.reserve(groups.size());
  for (SimParameter p : groups) {
    switch (p) {
      case SimParameter::RestJoints: out.push_back(jointsVJP()); break;
      case SimParameter::BoneInertia: out.push_back(inertiaVJP()); break;
      case SimParameter::PoseTargets: out.push_back(poseTargetsVJP(c)); break;
      case SimParameter::RootTranslationTarget:
        out.push_back(v.tracking ? VecX(-v.options.root_stiffness * totalMass(v) *
                                        lambdaT(lambda, 0))
                                 : VecX(VecX::Zero(3)));
        break;
      case SimParameter::Stiffnesses: out.push_back(stiffnessesVJP(c)); break;
      case SimParameter::ColliderOffsets: out.push_back(colliderOffsetsVJP(c)); break;
      case SimParameter::Shape: {
        VecX shape = shapeSurfaceVJP(c);
        if (!shape_surface_only) {
          shape.noalias() += v.joints_shape_jacobian.transpose() * jointsVJP();
          shape.noalias() += v.inertia_shape_jacobian.transpose() * inertiaVJP();
        }
        out.push_back(std::move(shape));
        break;
      }
      default:
        throw InputError("SimParameter: unknown parameter group " + std::to_string(int(p)));
    }
  }
  return out;
}

namespace {

void checkPreviousStateVector(const SimulableParameterView& v, const VecX& x, const char* who,
                              const char* name) {
  if (x.size() != 6 * v.num_bones)
    throw InputError(std::string("Simulable::") + who + ": " + name + " has " +
                     std::to_string(x.size()) + " values, expected numDofs() = " +
                     std::to_string(6 * v.num_bones));
}

// Bone b's inertia blocks ∂g_b/∂q_n,b and ∂g_b/∂q_{n−1},b (6 × 6 each).
void inertiaPreviousBlocks(const SimulableParameterView& v, int b, Mat6& G1, Mat6& G2) {
  rigidInertiaGradientPreviousStates(v.t.row(b).transpose(), v.R[b], v.t_n.row(b).transpose(),
                                     v.R_n[b], v.t_nm1.row(b).transpose(), v.R_nm1[b],
                                     v.inertia[b], v.options.time_step, &G1, &G2);
}

}  // namespace

void gradientPreviousStatesVJP(const SimulableParameterView& v, const VecX& lambda, VecX* a_n,
                               VecX* a_nm1) {
  checkPreviousStateVector(v, lambda, "getGradientPreviousStatesVJP", "lambda");
  if (a_n) a_n->setZero(lambda.size());
  if (a_nm1) a_nm1->setZero(lambda.size());
  if (v.is_static) return;
  Mat6 G1, G2;
  for (int b = 0; b < v.num_bones; ++b) {
    inertiaPreviousBlocks(v, b, G1, G2);
    const Vec6 l = lambda.segment<6>(6 * b);
    if (a_n) a_n->segment<6>(6 * b).noalias() = G1.transpose() * l;
    if (a_nm1) a_nm1->segment<6>(6 * b).noalias() = G2.transpose() * l;
  }
}

VecX gradientPreviousStatesJVP(const SimulableParameterView& v, const VecX& dq_n,
                               const VecX& dq_nm1) {
  checkPreviousStateVector(v, dq_n, "getGradientPreviousStatesJVP", "dq_n");
  checkPreviousStateVector(v, dq_nm1, "getGradientPreviousStatesJVP", "dq_nm1");
  VecX out = VecX::Zero(dq_n.size());
  if (v.is_static) return out;
  Mat6 G1, G2;
  for (int b = 0; b < v.num_bones; ++b) {
    inertiaPreviousBlocks(v, b, G1, G2);
    out.segment<6>(6 * b).noalias() =
        G1 * dq_n.segment<6>(6 * b) + G2 * dq_nm1.segment<6>(6 * b);
  }
  return out;
}

}  // namespace flsh::detail
