#include "sim/terms/tracking_spring_term.h"

#include "flsh/core/rotation.h"
#include "flsh/energy/skeleton_energies.h"
#include "sim/hessian_blocks.h"
#include "sim/terms/term_blocks.h"

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
// (root: parent I), so ∂g/∂k_b = u_b, and a parameter x that moves k_b by ∂k_b/∂x gives the
// blocks u ∂k_b/∂x on the rotation rows of b and of its parent. k_b = scale · I_b: ∂I_b/∂J_c =
// 2(m̄_c + M_c d) for c in the subtree, minus their sum for J_b; ∂I_b/∂(M_c, m̄_c, S_c) = (‖d‖²,
// 2d, tr). The root position spring k_pos (t_0 − (J_0 + trans)) gives −k_pos I for J_0 and the
// target, and (t_0 − target) ∂k_pos/∂M_c. The target rotation exp(θ + δ) = exp([J_l(θ)δ]×)
// exp(θ) moves the rotation gradient w = k R_p log(R_pᵀR_b R_targetᵀ) by −k R_p J_l(e)⁻ᵀ J_l(θ) δ,
// e = log(R_pᵀR_b R_targetᵀ).
template <class Sink>
void TrackingSpringTerm::parameterBlocks(const TermContext& c, Sink& sink) const {
  const bool joints = sink.wants(SimParameter::RestJoints);
  const bool inertia = sink.wants(SimParameter::BoneInertia);
  const bool targets = sink.wants(SimParameter::PoseTargets);
  const bool root_target = sink.wants(SimParameter::RootTranslationTarget);
  const bool stiffnesses = sink.wants(SimParameter::Stiffnesses);
  if (!c.tracking || !(joints || inertia || targets || root_target || stiffnesses)) return;
  const int n = c.num_bones;
  const SimulableOptions& o = c.options;
  const Vec3 root_gap = c.t.row(0).transpose() - c.target_t0;
  const Mat3 root_pull = -c.root_k_pos * Mat3::Identity();  // ∂g_t,0/∂J_0 and ∂/∂target
  Vec6 u;
  for (int b = 0; b < n; ++b) {
    const int p = c.parents[b];
    trackingSpringEnergy(p < 0 ? Mat3::Identity() : c.R[p], c.R[b], c.target_R[b], 1.0, &u);
    // ∂g/∂x = u ∂k_b/∂x for a row dk = ∂k_b/∂x (1 × cols) at parameter `param` (rank one).
    const auto stiffnessBlocks = [&](SimParameter group, int param, const auto& dk) {
      sink.add(group, rotationRow(b), param, u.tail<3>(), dk);
      if (p >= 0) sink.add(group, rotationRow(p), param, u.head<3>(), dk);
    };
    const double scale = b == 0 ? o.root_stiffness : o.tracking_stiffness;
    if (joints || inertia) {
      Vec3 sum = Vec3::Zero();  // −∂I_b/∂J_b
      Eigen::Matrix<double, 1, kBoneInertiaValues> dI = decltype(dI)::Zero();
      for (int k : subtrees_[b]) {
        const Vec3 d = (c.J.row(k) - c.J.row(b)).transpose();
        const BoneInertia& in = c.inertia[k];
        if (joints) {
          const Vec3 dJ = 2.0 * (in.first_moment + in.mass * d);
          sum += dJ;
          stiffnessBlocks(SimParameter::RestJoints, 3 * k, scale * dJ.transpose());
        }
        if (inertia) {
          dI(0) = d.squaredNorm();
          dI.segment<3>(1) = 2.0 * d.transpose();
          dI.segment<3>(4).setOnes();  // tr(S) = S_xx + S_yy + S_zz
          stiffnessBlocks(SimParameter::BoneInertia, kBoneInertiaValues * k, scale * dI);
        }
      }
      if (joints) stiffnessBlocks(SimParameter::RestJoints, 3 * b, -scale * sum.transpose());
    }
    if (inertia)  // k_pos = root_stiffness · Σ M_k
      sink.add(SimParameter::BoneInertia, translationRow(0), kBoneInertiaValues * b,
               o.root_stiffness * root_gap);
    if (targets) {
      const Mat3 R_p = p < 0 ? Mat3::Identity() : c.R[p];
      const double stiffness = scale * trackingMoment(c.J, c.inertia, o, subtrees_[b], b);
      const Vec3 theta = logSO3(c.target_R[b]);
      const Vec3 e = logSO3(R_p.transpose() * c.R[b] * c.target_R[b].transpose());
      const Mat3 dw =
          -stiffness * R_p * leftJacobianInverseSO3(e).transpose() * leftJacobianSO3(theta);
      sink.add(SimParameter::PoseTargets, rotationRow(b), 3 * b, dw);
      if (p >= 0) sink.add(SimParameter::PoseTargets, rotationRow(p), 3 * b, -dw);
    }
    if (stiffnesses) {
      const double moment = trackingMoment(c.J, c.inertia, o, subtrees_[b], b);
      stiffnessBlocks(SimParameter::Stiffnesses, b == 0 ? 2 : 1,
                      Eigen::Matrix<double, 1, 1>(moment));
    }
  }
  if (joints) sink.add(SimParameter::RestJoints, translationRow(0), 0, root_pull);
  if (root_target) sink.add(SimParameter::RootTranslationTarget, translationRow(0), 0, root_pull);
  if (stiffnesses)
    sink.add(SimParameter::Stiffnesses, translationRow(0), 2, totalMass(c.inertia) * root_gap);
}

}  // namespace flsh::detail

template class flsh::TermWithParameterBlocks<flsh::detail::TrackingSpringTerm>;
