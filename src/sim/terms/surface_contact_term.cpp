#include "sim/terms/surface_contact_term.h"

#include "flsh/body/smpl_skeleton.h"
#include "flsh/contact/contact_energy.h"
#include "flsh/core/rotation.h"
#include "flsh/sim/skeleton_energies.h"
#include "sim/terms/term_products.h"

namespace flsh::detail {

namespace {

using Influence = SparseSkinWeights::Influence;

// y_ib = R_b (X_i − J_b): vertex i's lever arm on bone b.
Vec3 leverArm(const TermContext& c, int i, int b) {
  return c.R[b] * (c.avatar.restVertices().row(i) - c.J.row(b)).transpose();
}

// Exact contact node Hessians (3 × 3 per candidate) against the given colliders.
std::vector<Mat3> nodeHessians(const TermContext& c, const std::vector<Collider>& colliders) {
  const SurfaceContactState& s = c.contact;
  const int n = int(s.candidates.size());
  std::vector<Mat3> H(size_t(n), Mat3::Zero());
  if (n == 0) return H;
  ContactOptions options = c.options.contact;
  options.exact_hessian = true;
  std::vector<Triplet> triplets;
  colliderContactEnergy(s.nodes, s.areas, colliders, c.time, options, nullptr, &triplets, 0,
                        nullptr);
  for (const Triplet& e : triplets) {
    const int j = e.row() / 3;
    H[size_t(j)](e.row() - 3 * j, e.col() - 3 * j) += e.value();
  }
  return H;
}

}  // namespace

SurfaceContactTerm::SurfaceContactTerm(int num_bones) : pair_blocks_(num_bones) {}

double SurfaceContactTerm::evaluate(const TermContext& c, VecX* g, int offset) const {
  const SurfaceContactState& s = c.contact;
  if (!g) return s.energy;
  for (size_t j = 0; j < s.candidates.size(); ++j) {
    const Vec3 gx = s.gradient.segment<3>(3 * j);
    if (gx.isZero(0.0)) continue;
    const int i = s.candidates[j];
    for (int k = c.skin.start[i]; k < c.skin.start[i + 1]; ++k) {
      const int b = c.skin.entries[k].bone;
      const double w = c.skin.entries[k].weight;
      const Vec3 y = leverArm(c, i, b);
      g->segment<3>(offset + 6 * b) += w * gx;
      g->segment<3>(offset + 6 * b + 3) += w * y.cross(gx);
    }
  }
  return s.energy;
}

void SurfaceContactTerm::addHessian(const TermContext& c, std::vector<Triplet>& H, int offset,
                                    bool psd) const {
  const SurfaceContactState& s = c.contact;
  if (s.active == 0) return;
  ContactOptions contact_options = c.options.contact;
  contact_options.exact_hessian = !psd;
  node_hessian_.clear();
  colliderContactEnergy(s.nodes, s.areas, c.colliders, c.time, contact_options, nullptr,
                        &node_hessian_, 0, nullptr);
  // colliderContactEnergy emits 9 consecutive triplets (one 3 × 3 block) per active pair.
  Eigen::Matrix<double, 3, 6> Jb[kNumJoints];
  int bones[kNumJoints];
  for (size_t start = 0; start + 9 <= node_hessian_.size(); start += 9) {
    const int j = node_hessian_[start].row() / 3;
    Mat3 Hx;
    for (int e = 0; e < 9; ++e) {
      const Triplet& t = node_hessian_[start + e];
      Hx(t.row() - 3 * j, t.col() - 3 * j) = t.value();
    }
    const int i = s.candidates[size_t(j)];
    const int count = c.skin.start[i + 1] - c.skin.start[i];
    for (int a = 0; a < count; ++a) {
      const Influence& inf = c.skin.entries[size_t(c.skin.start[i] + a)];
      const Vec3 y = leverArm(c, i, inf.bone);
      bones[a] = inf.bone;
      Jb[a].leftCols<3>() = inf.weight * Mat3::Identity();
      Jb[a].rightCols<3>() = -inf.weight * skew(y);
    }
    for (int a = 0; a < count; ++a) {
      const Eigen::Matrix<double, 6, 3> JaT_H = Jb[a].transpose() * Hx;
      for (int b = 0; b < count; ++b) pair_blocks_.block(bones[a], bones[b]) += JaT_H * Jb[b];
    }
  }
  // Curvature of the rotating contact points, summed per bone (Σ_i w_ib g_i·∂²y_ib); the PSD
  // form keeps its projection on the PSD cone (the stabilizing part) instead of dropping it.
  Mat3 curvature[kNumJoints];
  bool has_curvature[kNumJoints] = {};
  for (size_t j = 0; j < s.candidates.size(); ++j) {
    const Vec3 gx = s.gradient.segment<3>(3 * j);
    if (gx.isZero(0.0)) continue;
    const int i = s.candidates[j];
    for (int k = c.skin.start[i]; k < c.skin.start[i + 1]; ++k) {
      const int b = c.skin.entries[k].bone;
      if (!has_curvature[b]) curvature[b].setZero();
      has_curvature[b] = true;
      curvature[b] += c.skin.entries[k].weight * rotationCurvature(gx, leverArm(c, i, b));
    }
  }
  for (int b = 0; b < c.num_bones; ++b)
    if (has_curvature[b])
      pair_blocks_.block(b, b).bottomRightCorner<3, 3>() +=
          psd ? projectToPSD<3>(curvature[b]) : curvature[b];
  pair_blocks_.emit(H, offset);
}

// The node gradient g_x(x, a, k, o) of candidate j is pulled back by g_t,b += w g_x,
// g_ω,b += w y_ib × g_x, so Λᵀ ∂g/∂p = μ_jᵀ ∂g_x/∂p + (what turns y_ib), with the node cotangent
// μ_j = Σ_b w_ib (Λt_b − [y_ib]× Λω_b) (3 × m). ∂g_x/∂x = H_x (exact); x moves with J_c by
// −w_ic R_c and with the rest vertex by Σ_c w_ic R_c; y_ib by −R_b dJ_b and R_b dX_i. g_x is
// linear in the area and in the stiffness, and depends on x − o_k for collider k.
template <class Lambda, class Block>
void SurfaceContactTerm::products(const TermContext& c, const Lambda& l,
                                  ParameterProducts<Block>& out) const {
  const SurfaceContactState& s = c.contact;
  const size_t n = s.candidates.size();
  if (n == 0 || !(out.wants(SimParameter::RestJoints) || out.wants(SimParameter::Stiffnesses) ||
                  out.wants(SimParameter::ColliderOffsets) || out.wants(SimParameter::Shape)))
    return;
  const std::vector<Mat3> H = nodeHessians(c, c.colliders);
  const auto cotangent = [&](size_t j) {
    const int i = s.candidates[j];
    Rows3Of<Lambda> mu = Rows3Of<Lambda>::Zero(3, l.cols());
    for (int k = c.skin.start[i]; k < c.skin.start[i + 1]; ++k) {
      const int b = c.skin.entries[k].bone;
      mu += c.skin.entries[k].weight * (lambdaT(l, b) - skew(leverArm(c, i, b)) * lambdaW(l, b));
    }
    return mu;
  };
  // Only touching candidates (a nonzero node gradient or Hessian) enter most products.
  const auto touching = [&](size_t j) {
    return !(s.gradient.template segment<3>(3 * j).isZero(0.0) && H[j].isZero(0.0));
  };
  std::vector<Rows3Of<Lambda>> mu(n);
  for (size_t j = 0; j < n; ++j)
    if (touching(j)) mu[j] = cotangent(j);

  if (out.wants(SimParameter::RestJoints)) {
    Block& D = out[SimParameter::RestJoints];
    for (size_t j = 0; j < n; ++j) {
      if (!touching(j)) continue;
      const int i = s.candidates[j];
      const Vec3 gx = s.gradient.segment<3>(3 * j);
      const Rows3Of<Lambda> Hmu = H[j] * mu[j];
      for (int k = c.skin.start[i]; k < c.skin.start[i + 1]; ++k) {
        const int b = c.skin.entries[k].bone;
        const double w = c.skin.entries[k].weight;
        D.template middleRows<3>(3 * b) -=
            w * c.R[b].transpose() * (skew(gx) * lambdaW(l, b) + Hmu);
      }
    }
  }
  if (out.wants(SimParameter::Stiffnesses)) {
    ContactOptions unit = c.options.contact;
    unit.stiffness = 1.0;
    VecX gx = VecX::Zero(3 * Eigen::Index(n));
    colliderContactEnergy(s.nodes, s.areas, c.colliders, c.time, unit, &gx);
    Block& D = out[SimParameter::Stiffnesses];
    for (size_t j = 0; j < n; ++j) {
      const Vec3 g = gx.segment<3>(3 * j);
      if (g.isZero(0.0)) continue;
      // A zero contact stiffness leaves g_x = 0 (not touching) but not the unit gradient.
      D.row(3) += g.transpose() * (touching(j) ? mu[j] : cotangent(j));
    }
  }
  if (out.wants(SimParameter::ColliderOffsets)) {
    Block& D = out[SimParameter::ColliderOffsets];
    const int nc = int(c.colliders.size());
    for (int k = 0; k < nc; ++k) {
      // With one collider the all-collider Hessians are its own.
      const std::vector<Mat3> Hk = nc == 1 ? H : nodeHessians(c, {c.colliders[k]});
      for (size_t j = 0; j < n; ++j) {
        if (Hk[j].isZero(0.0)) continue;
        D.template middleRows<3>(3 * k) -= Hk[j] * (touching(j) ? mu[j] : cotangent(j));
      }
    }
  }
  if (out.wants(SimParameter::Shape)) {
    Block& D = out[SimParameter::Shape];
    const MatX& shapedirs = c.avatar.body().shapedirs;
    const MatX& areas_jacobian = c.avatar.vertexAreasShapeJacobian();
    for (size_t j = 0; j < n; ++j) {
      if (!touching(j)) continue;
      const int i = s.candidates[j];
      const Vec3 gx = s.gradient.segment<3>(3 * j);
      Mat3 dx_dX = Mat3::Zero();
      Rows3Of<Lambda> turn = Rows3Of<Lambda>::Zero(3, l.cols());  // the rotating lever arms
      for (int k = c.skin.start[i]; k < c.skin.start[i + 1]; ++k) {
        const int b = c.skin.entries[k].bone;
        const double w = c.skin.entries[k].weight;
        dx_dX += w * c.R[b];
        turn -= w * c.R[b].transpose() * skew(gx) * lambdaW(l, b);
      }
      const Rows3Of<Lambda> node = dx_dX.transpose() * (H[j] * mu[j]) - turn;
      D.noalias() += shapedirs.middleRows<3>(3 * i).transpose() * node;
      if (s.areas[j] > 0.0)
        D.noalias() += areas_jacobian.row(i).transpose() * ((gx.transpose() * mu[j]) / s.areas[j]);
    }
  }
}

template void SurfaceContactTerm::products(const TermContext&, const VecX&,
                                           ParameterProducts<VecX>&) const;
template void SurfaceContactTerm::products(const TermContext&, const MatX&,
                                           ParameterProducts<MatX>&) const;

}  // namespace flsh::detail
