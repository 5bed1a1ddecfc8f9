#include "flsh/core/hessian_blocks.h"

namespace flsh {

void appendBlockTriplets(const std::vector<FixedHessianBlocks>& lists, std::vector<Triplet>& H) {
  for (const FixedHessianBlocks& list : lists)
    for (size_t k = 0; !list.empty() && k < list.positions->size(); ++k) {
      const auto [row, col] = (*list.positions)[k];
      for (int j = 0; j < 3; ++j)
        for (int i = 0; i < 3; ++i)
          H.emplace_back(row + list.offset + i, col + list.offset + j, (*list.values)[k](i, j));
    }
}

}  // namespace flsh
