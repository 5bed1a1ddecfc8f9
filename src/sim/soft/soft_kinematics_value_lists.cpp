// SoftKinematics' Hessian value lists for the ROM (soft_kinematics.h, "the ROM's Hessian value
// lists"): the fixed pattern of z–z and bone–z blocks, the soft–soft blocks of a node, and each
// list's zeroing, completion (the bones' dense mode rows folded in, the lower blocks mirrored)
// and hand-over as triplets or fixed blocks. The bone–soft blocks (addBoneSoft, a template of
// mapHessian's) stay beside mapHessian in soft_kinematics.cpp.
#include <algorithm>

#include "sim/soft/soft_kinematics.h"

namespace flsh::detail {

namespace {

// Zeroes `count` 3 × 3 blocks stored back to back (one vectorized pass).
void zeroBlocks(Mat3* blocks, int count) {
  static_assert(sizeof(Mat3) == 9 * sizeof(double), "Mat3 must be 9 packed doubles");
  Eigen::Map<VecX>(blocks->data(), 9 * Eigen::Index(count)).setZero();
}

}  // namespace

void SoftKinematics::buildReducedPattern(const std::vector<std::pair<int, int>>& handle_pairs) {
  if (!reduced_) return;
  // Every (handle, handle) pair some node couples, plus the terms' (elastic tets, rest
  // stiffness); every (bone row block, handle) pair some node's skinning couples.
  // Groups: the handles, then the modes three by three (every soft node has every modal group).
  const int H = num_groups_, rows = 2 * num_bones_;
  std::vector<char> zz(size_t(H) * H, 0), bz(size_t(rows) * H, 0);
  std::vector<int> groups;
  for (int j = 0; j < numNodes(); ++j) {
    groups.clear();
    for (int a = phi_start_[j]; a < phi_start_[j + 1]; ++a) groups.push_back(phi_[a].first);
    if (node_dof_[j] >= 0)
      for (int g = num_handles_; g < num_groups_; ++g) groups.push_back(g);
    for (int a : groups) {
      for (int b : groups) zz[size_t(a) * H + b] = 1;
      for (int k = influence_start_[j]; k < influence_start_[j + 1]; ++k)
        for (int r = 0; r < 2; ++r) bz[size_t(2 * influences_[k].bone + r) * H + a] = 1;
    }
  }
  for (const auto& [a, b] : handle_pairs) zz[size_t(a) * H + b] = 1;
  // Slots: the z–z blocks, then the bone–z blocks, then their transposes (z–bone).
  zz_slot_.assign(zz.size(), -1);
  bz_slot_.assign(bz.size(), -1);
  reduced_positions_.clear();
  for (int k = 0; k < H; ++k)  // column-major
    for (int h = 0; h < H; ++h)
      if (zz[size_t(h) * H + k]) {
        zz_slot_[size_t(h) * H + k] = int(reduced_positions_.size());
        reduced_positions_.emplace_back(bone_dofs_ + 3 * h, bone_dofs_ + 3 * k);
      }
  num_zz_ = int(reduced_positions_.size());
  zz_mirror_
      .clear();  // the terms sum the upper blocks (h ≤ k); the lower ones are their transposes
  for (int h = 0; h < H; ++h)
    for (int k = 0; k < h; ++k)
      if (zz_slot_[size_t(h) * H + k] >= 0)
        zz_mirror_.emplace_back(zz_slot_[size_t(h) * H + k], zz_slot_[size_t(k) * H + h]);
  for (int h = 0; h < H; ++h)
    for (int r = 0; r < rows; ++r)
      if (bz[size_t(r) * H + h]) {
        bz_slot_[size_t(r) * H + h] = int(reduced_positions_.size());
        reduced_positions_.emplace_back(3 * r, bone_dofs_ + 3 * h);
      }
  num_bz_ = int(reduced_positions_.size()) - num_zz_;
  for (int k = 0; k < num_bz_; ++k) {
    const auto [row, col] = reduced_positions_[size_t(num_zz_ + k)];
    reduced_positions_.emplace_back(col, row);
  }
  for (auto& values : reduced_values_) values.assign(reduced_positions_.size(), Mat3::Zero());
  for (RowMatX& acc : bone_modes_) acc.setZero(6 * num_bones_, num_modes_);
  for (auto& touched : bone_modes_touched_) touched.assign(size_t(num_bones_), 0);
}

void SoftKinematics::addSoftSoft(std::vector<Triplet>& H, int offset, int j, const Mat3& B,
                                 int list) const {
  if (!reduced_) {
    if (node_dof_[j] < 0) return;
    const int u_index = offset + bone_dofs_ + node_dof_[j];
    addBlock(H, u_index, u_index, B);
    return;
  }
  // B is symmetric: the upper triangle of handle pairs (φ_ rows are sorted by handle);
  // flushList mirrors it.
  Mat3* values = reduced_values_[size_t(list)].data();
  const size_t groups = size_t(num_groups_);
  for (int a = phi_start_[j]; a < phi_start_[j + 1]; ++a) {
    const size_t row = size_t(phi_[a].first) * groups;
    for (int b = a; b < phi_start_[j + 1]; ++b)
      values[zz_slot_[row + size_t(phi_[b].first)]] += (phi_[a].second * phi_[b].second) * B;
  }
  if (num_modes_ == 0 || node_dof_[j] < 0) return;
  // Handle–mode blocks φ_h B Ψ_jk and the upper mode–mode blocks Ψ_jgᵀ B Ψ_jk (g ≤ k); the
  // handles come before the modes, so every handle–mode pair is upper.
  const auto Psi = modeRows(j);
  const Eigen::Matrix<double, 3, Eigen::Dynamic> BPsi = B * Psi;
  const int mode_groups = num_modes_ / 3;
  for (int a = phi_start_[j]; a < phi_start_[j + 1]; ++a) {
    const int* slots = &zz_slot_[size_t(phi_[a].first) * groups + size_t(num_handles_)];
    for (int k = 0; k < mode_groups; ++k)
      values[slots[k]] += phi_[a].second * BPsi.middleCols<3>(3 * k);
  }
  for (int g = 0; g < mode_groups; ++g) {
    const int* slots = &zz_slot_[size_t(num_handles_ + g) * groups + size_t(num_handles_)];
    const Mat3 Psi_g_t = Psi.middleCols<3>(3 * g).transpose();
    for (int k = g; k < mode_groups; ++k)
      values[slots[k]].noalias() += Psi_g_t * BPsi.middleCols<3>(3 * k);
  }
}

void SoftKinematics::beginList(int list) const {
  if (!reduced_) return;
  // The summed slots only (z–z and bone–z; the z–bone ones are written by the mirroring).
  zeroBlocks(reduced_values_[size_t(list)].data(), num_zz_ + num_bz_);
  mirrored_[size_t(list)] = false;
  if (num_modes_ == 0) return;
  RowMatX& acc = bone_modes_[size_t(list)];  // sized by buildReducedPattern
  std::vector<char>& touched = bone_modes_touched_[size_t(list)];
  for (int b = 0; b < num_bones_; ++b)
    if (touched[size_t(b)]) acc.middleRows<6>(6 * b).setZero();
  std::fill(touched.begin(), touched.end(), 0);
}

void SoftKinematics::mirrorReduced(int list) const {
  std::vector<Mat3>& values = reduced_values_[size_t(list)];
  if (num_modes_ > 0) {  // the bones' dense rows (addBoneSoft) into their bone–z slots, once
    RowMatX& acc = bone_modes_[size_t(list)];
    std::vector<char>& touched = bone_modes_touched_[size_t(list)];
    const size_t groups = size_t(num_groups_);
    for (int b = 0; b < num_bones_; ++b) {
      if (!touched[size_t(b)]) continue;
      for (int r = 0; r < 2; ++r) {
        const int* slots = &bz_slot_[size_t(2 * b + r) * groups + size_t(num_handles_)];
        for (int g = 0; g < num_modes_ / 3; ++g)
          values[size_t(slots[g])] += acc.block<3, 3>(6 * b + 3 * r, 3 * g);
      }
      acc.middleRows<6>(6 * b).setZero();
      touched[size_t(b)] = 0;
    }
  }
  for (const auto& [lower, upper] : zz_mirror_)
    values[size_t(lower)] = values[size_t(upper)].transpose();
  for (int k = 0; k < num_bz_; ++k)
    values[size_t(num_zz_ + num_bz_ + k)] = values[size_t(num_zz_ + k)].transpose();
}

void SoftKinematics::flushList(int list, std::vector<Triplet>& H, int offset,
                               std::vector<FixedHessianBlocks>* blocks) const {
  if (!reduced_) return;
  std::vector<Mat3>& values = reduced_values_[size_t(list)];
  if (!mirrored_[size_t(list)]) mirrorReduced(list);
  if (blocks) {
    blocks->push_back({&reduced_positions_, &values, offset});
    return;
  }
  for (size_t k = 0; k < values.size(); ++k)
    if (!values[k].isZero(0.0))
      addBlock(H, offset + reduced_positions_[k].first, offset + reduced_positions_[k].second,
               values[k]);
}

}  // namespace flsh::detail
