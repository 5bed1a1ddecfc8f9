#include "sim/terms/bone_gravity_term.h"

#include "flsh/core/rotation.h"
#include "flsh/energy/skeleton_energies.h"
#include "sim/hessian_blocks.h"
#include "sim/terms/term_blocks.h"

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

// The gradient [−M g; g × (R m̄)] per bone is linear in M and m̄: ∂g_t/∂M = −g and
// ∂g_ω/∂m̄ = [g]× R.
template <class Sink>
void BoneGravityTerm::parameterBlocks(const TermContext& c, Sink& sink) const {
  if (!sink.wants(SimParameter::BoneInertia)) return;
  const Vec3& gravity = c.options.gravity;
  const Mat3 turn = skew(gravity);
  for (int b = 0; b < c.num_bones; ++b) {
    const int col = kBoneInertiaValues * b;
    sink.add(SimParameter::BoneInertia, translationRow(b), col, -gravity);
    sink.add(SimParameter::BoneInertia, rotationRow(b), col + 1, turn * c.R[b]);
  }
}

}  // namespace flsh::detail

template class flsh::TermWithParameterBlocks<flsh::detail::BoneGravityTerm>;
