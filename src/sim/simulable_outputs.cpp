// Simulable: poses, meshes and nodes read off the state, their Jacobians, and the soft-tissue
// accessors.
#include <string>

#include "flsh/body/body_forward.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "flsh/sim/simulable.h"
#include "flsh/energy/skeleton_energies.h"
#include "sim/simulable_impl.h"

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

Vec3 Simulable::Impl::node(int i) const {
  const Vec3 X = avatar->restVertices().row(i).transpose();
  Vec3 x = Vec3::Zero();
  for (int k = surface.weights.start[i]; k < surface.weights.start[i + 1]; ++k) {
    const int b = surface.weights.entries[k].bone;
    x += surface.weights.entries[k].weight *
         (q.R[b] * (X - J.row(b).transpose()) + q.t.row(b).transpose());
  }
  return x;
}

MatX3 Simulable::getNodes() const {
  const Impl& m = *impl_;
  if (m.soft) {
    m.prepareSoft();
    MatX3 x;
    m.soft->surface(&x, nullptr);
    return x;
  }
  MatX3 nodes(m.avatar->restVertices().rows(), 3);
  for (int i = 0; i < nodes.rows(); ++i) nodes.row(i) = m.node(i).transpose();
  return nodes;
}

// ∂x_i/∂t_b = w_ib I, ∂x_i/∂δω_b = −w_ib [R_b(X_i − J_b)]×.
SpMat Simulable::getNodesStateJacobian() const {
  const Impl& m = *impl_;
  if (m.soft) {
    m.prepareSoft();
    std::vector<Triplet> triplets;
    m.soft->surfaceJacobian(triplets);
    SpMat D(3 * m.soft->numSurface(), m.dofs());
    D.setFromTriplets(triplets.begin(), triplets.end());
    return D;
  }
  const MatX3& X = m.avatar->restVertices();
  std::vector<Triplet> triplets;
  triplets.reserve(m.surface.weights.entries.size() * 9);
  for (int i = 0; i < X.rows(); ++i) {
    for (int k = m.surface.weights.start[i]; k < m.surface.weights.start[i + 1]; ++k) {
      const int b = m.surface.weights.entries[k].bone;
      const double w = m.surface.weights.entries[k].weight;
      const Mat3 dx_dw = -w * skew(m.q.R[b] * (X.row(i) - m.J.row(b)).transpose());
      for (int r = 0; r < 3; ++r) {
        triplets.emplace_back(3 * i + r, 6 * b + r, w);
        for (int c = 0; c < 3; ++c) triplets.emplace_back(3 * i + r, 6 * b + 3 + c, dx_dw(r, c));
      }
    }
  }
  SpMat D(3 * X.rows(), m.dofs());
  D.setFromTriplets(triplets.begin(), triplets.end());
  return D;
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
std::vector<std::pair<int, double>> Simulable::nodeDisplacementBasis(int j) const {
  const Impl& m = *impl_;
  const int n = m.soft ? m.soft->numNodes() : int(m.avatar->restVertices().rows());
  if (j < 0 || j >= n)
    throw InputError("Simulable::nodeDisplacementBasis: node " + std::to_string(j) +
                     " outside [0, " + std::to_string(n) + ")");
  std::vector<std::pair<int, double>> basis;
  if (!m.soft) return basis;
  m.soft->displacementBasis(j, basis);
  for (auto& entry : basis) entry.first += m.boneDofs();
  return basis;
}
MatX3 Simulable::getUnposedSurface() const {
  const Impl& m = *impl_;
  if (!m.soft) return m.avatar->restVertices();
  m.prepareSoft();
  MatX3 Y;
  m.soft->surface(nullptr, &Y);
  return Y;
}
MatX3 Simulable::getVolumeNodes() const {
  const Impl& m = *impl_;
  if (!m.soft) return getNodes();
  if (!m.soft->reduced()) {
    m.prepareSoft();
    return m.soft->currentPositions();
  }
  MatX3 x;  // the ROM skins only the nodes its energies read
  m.soft->positions(m.frames(m.q), m.soft->u, x);
  return x;
}

const std::vector<Mat3>& Simulable::boneRotations() const { return impl_->q.R; }
const MatX3& Simulable::bonePositions() const { return impl_->q.t; }

}  // namespace flsh
