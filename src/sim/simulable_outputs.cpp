// Simulable: poses, meshes and nodes read off the state, their Jacobians, and the soft-tissue
// accessors.
#include <string>
#include <utility>
#include <vector>

#include "flsh/body/body_forward.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "flsh/energy/skeleton_energies.h"
#include "flsh/sim/simulable.h"
#include "sim/simulable_impl.h"
#include "sim/soft/surface_frames.h"
#include "sim/terms/term_blocks.h"

namespace flsh {

using detail::BoneStates;
using detail::kDofsPerBone;

// ---- outputs -----------------------------------------------------------------------------

VecX Simulable::getPose() const {
  const Impl& m = *impl_;
  VecX pose(3 * m.num_bones);
  for (int b = 0; b < m.num_bones; ++b) {
    const int p = m.parents[b];
    pose.segment<3>(3 * b) = logSO3(p < 0 ? m.q.R[b] : Mat3(m.q.R[p].transpose() * m.q.R[b]));
  }
  return pose;
}

Vec3 Simulable::getTrans() const { return (impl_->q.t.row(0) - impl_->J.row(0)).transpose(); }

// θ_b = log(R_pᵀR_b): a world increment δω_b left-multiplies R_pᵀR_b by exp([R_pᵀδω_b]×), so
// dθ_b = J_l(θ_b)⁻¹ R_pᵀ (δω_b − δω_p).
MatX Simulable::getStateJacobian() const {
  const Impl& m = *impl_;
  MatX D = MatX::Zero(3 * m.num_bones + 3, m.dofs());
  const VecX pose = getPose();
  for (int b = 0; b < m.num_bones; ++b) {
    const int p = m.parents[b];
    const Mat3 Jinv = leftJacobianInverseSO3(pose.segment<3>(3 * b));
    if (p < 0) {
      D.block<3, 3>(3 * b, 6 * b + 3) = Jinv;
    } else {
      const Mat3 block = Jinv * m.q.R[p].transpose();
      D.block<3, 3>(3 * b, 6 * b + 3) = block;
      D.block<3, 3>(3 * b, 6 * p + 3) = -block;
    }
  }
  D.block<3, 3>(3 * m.num_bones, 0) = Mat3::Identity();
  return D;
}

MatX3 Simulable::getVertices() const {
  if (impl_->soft) return getNodes();
  const SoftAvatar& avatar = *impl_->avatar;
  return poseBody(avatar.body(), avatar.betas(), getPose(), getTrans()).vertices;
}

MatX3 Simulable::getNodes() const {
  const Impl& m = *impl_;
  m.prepare();
  MatX3 x;
  m.kinematics->surface(&x, nullptr);
  return x;
}

// ∂x_i/∂t_b = w_ib I, ∂x_i/∂δω_b = −w_ib [R_b(X_i − J_b)]× (skeleton); soft: SoftKinematics.
SpMat Simulable::getNodesStateJacobian() const {
  const Impl& m = *impl_;
  m.prepare();
  std::vector<Triplet> triplets;
  m.kinematics->surfaceJacobian(triplets);
  SpMat D(3 * m.kinematics->numSurface(), m.dofs());
  D.setFromTriplets(triplets.begin(), triplets.end());
  return D;
}

// Soft tissue: x_i moves with its held pose blend offset P_i(R_n) by M_i = Σ_b w_ib R_b, so the
// cotangent of P_i is M_iᵀ ∂L/∂x_i, chained to q_n's rotations by the kinematics.
// The rest joint J_b moves x_i by −w_ib R_b.
void Simulable::getNodesCotangents(const MatX3& dL_dnodes, VecX* state, VecX* previous_state,
                                   VecX* rest_joints, VecX* rest_nodes_shape) const {
  const Impl& m = *impl_;
  const int V = m.kinematics->numSurface();
  if (dL_dnodes.rows() != V)
    throw InputError("Simulable::getNodesCotangents: dL_dnodes has shape " +
                     shapeString({long(dL_dnodes.rows()), 3}) + ", expected " +
                     shapeString({long(V), 3}));
  m.prepare();
  m.kinematics->surface(nullptr, nullptr);  // the ROM skins its surface nodes here
  if (state) {
    *state = VecX::Zero(m.dofs());
    m.kinematics->surfaceForces(dL_dnodes, *state);
  }
  if (rest_joints) {
    *rest_joints = VecX::Zero(3 * m.num_bones);
    detail::SkinnedPoint point;
    for (int i = 0; i < V; ++i) {
      if (dL_dnodes.row(i).isZero(0.0)) continue;
      m.kinematics->surfacePoint(i, point, false);
      for (int a = 0; a < point.count; ++a) {
        const int b = point.bone[a];
        rest_joints->segment<3>(3 * b) -=
            point.weight[a] * (m.q.R[b].transpose() * dL_dnodes.row(i).transpose());
      }
    }
  }
  if (rest_nodes_shape) *rest_nodes_shape = VecX::Zero(parameterSize(SimParameter::Shape));
  if (previous_state) *previous_state = VecX::Zero(m.dofs());
  if (!m.soft || !(previous_state || rest_nodes_shape)) return;
  const detail::SoftKinematics& kin = m.soft->kinematics();
  MatX3 offsets(V, 3);  // cotangent of the surface nodes' Y_i (the held offsets P_i, X̄_i)
  for (int i = 0; i < V; ++i) offsets.row(i) = dL_dnodes.row(i) * kin.M(i);
  if (previous_state) m.soft->addPoseBlendCotangent(m.q_n.R, offsets, *previous_state);
  if (rest_nodes_shape) m.soft->addRestNodesCotangent(offsets, *rest_nodes_shape);
}

SurfaceFrame Simulable::getSurfaceFrame() const {
  const Impl& m = *impl_;
  if (!m.soft) throw InputError("Simulable::getSurfaceFrame: the simulable has no soft tissue");
  const detail::SoftKinematics& kin = m.soft->kinematics();
  // The ROM holds the rotations it set its blend from; the FEM's offsets come from q_n's.
  const std::vector<Mat3>* held = kin.heldPoseRotations();
  return {m.q.R, m.q.t, held ? *held : m.q_n.R, kin.u};
}

RowMatX Simulable::getNodesOfFrames(const std::vector<SurfaceFrame>& frames) const {
  const Impl& m = *impl_;
  if (!m.soft) throw InputError("Simulable::getNodesOfFrames: the simulable has no soft tissue");
  return detail::surfaceOfFrames(m.soft->kinematics(), frames);
}

void Simulable::getNodesCotangentsOfFrames(const std::vector<SurfaceFrame>& frames,
                                           const RowMatX& dL_dnodes, RowMatX* state,
                                           RowMatX* previous_state, VecX* rest_joints,
                                           VecX* rest_nodes_shape) const {
  const Impl& m = *impl_;
  if (!m.soft)
    throw InputError("Simulable::getNodesCotangentsOfFrames: the simulable has no soft tissue");
  detail::SurfaceFrameCotangents c =
      detail::surfaceCotangentsOfFrames(m.soft->kinematics(), frames, dL_dnodes);
  if (state) *state = std::move(c.state);
  if (previous_state) {
    *previous_state = RowMatX::Zero(c.rotations.rows(), m.dofs());
    for (int b = 0; b < m.num_bones; ++b)
      previous_state->middleCols<3>(detail::rotationRow(b)) = c.rotations.middleCols<3>(3 * b);
  }
  if (rest_joints) *rest_joints = std::move(c.rest_joints);
  if (rest_nodes_shape) {
    const VecX sum = c.unposed.colwise().sum().transpose();  // rows 3i + c
    const MatX3 summed = Eigen::Map<const MatX3>(sum.data(), m.kinematics->numSurface(), 3);
    *rest_nodes_shape = VecX::Zero(parameterSize(SimParameter::Shape));
    m.soft->addRestNodesCotangent(summed, *rest_nodes_shape);
  }
}

// ---- soft tissue --------------------------------------------------------------------------

bool Simulable::hasSoftTissue() const { return impl_->soft != nullptr; }
int Simulable::numBoneDofs() const { return impl_->boneDofs(); }
const VecXi& Simulable::softNodes() const {
  static const VecXi none;
  return impl_->soft ? impl_->soft->softNodes() : none;
}
int Simulable::nodeSoftDof(int j) const {
  const Impl& m = *impl_;
  const int n = m.soft ? m.soft->numNodes() : int(m.avatar->restVertices().rows());
  if (j < 0 || j >= n)
    throw InputError("Simulable::nodeSoftDof: node " + std::to_string(j) + " outside [0, " +
                     std::to_string(n) + ")");
  if (!m.soft || m.soft->nodeDof(j) < 0) return -1;
  return m.boneDofs() + m.soft->nodeDof(j);
}
MatX3 Simulable::getSoftTissueDisplacements() const {
  const Impl& m = *impl_;
  const int V = int(m.avatar->restVertices().rows());
  MatX3 u = MatX3::Zero(V, 3);
  if (m.soft)
    for (int i = 0; i < V; ++i) u.row(i) = m.soft->displacementOf(m.soft->u, i).transpose();
  return u;
}
bool Simulable::hasReducedModel() const { return impl_->soft && impl_->soft->reduced(); }
std::vector<std::pair<int, Mat3>> Simulable::nodeDisplacementBasis(int j) const {
  const Impl& m = *impl_;
  const int n = m.soft ? m.soft->numNodes() : int(m.avatar->restVertices().rows());
  if (j < 0 || j >= n)
    throw InputError("Simulable::nodeDisplacementBasis: node " + std::to_string(j) +
                     " outside [0, " + std::to_string(n) + ")");
  std::vector<std::pair<int, Mat3>> basis;
  if (!m.soft) return basis;
  m.soft->displacementBasis(j, basis);
  for (auto& entry : basis) entry.first += m.boneDofs();
  return basis;
}
MatX3 Simulable::getUnposedSurface() const {
  const Impl& m = *impl_;
  m.prepare();
  MatX3 Y;
  m.kinematics->surface(nullptr, &Y);
  return Y;
}
MatX3 Simulable::getVolumeNodes() const {
  const Impl& m = *impl_;
  if (!m.soft) return getNodes();
  if (!m.soft->reduced()) {
    m.prepare();
    return m.soft->currentPositions();
  }
  MatX3 x;  // the ROM skins only the nodes its energies read
  m.soft->positions(m.frames(m.q), m.soft->u, x);
  return x;
}

const std::vector<Mat3>& Simulable::boneRotations() const { return impl_->q.R; }
const MatX3& Simulable::bonePositions() const { return impl_->q.t; }

}  // namespace flsh
