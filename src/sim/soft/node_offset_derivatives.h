// The node terms' derivatives in the nodes' unposed positions (ARCHITECTURE.md §6), private to
// Simulable: ∂g/∂Y for an offset d_j added to every node's Y_j = X̄_j + P_j + u_j, in the
// current state and in the states the inertia's prediction x̂ is skinned from, as the held
// pose blend P (and the rest nodes X̄(β)) move them. The soft skeletons' adjoint chains it to
// q_n's rotations through the pose blend (SoftKinematics::poseBlendCotangent). Elasticity reads
// u alone and has none.
//
// A term derives from WithNodeOffsetBlocks<Derived> and writes the blocks once, as
//   template <class Sink> void nodeOffsetBlocks(const TermContext& c, Sink& sink) const;
// (node_offset_blocks.h: the sinks and the two products built from it).
#pragma once

#include "flsh/core/types.h"
#include "flsh/sim/energy_term.h"

namespace flsh::detail {

class NodeOffsetDerivatives {
 public:
  virtual ~NodeOffsetDerivatives() = default;
  /// ADDS (∂g/∂Y)ᵀ λ into out (#N × 3; λ: numDofs, the simulable's own DoFs).
  virtual void addNodeOffsetProducts(const TermContext& c, const VecX& lambda,
                                     MatX3& out) const = 0;
  /// ADDS ∂g/∂Y dY into out (numDofs; dY: #N × 3).
  virtual void addNodeOffsetTangent(const TermContext& c, const MatX3& dY, VecX& out) const = 0;
};

/// The two products from Derived::nodeOffsetBlocks (defined in node_offset_blocks.h; each
/// term's .cpp instantiates them).
template <class Derived>
class WithNodeOffsetBlocks : public NodeOffsetDerivatives {
 public:
  void addNodeOffsetProducts(const TermContext& c, const VecX& lambda, MatX3& out) const final;
  void addNodeOffsetTangent(const TermContext& c, const MatX3& dY, VecX& out) const final;
};

}  // namespace flsh::detail
