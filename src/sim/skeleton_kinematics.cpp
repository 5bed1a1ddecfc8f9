#include "sim/skeleton_kinematics.h"

#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/rotation.h"
#include "flsh/energy/skeleton_energies.h"
#include "sim/terms/term_blocks.h"

namespace flsh::detail {

namespace {

// Calls visit(i, b, w_ib, f) for every influence (b, w_ib) of every listed vertex i whose force
// f (forces.segment<3>(3j) for vertices[j]) is not zero.
template <class Visit>
void forEachForcedInfluence(const SparseSkinWeights& w, const std::vector<int>& vertices,
                            const VecX& forces, Visit&& visit) {
  for (size_t j = 0; j < vertices.size(); ++j) {
    const Vec3 f = forces.segment<3>(3 * Eigen::Index(j));
    if (f.isZero(0.0)) continue;
    const int i = vertices[j];
    for (int k = w.start[i]; k < w.start[i + 1]; ++k)
      visit(i, w.entries[k].bone, w.entries[k].weight, f);
  }
}

}  // namespace

void SkeletonKinematics::contactMargins(double* margin) const {
  for (int b = 0; b < kNumJoints; ++b) margin[b] = 0.0;
}

void SkeletonKinematics::surface(MatX3* x, MatX3* Y) const {
  if (Y) *Y = rest_;
  if (!x) return;
  const SparseSkinWeights& w = surface_.weights;
  const std::vector<Mat3>& R = *R_;
  const MatX3& t = *t_;
  x->resize(rest_.rows(), 3);
  for (Eigen::Index i = 0; i < rest_.rows(); ++i) {
    const Vec3 X = rest_.row(i).transpose();
    Vec3 xi = Vec3::Zero();
    for (int k = w.start[i]; k < w.start[i + 1]; ++k) {
      const int b = w.entries[k].bone;
      xi += w.entries[k].weight * (R[b] * (X - joints_.row(b).transpose()) + t.row(b).transpose());
    }
    x->row(i) = xi.transpose();
  }
}

void SkeletonKinematics::surfaceJacobian(std::vector<Triplet>& triplets) const {
  const SparseSkinWeights& w = surface_.weights;
  triplets.reserve(triplets.size() + w.entries.size() * 12);
  for (int i = 0; i < int(rest_.rows()); ++i)
    for (int k = w.start[i]; k < w.start[i + 1]; ++k) {
      const int b = w.entries[k].bone;
      const double wb = w.entries[k].weight;
      const Mat3 dx_dw = -wb * skew(leverArm(*R_, i, b));
      for (int r = 0; r < 3; ++r) {
        triplets.emplace_back(3 * i + r, 6 * b + r, wb);
        for (int c = 0; c < 3; ++c) triplets.emplace_back(3 * i + r, 6 * b + 3 + c, dx_dw(r, c));
      }
    }
}

void SkeletonKinematics::positions(const std::vector<int>& vertices, const BoneFrames& bones,
                                   MatX3& x) const {
  const int n = int(vertices.size());
  x.resize(n, 3);
  if (n == 0) return;
  // Each bone's translation t_b − R_b J_b formed once per call, not per vertex.
  const int num_bones = int(joints_.rows());
  Vec3 bone_shift[kNumJoints];
  for (int b = 0; b < num_bones; ++b)
    bone_shift[b] = bones.t.row(b).transpose() - bones.R[b] * joints_.row(b).transpose();
  const SparseSkinWeights& w = surface_.weights;
  for (int j = 0; j < n; ++j) {
    const int i = vertices[size_t(j)];
    const Vec3 Xi = rest_.row(i).transpose();
    Vec3 xi = Vec3::Zero();
    for (int k = w.start[i]; k < w.start[i + 1]; ++k) {
      const int b = w.entries[k].bone;
      xi += w.entries[k].weight * (bones.R[b] * Xi + bone_shift[b]);
    }
    x.row(j) = xi.transpose();
  }
}

void SkeletonKinematics::mapForces(const std::vector<int>& vertices, const VecX& forces,
                                   const std::vector<Mat3>& R, VecX& g, int offset) const {
  forEachForcedInfluence(surface_.weights, vertices, forces,
                         [&](int i, int b, double wb, const Vec3& f) {
                           g.segment<3>(offset + 6 * b) += wb * f;
                           g.segment<3>(offset + 6 * b + 3) += wb * leverArm(R, i, b).cross(f);
                         });
}

void SkeletonKinematics::surfaceForces(const MatX3& forces, VecX& g) const {
  std::vector<int> vertices(static_cast<size_t>(numSurface()));
  for (int i = 0; i < numSurface(); ++i) vertices[size_t(i)] = i;
  mapForces(vertices, Eigen::Map<const VecX>(forces.data(), forces.size()), *R_, g, 0);
}

void SkeletonKinematics::mapHessian(const std::vector<int>& vertices,
                                    const std::vector<std::pair<int, Mat3>>& node_blocks,
                                    const VecX& forces, const std::vector<Mat3>& R, bool psd,
                                    BonePairBlocks& blocks) const {
  const SparseSkinWeights& w = surface_.weights;
  Eigen::Matrix<double, 3, 6> Jb[kNumJoints];
  int bones[kNumJoints];
  for (const auto& [j, K] : node_blocks) {
    const int i = vertices[size_t(j)];
    const int count = w.start[i + 1] - w.start[i];
    for (int a = 0; a < count; ++a) {
      const SparseSkinWeights::Influence& inf = w.entries[size_t(w.start[i] + a)];
      const Vec3 y = leverArm(R, i, inf.bone);
      bones[a] = inf.bone;
      Jb[a].leftCols<3>() = inf.weight * Mat3::Identity();
      Jb[a].rightCols<3>() = -inf.weight * skew(y);
    }
    for (int a = 0; a < count; ++a) {
      const Eigen::Matrix<double, 6, 3> JaT_K = Jb[a].transpose() * K;
      for (int b = 0; b < count; ++b) blocks.block(bones[a], bones[b]) += JaT_K * Jb[b];
    }
  }
  // Curvature of the rotating points, summed per bone (Σ_i w_ib f_i·∂²y_ib); the PSD form keeps
  // its projection on the PSD cone (the stabilizing part) instead of dropping it.
  Mat3 curvature[kNumJoints];
  bool has_curvature[kNumJoints] = {};
  forEachForcedInfluence(w, vertices, forces, [&](int i, int b, double wb, const Vec3& f) {
    if (!has_curvature[b]) curvature[b].setZero();
    has_curvature[b] = true;
    curvature[b] += wb * rotationCurvature(f, leverArm(R, i, b));
  });
  const int num_bones = int(joints_.rows());
  for (int b = 0; b < num_bones; ++b)
    if (has_curvature[b])
      blocks.block(b, b).bottomRightCorner<3, 3>() +=
          psd ? projectToPSD<3>(curvature[b]) : curvature[b];
}

void SkeletonKinematics::point(int i, const std::vector<Mat3>& R, SkinnedPoint& p) const {
  const SparseSkinWeights& w = surface_.weights;
  p.count = w.start[i + 1] - w.start[i];
  for (int a = 0; a < p.count; ++a) {
    const SparseSkinWeights::Influence& inf = w.entries[size_t(w.start[i] + a)];
    p.bone[a] = inf.bone;
    p.weight[a] = inf.weight;
    p.lever[a] = leverArm(R, i, inf.bone);
  }
}

}  // namespace flsh::detail
