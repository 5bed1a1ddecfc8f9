#include "sim/terms/bone_gravity_term.h"

#include "flsh/core/rotation.h"
#include "flsh/sim/skeleton_energies.h"
#include "sim/hessian_blocks.h"
#include "sim/terms/term_products.h"

namespace flsh::detail {

double BoneGravityTerm::evaluate(const TermContext& c, VecX* g, int offset) const {
  double E = 0.0;
  Vec6 g6;
  for (int b = 0; b < c.num_bones; ++b) {
    E += gravityEnergy(c.t.row(b).transpose(), c.R[b], c.inertia[b], c.options.gravity,
                       g ? &g6 : nullptr);
    if (g) g->segment<6>(offset + 6 * b) += g6;
  }
  return E;
}

void BoneGravityTerm::addHessian(const TermContext& c, std::vector<Triplet>& H, int offset,
                                 bool psd) const {
  Mat6 H6;
  for (int b = 0; b < c.num_bones; ++b) {
    gravityEnergy(c.t.row(b).transpose(), c.R[b], c.inertia[b], c.options.gravity, nullptr, &H6,
                  psd);
    const int ib = offset + 6 * b;
    addBlock(H, ib + 3, ib + 3, H6.bottomRightCorner<3, 3>());
  }
}

template <class Lambda, class Block>
void BoneGravityTerm::products(const TermContext& c, const Lambda& l,
                               ParameterProducts<Block>& out) const {
  if (!out.wants(SimParameter::BoneInertia)) return;
  Block& o = out[SimParameter::BoneInertia];
  const Vec3& gravity = c.options.gravity;
  for (int b = 0; b < c.num_bones; ++b) {
    const int col = kBoneInertiaValues * b;
    o.row(col) -= gravity.transpose() * lambdaT(l, b);
    // λω·(g × R m̄) = m̄ · Rᵀ(λω × g) = −m̄ · Rᵀ [g]× λω.
    o.template middleRows<3>(col + 1) -= c.R[b].transpose() * skew(gravity) * lambdaW(l, b);
  }
}

template void BoneGravityTerm::products(const TermContext&, const VecX&,
                                        ParameterProducts<VecX>&) const;
template void BoneGravityTerm::products(const TermContext&, const MatX&,
                                        ParameterProducts<MatX>&) const;

}  // namespace flsh::detail
