// How Simulable's energy loops ask a term for its Hessian when the term can do better than
// triplets (private to Simulable): blocks at positions fixed for the whole simulation (returned
// as FixedHessianBlocks, which the scene's assembler adds without sorting triplets), or blocks
// summed into a value list that several terms share (the ROM's, at the basis' fixed pattern)
// and that the caller begins and flushes once per part of the Hessian. The skeleton's terms give
// triplets only; the soft tissue's node terms do both.
#pragma once

#include <vector>

#include "flsh/core/hessian_blocks.h"
#include "flsh/sim/energy_term.h"

namespace flsh::detail {

class BlockHessianTerm {
 public:
  virtual ~BlockHessianTerm() = default;
  /// The Hessian at the context's state (exact, or psd): triplets APPENDED to H (indices
  /// shifted by offset), blocks at fixed positions appended to `blocks` when it is not null (else
  /// as triplets), and blocks of a shared value list SUMMED into it (not begun, not flushed).
  virtual void addHessianBlocks(const TermContext& c, std::vector<Triplet>& H,
                                std::vector<FixedHessianBlocks>* blocks, int offset,
                                bool psd) const = 0;
};

/// The Hessian value lists a model's terms sum into: list 0 for the dynamic part, 1 for the
/// potential part. beginList zeroes one; flushList hands it over (triplets into H, or with
/// `blocks` as fixed blocks valid until the list is begun again).
class HessianValueLists {
 public:
  virtual ~HessianValueLists() = default;
  virtual void beginList(int list) const = 0;
  virtual void flushList(int list, std::vector<Triplet>& H, int offset,
                         std::vector<FixedHessianBlocks>* blocks) const = 0;
};

/// One term of a model's energy as the loops see it: the term, and its block form if it has one.
struct TermEntry {
  const EnergyTerm* term = nullptr;
  const BlockHessianTerm* blocks = nullptr;
};

/// The term's Hessian in its block form when it has one (and `blocks` or a value list can take
/// it), else its triplets.
inline void addTermHessian(const TermEntry& entry, const TermContext& c, std::vector<Triplet>& H,
                           std::vector<FixedHessianBlocks>* blocks, int offset, bool psd) {
  if (entry.blocks)
    entry.blocks->addHessianBlocks(c, H, blocks, offset, psd);
  else
    entry.term->addHessian(c, H, offset, psd);
}

}  // namespace flsh::detail
