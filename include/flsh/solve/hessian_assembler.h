// HessianAssembler: sums Hessian triplets and fixed 3 × 3 block lists into a sparse matrix on
// a pattern kept across calls (used by Scene for soft-tissue scenes).
#pragma once

#include <utility>
#include <vector>

#include "flsh/core/hessian_blocks.h"
#include "flsh/core/types.h"

namespace flsh {

/// Sums Hessian triplets (duplicates added) into a column-major n × n matrix on a pattern kept
/// across calls, in one linear pass: the value slot of every triplet is cached with its
/// position, so while the triplet order repeats (it does between Newton iterations) no lookup,
/// sort or setFromTriplets happens. A triplet whose position changed is looked up in its
/// column (binary search); one outside the pattern makes the pattern grow by the whole block of
/// its DoF groups (row group × column group, see setGroups), then the pass is redone. The
/// pattern always stores the diagonal blocks (Newton's diagonal shifts keep the pattern) and
/// only grows, so a linear solver keeps its symbolic analysis between growths.
/// The triplet list may be split into segments (e.g. one per energy term) with their own caches,
/// so that a segment whose length changes (contacts) does not move the others' slots.
class HessianAssembler {
 public:
  /// DoF groups: group k holds DoFs [group_start[k], group_start[k + 1]); group_start starts at
  /// 0, increases strictly and ends at n. Resets the pattern. Without a call, every DoF is its
  /// own group (the pattern is then the union of the positions seen, plus the diagonal).
  void setGroups(std::vector<int> group_start);
  /// Adds the blocks (row group, column group) to the pattern before the next assembly
  /// (structure known in advance, e.g. couplings that contacts may create later).
  void addBlocks(const std::vector<std::pair<int, int>>& blocks);
  /// H = Σ triplets on the pattern (H takes the pattern when it has another one). `segment_end`:
  /// end index of each segment of `triplets`, increasing, the last = triplets.size() (empty:
  /// one segment). Throws InputError for a triplet outside n × n or bad segment ends.
  void assemble(const std::vector<Triplet>& triplets, const std::vector<size_t>& segment_end, int n,
                SpMat& H);
  /// The same plus lists of 3 × 3 blocks of fixed position (see FixedHessianBlocks; the blocks
  /// of one list must have distinct positions, or InputError). A list's value slots are cached
  /// while its positions and offset repeat, and its blocks are added in parallel (OpenMP).
  void assemble(const std::vector<Triplet>& triplets, const std::vector<size_t>& segment_end,
                const std::vector<FixedHessianBlocks>& blocks, int n, SpMat& H);
  /// Full n × n storage (for small systems that are dense anyway, e.g. reduced-model scenes on
  /// the dense solver): every entry is in the pattern, a triplet's value slot is col·n + row and
  /// no slot cache is kept; segments, groups and added blocks then make no difference. Resets
  /// the pattern. n is limited to kMaxDenseDofs.
  void setDense(bool dense);
  bool dense() const { return dense_; }
  static constexpr int kMaxDenseDofs = 8192;
  const SpMat& pattern() const { return pattern_; }
  int numPatternBuilds() const { return pattern_builds_; }  ///< first build and growths
  /// Triplets of the last assemble() whose value slot had to be looked up (not cached).
  size_t lastLookups() const { return last_lookups_; }

 private:
  void grow(int n);
  bool fill(const std::vector<Triplet>& triplets, const std::vector<size_t>& segment_end, SpMat& H);
  bool fillBlocks(const std::vector<FixedHessianBlocks>& blocks, SpMat& H);
  void fillDense(const std::vector<Triplet>& triplets,
                 const std::vector<FixedHessianBlocks>& blocks, int n, SpMat& H);
  SpMat pattern_;                 // values unused (zero)
  std::vector<int> group_start_;  // as set by setGroups (empty: one DoF per group)
  std::vector<int> group_of_;     // group of each DoF
  std::vector<std::pair<int, int>> pending_blocks_;  // (row group, column group) to add
  // Per segment: pattern row·n + col key and value index of each triplet slot.
  std::vector<std::vector<long long>> slot_key_;
  std::vector<std::vector<int>> slot_index_;
  // Per fixed-block list: the positions and offset its slots were found for, and the value
  // slot of each block's three column tops (empty: not looked up yet).
  struct BlockSlots {
    std::vector<std::pair<int, int>> positions;
    int offset = 0;
    std::vector<int> slots;
  };
  std::vector<BlockSlots> block_slots_;
  std::vector<long long> old_key_;  // a segment's previous slots from its first moved one
  std::vector<int> old_index_;
  int pattern_builds_ = 0;
  size_t last_lookups_ = 0;
  bool dense_ = false;
};

/// H takes P's pattern (kept, with its storage, when it already has it) with zero values (or,
/// zero = false, values left to the caller). With the full n × n pattern the column starts
/// decide (a compressed column holds sorted distinct rows): no comparison of the n² row indices.
void resetToPattern(const SpMat& P, SpMat& H, bool zero = true);

}  // namespace flsh
