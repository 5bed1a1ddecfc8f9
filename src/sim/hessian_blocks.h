// Hessian assembly helpers shared by the skeleton and soft-tissue terms of Simulable (private).
#pragma once

#include <memory>
#include <vector>

#include "flsh/core/types.h"
#include "flsh/energy/skeleton_energies.h"

namespace flsh::detail {

/// Appends a dense block as triplets at (row0, col0). One resize, then plain stores:
/// emplace_back per entry was not inlined (a call each).
template <class Derived>
void addBlock(std::vector<Triplet>& H, int row0, int col0,
              const Eigen::MatrixBase<Derived>& block) {
  const size_t start = H.size();
  H.resize(start + size_t(block.rows() * block.cols()));
  Triplet* out = H.data() + start;
  for (int c = 0; c < block.cols(); ++c)
    for (int r = 0; r < block.rows(); ++r) *out++ = Triplet(row0 + r, col0 + c, block(r, c));
}

/// One value per key of a fixed range [0, size), accumulated over many points and read once:
/// at(key) resets a value to `zero` on its first touch; touched() lists the touched keys in
/// first-touch order; forget() makes them untouched again. Storage stays allocated.
template <class Value, class Allocator = std::allocator<Value>>
class TouchedValues {
 public:
  void resize(size_t size, const Value& zero) {
    zero_ = zero;
    values_.assign(size, zero);
    touched_.assign(size, 0);
    list_.clear();
  }
  Value& at(int key) {
    if (!touched_[key]) {
      touched_[key] = 1;
      values_[key] = zero_;
      list_.push_back(key);
    }
    return values_[key];
  }
  const std::vector<int>& touched() const { return list_; }
  void forget() {
    for (int key : list_) touched_[key] = 0;
    list_.clear();
  }

 private:
  Value zero_{};
  std::vector<Value, Allocator> values_;
  std::vector<char> touched_;
  std::vector<int> list_;
};

/// N × N blocks of a (row blocks × column blocks) matrix accumulated over many points and
/// emitted once: block(r, c) zeroes a block on first touch; emit() appends the touched ones at
/// (row0 + N r, col0 + N c) and forgets them. Storage stays allocated between evaluations.
template <int N>
class TouchedBlocks {
 public:
  using Block = Eigen::Matrix<double, N, N>;
  void resize(int row_blocks, int col_blocks) {
    cols_ = col_blocks;
    blocks_.resize(size_t(row_blocks) * col_blocks, Block::Zero());
  }
  Block& block(int r, int c) { return blocks_.at(r * cols_ + c); }
  void emit(std::vector<Triplet>& H, int row0, int col0) {
    for (int key : blocks_.touched())
      addBlock(H, row0 + N * (key / cols_), col0 + N * (key % cols_), blocks_.at(key));
    blocks_.forget();
  }

 private:
  int cols_ = 0;
  TouchedValues<Block, Eigen::aligned_allocator<Block>> blocks_;
};

/// 6 × 6 Hessian blocks per ordered bone pair (b, c), emitted at (offset + 6b, offset + 6c).
class BonePairBlocks : public TouchedBlocks<6> {
 public:
  explicit BonePairBlocks(int num_bones = 0) { resize(num_bones); }
  void resize(int num_bones) { TouchedBlocks<6>::resize(num_bones, num_bones); }
  void emit(std::vector<Triplet>& H, int offset) { TouchedBlocks<6>::emit(H, offset, offset); }
};

}  // namespace flsh::detail
