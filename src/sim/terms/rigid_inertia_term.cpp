#include "sim/terms/rigid_inertia_term.h"

#include "flsh/core/rotation.h"
#include "flsh/energy/skeleton_energies.h"
#include "sim/hessian_blocks.h"
#include "sim/terms/term_blocks.h"

namespace flsh::detail {

namespace {

// Symmetric basis of the second moment in the order xx, yy, zz, xy, xz, yz.
Mat3 secondMomentBasis(int k) {
  static const int rows[6] = {0, 1, 2, 0, 0, 1}, cols[6] = {0, 1, 2, 1, 2, 2};
  Mat3 E = Mat3::Zero();
  E(rows[k], cols[k]) = 1.0;
  E(cols[k], rows[k]) = 1.0;
  return E;
}

double boneInertia(const TermContext& c, int b, Vec6* g, Mat6* H, bool psd) {
  return rigidInertiaEnergy(c.t.row(b).transpose(), c.R[b], c.t_n.row(b).transpose(), c.R_n[b],
                            c.t_nm1.row(b).transpose(), c.R_nm1[b], c.inertia[b],
                            c.options.time_step, g, H, psd);
}

// Bone b's blocks ∂g_b/∂q_n,b and ∂g_b/∂q_{n−1},b (6 × 6 each; either may be null).
void previousBlocks(const TermContext& c, int b, Mat6* G1, Mat6* G2) {
  rigidInertiaGradientPreviousStates(c.t.row(b).transpose(), c.R[b], c.t_n.row(b).transpose(),
                                     c.R_n[b], c.t_nm1.row(b).transpose(), c.R_nm1[b], c.inertia[b],
                                     c.options.time_step, G1, G2);
}

}  // namespace

double RigidInertiaTerm::evaluate(const TermContext& c, VecX* g, int offset) const {
  if (c.is_static) return 0.0;
  double E = 0.0;
  Vec6 gb;
  for (int b = 0; b < c.num_bones; ++b) {
    E += boneInertia(c, b, g ? &gb : nullptr, nullptr, false);
    if (g) g->segment<6>(offset + 6 * b) += gb;
  }
  return E;
}

void RigidInertiaTerm::addHessian(const TermContext& c, std::vector<Triplet>& H, int offset,
                                  bool psd) const {
  if (c.is_static) return;
  Mat6 Hb;
  for (int b = 0; b < c.num_bones; ++b) {
    boneInertia(c, b, nullptr, &Hb, psd);
    addBlock(H, offset + 6 * b, offset + 6 * b, Hb);
  }
}

// The gradient inv_h2 [M u + (R − A) m̄; (R m̄) × u + vee(R S Aᵀ − A S Rᵀ)] with A = 2R_n −
// R_{n−1}, u = t − (2t_n − t_{n−1}), linear in M, m̄, S.
template <class Sink>
void RigidInertiaTerm::parameterBlocks(const TermContext& c, Sink& sink) const {
  if (c.is_static || !sink.wants(SimParameter::BoneInertia)) return;
  const double inv_h2 = 1.0 / (c.options.time_step * c.options.time_step);
  Eigen::Matrix<double, 3, 6> dS;  // ∂g_ω/∂S in the basis xx, yy, zz, xy, xz, yz
  for (int b = 0; b < c.num_bones; ++b) {
    const int col = kBoneInertiaValues * b;
    const Mat3 A = 2.0 * c.R_n[b] - c.R_nm1[b];
    const Vec3 u = c.t.row(b).transpose() - (2.0 * c.t_n.row(b) - c.t_nm1.row(b)).transpose();
    sink.add(SimParameter::BoneInertia, translationRow(b), col, inv_h2 * u);
    sink.add(SimParameter::BoneInertia, translationRow(b), col + 1, inv_h2 * (c.R[b] - A));
    sink.add(SimParameter::BoneInertia, rotationRow(b), col + 1, -inv_h2 * skew(u) * c.R[b]);
    for (int k = 0; k < 6; ++k) {
      const Mat3 RSAt = c.R[b] * secondMomentBasis(k) * A.transpose();
      dS.col(k) = inv_h2 * vee(RSAt - RSAt.transpose());
    }
    sink.add(SimParameter::BoneInertia, rotationRow(b), col + 4, dS);
  }
}

void RigidInertiaTerm::addPreviousStatesProducts(const TermContext& c, const VecX& lambda,
                                                 VecX* a_n, VecX* a_nm1) const {
  if (c.is_static) return;
  Mat6 G1, G2;
  for (int b = 0; b < c.num_bones; ++b) {
    previousBlocks(c, b, &G1, &G2);
    const Vec6 l = lambda.segment<6>(6 * b);
    if (a_n) a_n->segment<6>(6 * b).noalias() += G1.transpose() * l;
    if (a_nm1) a_nm1->segment<6>(6 * b).noalias() += G2.transpose() * l;
  }
}

void RigidInertiaTerm::addPreviousStatesTangent(const TermContext& c, const VecX& dq_n,
                                                const VecX& dq_nm1, VecX& out) const {
  if (c.is_static) return;
  Mat6 G1, G2;
  for (int b = 0; b < c.num_bones; ++b) {
    previousBlocks(c, b, &G1, &G2);
    out.segment<6>(6 * b).noalias() += G1 * dq_n.segment<6>(6 * b) + G2 * dq_nm1.segment<6>(6 * b);
  }
}

void RigidInertiaTerm::addPreviousStateJacobian(const TermContext& c, int which, MatX& D) const {
  if (c.is_static) return;
  Mat6 block;
  for (int b = 0; b < c.num_bones; ++b) {
    previousBlocks(c, b, which == 1 ? &block : nullptr, which == 2 ? &block : nullptr);
    D.block<6, 6>(6 * b, 6 * b) += block;
  }
}

}  // namespace flsh::detail

template class flsh::TermWithParameterBlocks<flsh::detail::RigidInertiaTerm>;
