#include "flsh/solve/scene.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <omp.h>
#include <string>

#include "flsh/contact/contact_energy.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "core/first_failure.h"

namespace flsh {

namespace {
// Vertices per broad-phase cluster: small enough to prune, large enough to amortize the test.
constexpr int kClusterSize = 24;
using Mat6 = Eigen::Matrix<double, 6, 6>;
using Mat36 = Eigen::Matrix<double, 3, 6>;
using Vec9 = Eigen::Matrix<double, 9, 1>;
using Mat9 = Eigen::Matrix<double, 9, 9>;
using Box3 = Eigen::AlignedBox3d;

/// ½(g pᵀ + p gᵀ) − (g·p) I: the Hessian of gᵀ exp([δ]×) p at δ = 0 (second-order rotation
/// term of a point p = R(X − J) rotated by a world-frame increment δ, contracted with g).
Mat3 rotationCurvature(const Vec3& g, const Vec3& p) {
  Mat3 M = 0.5 * (g * p.transpose() + p * g.transpose());
  M.diagonal().array() -= g.dot(p);
  return M;
}
}  // namespace

/// Skinning data of one simulable and its posed capsules and (lazily) nodes at the last state
/// seen. Nodes are x_i = Σ_b w_ib (R_b (Y_i − J_b) + t_b), the formula of
/// Simulable::getNodes, computed only for the vertex groups the broad phase keeps. Y is the
/// unposed surface: the rest vertices X for the skeleton, getUnposedSurface() (moving with the
/// soft-tissue displacements) for the soft-tissue model. The rest bounds below are taken on X;
/// a soft vertex is further off by at most |Σ_b w_ib R_b (Y_i − X_i)| ≤ Σ_b |w_ib| |Y_i − X_i|.
struct Scene::AvatarContactData {
  int bones = 0;
  // Soft tissue: each vertex's u as state entries of the simulable, u_i = Σ w q.segment<3>(index)
  // over soft_basis[soft_start[i] .. soft_start[i + 1]) (one entry per soft node in the FEM,
  // the handles reaching it in the ROM, none on bone nodes), and the unposed surface Y (#V × 3,
  // m) of the cached posed data; with it the displacement margins of each cluster and bone
  // group (m).
  bool soft = false;
  std::vector<int> soft_start;
  std::vector<std::pair<int, double>> soft_basis;
  MatX3 surface;
  std::vector<double> cluster_shift, group_shift;
  // Per vertex i, its nonzero skinning weights: bones weight_bone[k], values weight_value[k]
  // for k in [weight_start[i], weight_start[i + 1]).
  std::vector<int> weight_start, weight_bone;
  std::vector<double> weight_value;
  // Vertices grouped by their dominant bone b (group b), each group split into spatial
  // clusters of at most kClusterSize vertices: cluster k (of bone cluster_bone[k]) holds
  // cluster_vertices[cluster_start[k] .. cluster_start[k + 1]); the groups of bone b are
  // clusters bone_clusters[b] .. bone_clusters[b + 1]. In the bone's rest frame (offsets
  // X − J_b) a cluster lies in the sphere (offset, radius) and within `extent` of J_b.
  struct Bound {
    Vec3 offset = Vec3::Zero();
    double radius = 0.0, extent = 0.0;
    // Other bones c: max w_ic over the set, and the set's extent about c's joint, max |X − J_c|.
    struct CoWeight {
      int bone;
      double weight, extent;
    };
    std::vector<CoWeight> coweights;
  };
  std::vector<int> bone_clusters, cluster_start, cluster_vertices, cluster_bone;
  std::vector<Bound> group_rest, cluster_rest;

  // Cache key: the bone transforms (and for soft tissue the surface Y) the posed data below
  // belong to; `version` counts changes.
  bool valid = false;
  long version = 0;
  std::vector<Mat3> key_rotations;
  MatX3 key_positions;

  // Posed bounds: a vertex x_i = x_ib + Σ_{c≠b} w_ic (x_ic − x_ib) (x_ib: its rigid position on
  // its dominant bone b) lies within `bound` of `center`, since
  // |x_ic − x_ib| ≤ ‖R_c − R_b‖₂ |X − J_b| + |R_c (J_b − J_c) + t_c − t_b| and equally
  // ≤ ‖R_c − R_b‖₂ |X − J_c| + |R_b (J_b − J_c) + t_c − t_b|; the smaller is used (for a
  // vertex near the joint of b and c one of the two joint terms is the small joint-spring gap).
  // joint_gap_c holds the second joint term.
  std::vector<Vec3> group_center, cluster_center;
  std::vector<double> group_bound, cluster_bound;
  std::vector<double> rotation_gap, joint_gap, joint_gap_c;  // per bone pair b·bones + c
  std::vector<char> cluster_posed;  // nodes of the cluster computed for this state
  MatX3 nodes;                      // #V × 3, valid for posed clusters only
  struct PosedCapsule {
    int bone = 0;
    Vec3 a_rotated, b_rotated;  // R_b (a − J_b), R_b (b − J_b): a' = a_rotated + t_b
    Vec3 a, b;                  // posed end points, m
    double radius = 0.0;
    Vec3 center;  // bounding sphere of the capsule
    double bound = 0.0;
  };
  std::vector<PosedCapsule> capsules;
};

namespace {
/// Appends the dense block B at (row, col) as triplets.
template <class Derived>
void appendBlock(std::vector<Triplet>& H, int row, int col, const Eigen::MatrixBase<Derived>& B) {
  for (int c = 0; c < B.cols(); ++c)
    for (int r = 0; r < B.rows(); ++r) H.emplace_back(row + r, col + c, B(r, c));
}

/// Squared distance from x to the segment [a, b].
double segmentDistanceSquared(const Vec3& x, const Vec3& a, const Vec3& b) {
  const Vec3 ab = b - a;
  const double length2 = ab.squaredNorm();
  double t = length2 > 0.0 ? (x - a).dot(ab) / length2 : 0.0;
  t = std::min(1.0, std::max(0.0, t));
  return (x - a - t * ab).squaredNorm();
}
}  // namespace

/// 6 × 6 Hessian blocks between the bones of two simulables, accumulated per vertex–capsule
/// contact and flushed as triplets once per ordered pair (so each bone pair emits 36 entries,
/// not 36 per contact).
struct Scene::BlockAccumulator {
  int size = 0;  // bones of A followed by bones of B
  std::vector<Mat6> blocks;
  std::vector<char> touched;
  std::vector<int> touched_list;

  void reset(int bones) {
    if (bones != size) {
      size = bones;
      blocks.assign(size_t(size) * size, Mat6::Zero());
      touched.assign(size_t(size) * size, 0);
    }
    touched_list.clear();
  }
  Mat6& at(int i, int j) {
    const int index = i * size + j;
    if (!touched[index]) {
      touched[index] = 1;
      blocks[index].setZero();
      touched_list.push_back(index);
    }
    return blocks[index];
  }
  /// Appends the touched blocks; local bone l maps to merged DoF dof(l) + 0..5.
  template <class DofOf>
  void flush(const DofOf& dof, std::vector<Triplet>& H) {
    for (int index : touched_list) {
      const int row = dof(index / size), col = dof(index % size);
      const Mat6& B = blocks[index];
      for (int c = 0; c < 6; ++c)
        for (int r = 0; r < 6; ++r) H.emplace_back(row + r, col + c, B(r, c));
      touched[index] = 0;
    }
    touched_list.clear();
  }
};

// ---- general Hessian pattern -------------------------------------------------------------------

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

// H takes P's pattern (kept, with its storage, when it already has it) with zero values (or,
// zero = false, values left to the caller). With
// the full n × n pattern the column starts decide (a compressed column holds sorted distinct
// rows): no comparison of the n² row indices.
void resetToPattern(const SpMat& P, SpMat& H, bool zero = true) {
  const int n = int(P.rows());
  const Eigen::Index nnz = P.nonZeros();
  const bool full = nnz == Eigen::Index(n) * n;
  const bool same = H.rows() == n && H.cols() == n && H.isCompressed() && H.nonZeros() == nnz &&
                    std::equal(P.outerIndexPtr(), P.outerIndexPtr() + n + 1, H.outerIndexPtr()) &&
                    (full ||
                     std::equal(P.innerIndexPtr(), P.innerIndexPtr() + nnz, H.innerIndexPtr()));
  if (!same) H = P;
  if (zero) std::fill(H.valuePtr(), H.valuePtr() + nnz, 0.0);
}

}  // namespace

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
                       std::to_string(blocks[b].values ? blocks[b].values->size() : 0) +
                       " values");
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
          throw InputError("HessianAssembler::assemble: triplet " + std::to_string(k) +
                           " at (" + std::to_string(r) + ", " + std::to_string(c) +
                           ") is outside the " + std::to_string(n) + " × " + std::to_string(n) +
                           " matrix");
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
            for (int i = 0; i < 3; ++i) pending_blocks_.emplace_back(group_of_[r + i], group_of_[c]);
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

NewtonOptions softTissueNewtonDefaults() {
  NewtonOptions options;
  options.exact_hessian = true;
  options.linear_solver = LinearSolverType::Cholmod;
  options.lagged.enabled = true;  // one 25k-DoF factorization costs ~20 preconditioned CG steps
  // Looser than the generic 1e-2: fewer refreshes of the lagged factor for the same Newton
  // iterations and accuracy (see scene.h).
  options.lagged.cg_relative_tolerance = 5e-2;
  options.gradient_tolerance = 1e-5;  // measured trade-off: see scene.h
  // Chord steps near convergence: FEM walk, 30 steps: 3.70 instead of 4.10 assemblies per
  // step for the same Newton and PCG counts, 0.0097 mm from a 1e-8 solve (0.0070 without);
  // 1e-3: 4.33 Newton iterations per step.
  options.lagged.reuse_hessian_below = 1e-4;
  return options;
}

// Measured on the walking full body (rom_benchmark, docs/benchmarks.md): the exact Hessian at
// 1e-6 stays within 0.025 mm of a 1e-9 solve at the speed of the PSD form at 1e-5 (1.2 mm off);
// the lagged factor saves most factorizations (~70 against ~60 steps/s).
NewtonOptions reducedNewtonDefaults() {
  NewtonOptions options;
  options.exact_hessian = true;
  options.lagged.enabled = true;
  options.gradient_tolerance = 1e-6;
  // Chord steps near convergence: walk, 300 steps: 3.57 instead of 4.07 assemblies per step,
  // 4.07 instead of 4.04 Newton iterations, the same 0.0017 mm from a 1e-9 solve; 1e-3: 4.13
  // iterations, 3.53 assemblies.
  options.lagged.reuse_hessian_below = 1e-4;
  return options;
}

Scene::Scene(const SceneOptions& options)
    : options_(options), blocks_(std::make_unique<BlockAccumulator>()) {
  const double k = options.avatar_contact_options.stiffness;
  if (!(k >= 0.0) || !std::isfinite(k))
    throw InputError(
        "Scene: SceneOptions::avatar_contact_options.stiffness must be finite and "
        "≥ 0 (N/m³), got " +
        std::to_string(k));
}

Scene::~Scene() = default;

void Scene::addSimulable(std::shared_ptr<Simulable> simulable) {
  if (!simulable) throw InputError("Scene::addSimulable: simulable is null");
  if (!simulables_.empty()) {
    const double h0 = simulables_.front()->options().time_step;
    const double h = simulable->options().time_step;
    if (std::abs(h - h0) > 1e-12 * std::abs(h0))
      throw InputError("Scene::addSimulable: all simulables must share one time step; simulable " +
                       std::to_string(simulables_.size()) +
                       " has time_step = " + std::to_string(h) + " s, expected " +
                       std::to_string(h0) + " s (simulable 0)");
  }
  simulable->setColliders(colliders_);
  offsets_.push_back(num_dofs_);
  num_dofs_ += simulable->numDofs();
  simulables_.push_back(std::move(simulable));
  contact_data_.emplace_back();
  general_.reset();  // its DoF groups follow the simulables
}

void Scene::addCollider(const Collider& collider) {
  colliders_.push_back(collider);
  for (auto& s : simulables_) s->setColliders(colliders_);
}

void Scene::initialize() {
  for (auto& s : simulables_) s->initialize();
  for (auto& data : contact_data_)
    if (data) data->valid = false;
}

bool Scene::hasSoftTissue() const {
  for (const auto& s : simulables_)
    if (s->numDofs() > s->numBoneDofs()) return true;
  return false;
}

bool Scene::hasFemSoftTissue() const {
  for (const auto& s : simulables_)
    if (s->numDofs() > s->numBoneDofs() && !s->hasReducedModel()) return true;
  return false;
}

const NewtonOptions& Scene::newtonOptions() const {
  if (!hasSoftTissue()) return options_.newton;
  return hasFemSoftTissue() ? options_.soft_tissue_newton : options_.reduced_newton;
}

void Scene::ensureSolver() {
  // Auto, skeleton: the simplicial sparse Cholesky. The scene's Hessian is block tree-sparse
  // with a fixed pattern, so one analysis serves every step; measured on the walking SMPL-size
  // avatar it factors in ~36 µs against ~70 µs for the dense LLT (144 DoFs) and ~290 µs for
  // CHOLMOD's supernodal factor, and ~73 µs against ~380 µs (dense) for two avatars.
  // Auto, soft tissue: CHOLMOD's supernodal factor (thousands of 3 × 3 node blocks).
  if (!solver_) {
    const LinearSolverType requested = newtonOptions().linear_solver;
    // Auto, reduced model only: dense up to 1500 DoFs (the handle blocks are dense).
    const LinearSolverType type =
        requested != LinearSolverType::Auto ? requested
        : hasFemSoftTissue()                ? LinearSolverType::Cholmod
        : hasSoftTissue()     ? (num_dofs_ <= 1500 ? LinearSolverType::Dense : LinearSolverType::Cholmod)
                              : LinearSolverType::SparseLLT;
    solver_ = makeLinearSolver(type, num_dofs_);
    solver_type_ = type;
    last_solver_dofs_ = num_dofs_;
  }
}

StepStats Scene::step() {
  if (simulables_.empty())
    throw Error("Scene::step: the scene has no simulables (call addSimulable first)");
  const auto start = std::chrono::steady_clock::now();
  // Kept so that a step ending in a non-finite state can be undone (below).
  std::vector<SimulableStep> before;
  before.reserve(simulables_.size());
  for (auto& s : simulables_) before.push_back(s->saveStep());
  for (auto& s : simulables_) s->preUpdate();
  ensureSolver();
  if (options_.lower_energy_start && hasSoftTissue()) {
    const double at_prediction = energy();
    for (auto& s : simulables_) s->setStepStart(Simulable::StepStart::PreviousState);
    // A non-finite energy at the prediction keeps the previous state.
    if (at_prediction <= energy())
      for (auto& s : simulables_) s->setStepStart(Simulable::StepStart::Prediction);
  }
  StepStats stats;
  stats.newton = newtonSolve(*this, newtonOptions(), solver_.get());
  // Newton rejects non-finite energies, but a state can still overflow where no energy looks
  // (e.g. a rotation): never hand a NaN state on. The scene goes back to before the step.
  for (size_t i = 0; i < simulables_.size(); ++i) {
    if (simulables_[i]->getState().allFinite()) continue;
    for (size_t j = 0; j < simulables_.size(); ++j) simulables_[j]->restoreStep(before[j]);
    throw Error("Scene::step: simulable " + std::to_string(i) +
                " has a non-finite state after the step to t = " +
                std::to_string(before[i].time + simulables_[i]->options().time_step) +
                " s (Newton: " + stats.newton.message +
                "); the scene is restored to its state before the step");
  }
  // Newton's last evaluation is the gradient at the final state, so these counts belong to it.
  for (auto& s : simulables_) stats.active_contacts += s->stats().active_contacts;
  stats.active_contacts += avatar_contacts_;
  for (auto& s : simulables_) s->postUpdate();
  stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return stats;
}

double Scene::time() const { return simulables_.empty() ? 0.0 : simulables_.front()->time(); }

void Scene::setStatic(bool on) {
  for (auto& s : simulables_) s->setStatic(on);
}

int Scene::numDofs() const { return num_dofs_; }

bool Scene::avatarContactActive() const {
  return options_.avatar_contact && simulables_.size() >= 2 &&
         options_.avatar_contact_options.stiffness > 0.0;
}

double Scene::energy() {
  double e = 0.0;
  for (auto& s : simulables_) e += s->getDynamicEnergyScalar() + s->getPotentialEnergyScalar();
  if (avatarContactActive()) e += avatarContactEnergy(nullptr, nullptr, true);
  return e;
}

void Scene::gradient(VecX& g) {
  double energy = 0.0;  // the same passes give it (Simulable::getGradientVector does the same)
  energyAndGradient(energy, g);
}

bool Scene::energyAndGradient(double& energy, VecX& g) {
  g.setZero(num_dofs_);
  energy = 0.0;
  for (size_t i = 0; i < simulables_.size(); ++i)
    energy += simulables_[i]->getEnergyAndGradientVector(g, offsets_[i]);
  if (avatarContactActive()) energy += avatarContactEnergy(&g, nullptr, true);
  return true;
}

void Scene::hessian(SpMat& H, bool psd) {
  triplets_.clear();
  if (usesGeneralPattern()) {
    // One cached segment per energy kind, so a term whose triplet count changes (contacts)
    // does not move the others' value slots.
    segment_end_.clear();
    fixed_blocks_.clear();
    for (size_t i = 0; i < simulables_.size(); ++i) {
      // The FEM's elastic node pairs and its bone–tissue coupling come as fixed blocks (the
      // same lists in the same order every call): no 9 triplets per block.
      segment_end_.push_back(
          simulables_[i]->getHessianTripletVector(triplets_, fixed_blocks_, offsets_[i], psd));
      segment_end_.push_back(triplets_.size());
    }
    if (avatarContactActive()) avatarContactEnergy(nullptr, &triplets_, psd);
    segment_end_.push_back(triplets_.size());
    if (!general_) setUpGeneralPattern();
    general_->assemble(triplets_, segment_end_, fixed_blocks_, num_dofs_, H);
    return;
  }
  for (size_t i = 0; i < simulables_.size(); ++i) {
    simulables_[i]->getDynamicHessianTripletVector(triplets_, offsets_[i], psd);
    simulables_[i]->getPotentialHessianTripletVector(triplets_, offsets_[i], psd);
  }
  if (avatarContactActive()) avatarContactEnergy(nullptr, &triplets_, psd);
  if (!fillHessian(H)) {
    // A block outside the pattern (a new avatar–avatar pair): grow the pattern once.
    rebuildHessianPattern();
    if (!fillHessian(H)) throw Error("Scene::hessian: the Hessian pattern misses an entry");
  }
}

// Writes the triplets into H with the fixed pattern (H takes the pattern if it has another
// one). False if a triplet falls outside the pattern.
bool Scene::fillHessian(SpMat& H) const {
  const int n = num_dofs_, bones = n / 6;
  if (hessian_pattern_.rows() != n) return false;
  const SpMat& P = hessian_pattern_;
  resetToPattern(P, H);
  double* values = H.valuePtr();
  const int* outer = H.outerIndexPtr();
  const size_t count = triplets_.size();
  if (fill_key_.size() < count) {
    fill_key_.resize(count, -1);
    fill_index_.resize(count, 0);
  }
  for (size_t k = 0; k < count; ++k) {
    const Triplet& t = triplets_[k];
    const int r = t.row(), c = t.col();
    const long long key = (long long)r * n + c;
    if (key != fill_key_[k]) {
      const int rank = block_rank_[size_t(r / 6) * bones + c / 6];
      if (rank < 0) return false;
      fill_key_[k] = key;
      fill_index_[k] = outer[c] + 6 * rank + r % 6;
    }
    values[fill_index_[k]] += t.value();
  }
  return true;
}

void Scene::rebuildHessianPattern() {
  const int n = num_dofs_, bones = n / 6;
  // Block pairs (a, b): the old pattern's, the current triplets', every bone's diagonal, and
  // within each simulable every pair of bones that share a skinned vertex.
  std::vector<char> present(size_t(bones) * bones, 0);
  if (block_rank_.size() == present.size())
    for (size_t k = 0; k < present.size(); ++k) present[k] = block_rank_[k] >= 0;
  for (const Triplet& t : triplets_) present[size_t(t.row() / 6) * bones + t.col() / 6] = 1;
  for (int b = 0; b < bones; ++b) present[size_t(b) * bones + b] = 1;
  for (size_t i = 0; i < simulables_.size(); ++i) {
    const Simulable& sim = *simulables_[i];
    const MatX& W = sim.avatar().body().weights;  // #V × bones
    if (sim.numDofs() != 6 * W.cols()) continue;
    const int first = offsets_[i] / 6, local_bones = int(W.cols());
    std::vector<int> influencing;
    for (int v = 0; v < W.rows(); ++v) {
      influencing.clear();
      for (int b = 0; b < local_bones; ++b)
        if (W(v, b) != 0.0) influencing.push_back(first + b);
      for (int a : influencing)
        for (int b : influencing) present[size_t(a) * bones + b] = 1;
    }
  }
  std::vector<Triplet> structure;
  block_rank_.assign(present.size(), -1);
  for (int bc = 0; bc < bones; ++bc) {
    int rank = 0;
    for (int br = 0; br < bones; ++br) {
      if (!present[size_t(br) * bones + bc]) continue;
      block_rank_[size_t(br) * bones + bc] = rank++;
      for (int c = 0; c < 6; ++c)
        for (int r = 0; r < 6; ++r) structure.emplace_back(6 * br + r, 6 * bc + c, 0.0);
    }
  }
  hessian_pattern_.resize(n, n);
  hessian_pattern_.setFromTriplets(structure.begin(), structure.end());
  hessian_pattern_.makeCompressed();
  fill_key_.clear();  // value indices refer to the old pattern
}

bool Scene::usesGeneralPattern() const {
  if (options_.general_hessian_pattern) return true;
  for (const auto& s : simulables_)
    if (s->numDofs() != s->numBoneDofs()) return true;  // not only bone blocks
  return false;
}

void Scene::setUpGeneralPattern() {
  // DoF groups: 6 per bone, 3 per soft-tissue node (leftover DoFs of another layout: 1 each).
  std::vector<int> group_start{0};
  std::vector<int> first_group(simulables_.size());
  for (size_t i = 0; i < simulables_.size(); ++i) {
    const Simulable& sim = *simulables_[i];
    first_group[i] = int(group_start.size()) - 1;
    const int end = offsets_[i] + sim.numDofs();
    int dof = offsets_[i];
    for (; dof + 6 <= offsets_[i] + sim.numBoneDofs(); dof += 6) group_start.push_back(dof + 6);
    for (; dof + 3 <= end && dof >= offsets_[i] + sim.numBoneDofs(); dof += 3)
      group_start.push_back(dof + 3);
    for (; dof < end; ++dof) group_start.push_back(dof + 1);
  }
  general_ = std::make_unique<HessianAssembler>();
  general_->setGroups(group_start);
  // The dense solver gets a dense matrix anyway (reduced-model scenes: the handle block is
  // dense): full storage spares the slot cache (rom_benchmark: the fill was ~20 % of a step).
  if (solver_ && solver_type_ == LinearSolverType::Dense &&
      num_dofs_ <= HessianAssembler::kMaxDenseDofs) {
    general_->setDense(true);
    return;
  }
  // Couplings collider contacts create (as for the block pattern): within each simulable,
  // every pair of bones that share a surface vertex, and each soft surface vertex's u with
  // those bones.
  std::vector<std::pair<int, int>> blocks;
  std::vector<int> influencing;
  std::vector<char> pair_seen;
  for (size_t i = 0; i < simulables_.size(); ++i) {
    const Simulable& sim = *simulables_[i];
    const MatX& W = sim.avatar().body().weights;  // #V × bones
    const int bones = int(W.cols());
    if (sim.numBoneDofs() != 6 * bones) continue;
    const int bone0 = first_group[i];
    pair_seen.assign(size_t(bones) * bones, 0);
    const bool soft = sim.numDofs() > sim.numBoneDofs();
    for (int v = 0; v < W.rows(); ++v) {
      influencing.clear();
      for (int b = 0; b < bones; ++b)
        if (W(v, b) != 0.0) influencing.push_back(b);
      for (int a : influencing)
        for (int b : influencing)
          if (!pair_seen[size_t(a) * bones + b]) {
            pair_seen[size_t(a) * bones + b] = 1;
            blocks.emplace_back(bone0 + a, bone0 + b);
          }
      if (!soft) continue;
      // The groups of the state entries u_v is made of (groups of 3 after the bones).
      for (const auto& entry : sim.nodeDisplacementBasis(v)) {
        const int group = bone0 + bones + (entry.first - sim.numBoneDofs()) / 3;
        for (int b : influencing) {
          blocks.emplace_back(group, bone0 + b);
          blocks.emplace_back(bone0 + b, group);
        }
      }
    }
  }
  general_->addBlocks(blocks);
}

void Scene::step(const VecX& dq) {
  if (dq.size() != num_dofs_)
    throw InputError("Scene::step: dq must have numDofs() = " + std::to_string(num_dofs_) +
                     " entries, got " + std::to_string(dq.size()));
  for (size_t i = 0; i < simulables_.size(); ++i)
    simulables_[i]->updateState(dq.segment(offsets_[i], simulables_[i]->numDofs()));
}

void Scene::push() {
  for (auto& s : simulables_) s->pushState();
  ++stack_depth_;
}

void Scene::pop() {
  if (stack_depth_ == 0) throw Error("Scene::pop: no state was pushed");
  for (auto& s : simulables_) s->popState();
  --stack_depth_;
}

// Keeps the current (accepted) states and forgets the saved ones: no pop-and-reapply.
bool Scene::discardPushed() {
  if (stack_depth_ == 0) throw Error("Scene::discardPushed: no state was pushed");
  for (auto& s : simulables_) s->discardState();
  --stack_depth_;
  return true;
}

void Scene::fixKinematic(VecX& g, SpMat* H) {
  bool any_kinematic = false;
  for (size_t i = 0; i < simulables_.size(); ++i) {
    simulables_[i]->fixVectorKinematic(g, offsets_[i]);
    any_kinematic = any_kinematic || !simulables_[i]->options().kinematic_bones.empty();
  }
  if (!H || !any_kinematic) return;
  // In place, keeping the pattern (and the solver's analysis): kinematic rows and columns
  // become those of the identity. hessian() always stores the diagonal.
  std::vector<char> kinematic(num_dofs_, 0);
  for (size_t i = 0; i < simulables_.size(); ++i)
    for (int b : simulables_[i]->options().kinematic_bones)
      std::fill_n(kinematic.begin() + offsets_[i] + 6 * b, 6, 1);
  for (int k = 0; k < H->outerSize(); ++k)
    for (SpMat::InnerIterator it(*H, k); it; ++it)
      if (kinematic[it.row()] || kinematic[it.col()])
        it.valueRef() = it.row() == it.col() ? 1.0 : 0.0;
}

// ---- avatar–avatar contact -------------------------------------------------------------------

Scene::AvatarContactData& Scene::contactData(int i) const {
  auto& slot = contact_data_[i];
  const Simulable& sim = *simulables_[i];
  const SoftAvatar& avatar = sim.avatar();
  const MatX3& X = avatar.restVertices();
  const MatX3& J = avatar.restJoints();
  if (!slot) {
    const MatX& W = avatar.body().weights;
    const int V = int(W.rows()), bones = int(W.cols());
    if (sim.numBoneDofs() != 6 * bones)
      throw Error("Scene::avatarContactEnergy: simulable " + std::to_string(i) + " has " +
                  std::to_string(sim.numBoneDofs()) +
                  " bone DoFs; avatar–avatar contact needs 6 per skinning bone (" +
                  std::to_string(6 * bones) + ")");
    if (X.rows() != V || avatar.vertexAreas().size() != V || J.rows() != bones)
      throw Error("Scene::avatarContactEnergy: simulable " + std::to_string(i) +
                  ": avatar rest vertices / areas / joints do not match the skinning weights " +
                  shapeString({long(V), long(bones)}) + " (is the avatar initialized?)");
    auto data = std::make_unique<AvatarContactData>();
    data->bones = bones;
    data->soft = sim.numDofs() > sim.numBoneDofs();
    if (data->soft) {
      data->soft_start.assign(1, 0);
      for (int v = 0; v < V; ++v) {
        for (const auto& [index, weight] : sim.nodeDisplacementBasis(v)) {
          if (index < sim.numBoneDofs() || index + 3 > sim.numDofs())
            throw Error("Scene::avatarContactEnergy: simulable " + std::to_string(i) +
                        ": nodeDisplacementBasis(" + std::to_string(v) + ") names state index " +
                        std::to_string(index) + ", outside the soft-tissue DoFs [" +
                        std::to_string(sim.numBoneDofs()) + ", " + std::to_string(sim.numDofs()) +
                        ")");
          data->soft_basis.emplace_back(index, weight);
        }
        data->soft_start.push_back(int(data->soft_basis.size()));
      }
    }
    data->weight_start.reserve(V + 1);
    std::vector<int> dominant(V, 0);
    for (int v = 0; v < V; ++v) {
      data->weight_start.push_back(int(data->weight_bone.size()));
      double best = -1.0;
      for (int b = 0; b < bones; ++b) {
        const double w = W(v, b);
        if (w == 0.0) continue;
        data->weight_bone.push_back(b);
        data->weight_value.push_back(w);
        if (w > best) best = w, dominant[v] = b;
      }
    }
    data->weight_start.push_back(int(data->weight_bone.size()));
    // Rest bound of a vertex set on bone b.
    const auto restBound = [&](int b, const int* begin, const int* end) {
      AvatarContactData::Bound bound;
      Box3 box;
      box.setEmpty();
      for (const int* v = begin; v != end; ++v) box.extend((X.row(*v) - J.row(b)).transpose());
      bound.offset = box.center();
      std::vector<double> coweight(bones, 0.0), coextent(bones, 0.0);
      for (const int* v = begin; v != end; ++v) {
        const Vec3 offset = (X.row(*v) - J.row(b)).transpose();
        bound.radius = std::max(bound.radius, (offset - bound.offset).norm());
        bound.extent = std::max(bound.extent, offset.norm());
        for (int w = data->weight_start[*v]; w < data->weight_start[*v + 1]; ++w)
          if (data->weight_bone[w] != b)
            coweight[data->weight_bone[w]] =
                std::max(coweight[data->weight_bone[w]], data->weight_value[w]);
      }
      for (int c = 0; c < bones; ++c) {
        if (!(coweight[c] > 0.0)) continue;
        for (const int* v = begin; v != end; ++v)
          coextent[c] = std::max(coextent[c], (X.row(*v) - J.row(c)).norm());
        bound.coweights.push_back({c, coweight[c], coextent[c]});
      }
      return bound;
    };
    std::vector<std::vector<int>> group(bones);
    for (int v = 0; v < V; ++v) group[dominant[v]].push_back(v);
    data->bone_clusters.assign(1, 0);
    data->cluster_start.assign(1, 0);
    for (int b = 0; b < bones; ++b) {
      data->group_rest.push_back(restBound(b, group[b].data(), group[b].data() + group[b].size()));
      // Median splits along the longest axis until the pieces are small.
      std::vector<std::pair<int, int>> pending;
      if (!group[b].empty()) pending.emplace_back(0, int(group[b].size()));
      while (!pending.empty()) {
        const auto [begin, end] = pending.back();
        pending.pop_back();
        int* first = group[b].data() + begin;
        int* last = group[b].data() + end;
        if (end - begin <= kClusterSize) {
          data->cluster_vertices.insert(data->cluster_vertices.end(), first, last);
          data->cluster_start.push_back(int(data->cluster_vertices.size()));
          data->cluster_bone.push_back(b);
          data->cluster_rest.push_back(restBound(b, first, last));
          continue;
        }
        Box3 box;
        box.setEmpty();
        for (const int* v = first; v != last; ++v) box.extend(X.row(*v).transpose());
        int axis = 0;
        box.sizes().maxCoeff(&axis);
        int* middle = first + (end - begin) / 2;
        std::nth_element(first, middle, last,
                         [&](int u, int v) { return X(u, axis) < X(v, axis); });
        pending.emplace_back(begin, begin + (end - begin) / 2);
        pending.emplace_back(begin + (end - begin) / 2, end);
      }
      data->bone_clusters.push_back(int(data->cluster_bone.size()));
    }
    const int clusters = int(data->cluster_bone.size());
    data->group_center.assign(bones, Vec3::Zero());
    data->group_bound.assign(bones, 0.0);
    data->cluster_center.assign(clusters, Vec3::Zero());
    data->cluster_bound.assign(clusters, 0.0);
    data->cluster_posed.assign(clusters, 0);
    data->cluster_shift.assign(clusters, 0.0);
    data->group_shift.assign(bones, 0.0);
    data->rotation_gap.assign(bones * bones, 0.0);
    data->joint_gap.assign(bones * bones, 0.0);
    data->joint_gap_c.assign(bones * bones, 0.0);
    data->nodes.resize(V, 3);
    slot = std::move(data);
  }

  // Refresh the posed data when the bone transforms (or the unposed surface) changed since the
  // last call.
  AvatarContactData& data = *slot;
  const std::vector<Mat3>& R = sim.boneRotations();
  const MatX3& T = sim.bonePositions();
  bool same = data.valid && data.key_positions.rows() == T.rows() && data.key_positions == T;
  for (int b = 0; same && b < data.bones; ++b) same = data.key_rotations[b] == R[b];
  MatX3 surface;
  if (data.soft) {
    surface = sim.getUnposedSurface();
    if (surface.rows() != X.rows())
      throw Error("Scene::avatarContactEnergy: simulable " + std::to_string(i) +
                  ": getUnposedSurface() has " + std::to_string(surface.rows()) +
                  " rows, expected #V = " + std::to_string(X.rows()));
    same = same && surface.rows() == data.surface.rows() && surface == data.surface;
  }
  if (same) return data;

  data.key_rotations = R;
  data.key_positions = T;
  ++data.version;
  const int bones = data.bones;
  if (data.soft &&
      !(data.valid && surface.rows() == data.surface.rows() && surface == data.surface)) {
    data.surface = std::move(surface);
    for (size_t k = 0; k < data.cluster_bone.size(); ++k) {
      double shift = 0.0;
      for (int c = data.cluster_start[k]; c < data.cluster_start[k + 1]; ++c) {
        const int v = data.cluster_vertices[c];
        double weight_sum = 0.0;
        for (int w = data.weight_start[v]; w < data.weight_start[v + 1]; ++w)
          weight_sum += std::abs(data.weight_value[w]);
        shift = std::max(shift, weight_sum * (data.surface.row(v) - X.row(v)).norm());
      }
      data.cluster_shift[k] = shift;
    }
    for (int b = 0; b < bones; ++b) {
      data.group_shift[b] = 0.0;
      for (int k = data.bone_clusters[b]; k < data.bone_clusters[b + 1]; ++k)
        data.group_shift[b] = std::max(data.group_shift[b], data.cluster_shift[k]);
    }
  }
  for (int b = 0; b < bones; ++b) {
    for (const auto& co : data.group_rest[b].coweights) {
      const int c = co.bone;
      data.rotation_gap[b * bones + c] =
          std::sqrt(std::max(0.0, 3.0 - (R[b].transpose() * R[c]).trace()));  // ‖R_c − R_b‖₂
      const Vec3 joints = (J.row(b) - J.row(c)).transpose();
      const Vec3 shift = (T.row(c) - T.row(b)).transpose();
      data.joint_gap[b * bones + c] = (R[c] * joints + shift).norm();
      data.joint_gap_c[b * bones + c] = (R[b] * joints + shift).norm();
    }
  }
  const auto posedBound = [&](int b, const AvatarContactData::Bound& rest, Vec3& center,
                              double& bound) {
    double margin = 0.0;
    for (const auto& co : rest.coweights) {
      const int pair = b * bones + co.bone;
      margin += co.weight * std::min(data.rotation_gap[pair] * rest.extent + data.joint_gap[pair],
                                     data.rotation_gap[pair] * co.extent + data.joint_gap_c[pair]);
    }
    center = R[b] * rest.offset + T.row(b).transpose();
    bound = rest.radius + margin;
  };
  for (int b = 0; b < bones; ++b) {
    posedBound(b, data.group_rest[b], data.group_center[b], data.group_bound[b]);
    data.group_bound[b] += data.group_shift[b];
  }
  for (size_t k = 0; k < data.cluster_bone.size(); ++k) {
    posedBound(data.cluster_bone[k], data.cluster_rest[k], data.cluster_center[k],
               data.cluster_bound[k]);
    data.cluster_bound[k] += data.cluster_shift[k];
    data.cluster_posed[k] = 0;
  }
  data.capsules.clear();
  for (const BoneCapsule& c : avatar.boneCapsules()) {
    if (!(c.radius > 0.0)) continue;  // bones that dominate no vertex have no capsule
    AvatarContactData::PosedCapsule p;
    p.bone = c.bone;
    const Vec3 joint = J.row(c.bone).transpose();
    const Vec3 t = T.row(c.bone).transpose();
    p.a_rotated = R[c.bone] * (c.a - joint);
    p.b_rotated = R[c.bone] * (c.b - joint);
    p.a = p.a_rotated + t;
    p.b = p.b_rotated + t;
    p.radius = c.radius;
    p.center = 0.5 * (p.a + p.b);
    p.bound = 0.5 * (p.a - p.b).norm() + c.radius;
    data.capsules.push_back(p);
  }
  data.valid = true;
  return data;
}

void Scene::poseCluster(int i, int cluster) const {
  AvatarContactData& data = *contact_data_[i];
  if (data.cluster_posed[cluster]) return;
  const Simulable& sim = *simulables_[i];
  const MatX3& Y = data.soft ? data.surface : sim.avatar().restVertices();
  const MatX3& J = sim.avatar().restJoints();
  const std::vector<Mat3>& R = sim.boneRotations();
  const MatX3& T = sim.bonePositions();
  for (int k = data.cluster_start[cluster]; k < data.cluster_start[cluster + 1]; ++k) {
    const int v = data.cluster_vertices[k];
    const Vec3 Yv = Y.row(v).transpose();
    Vec3 x = Vec3::Zero();
    for (int w = data.weight_start[v]; w < data.weight_start[v + 1]; ++w) {
      const int b = data.weight_bone[w];
      x += data.weight_value[w] * (R[b] * (Yv - J.row(b).transpose()) + T.row(b).transpose());
    }
    data.nodes.row(v) = x.transpose();
  }
  data.cluster_posed[cluster] = 1;
}

double Scene::avatarContactEnergy(VecX* g, std::vector<Triplet>* H, bool psd, int* active) const {
  int contacts = 0;
  double energy = 0.0;
  if (g && g->size() != num_dofs_)
    throw InputError("Scene::avatarContactEnergy: g must have numDofs() = " +
                     std::to_string(num_dofs_) + " entries, got " + std::to_string(g->size()));
  ContactOptions contact_options = options_.avatar_contact_options;
  contact_options.exact_hessian = !psd;
  const double stiffness = contact_options.stiffness;
  const int n_sim = int(simulables_.size());
  // Refresh every posed cache once; the cached contact pairs stay valid while no avatar moved.
  bool pairs_valid = int(contact_pairs_versions_.size()) == n_sim &&
                     contact_pairs_.size() == size_t(n_sim) * n_sim;
  contact_pairs_versions_.resize(n_sim, -1);
  contact_pairs_.resize(size_t(n_sim) * n_sim);
  for (int i = 0; i < n_sim; ++i) {
    const long version = contactData(i).version;
    pairs_valid = pairs_valid && contact_pairs_versions_[i] == version;
    contact_pairs_versions_[i] = version;
  }

  Vec9 grad9;
  Mat9 hess9;
  std::vector<Mat36> P;  // ∂x/∂(t_k, δω_k) per weight of the vertex
  std::vector<Mat36> HxxP;
  std::vector<Mat36> Huk;  // ∂²E/∂u∂(t_k, δω_k) per weight (soft vertices)
  std::vector<Vec3> p_rotated;  // R_k (X − J_k) per weight of the vertex
  for (int ia = 0; ia < n_sim; ++ia) {
    AvatarContactData& A = *contact_data_[ia];
    const Simulable& simA = *simulables_[ia];
    const SoftAvatar& avatarA = simA.avatar();
    const MatX3& YA = A.soft ? A.surface : avatarA.restVertices();
    const MatX3& JA = avatarA.restJoints();
    const VecX& areas = avatarA.vertexAreas();
    const std::vector<Mat3>& RA = simA.boneRotations();
    for (int ib = 0; ib < n_sim; ++ib) {
      if (ib == ia) continue;
      const AvatarContactData& B = *contact_data_[ib];
      if (H) blocks_->reset(A.bones + B.bones);
      // Broad phase once per state: the (capsule, vertex) pairs in contact are kept while
      // neither avatar moved (energy, gradient and Hessian at one state share them).
      std::vector<std::pair<int, int>>& pairs = contact_pairs_[ia * n_sim + ib];
      if (!pairs_valid) {
        pairs.clear();
        for (int ci = 0; ci < int(B.capsules.size()); ++ci) {
          const auto& cap = B.capsules[ci];
          const double bound2 = cap.bound * cap.bound, radius2 = cap.radius * cap.radius;
          for (int bone = 0; bone < A.bones; ++bone) {
            if (A.bone_clusters[bone] == A.bone_clusters[bone + 1] ||
                (A.group_center[bone] - cap.center).norm() > A.group_bound[bone] + cap.bound)
              continue;
            for (int cluster = A.bone_clusters[bone]; cluster < A.bone_clusters[bone + 1];
                 ++cluster) {
              const double reach = A.cluster_bound[cluster] + cap.radius;
              if (segmentDistanceSquared(A.cluster_center[cluster], cap.a, cap.b) > reach * reach)
                continue;
              poseCluster(ia, cluster);
              for (int k = A.cluster_start[cluster]; k < A.cluster_start[cluster + 1]; ++k) {
                const int v = A.cluster_vertices[k];
                const Vec3 x = A.nodes.row(v).transpose();
                if ((x - cap.center).squaredNorm() > bound2) continue;
                if (segmentDistanceSquared(x, cap.a, cap.b) >= radius2) continue;
                pairs.emplace_back(ci, v);
              }
            }
          }
        }
      }
      for (const auto& [ci, v] : pairs) {
        const auto& cap = B.capsules[ci];
        const Vec3 x = A.nodes.row(v).transpose();
        ++contacts;
        const bool derivatives = g || H;
        energy +=
            vertexCapsulePenalty(x, cap.a, cap.b, cap.radius, stiffness * areas[v], contact_options,
                                 derivatives ? &grad9 : nullptr, H ? &hess9 : nullptr);
        if (!derivatives) continue;

        // Chain rule through x = Σ_k w_k (R_k (Y − J_k) + t_k) (+ u: ∂x/∂u = M = Σ_k w_k R_k)
        // and a' = R_b (a − J_b) + t_b.
        const int w_begin = A.weight_start[v], w_end = A.weight_start[v + 1];
        const int nw = w_end - w_begin;
        const int s_begin = A.soft ? A.soft_start[v] : 0;
        const int s_end = A.soft ? A.soft_start[v + 1] : 0;
        const bool has_u = s_end > s_begin;
        p_rotated.resize(nw);
        Mat3 M = Mat3::Zero();
        for (int w = 0; w < nw; ++w) {
          const int bone = A.weight_bone[w_begin + w];
          p_rotated[w] = RA[bone] * (YA.row(v) - JA.row(bone)).transpose();
          if (has_u) M += A.weight_value[w_begin + w] * RA[bone];
        }
        const Vec3 gx = grad9.segment<3>(0), ga = grad9.segment<3>(3), gb = grad9.segment<3>(6);
        if (g) {
          for (int w = 0; w < nw; ++w) {
            const int dof = offsets_[ia] + 6 * A.weight_bone[w_begin + w];
            const double weight = A.weight_value[w_begin + w];
            g->segment<3>(dof) += weight * gx;
            g->segment<3>(dof + 3) += weight * p_rotated[w].cross(gx);
          }
          const int dof = offsets_[ib] + 6 * cap.bone;
          g->segment<3>(dof) += ga + gb;
          g->segment<3>(dof + 3) += cap.a_rotated.cross(ga) + cap.b_rotated.cross(gb);
          if (has_u) {
            const Vec3 gu = M.transpose() * gx;
            for (int k = s_begin; k < s_end; ++k)
              g->segment<3>(offsets_[ia] + A.soft_basis[k].first) += A.soft_basis[k].second * gu;
          }
        }
        if (!H) continue;
        P.resize(nw);
        HxxP.resize(nw);
        const Mat3 Hxx = hess9.block<3, 3>(0, 0);
        for (int w = 0; w < nw; ++w) {
          const double weight = A.weight_value[w_begin + w];
          P[w].leftCols<3>() = weight * Mat3::Identity();
          P[w].rightCols<3>() = -weight * skew(p_rotated[w]);
          HxxP[w] = Hxx * P[w];
        }
        Mat6 Q;  // ∂(a', b')/∂(t_b, δω_b)
        Q << Mat3::Identity(), -skew(cap.a_rotated), Mat3::Identity(), -skew(cap.b_rotated);
        const Mat36 HxyQ = hess9.block<3, 6>(0, 3) * Q;
        const int bone_b = A.bones + cap.bone;  // local index in the accumulator
        Mat6& Bbb = blocks_->at(bone_b, bone_b);
        Bbb.noalias() += Q.transpose() * hess9.block<6, 6>(3, 3) * Q;
        if (!psd) {
          Bbb.bottomRightCorner<3, 3>() +=
              rotationCurvature(ga, cap.a_rotated) + rotationCurvature(gb, cap.b_rotated);
        }
        for (int w = 0; w < nw; ++w) {
          const int bone_k = A.weight_bone[w_begin + w];
          for (int u = 0; u < nw; ++u)
            blocks_->at(bone_k, A.weight_bone[w_begin + u]).noalias() += P[w].transpose() * HxxP[u];
          const Mat6 cross = P[w].transpose() * HxyQ;
          blocks_->at(bone_k, bone_b) += cross;
          blocks_->at(bone_b, bone_k) += cross.transpose();
          if (!psd)
            blocks_->at(bone_k, bone_k).bottomRightCorner<3, 3>() +=
                A.weight_value[w_begin + w] * rotationCurvature(gx, p_rotated[w]);
        }
        if (has_u) {
          // u rows: Mᵀ Hxx M with itself, Mᵀ Hxx P_k with A's bones (plus, exact, the term of
          // x's change w_k [δω_k]× R_k δu: ∂²E/∂u∂δω_k = w_k R_kᵀ [gx]×), Mᵀ Hxy Q with B's bone;
          // then through u = Σ w q_index to the state entries.
          const Mat3 MtH = M.transpose() * Hxx;
          const Mat3 Huu = MtH * M;
          const Mat36 HuB = M.transpose() * HxyQ;
          Huk.resize(nw);
          for (int w = 0; w < nw; ++w) {
            const int bone_k = A.weight_bone[w_begin + w];
            Huk[w] = MtH * P[w];
            if (!psd)
              Huk[w].rightCols<3>() +=
                  A.weight_value[w_begin + w] * RA[bone_k].transpose() * skew(gx);
          }
          for (int k = s_begin; k < s_end; ++k) {
            const int du = offsets_[ia] + A.soft_basis[k].first;
            const double wk = A.soft_basis[k].second;
            for (int l = s_begin; l < s_end; ++l)
              appendBlock(*H, du, offsets_[ia] + A.soft_basis[l].first,
                          (wk * A.soft_basis[l].second) * Huu);
            for (int w = 0; w < nw; ++w) {
              const int bone_k = A.weight_bone[w_begin + w];
              appendBlock(*H, du, offsets_[ia] + 6 * bone_k, wk * Huk[w]);
              appendBlock(*H, offsets_[ia] + 6 * bone_k, du, wk * Huk[w].transpose());
            }
            appendBlock(*H, du, offsets_[ib] + 6 * cap.bone, wk * HuB);
            appendBlock(*H, offsets_[ib] + 6 * cap.bone, du, wk * HuB.transpose());
          }
        }
      }
      if (H) {
        const int off_a = offsets_[ia], off_b = offsets_[ib], bones_a = A.bones;
        blocks_->flush(
            [&](int local) {
              return local < bones_a ? off_a + 6 * local : off_b + 6 * (local - bones_a);
            },
            *H);
      }
    }
  }
  avatar_contacts_ = contacts;
  if (active) *active = contacts;
  return energy;
}

}  // namespace flsh
