// The base of the soft skeletons' node terms (private to Simulable): each reads the soft
// kinematics and gives its Hessian in block form (BlockHessianTerm); evaluated alone
// (EnergyTerm::addHessian), that is its blocks as triplets between a begin and a flush of its
// value list (List: 0 for the dynamic part, 1 for the potential part). Base: EnergyTerm, or
// TermWithParameterBlocks<Derived> for a term with parameter derivatives (term_blocks.h).
#pragma once

#include <vector>

#include "flsh/sim/energy_term.h"
#include "sim/block_hessian_term.h"
#include "sim/soft/soft_kinematics.h"

namespace flsh::detail {

template <int List, class Base = EnergyTerm>
class NodeTerm : public Base, public BlockHessianTerm {
 public:
  void addHessian(const TermContext& c, std::vector<Triplet>& H, int offset, bool psd) const final {
    kin_.beginList(List);
    addHessianBlocks(c, H, nullptr, offset, psd);
    kin_.flushList(List, H, offset, nullptr);
  }

 protected:
  explicit NodeTerm(const SoftKinematics& kinematics) : kin_(kinematics) {}
  /// Runs hessian(fixed) (fixed: null unless `blocks` asks for fixed blocks) and appends the
  /// fixed blocks it returns to `blocks`.
  template <class Hessian>
  static void collectFixedBlocks(std::vector<FixedHessianBlocks>* blocks, Hessian&& hessian) {
    FixedHessianBlocks fixed;
    hessian(blocks ? &fixed : nullptr);
    if (blocks && !fixed.empty()) blocks->push_back(fixed);
  }
  const SoftKinematics& kin_;
};

}  // namespace flsh::detail
