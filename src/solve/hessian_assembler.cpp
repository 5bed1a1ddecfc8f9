// HessianAssembler (hessian_assembler.h): triplets and fixed block lists summed on a pattern
// that only grows, with cached value slots.
#include "flsh/solve/hessian_assembler.h"

#include <omp.h>

#include <algorithm>
#include <limits>
#include <string>

#include "core/first_failure.h"
#include "flsh/core/error.h"

namespace flsh {

namespace {

// Throws InputError if the block at (row, col) of fixed-block list `b` reaches outside the
// n × n matrix.
void checkBlockPosition(long long row, long long col, size_t b, int n) {
  if (row < 0 || col < 0 || row + 3 > n || col + 3 > n)
    throw InputError("HessianAssembler::assemble: fixed block at (" + std::to_string(row) + ", " +
                     std::to_string(col) + ") of list " + std::to_string(b) + " is outside the " +
                     std::to_string(n) + " × " + std::to_string(n) + " matrix");
}

// Checks every block of a list (wherever a list's positions are first read: slot lookup).
void checkBlockPositions(const FixedHessianBlocks& list, size_t b, int n) {
  for (const auto& [r, c] : *list.positions)
    checkBlockPosition((long long)r + list.offset, (long long)c + list.offset, b, n);
}

}  // namespace

void resetToPattern(const SpMat& P, SpMat& H, bool zero) {
  const int n = int(P.rows());
  const Eigen::Index nnz = P.nonZeros();
  const bool full = nnz == Eigen::Index(n) * n;
  const bool same =
      H.rows() == n && H.cols() == n && H.isCompressed() && H.nonZeros() == nnz &&
      std::equal(P.outerIndexPtr(), P.outerIndexPtr() + n + 1, H.outerIndexPtr()) &&
      (full || std::equal(P.innerIndexPtr(), P.innerIndexPtr() + nnz, H.innerIndexPtr()));
  if (!same) H = P;
  if (zero) std::fill(H.valuePtr(), H.valuePtr() + nnz, 0.0);
}

void HessianAssembler::setGroups(std::vector<int> group_start) {
  if (group_start.empty() || group_start.front() != 0)
    throw InputError(
        "HessianAssembler::setGroups: group_start must start at 0, got " +
        (group_start.empty() ? std::string("an empty list") : std::to_string(group_start.front())));
  for (size_t k = 1; k < group_start.size(); ++k)
    if (group_start[k] <= group_start[k - 1])
      throw InputError("HessianAssembler::setGroups: group_start must increase strictly; entry " +
                       std::to_string(k) + " is " + std::to_string(group_start[k]) + " after " +
                       std::to_string(group_start[k - 1]));
  group_start_ = std::move(group_start);
  group_of_.clear();
  pattern_ = SpMat();
  pending_blocks_.clear();
  slot_key_.clear();
  slot_index_.clear();
  block_slots_.clear();
}

void HessianAssembler::setDense(bool dense) {
  dense_ = dense;
  pattern_ = SpMat();
  slot_key_.clear();
  slot_index_.clear();
  block_slots_.clear();
}

void HessianAssembler::addBlocks(const std::vector<std::pair<int, int>>& blocks) {
  pending_blocks_.insert(pending_blocks_.end(), blocks.begin(), blocks.end());
}

void HessianAssembler::assemble(const std::vector<Triplet>& triplets,
                                const std::vector<size_t>& segment_end, int n, SpMat& H) {
  assemble(triplets, segment_end, {}, n, H);
}

void HessianAssembler::assemble(const std::vector<Triplet>& triplets,
                                const std::vector<size_t>& segment_end,
                                const std::vector<FixedHessianBlocks>& blocks, int n, SpMat& H) {
  if (n < 0)
    throw InputError("HessianAssembler::assemble: n must be ≥ 0, got " + std::to_string(n));
  if (!group_start_.empty() && group_start_.back() != n)
    throw InputError("HessianAssembler::assemble: the DoF groups cover " +
                     std::to_string(group_start_.back()) +
                     " DoFs (setGroups), but n = " + std::to_string(n));
  for (size_t s = 0; s < segment_end.size(); ++s)
    if (segment_end[s] > triplets.size() || (s > 0 && segment_end[s] < segment_end[s - 1]) ||
        (s + 1 == segment_end.size() && segment_end[s] != triplets.size()))
      throw InputError("HessianAssembler::assemble: segment_end must increase and end at the " +
                       std::to_string(triplets.size()) + " triplets; entry " + std::to_string(s) +
                       " is " + std::to_string(segment_end[s]));
  for (size_t b = 0; b < blocks.size(); ++b) {
    if (blocks[b].empty()) continue;
    if (!blocks[b].values || blocks[b].values->size() != blocks[b].positions->size())
      throw InputError("HessianAssembler::assemble: fixed-block list " + std::to_string(b) +
                       " has " + std::to_string(blocks[b].positions->size()) + " positions but " +
                       std::to_string(blocks[b].values ? blocks[b].values->size() : 0) + " values");
  }
  if (dense_) {
    if (n > kMaxDenseDofs)
      throw InputError("HessianAssembler::assemble: dense storage holds at most " +
                       std::to_string(kMaxDenseDofs) + " DoFs, got n = " + std::to_string(n));
    fillDense(triplets, blocks, n, H);
    return;
  }
  if (int(group_of_.size()) != n) {
    group_of_.resize(n);
    if (group_start_.empty()) {
      for (int d = 0; d < n; ++d) group_of_[d] = d;
    } else {
      for (size_t k = 0; k + 1 < group_start_.size(); ++k)
        std::fill(group_of_.begin() + group_start_[k], group_of_.begin() + group_start_[k + 1],
                  int(k));
    }
  }
  if (pattern_.rows() != n) {
    // First build: every diagonal block, so that Newton's diagonal shifts keep the pattern.
    const int groups = group_start_.empty() ? n : int(group_start_.size()) - 1;
    for (int k = 0; k < groups; ++k) pending_blocks_.emplace_back(k, k);
  }
  if (!pending_blocks_.empty()) grow(n);
  const std::vector<size_t> whole{triplets.size()};
  const std::vector<size_t>& ends = segment_end.empty() ? whole : segment_end;
  // fill() and fillBlocks() leave the missing blocks in pending_blocks_.
  auto fillAll = [&] {
    resetToPattern(pattern_, H);
    const bool triplets_in = fill(triplets, ends, H);
    const bool blocks_in = fillBlocks(blocks, H);
    return triplets_in && blocks_in;
  };
  if (fillAll()) return;
  grow(n);
  if (!fillAll())
    throw Error("HessianAssembler::assemble: the grown pattern still misses an entry");
}

// Old slots searched ahead for a moved triplet's key (a removed run of triplets up to this long
// is recognized; a longer one costs one lookup per later slot).
constexpr long kResyncWindow = 48;

void HessianAssembler::fillDense(const std::vector<Triplet>& triplets,
                                 const std::vector<FixedHessianBlocks>& blocks, int n, SpMat& H) {
  if (pattern_.rows() != n || pattern_.nonZeros() != Eigen::Index(n) * n) {
    pattern_.resize(n, n);
    pattern_.resizeNonZeros(Eigen::Index(n) * n);
    for (int c = 0; c <= n; ++c) pattern_.outerIndexPtr()[c] = c * n;
    for (int c = 0; c < n; ++c)
      for (int r = 0; r < n; ++r) pattern_.innerIndexPtr()[c * n + r] = r;
    std::fill(pattern_.valuePtr(), pattern_.valuePtr() + pattern_.nonZeros(), 0.0);
    ++pattern_builds_;
  }
  resetToPattern(pattern_, H, false);
  double* values = H.valuePtr();
  last_lookups_ = 0;
  // Two threads from 256 DoFs (when OpenMP may use two), each owning a range of columns
  // (contiguous in column-major storage): it zeroes them, then adds the entries of every
  // triplet and block that fall in them, in list order (the same sums as on one thread, bit for
  // bit). Both threads check every position.
  const int threads = n >= 256 && omp_get_max_threads() >= 2 ? 2 : 1;
  detail::FirstFailure failure;
#pragma omp parallel num_threads(threads) if (threads > 1)
  {
    const int parts = omp_get_num_threads(), t = omp_get_thread_num();
    const int c0 = int(long(t) * n / parts), c1 = int(long(t + 1) * n / parts);
    failure.run([&] {
      std::fill(values + size_t(c0) * n, values + size_t(c1) * n, 0.0);
      for (size_t k = 0; k < triplets.size(); ++k) {
        const Triplet& tr = triplets[k];
        const int r = tr.row(), c = tr.col();
        if (unsigned(r) >= unsigned(n) || unsigned(c) >= unsigned(n))
          throw InputError("HessianAssembler::assemble: triplet " + std::to_string(k) + " at (" +
                           std::to_string(r) + ", " + std::to_string(c) + ") is outside the " +
                           std::to_string(n) + " × " + std::to_string(n) + " matrix");
        if (c >= c0 && c < c1) values[size_t(c) * n + r] += tr.value();
      }
      // Consecutive lists on the same positions and offset (the ROM's two parts) are summed
      // block by block and added once.
      for (size_t b = 0; b < blocks.size();) {
        const FixedHessianBlocks& list = blocks[b];
        size_t end = b + 1;
        while (end < blocks.size() && blocks[end].positions == list.positions &&
               blocks[end].offset == list.offset && !blocks[end].empty())
          ++end;
        if (list.empty()) {
          b = end;
          continue;
        }
        const size_t count = list.positions->size();
        for (size_t k = 0; k < count; ++k) {
          const long long r = (long long)(*list.positions)[k].first + list.offset;
          const long long c = (long long)(*list.positions)[k].second + list.offset;
          if (r < 0 || c < 0 || r + 3 > n || c + 3 > n) checkBlockPosition(r, c, b, n);
          if (c + 3 <= c0 || c >= c1) continue;
          Mat3 B = (*list.values)[k];
          for (size_t other = b + 1; other < end; ++other) B += (*blocks[other].values)[k];
          for (int j = 0; j < 3; ++j) {
            if (c + j < c0 || c + j >= c1) continue;
            double* column = values + size_t(c + j) * n + r;
            for (int i = 0; i < 3; ++i) column[i] += B(i, j);
          }
        }
        b = end;
      }
    });
  }
  failure.rethrow();
}

// Sums the triplets into H on pattern_; false (and the missing blocks in pending_blocks_) if
// some triplet falls outside it.
bool HessianAssembler::fill(const std::vector<Triplet>& triplets,
                            const std::vector<size_t>& segment_end, SpMat& H) {
  const SpMat& P = pattern_;
  const int n = int(P.rows());
  double* values = H.valuePtr();
  const int* outer = P.outerIndexPtr();
  const int* inner = P.innerIndexPtr();
  if (slot_key_.size() < segment_end.size()) {
    slot_key_.resize(segment_end.size());
    slot_index_.resize(segment_end.size());
  }
  last_lookups_ = 0;
  bool complete = true;
  size_t begin = 0;
  for (size_t s = 0; s < segment_end.size(); ++s) {
    const size_t count = segment_end[s] - begin;
    std::vector<long long>& keys = slot_key_[s];
    std::vector<int>& index = slot_index_[s];
    if (keys.size() < count) {
      keys.resize(count, -1);
      index.resize(count, 0);
    }
    const Triplet* t = triplets.data() + begin;
    // After the first moved slot, slots are matched against the previous call's from there on
    // (old_key_) with a running shift: triplets inserted or removed in the middle of a segment
    // then cost one lookup each instead of one for every later slot.
    bool moved = false;
    size_t moved_from = 0;
    long shift = 0;
    for (size_t k = 0; k < count; ++k) {
      const int r = t[k].row(), c = t[k].col();
      if (unsigned(r) >= unsigned(n) || unsigned(c) >= unsigned(n))
        throw InputError("HessianAssembler::assemble: triplet " + std::to_string(begin + k) +
                         " at (" + std::to_string(r) + ", " + std::to_string(c) +
                         ") is outside the " + std::to_string(n) + " × " + std::to_string(n) +
                         " matrix");
      const long long key = (long long)r * n + c;
      if (!moved && key == keys[k]) {
        values[index[k]] += t[k].value();
        continue;
      }
      if (!moved) {
        moved = true;
        moved_from = k;
        old_key_.assign(keys.begin() + k, keys.end());
        old_index_.assign(index.begin() + k, index.end());
      }
      const long old_count = long(old_key_.size());
      const long o = long(k - moved_from) + shift;  // this slot's place among the old ones
      int slot = -1;
      if (o >= 0 && o < old_count && old_key_[o] == key) {
        slot = old_index_[o];
      } else {
        // Removed triplets: the key a little further on (not where no old slot was filled).
        const long scan_end = o >= 0 && o < old_count && old_key_[o] >= 0
                                  ? std::min(old_count, o + 1 + kResyncWindow)
                                  : 0;
        for (long p = std::max(0L, o + 1); p < scan_end; ++p)
          if (old_key_[p] == key) {
            shift += p - o;
            slot = old_index_[p];
            break;
          }
        if (slot < 0) {
          ++last_lookups_;
          const int* found = std::lower_bound(inner + outer[c], inner + outer[c + 1], r);
          if (found == inner + outer[c + 1] || *found != r) {
            pending_blocks_.emplace_back(group_of_[r], group_of_[c]);
            complete = false;
            keys[k] = -1;
            --shift;  // taken as inserted: the next slot is matched with the same old one
            continue;
          }
          slot = int(found - inner);
          --shift;
        }
      }
      keys[k] = key;
      index[k] = slot;
      values[slot] += t[k].value();
    }
    begin = segment_end[s];
  }
  return complete;
}

// Adds the fixed blocks into H on pattern_ (values already reset); false (and the missing
// group blocks in pending_blocks_) if some block falls outside it.
bool HessianAssembler::fillBlocks(const std::vector<FixedHessianBlocks>& blocks, SpMat& H) {
  const int* outer = pattern_.outerIndexPtr();
  const int* inner = pattern_.innerIndexPtr();
  double* values = H.valuePtr();
  if (block_slots_.size() < blocks.size()) block_slots_.resize(blocks.size());
  bool complete = true;
  for (size_t b = 0; b < blocks.size(); ++b) {
    const FixedHessianBlocks& list = blocks[b];
    if (list.empty()) continue;
    const std::vector<std::pair<int, int>>& positions = *list.positions;
    const int count = int(positions.size());
    BlockSlots& cache = block_slots_[b];
    if (cache.offset != list.offset || cache.positions != positions ||
        cache.slots.size() != 3 * positions.size()) {
      const long long n = pattern_.rows();
      checkBlockPositions(list, b, int(n));
      // Distinct positions: the blocks are added in parallel below.
      std::vector<long long> keys(positions.size());
      for (int k = 0; k < count; ++k)
        keys[size_t(k)] = (long long)positions[size_t(k)].second * n + positions[size_t(k)].first;
      std::sort(keys.begin(), keys.end());
      if (std::adjacent_find(keys.begin(), keys.end()) != keys.end())
        throw InputError("HessianAssembler::assemble: fixed-block list " + std::to_string(b) +
                         " has two blocks at the same position");
      cache.positions = positions;
      cache.offset = list.offset;
      cache.slots.assign(3 * positions.size(), -1);
      bool found_all = true;
      for (int k = 0; k < count; ++k) {
        const int r = positions[size_t(k)].first + list.offset;
        const int c0 = positions[size_t(k)].second + list.offset;
        for (int j = 0; j < 3; ++j) {
          const int c = c0 + j;
          const int* begin = inner + outer[c];
          const int* end = inner + outer[c + 1];
          const int* found = std::lower_bound(begin, end, r);
          // Rows r … r + 2 are consecutive entries of the column when all three are stored.
          if (end - found < 3 || found[0] != r || found[2] != r + 2) {
            for (int i = 0; i < 3; ++i)
              pending_blocks_.emplace_back(group_of_[r + i], group_of_[c]);
            found_all = false;
            continue;
          }
          cache.slots[3 * size_t(k) + size_t(j)] = int(found - inner);
        }
      }
      if (!found_all) {
        cache.slots.clear();  // looked up again after the growth
        complete = false;
        continue;
      }
    }
    const int* slots = cache.slots.data();
    const Mat3* B = list.values->data();
#pragma omp parallel for schedule(static) if (count > 20000)
    for (int k = 0; k < count; ++k)
      for (int j = 0; j < 3; ++j) {
        double* v = values + slots[3 * k + j];
        v[0] += B[k](0, j);
        v[1] += B[k](1, j);
        v[2] += B[k](2, j);
      }
  }
  return complete;
}

// Adds pending_blocks_ (whole group × group blocks) to the pattern, column by column, and moves
// the cached value slots to their entries' new places (a linear pass: no sort of the triplets).
void HessianAssembler::grow(int n) {
  for (BlockSlots& cache : block_slots_) cache.slots.clear();  // looked up again on the new pattern
  const bool grouped = !group_start_.empty();
  const int groups = grouped ? int(group_start_.size()) - 1 : n;
  const auto first = [&](int g) { return grouped ? group_start_[g] : g; };
  const auto last = [&](int g) { return grouped ? group_start_[g + 1] : g + 1; };
  // Pending row groups bucketed by column group, without duplicates, sorted.
  std::vector<int> start(groups + 1, 0);
  for (const auto& [gr, gc] : pending_blocks_) {
    if (gr < 0 || gr >= groups || gc < 0 || gc >= groups)
      throw InputError("HessianAssembler::addBlocks: block (" + std::to_string(gr) + ", " +
                       std::to_string(gc) + ") is outside the " + std::to_string(groups) +
                       " DoF groups");
    ++start[gc + 1];
  }
  for (int g = 0; g < groups; ++g) start[g + 1] += start[g];
  std::vector<int> row_groups(pending_blocks_.size());
  {
    std::vector<int> next(start.begin(), start.end() - 1);
    for (const auto& [gr, gc] : pending_blocks_) row_groups[next[gc]++] = gr;
  }
  pending_blocks_.clear();
  std::vector<int> mark(groups, -1), unique_end(groups, 0);
  for (int gc = 0; gc < groups; ++gc) {
    int* begin = row_groups.data() + start[gc];
    int* end = begin;
    for (int k = start[gc]; k < start[gc + 1]; ++k)
      if (mark[row_groups[k]] != gc) mark[row_groups[k]] = gc, *end++ = row_groups[k];
    std::sort(begin, end);
    unique_end[gc] = int(end - row_groups.data());
  }

  const bool had_pattern = pattern_.rows() == n;
  const int* old_outer = had_pattern ? pattern_.outerIndexPtr() : nullptr;
  const int* old_inner = had_pattern ? pattern_.innerIndexPtr() : nullptr;
  const Eigen::Index old_nnz = had_pattern ? pattern_.nonZeros() : 0;
  std::vector<int> outer(n + 1, 0), inner, moved(old_nnz);
  inner.reserve(size_t(old_nnz) + row_groups.size());
  std::vector<int> added;
  for (int c = 0; c < n; ++c) {
    const int gc = grouped ? group_of_[c] : c;
    added.clear();
    for (int k = start[gc]; k < unique_end[gc]; ++k)
      for (int r = first(row_groups[k]); r < last(row_groups[k]); ++r) added.push_back(r);
    // Merge the column's old rows (sorted) with the added ones (sorted), recording where each
    // old entry lands.
    int o = had_pattern ? old_outer[c] : 0;
    const int o_end = had_pattern ? old_outer[c + 1] : 0;
    size_t a = 0;
    while (o < o_end || a < added.size()) {
      if (a == added.size() || (o < o_end && old_inner[o] <= added[a])) {
        if (a < added.size() && old_inner[o] == added[a]) ++a;
        moved[o] = int(inner.size());
        inner.push_back(old_inner[o++]);
      } else {
        inner.push_back(added[a++]);
      }
    }
    outer[c + 1] = int(inner.size());
  }
  if (inner.size() > size_t(std::numeric_limits<int>::max()))
    throw Error("HessianAssembler: the Hessian pattern exceeds 2^31 entries");
  const std::vector<double> zeros(inner.size(), 0.0);
  pattern_ = Eigen::Map<const SpMat>(n, n, Eigen::Index(inner.size()), outer.data(), inner.data(),
                                     zeros.data());
  if (had_pattern) {
    for (auto& index : slot_index_)
      for (int& i : index) i = i < old_nnz ? moved[i] : 0;
  } else {
    for (auto& keys : slot_key_) std::fill(keys.begin(), keys.end(), -1);
  }
  ++pattern_builds_;
}

}  // namespace flsh
