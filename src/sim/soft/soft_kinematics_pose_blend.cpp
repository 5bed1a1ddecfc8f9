// SoftKinematics' pose blend (soft_kinematics.h, "pose blend"): the held offsets P_j =
// posedirs_j · feature(R) of the rotations a step holds them from (the FEM evaluates every node's,
// the ROM a node's when first read), their tangent and cotangent in those rotations for the
// adjoint, and the surface's offsets and cotangents of many pose blends at once (one product with
// the surface's posedirs rows: Simulable::getNodesOfFrames). Split from soft_kinematics.cpp, which
// keeps the skinning and the chain rule to the state.
#include <string>
#include <vector>

#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "sim/soft/on_two_threads.h"
#include "sim/soft/soft_kinematics.h"

namespace flsh::detail {

void SoftKinematics::featureOf(const std::vector<Mat3>& R, VecX& feature) const {
  for (int b = 1; b < num_bones_; ++b) {
    const Mat3 local = R[parents_[b]].transpose() * R[b];
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) feature[9 * (b - 1) + 3 * r + c] = local(r, c) - (r == c);
  }
}

void SoftKinematics::setPoseBlend(const std::vector<Mat3>& R) {
  featureOf(R, feature_);
  ++blend_epoch_;
  if (reduced_) {
    ++pose_stamp_;
    from_feature_ = true;
    held_R_ = R;
    return;
  }
  const VecX offsets = (*posedirs_) * feature_;  // row 3j + c
  blend_ = Eigen::Map<const MatX3>(offsets.data(), numNodes(), 3);
}

// dL_b = R_pᵀ ([δω_b]× − [δω_p]×) R_b for L_b = R_pᵀ R_b, the feature block of bone b ≥ 1.
void SoftKinematics::poseBlendTangent(const std::vector<Mat3>& R, const VecX& delta_omega,
                                      const std::vector<int>& nodes, MatX3& dP) const {
  VecX d_feature(feature_.size());
  for (int b = 1; b < num_bones_; ++b) {
    const int p = parents_[b];
    const Mat3 dL = R[p].transpose() *
                    (skew(Vec3(delta_omega.segment<3>(3 * b) - delta_omega.segment<3>(3 * p)))) *
                    R[b];
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) d_feature[9 * (b - 1) + 3 * r + c] = dL(r, c);
  }
  dP.resize(Eigen::Index(nodes.size()), 3);
  const bool dense = manyUnslotted(nodes);
  const VecX all = dense ? VecX((*posedirs_) * d_feature) : VecX();
  for (size_t k = 0; k < nodes.size(); ++k) {
    const int j = nodes[k], slot = reduced_ ? blend_slot_[size_t(j)] : -1;
    if (slot >= 0)
      dP.row(Eigen::Index(k)) = d_feature.transpose() * posedirs_T_.middleCols<3>(3 * slot);
    else if (dense)
      dP.row(Eigen::Index(k)) = all.segment<3>(3 * j).transpose();
    else
      dP.row(Eigen::Index(k)) = (posedirs_->middleRows<3>(3 * j) * d_feature).transpose();
  }
}

// posedirs is 3N × 207 column-major: a node's three rows are 207 scattered cache lines. The ROM's
// surface and mass nodes have their rows contiguous (posedirs_T_); for many other nodes one pass
// over the whole matrix (a product with a dense 3N vector) reads less than row by row.
bool SoftKinematics::manyUnslotted(const std::vector<int>& nodes) const {
  size_t unslotted = 0;
  for (int j : nodes) unslotted += reduced_ && blend_slot_[size_t(j)] >= 0 ? 0 : 1;
  return 8 * unslotted > size_t(numNodes());
}

// ⟨L̄_b, R_pᵀ [w]× R_b⟩ = ⟨A, [w]×⟩ = w · vee(A − Aᵀ) with A = R_p L̄_b R_bᵀ: +vee to bone b,
// −vee to its parent.
void SoftKinematics::poseBlendCotangent(const std::vector<Mat3>& R, const std::vector<int>& nodes,
                                        const std::vector<Vec3>& mu,
                                        VecX& rotation_cotangent) const {
  VecX feature_bar = VecX::Zero(feature_.size());
  const bool dense = manyUnslotted(nodes);
  if (dense) {  // the FEM's every node: one product with posedirs
    VecX all = VecX::Zero(posedirs_->rows());
    for (size_t k = 0; k < nodes.size(); ++k) all.segment<3>(3 * nodes[k]) += mu[k];
    feature_bar.noalias() += posedirs_->transpose() * all;
    addFeatureCotangent(R, feature_bar, rotation_cotangent);
    return;
  }
  // 207 × 3 blocks of the listed nodes' posedirs rows (the ROM's mass nodes: ~3.5 MB read per
  // call), from kSplitNodes nodes half on each thread, the halves added in a fixed order.
  const auto addRange = [&](size_t begin, size_t end, VecX& out) {
    for (size_t k = begin; k < end; ++k) {
      const int j = nodes[k], slot = reduced_ ? blend_slot_[size_t(j)] : -1;
      if (slot >= 0)
        out.noalias() += posedirs_T_.middleCols<3>(3 * slot) * mu[k];
      else
        out.noalias() += posedirs_->middleRows<3>(3 * j).transpose() * mu[k];
    }
  };
  const size_t count = nodes.size();
  if (count < kSplitNodes) {
    addRange(0, count, feature_bar);
  } else {
    VecX part[2];
    onTwoThreads([&](int p) {
      part[p] = VecX::Zero(feature_.size());
      addRange(p == 0 ? 0 : count / 2, p == 0 ? count / 2 : count, part[p]);
    });
    feature_bar = part[0] + part[1];
  }
  addFeatureCotangent(R, feature_bar, rotation_cotangent);
}

template <class Feature, class Out>
void SoftKinematics::addFeatureCotangent(const std::vector<Mat3>& R, const Feature& feature_bar,
                                         Out&& rotation_cotangent) const {
  for (int b = 1; b < num_bones_; ++b) {
    const int p = parents_[b];
    Mat3 L_bar;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) L_bar(r, c) = feature_bar[9 * (b - 1) + 3 * r + c];
    const Mat3 A = R[p] * L_bar * R[b].transpose();
    const Vec3 v = vee(A - A.transpose());
    rotation_cotangent.template segment<3>(3 * b) += v;
    rotation_cotangent.template segment<3>(3 * p) -= v;
  }
}

// The surface's posedirs rows are contiguous: the ROM's first 3#V columns of posedirs_T_ (the
// surface nodes take the first slots), the FEM's first 3#V rows of posedirs (nodes 0 .. #V − 1).
void SoftKinematics::surfacePoseBlendCotangents(const std::vector<std::vector<Mat3>>& R,
                                                const RowMatX& offsets_bar,
                                                RowMatX& rotation_cotangents) const {
  const Eigen::Index rows = offsets_bar.rows(), V3 = 3 * Eigen::Index(num_surface_);
  if (Eigen::Index(R.size()) != rows || offsets_bar.cols() != V3 ||
      rotation_cotangents.rows() != rows || rotation_cotangents.cols() != 3 * num_bones_)
    throw Error("SoftKinematics::surfacePoseBlendCotangents: inconsistent sizes");
  MatX feature_bar = MatX::Zero(feature_.size(), rows);
  if (reduced_)
    addLongInnerProduct(posedirs_T_.leftCols(V3), offsets_bar.transpose(), feature_bar);
  else
    addLongInnerProduct(posedirs_->topRows(V3).transpose(), offsets_bar.transpose(), feature_bar);
  for (Eigen::Index k = 0; k < rows; ++k)
    addFeatureCotangent(R[size_t(k)], feature_bar.col(k), rotation_cotangents.row(k));
}

RowMatX SoftKinematics::surfacePoseBlends(const std::vector<std::vector<Mat3>>& R) const {
  const Eigen::Index rows = Eigen::Index(R.size()), V3 = 3 * Eigen::Index(num_surface_);
  MatX features(feature_.size(), rows);
  VecX feature(feature_.size());
  for (Eigen::Index k = 0; k < rows; ++k) {
    featureOf(R[size_t(k)], feature);
    features.col(k) = feature;
  }
  RowMatX P(rows, V3);
  if (reduced_)
    P.noalias() = features.transpose() * posedirs_T_.leftCols(V3);
  else
    P.noalias() = features.transpose() * posedirs_->topRows(V3).transpose();
  return P;
}

Vec3 SoftKinematics::blendOf(int j) const {
  if (!reduced_ || blend_stamp_[j] == pose_stamp_) return blend_.row(j).transpose();
  const int slot = blend_slot_[j];
  const Vec3 P = slot >= 0 ? Vec3(posedirs_T_.middleCols<3>(3 * slot).transpose() * feature_)
                           : Vec3(posedirs_->middleRows<3>(3 * j) * feature_);
  blend_.row(j) = P.transpose();
  blend_stamp_[j] = pose_stamp_;
  return P;
}

void SoftKinematics::evaluatedPoseBlend(std::vector<int>& nodes, MatX3& offsets) const {
  nodes.clear();
  if (heldPoseRotations() && pose_stamp_ > 0)  // stamp 0: the rest pose's zero offsets
    for (int j = 0; j < numNodes(); ++j)
      if (blend_stamp_[size_t(j)] == pose_stamp_) nodes.push_back(j);
  offsets.resize(Eigen::Index(nodes.size()), 3);
  for (size_t k = 0; k < nodes.size(); ++k) offsets.row(Eigen::Index(k)) = blend_.row(nodes[k]);
}

void SoftKinematics::seedPoseBlend(const std::vector<int>& nodes, const MatX3& offsets) {
  if (!heldPoseRotations()) return;
  for (size_t k = 0; k < nodes.size(); ++k) {
    blend_.row(nodes[k]) = offsets.row(Eigen::Index(k));
    blend_stamp_[size_t(nodes[k])] = pose_stamp_;
  }
  ++blend_epoch_;
}

const MatX3& SoftKinematics::poseBlend() const {
  if (reduced_)
    for (int j = 0; j < numNodes(); ++j) blendOf(j);
  return blend_;
}

void SoftKinematics::setPoseBlendOffsets(const MatX3& offsets) {
  blend_ = offsets;
  ++blend_epoch_;
  if (reduced_) std::fill(blend_stamp_.begin(), blend_stamp_.end(), pose_stamp_);
  from_feature_ = false;
}

}  // namespace flsh::detail
