// The soft skeletons' surface for many states at once (surface_frames.h).
#include "sim/soft/surface_frames.h"

#include <string>

#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "sim/soft/on_two_threads.h"

namespace flsh::detail {

namespace {

std::vector<std::vector<Mat3>> heldRotations(const std::vector<SurfaceFrame>& frames) {
  std::vector<std::vector<Mat3>> held(frames.size());
  for (size_t k = 0; k < frames.size(); ++k) held[k] = frames[k].held_R;
  return held;
}

// Y (#frames × 3#V): the rest nodes, the held pose blends and the soft displacements, as
// SoftKinematics::nodeDisplacement has them (handles on every node, modes on soft nodes, the
// FEM's u_j on soft nodes).
RowMatX unposedSurface(const SoftKinematics& kin, const std::vector<SurfaceFrame>& frames) {
  const int V = kin.numSurface(), F = int(frames.size());
  RowMatX Y = kin.surfacePoseBlends(heldRotations(frames));
  const MatX3& rest = kin.restNodes();
  const Eigen::Map<const Eigen::RowVectorXd> rest_row(rest.data(), 3 * Eigen::Index(V));
  Y.rowwise() += rest_row;
  if (kin.reduced() && kin.numModes() > 0) {
    const int r = kin.numModes(), base = 3 * kin.numHandles();
    RowMatX Z(F, r);
    for (int k = 0; k < F; ++k) Z.row(k) = frames[size_t(k)].soft.segment(base, r).transpose();
    // Ψ's rows are zero on bone nodes (SoftKinematics::modeRows).
    Y.noalias() += Z * kin.allModeRows().topRows(3 * Eigen::Index(V)).transpose();
  }
  for (int k = 0; k < F; ++k) {
    const VecX& z = frames[size_t(k)].soft;
    for (int i = 0; i < V; ++i) {
      auto Yi = Y.row(k).segment<3>(3 * i);
      if (kin.reduced()) {
        for (auto* phi = kin.basisBegin(i); phi != kin.basisEnd(i); ++phi)
          Yi += phi->second * z.segment<3>(3 * phi->first).transpose();
      } else if (kin.nodeDof(i) >= 0) {
        Yi += z.segment<3>(kin.nodeDof(i)).transpose();
      }
    }
  }
  return Y;
}

void checkFrames(const SoftKinematics& kin, const std::vector<SurfaceFrame>& frames,
                 const char* who) {
  const int B = kin.numBones();
  for (size_t k = 0; k < frames.size(); ++k) {
    const SurfaceFrame& f = frames[k];
    if (int(f.R.size()) != B || int(f.held_R.size()) != B || f.t.rows() != B ||
        f.soft.size() != kin.numSoftDofs())
      throw InputError(
          std::string(who) + ": frame " + std::to_string(k) + " has " + std::to_string(f.R.size()) +
          " rotations, " + std::to_string(f.held_R.size()) + " held rotations, " +
          std::to_string(f.t.rows()) + " bone positions and " + std::to_string(f.soft.size()) +
          " soft state values, expected " + std::to_string(B) + ", " + std::to_string(B) + ", " +
          std::to_string(B) + " and " + std::to_string(kin.numSoftDofs()));
    if (!f.t.allFinite() || !f.soft.allFinite())
      throw InputError(std::string(who) + ": frame " + std::to_string(k) + " contains NaN or Inf");
  }
}

}  // namespace

RowMatX surfaceOfFrames(const SoftKinematics& kin, const std::vector<SurfaceFrame>& frames) {
  checkFrames(kin, frames, "Simulable::getNodesOfFrames");
  RowMatX x = unposedSurface(kin, frames);
  const int V = kin.numSurface(), F = int(frames.size());
#pragma omp parallel for schedule(static) if (F > 1)
  for (int k = 0; k < F; ++k) {
    const SurfaceFrame& f = frames[size_t(k)];
    Vec3 shift[kNumJoints];
    kin.boneShifts(f.R, f.t, shift);
    for (int i = 0; i < V; ++i) {
      auto row = x.row(k).segment<3>(3 * i);
      row = kin.skin(i, f.R, shift, row.transpose()).transpose();
    }
  }
  return x;
}

SurfaceFrameCotangents surfaceCotangentsOfFrames(const SoftKinematics& kin,
                                                 const std::vector<SurfaceFrame>& frames,
                                                 const RowMatX& dL_dnodes) {
  const char* who = "Simulable::getNodesCotangentsOfFrames";
  checkFrames(kin, frames, who);
  const int V = kin.numSurface(), F = int(frames.size()), B = kin.numBones();
  if (dL_dnodes.rows() != F || dL_dnodes.cols() != 3 * V)
    throw InputError(std::string(who) + ": dL_dnodes has shape " +
                     shapeString({long(dL_dnodes.rows()), long(dL_dnodes.cols())}) + ", expected " +
                     shapeString({long(F), 3L * V}) + " (frames × 3·#surface nodes)");
  if (!dL_dnodes.allFinite())
    throw InputError(std::string(who) + ": dL_dnodes contains NaN or Inf");
  const RowMatX Y = unposedSurface(kin, frames);
  const MatX3& J = kin.joints();
  const int bone_dofs = kin.boneDofs();
  SurfaceFrameCotangents out;
  out.state = RowMatX::Zero(F, bone_dofs + kin.numSoftDofs());
  out.unposed.resize(F, 3 * Eigen::Index(V));
  RowMatX joints = RowMatX::Zero(F, 3 * B);
#pragma omp parallel for schedule(static) if (F > 1)
  for (int k = 0; k < F; ++k) {
    const SurfaceFrame& f = frames[size_t(k)];
    auto g = out.state.row(k);
    auto joints_k = joints.row(k);
    for (int i = 0; i < V; ++i) {
      const Vec3 force = dL_dnodes.row(k).segment<3>(3 * i).transpose();
      const Vec3 Yi = Y.row(k).segment<3>(3 * i).transpose();
      Mat3 M = Mat3::Zero();
      for (auto* inf = kin.influencesBegin(i); inf != kin.influencesEnd(i); ++inf) {
        const int b = inf->bone;
        const double w = inf->weight;
        const Mat3& Rb = f.R[size_t(b)];
        M += w * Rb;
        if (force.isZero(0.0)) continue;
        const Vec3 lever = Rb * (Yi - J.row(b).transpose());
        g.segment<3>(6 * b) += (w * force).transpose();
        g.segment<3>(6 * b + 3) += (w * lever.cross(force)).transpose();
        joints_k.segment<3>(3 * b) -= (w * (Rb.transpose() * force)).transpose();
      }
      const Vec3 Y_bar = M.transpose() * force;
      out.unposed.row(k).segment<3>(3 * i) = Y_bar.transpose();
      if (!kin.isSoftNode(i)) continue;
      if (kin.reduced()) {
        for (auto* phi = kin.basisBegin(i); phi != kin.basisEnd(i); ++phi)
          g.segment<3>(bone_dofs + 3 * phi->first) += phi->second * Y_bar.transpose();
      } else {
        g.segment<3>(bone_dofs + kin.nodeDof(i)) += Y_bar.transpose();
      }
    }
  }
  if (kin.reduced() && kin.numModes() > 0)  // Ψᵀ dL/dY, zero rows on bone nodes
    addLongInnerProduct(out.unposed, kin.allModeRows().topRows(3 * Eigen::Index(V)),
                        out.state.rightCols(kin.numModes()));
  out.rest_joints = joints.colwise().sum().transpose();
  out.rotations = RowMatX::Zero(F, 3 * B);
  kin.surfacePoseBlendCotangents(heldRotations(frames), out.unposed, out.rotations);
  return out;
}

}  // namespace flsh::detail
