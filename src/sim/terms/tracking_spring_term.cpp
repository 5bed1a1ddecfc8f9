#include "sim/terms/tracking_spring_term.h"

#include "flsh/core/rotation.h"
#include "flsh/sim/skeleton_energies.h"
#include "sim/hessian_blocks.h"
#include "sim/terms/term_products.h"

namespace flsh::detail {

std::vector<std::vector<int>> boneSubtrees(const std::vector<int>& parents) {
  std::vector<std::vector<int>> sub(parents.size());
  for (int c = 0; c < int(parents.size()); ++c)
    for (int b = c; b >= 0; b = parents[size_t(b)]) sub[size_t(b)].push_back(c);
  return sub;
}

double totalMass(const std::vector<BoneInertia>& inertia) {
  double mass = 0.0;
  for (const BoneInertia& in : inertia) mass += in.mass;
  return mass;
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

TrackingSpringTerm::TrackingSpringTerm(const std::vector<int>& parents)
    : subtrees_(boneSubtrees(parents)) {}

void TrackingSpringTerm::stiffnesses(const MatX3& J, const std::vector<BoneInertia>& inertia,
                                     const SimulableOptions& options,
                                     std::vector<double>& tracking_k, double& root_k_pos,
                                     double& root_k_rot) const {
  const int n = int(subtrees_.size());
  tracking_k.assign(n, 0.0);
  for (int b = 1; b < n; ++b)
    tracking_k[b] =
        options.tracking_stiffness * trackingMoment(J, inertia, options, subtrees_[b], b);
  root_k_pos = options.root_stiffness * totalMass(inertia);
  root_k_rot = options.root_stiffness * trackingMoment(J, inertia, options, subtrees_[0], 0);
}

double TrackingSpringTerm::evaluate(const TermContext& c, VecX* g, int offset) const {
  if (!c.tracking) return 0.0;
  double E = 0.0;
  Vec6 g6;
  for (int b = 0; b < c.num_bones; ++b) {
    const int p = c.parents[b];
    const int ib = offset + 6 * b;
    if (p < 0) {
      E += rootSpringEnergy(c.t.row(b).transpose(), c.R[b], c.target_t0, c.target_R[b],
                            c.root_k_pos, c.root_k_rot, g ? &g6 : nullptr);
      if (g) g->segment<6>(ib) += g6;
      continue;
    }
    E += trackingSpringEnergy(c.R[p], c.R[b], c.target_R[b], c.tracking_k[b], g ? &g6 : nullptr);
    if (!g) continue;
    g->segment<3>(offset + 6 * p + 3) += g6.head<3>();
    g->segment<3>(ib + 3) += g6.tail<3>();
  }
  return E;
}

void TrackingSpringTerm::addHessian(const TermContext& c, std::vector<Triplet>& H, int offset,
                                    bool psd) const {
  if (!c.tracking) return;
  Mat6 H6;
  for (int b = 0; b < c.num_bones; ++b) {
    const int p = c.parents[b];
    const int ib = offset + 6 * b;
    if (p < 0) {
      rootSpringEnergy(c.t.row(b).transpose(), c.R[b], c.target_t0, c.target_R[b], c.root_k_pos,
                       c.root_k_rot, nullptr, &H6, psd);
      addBlock(H, ib, ib, H6);
      continue;
    }
    const int ip = offset + 6 * p;
    trackingSpringEnergy(c.R[p], c.R[b], c.target_R[b], c.tracking_k[b], nullptr, &H6, psd);
    addBlock(H, ip + 3, ip + 3, H6.topLeftCorner<3, 3>());
    addBlock(H, ip + 3, ib + 3, H6.topRightCorner<3, 3>());
    addBlock(H, ib + 3, ip + 3, H6.bottomLeftCorner<3, 3>());
    addBlock(H, ib + 3, ib + 3, H6.bottomRightCorner<3, 3>());
  }
}

// With unit stiffness the rotation gradient of spring b is u_b = [u_p; u_b] over [δω_p, δω_b]
// (root: parent I), so ∂g/∂k_b = u_b and every parameter that moves k_b enters through the
// weight s_b = λᵀ u_b (1 × m). k_b = scale · I_b: ∂I_b/∂J_c = 2(m̄_c + M_c d) for c in the
// subtree, minus their sum for J_b; ∂I_b/∂(M_c, m̄_c, S_c) = (‖d‖², 2d, tr). The root position
// spring k_pos (t_0 − (J_0 + trans)) adds −k_pos λt_0 to J_0 and the target, and M's share.
// The target rotation exp(θ + δ) = exp([J_l(θ)δ]×) exp(θ) moves the rotation gradient
// w = k R_p log(R_pᵀR_b R_targetᵀ) by −k R_p J_l(e)⁻ᵀ J_l(θ) δ, e = log(R_pᵀR_b R_targetᵀ).
template <class Lambda, class Block>
void TrackingSpringTerm::products(const TermContext& c, const Lambda& l,
                                  ParameterProducts<Block>& out) const {
  if (!c.tracking ||
      !(out.wants(SimParameter::RestJoints) || out.wants(SimParameter::BoneInertia) ||
        out.wants(SimParameter::PoseTargets) || out.wants(SimParameter::RootTranslationTarget) ||
        out.wants(SimParameter::Stiffnesses)))
    return;
  const int n = c.num_bones;
  const SimulableOptions& o = c.options;
  const auto scaleOf = [&](int b) { return b == 0 ? o.root_stiffness : o.tracking_stiffness; };
  const auto momentOf = [&](int b) { return trackingMoment(c.J, c.inertia, o, subtrees_[b], b); };
  std::vector<RowOf<Lambda>> weight(static_cast<size_t>(n));
  Vec6 u;
  for (int b = 0; b < n; ++b) {
    const int p = c.parents[b];
    trackingSpringEnergy(p < 0 ? Mat3::Identity() : c.R[p], c.R[b], c.target_R[b], 1.0, &u);
    weight[b] = u.tail<3>().transpose() * lambdaW(l, b);
    if (p >= 0) weight[b] += u.head<3>().transpose() * lambdaW(l, p);
  }
  const Vec3 root_gap = c.t.row(0).transpose() - c.target_t0;
  const RowOf<Lambda> root_pull = root_gap.transpose() * lambdaT(l, 0);
  if (out.wants(SimParameter::RestJoints)) {
    Block& D = out[SimParameter::RestJoints];
    for (int b = 0; b < n; ++b) {
      const RowOf<Lambda> s = scaleOf(b) * weight[b];
      for (int k : subtrees_[b]) {
        const Vec3 d = (c.J.row(k) - c.J.row(b)).transpose();
        const Vec3 dI = 2.0 * (c.inertia[k].first_moment + c.inertia[k].mass * d);
        D.template middleRows<3>(3 * k) += dI * s;
        D.template middleRows<3>(3 * b) -= dI * s;
      }
    }
    D.template topRows<3>() -= c.root_k_pos * lambdaT(l, 0);
  }
  if (out.wants(SimParameter::BoneInertia)) {
    Block& D = out[SimParameter::BoneInertia];
    for (int b = 0; b < n; ++b) {
      const RowOf<Lambda> s = scaleOf(b) * weight[b];
      for (int k : subtrees_[b]) {
        const Vec3 d = (c.J.row(k) - c.J.row(b)).transpose();
        const int col = kBoneInertiaValues * k;
        D.row(col) += d.squaredNorm() * s;
        D.template middleRows<3>(col + 1) += 2.0 * d * s;
        for (int e = 0; e < 3; ++e) D.row(col + 4 + e) += s;  // tr(S) = S_xx + S_yy + S_zz
      }
    }
    for (int k = 0; k < n; ++k) D.row(kBoneInertiaValues * k) += o.root_stiffness * root_pull;
  }
  if (out.wants(SimParameter::PoseTargets)) {
    Block& D = out[SimParameter::PoseTargets];
    for (int b = 0; b < n; ++b) {
      const int p = c.parents[b];
      const Mat3 R_p = p < 0 ? Mat3::Identity() : c.R[p];
      const double stiffness = scaleOf(b) * momentOf(b);
      const Vec3 theta = logSO3(c.target_R[b]);
      const Vec3 e = logSO3(R_p.transpose() * c.R[b] * c.target_R[b].transpose());
      const Mat3 dw =
          -stiffness * R_p * leftJacobianInverseSO3(e).transpose() * leftJacobianSO3(theta);
      Rows3Of<Lambda> lw = lambdaW(l, b);
      if (p >= 0) lw -= lambdaW(l, p);
      D.template middleRows<3>(3 * b) += dw.transpose() * lw;
    }
  }
  if (out.wants(SimParameter::RootTranslationTarget))
    out[SimParameter::RootTranslationTarget] -= c.root_k_pos * lambdaT(l, 0);
  if (out.wants(SimParameter::Stiffnesses)) {
    Block& D = out[SimParameter::Stiffnesses];
    for (int b = 0; b < n; ++b) D.row(b == 0 ? 2 : 1) += momentOf(b) * weight[b];
    D.row(2) += totalMass(c.inertia) * root_pull;
  }
}

template void TrackingSpringTerm::products(const TermContext&, const VecX&,
                                           ParameterProducts<VecX>&) const;
template void TrackingSpringTerm::products(const TermContext&, const MatX&,
                                           ParameterProducts<MatX>&) const;

}  // namespace flsh::detail
