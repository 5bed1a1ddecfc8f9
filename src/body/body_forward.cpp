// SMPL forward pass and its analytic Jacobians (ARCHITECTURE.md §2).
//
// Work is split into a per-frame skeleton stage (24 joints, cheap) and a per-vertex stage in
// which each thread takes one contiguous slab of vertices, forms their posed rest vertices
// (template + shape + pose blend shapes; the dense posedirs product dominates the cost and is
// streamed once per frame) and skins them. Batches multiply posedirs by a block of frames'
// pose features at once, so it is read once per block rather than once per frame.
#include "flsh/body/body_forward.h"

#include <omp.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <string>

#include "body/body_model_derived.h"
#include "flsh/body/model_finalized.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"

namespace flsh {

namespace {

constexpr int kJ = kNumJoints;
// Vertices per chunk of the pose Jacobian: a 3·256 × 72 buffer (440 kB) stays in L2 while
// its rows are assembled.
constexpr int kJacobianChunkVertices = 256;
// Vertices per unit of parallel work: 3·1024 rows of posedirs are long enough column segments
// to stream at full speed.
constexpr int kSlabVertices = 1024;
// Below this many vertices a parallel region costs more than it saves.
constexpr int kParallelMinVertices = 2048;
// Frames whose pose blend offsets are formed by one matrix product in poseBodyBatch:
// streams posedirs once per block instead of once per frame (3#V × 64 doubles of scratch).
constexpr int kBatchBlockFrames = 64;

using Mat34 = Eigen::Matrix<double, 3, 4>;
using Mat93 = Eigen::Matrix<double, 9, 3>;
using PoseFeature = Eigen::Matrix<double, kPoseFeatureSize, 1>;
using Derived = BodyModel::Derived;

/// Everything about one frame that depends on the 24 joints only.
struct Kinematics {
  std::array<Vec3, kJ> rest_joint;       // J_j(β), m
  std::array<Mat3, kJ> local_rotation;   // R_j = exp([θ_j]×)
  std::array<Mat3, kJ> rotation;         // Rg_j, rotation of bone j in the world
  std::array<Vec3, kJ> position;         // p_j, posed joint centre without trans, m
  std::array<Mat34, kJ> skin;            // [Rg_j | p_j − Rg_j J_j]: rest point ↦ posed point
  PoseFeature pose_feature;              // vec(R_j − I) row-major, j = 1..23
  std::array<bool, kJ> feature_nonzero;  // joint j ≥ 1 has R_j ≠ I (its 9 columns matter)
};

/// Pose derivatives of one frame's joints (only built when Jacobians are requested).
struct PoseDerivatives {
  std::array<Mat3, kJ> world_axes;    // Ω_k: column a = ω_{k,a} = Rg_parent(k) J_l(θ_k) e_a
  std::array<Mat93, kJ> blend_basis;  // D_k: row 3r + c, column a = d(R_k)_{rc} / dθ_{k,a}
  MatX position_betas;                // 3J × K, dp_j/dβ (row 3j + c)
  MatX skin_betas;                    // 3J × K, C_j = dp_j/dβ − Rg_j dJ_j/dβ
};

const Derived& requireFinalizedModel(const BodyModel& m, const std::string& fn,
                                     bool needs_smpl_skeleton = true) {
  requireFinalized(m, fn);
  if (needs_smpl_skeleton && m.numJoints() != kJ)
    throw InputError(fn + ": " + modelName(m) + " has " + std::to_string(m.numJoints()) +
                     " joints, expected " + std::to_string(kJ) + " (SMPL skeleton)");
  return *m.derived;
}

/// β zero padded to the model's K; throws for too many or non-finite values.
VecX paddedBetas(const BodyModel& m, const Eigen::Ref<const VecX>& betas, const std::string& fn) {
  const long K = m.numBetas();
  if (betas.size() > K)
    throw InputError(fn + ": betas has " + std::to_string(betas.size()) +
                     " values, expected at most " + std::to_string(K) +
                     " (the shape components of " + modelName(m) + ")");
  checkShapeCoefficients(betas, fn + ": betas");
  VecX padded = VecX::Zero(K);
  padded.head(betas.size()) = betas;
  return padded;
}

void computeKinematics(const BodyModel& m, const Derived& d, const VecX& betas,
                       const Eigen::Ref<const VecX>& pose72, Kinematics& k) {
  Eigen::Matrix<double, 3 * kJ, 1> joints = d.joints_template;
  joints.noalias() += d.joint_shapedirs * betas;
  for (int j = 0; j < kJ; ++j) {
    k.rest_joint[j] = joints.segment<3>(3 * j);
    k.local_rotation[j] = rodrigues(pose72.segment<3>(3 * j));
    const int p = m.parents[j];
    if (p < 0) {
      k.rotation[j] = k.local_rotation[j];
      k.position[j] = k.rest_joint[j];
    } else {
      k.rotation[j].noalias() = k.rotation[p] * k.local_rotation[j];
      k.position[j].noalias() = k.position[p] + k.rotation[p] * (k.rest_joint[j] - k.rest_joint[p]);
    }
    k.skin[j].leftCols<3>() = k.rotation[j];
    k.skin[j].col(3).noalias() = k.position[j] - k.rotation[j] * k.rest_joint[j];
  }
  k.feature_nonzero[0] = false;
  for (int j = 1; j < kJ; ++j) {
    const Mat3 block = k.local_rotation[j] - Mat3::Identity();
    bool nonzero = false;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) {
        k.pose_feature[9 * (j - 1) + 3 * r + c] = block(r, c);
        nonzero |= block(r, c) != 0.0;
      }
    k.feature_nonzero[j] = nonzero;
  }
}

void computePoseDerivatives(const BodyModel& m, const Derived& d, const Kinematics& k,
                            const Eigen::Ref<const VecX>& pose72, PoseDerivatives& pd) {
  for (int j = 0; j < kJ; ++j) {
    const Mat3 left_jacobian = leftJacobianSO3(pose72.segment<3>(3 * j));
    const int p = m.parents[j];
    pd.world_axes[j] = p < 0 ? left_jacobian : Mat3(k.rotation[p] * left_jacobian);
    for (int a = 0; a < 3; ++a) {
      const Mat3 dR = skew(left_jacobian.col(a)) * k.local_rotation[j];  // dR = [J_l e_a]× R
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) pd.blend_basis[j](3 * r + c, a) = dR(r, c);
    }
  }
  const MatX& joint_dirs = d.joint_shapedirs;
  pd.position_betas.resize(3 * kJ, joint_dirs.cols());
  pd.skin_betas.resize(3 * kJ, joint_dirs.cols());
  for (int j = 0; j < kJ; ++j) {
    const int p = m.parents[j];
    if (p < 0) {
      pd.position_betas.middleRows<3>(0) = joint_dirs.middleRows<3>(0);
    } else {
      pd.position_betas.middleRows<3>(3 * j) =
          pd.position_betas.middleRows<3>(3 * p) +
          k.rotation[p] * (joint_dirs.middleRows<3>(3 * j) - joint_dirs.middleRows<3>(3 * p));
    }
    pd.skin_betas.middleRows<3>(3 * j) =
        pd.position_betas.middleRows<3>(3 * j) - k.rotation[j] * joint_dirs.middleRows<3>(3 * j);
  }
}

/// Column ranges [start, start + length) of posedirs whose pose features are not all zero.
struct ColumnRun {
  int start, length;
};
std::vector<ColumnRun> activeFeatureRuns(const Kinematics& k) {
  std::vector<ColumnRun> runs;
  for (int j = 1; j < kJ; ++j) {
    if (!k.feature_nonzero[j]) continue;
    const int col = 9 * (j - 1);
    if (!runs.empty() && runs.back().start + runs.back().length == col)
      runs.back().length += 9;
    else
      runs.push_back({col, 9});
  }
  return runs;
}

/// Posed rest vertices v_posed = v_template + shapedirs β + posedirs · pose_feature of the
/// vertices [v0, v1), written to rows [3 v0, 3 v1) of `v_posed`. Dense posedirs: one product
/// per run of active feature columns over the whole slab (long contiguous column segments
/// stream best); sparse: `sparse_blend` already holds posedirs · pose_feature.
void posedRestSlab(const BodyModel& m, const Derived& d, const VecX& betas, const Kinematics& k,
                   const std::vector<ColumnRun>& runs, const VecX& sparse_blend, int v0, int v1,
                   VecX& v_posed_all) {
  const int rows = 3 * (v1 - v0), r0 = 3 * v0;
  auto v_posed = v_posed_all.segment(r0, rows);
  v_posed = Eigen::Map<const VecX>(m.v_template.data() + r0, rows);
  v_posed.noalias() += m.shapedirs.middleRows(r0, rows) * betas;
  if (d.use_sparse_posedirs) {
    v_posed += sparse_blend.segment(r0, rows);
  } else {
    for (const ColumnRun& run : runs)
      v_posed.noalias() += m.posedirs.block(r0, run.start, rows, run.length) *
                           k.pose_feature.segment(run.start, run.length);
  }
}

/// Rows [r0, r0 + n) of posedirs_k · D_k (n × 3) for joint k ≥ 1: the pose blend offset's
/// derivative with respect to θ_k before skinning. One matrix-vector product per column:
/// Eigen's general product spends its time packing such thin operands.
template <class Out>
void blendDerivativeRows(const MatX& posedirs, int r0, int n, int k, const Mat93& D, Out&& out) {
  const auto block = posedirs.block(r0, 9 * (k - 1), n, 9);
  for (int a = 0; a < 3; ++a) out.col(a).noalias() = block * D.col(a);
}

/// Linear blend skinning of vertex i: Σ_j w_ij [Rg_j | p_j − Rg_j J_j].
inline Mat34 blendedSkin(const Derived& d, const Kinematics& k, int i) {
  Mat34 T = Mat34::Zero();
  for (int e = d.weights.start[i]; e < d.weights.start[i + 1]; ++e)
    T += d.weights.entries[e].weight * k.skin[d.weights.entries[e].bone];
  return T;
}

/// The pose blend offsets posedirs · pose_feature when posedirs is stored sparse (else empty).
VecX sparseBlend(const Derived& d, const Kinematics& k) {
  if (!d.use_sparse_posedirs) return VecX();
  return d.posedirs_sparse * k.pose_feature;
}

/// Vertex i's rows of the pose and shape Jacobians. On entry `rows` (3 × 72) holds the pose
/// blend derivatives posedirs_i,k · D_k; they are mapped through M_i and the rigid part added.
using PoseRows = Eigen::Ref<Eigen::Matrix<double, 3, 3 * kJ>, 0, Eigen::OuterStride<>>;
void vertexJacobian(const BodyModel& m, const Derived& d, const Kinematics& k,
                    const PoseDerivatives& pd, int i, const Vec3& v_posed, const Mat3& M,
                    PoseRows rows, PosedBodyJacobians& jac) {
  // Bones in the subtree of joint a turn about p_a, so
  // dv/dθ_a = ω_a × Σ_{j ∈ subtree(a)} w_ij (x_ij − p_a): gather those sums per ancestor a.
  std::array<Vec3, kJ> subtree_point_sum;
  std::array<double, kJ> subtree_weight;
  std::array<bool, kJ> touched{};
  std::array<int, kJ> touched_list;
  int touched_count = 0;
  for (int e = d.weights.start[i]; e < d.weights.start[i + 1]; ++e) {
    const int j = d.weights.entries[e].bone;
    const double w = d.weights.entries[e].weight;
    const Vec3 x = k.skin[j].leftCols<3>() * v_posed + k.skin[j].col(3);
    for (int a = j; a >= 0; a = m.parents[a]) {
      if (!touched[a]) {
        touched[a] = true;
        touched_list[touched_count++] = a;
        subtree_point_sum[a].setZero();
        subtree_weight[a] = 0.0;
      }
      subtree_point_sum[a] += w * x;
      subtree_weight[a] += w;
    }
  }
  // Pose blend part M_i · posedirs_i,k · D_k (none for the root, which has no blend shape).
  rows.leftCols<3>().setZero();
  const Eigen::Matrix<double, 3, 3 * (kJ - 1)> blend = rows.rightCols<3 * (kJ - 1)>();
  rows.rightCols<3 * (kJ - 1)>().noalias() = M * blend;
  for (int t = 0; t < touched_count; ++t) {
    const int a = touched_list[t];
    const Vec3 arm = subtree_point_sum[a] - subtree_weight[a] * k.position[a];
    for (int col = 0; col < 3; ++col) rows.col(3 * a + col) += pd.world_axes[a].col(col).cross(arm);
  }
  // Shape: dv/dβ = M_i S_i + Σ_j w_ij (dp_j/dβ − Rg_j dJ_j/dβ).
  auto beta_rows = jac.vertices_betas.middleRows<3>(3 * i);
  beta_rows.noalias() = M * m.shapedirs.middleRows<3>(3 * i);
  for (int e = d.weights.start[i]; e < d.weights.start[i + 1]; ++e)
    beta_rows +=
        d.weights.entries[e].weight * pd.skin_betas.middleRows<3>(3 * d.weights.entries[e].bone);
}

PosedBody poseOneFrame(const BodyModel& m, const Derived& d, const VecX& betas, const VecX& pose72,
                       const Vec3& trans, PosedBodyJacobians* jac) {
  const int V = m.numVertices();
  const int K = m.numBetas();
  Kinematics k;
  computeKinematics(m, d, betas, pose72, k);

  PosedBody out;
  out.rest_joints.resize(kJ, 3);
  out.joints.resize(kJ, 3);
  out.transforms.resize(kJ);
  for (int j = 0; j < kJ; ++j) {
    out.rest_joints.row(j) = k.rest_joint[j].transpose();
    out.joints.row(j) = (k.position[j] + trans).transpose();
    out.transforms[j].setIdentity();
    out.transforms[j].topLeftCorner<3, 3>() = k.rotation[j];
    out.transforms[j].topRightCorner<3, 1>() = k.position[j];
  }
  out.vertices.resize(V, 3);

  const std::vector<ColumnRun> runs = activeFeatureRuns(k);
  const VecX sparse_blend = sparseBlend(d, k);

  PoseDerivatives pd;
  if (jac) {
    computePoseDerivatives(m, d, k, pose72, pd);
    jac->vertices_betas.resize(3 * V, K);
    jac->vertices_pose.resize(3 * V, 3 * kJ);
    jac->vertices_trans.resize(3 * V, 3);
    for (int i = 0; i < V; ++i) jac->vertices_trans.middleRows<3>(3 * i).setIdentity();
    jac->joints_betas = pd.position_betas;
    jac->joints_pose = MatX::Zero(3 * kJ, 3 * kJ);
    jac->joints_trans.resize(3 * kJ, 3);
    for (int j = 0; j < kJ; ++j) {
      jac->joints_trans.middleRows<3>(3 * j).setIdentity();
      for (int a = m.parents[j]; a >= 0; a = m.parents[a]) {
        const Vec3 lever = k.position[j] - k.position[a];
        for (int c = 0; c < 3; ++c)
          jac->joints_pose.block<3, 1>(3 * j, 3 * a + c) = pd.world_axes[a].col(c).cross(lever);
      }
    }
    if (d.use_sparse_posedirs)
      for (int j = 1; j < kJ; ++j)
        jac->vertices_pose.middleCols<3>(3 * j) =
            d.posedirs_sparse.middleCols(9 * (j - 1), 9) * pd.blend_basis[j];
  }

  // Slabs of vertices are independent: each forms its posed rest vertices and skins exactly
  // those. Dynamic scheduling lets a thread that runs take over the slabs of one that is
  // descheduled (the machine may be shared).
  VecX v_posed_all(3 * V);
  const int slabs = (V + kSlabVertices - 1) / kSlabVertices;
#pragma omp parallel for schedule(dynamic, 1) if (V >= kParallelMinVertices)
  for (int slab = 0; slab < slabs; ++slab) {
    const int v0 = slab * kSlabVertices, v1 = std::min(V, v0 + kSlabVertices);
    posedRestSlab(m, d, betas, k, runs, sparse_blend, v0, v1, v_posed_all);
    for (int i = v0; i < v1; ++i) {
      const Vec3 v_posed = v_posed_all.segment<3>(3 * i);
      const Mat34 T = blendedSkin(d, k, i);
      out.vertices.row(i) = (T.leftCols<3>() * v_posed + T.col(3) + trans).transpose();
    }
    if (jac) {
      // Pose rows are assembled chunk by chunk in a small buffer (the output's 72 columns lie
      // far apart in memory) and copied out in one block per chunk.
      MatX pose_rows(3 * kJacobianChunkVertices, 3 * kJ);
      for (int c0 = v0; c0 < v1; c0 += kJacobianChunkVertices) {
        const int n = std::min(kJacobianChunkVertices, v1 - c0);
        auto chunk_rows = pose_rows.topRows(3 * n);
        if (d.use_sparse_posedirs) {
          chunk_rows = jac->vertices_pose.middleRows(3 * c0, 3 * n);
        } else {
          for (int j = 1; j < kJ; ++j)
            blendDerivativeRows(m.posedirs, 3 * c0, 3 * n, j, pd.blend_basis[j],
                                chunk_rows.middleCols<3>(3 * j));
        }
        for (int i = c0; i < c0 + n; ++i) {
          const Vec3 v_posed = v_posed_all.segment<3>(3 * i);
          const Mat34 T = blendedSkin(d, k, i);
          vertexJacobian(m, d, k, pd, i, v_posed, T.leftCols<3>(),
                         chunk_rows.middleRows<3>(3 * (i - c0)), *jac);
        }
        jac->vertices_pose.middleRows(3 * c0, 3 * n) = chunk_rows;
      }
    }
  }
  return out;
}

}  // namespace

void checkShapeCoefficients(const Eigen::Ref<const VecX>& betas, const std::string& what) {
  for (Eigen::Index k = 0; k < betas.size(); ++k) {
    if (!std::isfinite(betas[k]))
      throw InputError(what + " contains NaN or Inf (value " + std::to_string(k) + ")");
    if (std::abs(betas[k]) > kMaxShapeCoefficient) {
      char text[32];
      std::snprintf(text, sizeof(text), "%.6g", betas[k]);
      throw InputError(what + "[" + std::to_string(k) + "] = " + text +
                       ", expected within [-100, 100] (shape coefficients, in standard "
                       "deviations of the shape space)");
    }
  }
}

PosedBody poseBody(const BodyModel& model, const Eigen::Ref<const VecX>& betas,
                   const Eigen::Ref<const VecX>& pose, const Vec3& trans,
                   PosedBodyJacobians* jacobians) {
  const Derived& d = requireFinalizedModel(model, "poseBody");
  const VecX padded = paddedBetas(model, betas, "poseBody");
  const VecX pose72 = toSmplPose(pose, "poseBody: pose");
  if (!trans.allFinite()) throw InputError("poseBody: trans contains NaN or Inf");
  return poseOneFrame(model, d, padded, pose72, trans, jacobians);
}

PosedBatch poseBodyBatch(const BodyModel& model, const Eigen::Ref<const VecX>& betas,
                         const Eigen::Ref<const RowMatX>& poses,
                         const Eigen::Ref<const RowMatX>& trans) {
  const Derived& d = requireFinalizedModel(model, "poseBodyBatch");
  const VecX padded = paddedBetas(model, betas, "poseBodyBatch");
  const RowMatX poses72 = toSmplPoses(poses, "poseBodyBatch: poses");
  if (trans.cols() != 3 || trans.rows() != poses.rows())
    throw InputError("poseBodyBatch: trans has shape " +
                     shapeString({long(trans.rows()), long(trans.cols())}) + ", expected " +
                     shapeString({long(poses.rows()), 3}) + " (one row per pose of poses " +
                     shapeString({long(poses.rows()), long(poses.cols())}) + ")");
  if (!trans.allFinite()) throw InputError("poseBodyBatch: trans contains NaN or Inf");

  const int T = int(poses72.rows());
  const int V = model.numVertices();
  PosedBatch out;
  out.vertices.resize(T, 3 * V);
  out.joints.resize(T, 3 * kJ);
  if (T == 0) return out;

  // Shaped rest vertices are shared by all frames.
  VecX shaped = Eigen::Map<const VecX>(model.v_template.data(), 3 * V);
  shaped.noalias() += model.shapedirs * padded;

  std::vector<Kinematics> kin(std::min(T, kBatchBlockFrames));
  MatX features(kPoseFeatureSize, kin.size());
  MatX sparse_blend;
  for (int t0 = 0; t0 < T; t0 += kBatchBlockFrames) {
    const int nb = std::min(kBatchBlockFrames, T - t0);
#pragma omp parallel for schedule(static) if (nb > 1)
    for (int b = 0; b < nb; ++b) {
      computeKinematics(model, d, padded, poses72.row(t0 + b).transpose(), kin[b]);
      for (int j = 0; j < kJ; ++j)
        out.joints.row(t0 + b).segment<3>(3 * j) =
            kin[b].position[j].transpose() + trans.row(t0 + b);
      features.col(b) = kin[b].pose_feature;
    }
    if (d.use_sparse_posedirs) sparse_blend.noalias() = d.posedirs_sparse * features.leftCols(nb);

    // Each slab of vertices multiplies its posedirs rows by the block's pose features (one
    // product: posedirs is read once per block, not once per frame) and skins those vertices
    // in every frame of the block. Independent slabs: no synchronisation between them.
    const int slabs = (V + kSlabVertices - 1) / kSlabVertices;
#pragma omp parallel for schedule(dynamic, 1) if (V >= kParallelMinVertices)
    for (int slab = 0; slab < slabs; ++slab) {
      const int v0 = slab * kSlabVertices, v1 = std::min(V, v0 + kSlabVertices);
      const int rows = 3 * (v1 - v0);
      MatX blend(rows, nb);
      if (d.use_sparse_posedirs)
        blend = sparse_blend.middleRows(3 * v0, rows);
      else
        blend.noalias() = model.posedirs.middleRows(3 * v0, rows) * features.leftCols(nb);
      for (int b = 0; b < nb; ++b) {
        const Kinematics& k = kin[b];
        const Vec3 frame_trans = trans.row(t0 + b).transpose();
        auto frame_vertices = out.vertices.row(t0 + b);
        for (int i = v0; i < v1; ++i) {
          const Vec3 v_posed = shaped.segment<3>(3 * i) + blend.col(b).segment<3>(3 * (i - v0));
          const Mat34 Tm = blendedSkin(d, k, i);
          frame_vertices.segment<3>(3 * i) =
              (Tm.leftCols<3>() * v_posed + Tm.col(3) + frame_trans).transpose();
        }
      }
    }
  }
  return out;
}

MatX3 shapedVertices(const BodyModel& model, const Eigen::Ref<const VecX>& betas) {
  requireFinalizedModel(model, "shapedVertices", false);
  const VecX padded = paddedBetas(model, betas, "shapedVertices");
  MatX3 shaped = model.v_template;
  Eigen::Map<VecX>(shaped.data(), shaped.size()).noalias() += model.shapedirs * padded;
  return shaped;
}

}  // namespace flsh
