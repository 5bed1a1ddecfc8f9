#include "sim/terms/joint_spring_term.h"

#include <utility>

#include "flsh/core/rotation.h"
#include "flsh/energy/skeleton_energies.h"
#include "sim/hessian_blocks.h"
#include "sim/terms/term_blocks.h"

namespace flsh::detail {

namespace {

double spring(const TermContext& c, int p, int b, double k, Vec12* g, Mat12* H, bool psd) {
  return jointSpringEnergy(c.t.row(p).transpose(), c.R[p], c.t.row(b).transpose(), c.R[b],
                           c.J.row(p).transpose(), c.J.row(b).transpose(), k, g, H, psd);
}

}  // namespace

double JointSpringTerm::evaluate(const TermContext& c, VecX* g, int offset) const {
  double E = 0.0;
  Vec12 g12;
  for (int b = 0; b < c.num_bones; ++b) {
    const int p = c.parents[b];
    if (p < 0) continue;
    E += spring(c, p, b, c.options.joint_stiffness, g ? &g12 : nullptr, nullptr, false);
    if (!g) continue;
    g->segment<6>(offset + 6 * p) += g12.head<6>();
    g->segment<6>(offset + 6 * b) += g12.tail<6>();
  }
  return E;
}

void JointSpringTerm::addHessian(const TermContext& c, std::vector<Triplet>& H, int offset,
                                 bool psd) const {
  Mat12 H12;
  for (int b = 0; b < c.num_bones; ++b) {
    const int p = c.parents[b];
    if (p < 0) continue;
    spring(c, p, b, c.options.joint_stiffness, nullptr, &H12, psd);
    const int ip = offset + 6 * p, ib = offset + 6 * b;
    // Rows/columns of δω_b are structurally zero (the spring does not rotate with bone b).
    addBlock(H, ip, ip, H12.topLeftCorner<6, 6>());
    addBlock(H, ip, ib, H12.block<6, 3>(0, 6));
    addBlock(H, ib, ip, H12.block<3, 6>(6, 0));
    addBlock(H, ib, ib, H12.block<3, 3>(6, 6));
  }
}

// d = y + t_p − t_b with y = R_p(J_b − J_p): dy = dd = R_p (dJ_b − dJ_p), and the gradient
// k [d; y × d; −d; 0] gives ∂g/∂J_b = k [R_p; [y − d]× R_p; −R_p; 0] (−that for J_p). The
// gradient is linear in k.
template <class Sink>
void JointSpringTerm::parameterBlocks(const TermContext& c, Sink& sink) const {
  const double kj = c.options.joint_stiffness;
  const bool joints = sink.wants(SimParameter::RestJoints);
  const bool stiffness = sink.wants(SimParameter::Stiffnesses);
  Vec12 g12;
  for (int b = 0; b < c.num_bones; ++b) {
    const int p = c.parents[b];
    if (p < 0) continue;
    if (joints) {
      const Vec3 y = c.R[p] * (c.J.row(b) - c.J.row(p)).transpose();
      const Vec3 d = y + c.t.row(p).transpose() - c.t.row(b).transpose();
      const Mat3 dt = kj * c.R[p];                // ∂g_t,p/∂J_b (∂g_t,b/∂J_b = −that)
      const Mat3 dw = kj * skew(y - d) * c.R[p];  // ∂g_ω,p/∂J_b
      for (const auto& [joint, sign] : {std::pair{b, 1.0}, std::pair{p, -1.0}}) {
        sink.add(SimParameter::RestJoints, translationRow(p), 3 * joint, sign * dt);
        sink.add(SimParameter::RestJoints, translationRow(b), 3 * joint, -sign * dt);
        sink.add(SimParameter::RestJoints, rotationRow(p), 3 * joint, sign * dw);
      }
    }
    if (stiffness) {
      spring(c, p, b, 1.0, &g12, nullptr, false);
      sink.add(SimParameter::Stiffnesses, translationRow(p), 0, g12.head<6>());
      sink.add(SimParameter::Stiffnesses, translationRow(b), 0, g12.tail<6>());
    }
  }
}

}  // namespace flsh::detail

template class flsh::TermWithParameterBlocks<flsh::detail::JointSpringTerm>;
