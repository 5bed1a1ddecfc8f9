// Hessian assembly helpers shared by the skeleton and soft-tissue terms of Simulable (private).
#pragma once

#include <vector>

#include "flsh/core/types.h"
#include "flsh/sim/skeleton_energies.h"

namespace flsh::detail {

/// Appends a dense block as triplets at (row0, col0). One resize, then plain stores:
/// emplace_back per entry was not inlined (a call each).
template <class Derived>
void addBlock(std::vector<Triplet>& H, int row0, int col0, const Eigen::MatrixBase<Derived>& block) {
  const size_t start = H.size();
  H.resize(start + size_t(block.rows() * block.cols()));
  Triplet* out = H.data() + start;
  for (int c = 0; c < block.cols(); ++c)
    for (int r = 0; r < block.rows(); ++r) *out++ = Triplet(row0 + r, col0 + c, block(r, c));
}

/// 6 × 6 Hessian blocks per ordered bone pair, accumulated over many points and emitted once:
/// block(b, c) zeroes a pair on first touch; emit() appends the touched ones and resets them.
/// Storage stays allocated between evaluations.
class BonePairBlocks {
 public:
  explicit BonePairBlocks(int num_bones = 0) { resize(num_bones); }
  void resize(int num_bones) {
    num_bones_ = num_bones;
    blocks_.assign(size_t(num_bones) * num_bones, Mat6::Zero());
    touched_.assign(size_t(num_bones) * num_bones, 0);
    list_.clear();
  }
  Mat6& block(int b, int c) {
    const int key = b * num_bones_ + c;
    if (!touched_[key]) {
      touched_[key] = 1;
      blocks_[key].setZero();
      list_.push_back(key);
    }
    return blocks_[key];
  }
  /// Appends every touched block at (offset + 6b, offset + 6c) and forgets them.
  void emit(std::vector<Triplet>& H, int offset) {
    for (int key : list_) {
      addBlock(H, offset + 6 * (key / num_bones_), offset + 6 * (key % num_bones_), blocks_[key]);
      touched_[key] = 0;
    }
    list_.clear();
  }

 private:
  int num_bones_ = 0;
  std::vector<Mat6> blocks_;
  std::vector<char> touched_;
  std::vector<int> list_;
};

/// 3 × 3 blocks of a (row blocks × column blocks) matrix accumulated over many points and emitted
/// once, as BonePairBlocks: block(r, c) zeroes a block on first touch; emit() appends the touched
/// ones at (row0 + 3r, col0 + 3c), with `mirror` also their transposes at (col0 + 3c, row0 + 3r),
/// and resets them.
class Block3Accumulator {
 public:
  void resize(int row_blocks, int col_blocks) {
    cols_ = col_blocks;
    blocks_.assign(size_t(row_blocks) * col_blocks, Mat3::Zero());
    touched_.assign(size_t(row_blocks) * col_blocks, 0);
    list_.clear();
  }
  Mat3& block(int r, int c) {
    const int key = r * cols_ + c;
    if (!touched_[key]) {
      touched_[key] = 1;
      blocks_[key].setZero();
      list_.push_back(key);
    }
    return blocks_[key];
  }
  void emit(std::vector<Triplet>& H, int row0, int col0, bool mirror) {
    for (int key : list_) {
      const int r = row0 + 3 * (key / cols_), c = col0 + 3 * (key % cols_);
      addBlock(H, r, c, blocks_[key]);
      if (mirror) addBlock(H, c, r, blocks_[key].transpose());
      touched_[key] = 0;
    }
    list_.clear();
  }

 private:
  int cols_ = 0;
  std::vector<Mat3> blocks_;
  std::vector<char> touched_;
  std::vector<int> list_;
};

}  // namespace flsh::detail
