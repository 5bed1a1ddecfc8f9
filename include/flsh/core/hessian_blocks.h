// Lists of 3 × 3 Hessian blocks at fixed positions: how the soft-tissue models hand their
// node-pair blocks to an assembler (solve/hessian_assembler.h) without expanding them.
#pragma once

#include <utility>
#include <vector>

#include "flsh/core/types.h"

namespace flsh {

/// 3 × 3 Hessian blocks whose positions stay the same from one evaluation to the next (the FEM's
/// elastic node pairs, its bone–tissue coupling and node-diagonal blocks; the ROM's bone–handle
/// and handle–handle blocks), handed to an
/// assembler without expanding them into triplets. Block k is added at rows
/// positions[k].first … + 2 and columns positions[k].second … + 2 (plus `offset`); the
/// positions of one list are distinct. Both vectors belong to the simulable and hold until its
/// next Hessian evaluation.
struct FixedHessianBlocks {
  const std::vector<std::pair<int, int>>* positions = nullptr;
  const std::vector<Mat3>* values = nullptr;
  int offset = 0;
  bool empty() const { return !positions || positions->empty(); }
};

/// Appends the blocks of `lists` to H as triplets (9 per block), for callers that want a plain
/// triplet list (e.g. to build a sparse matrix of the whole Hessian).
void appendBlockTriplets(const std::vector<FixedHessianBlocks>& lists, std::vector<Triplet>& H);

}  // namespace flsh
