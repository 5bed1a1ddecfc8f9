#include "sim/soft/node_contact_term.h"

#include "flsh/core/rotation.h"
#include "sim/soft/node_offset_blocks.h"
#include "sim/terms/term_blocks.h"

namespace flsh::detail {

void NodeContactTerm::addHessianBlocks(const TermContext& c, std::vector<Triplet>& H,
                                       std::vector<FixedHessianBlocks>* blocks, int offset,
                                       bool psd) const {
  evaluate(c.colliders, c.time, c.options.contact, nullptr, &H, offset, psd, nullptr,
           &c.contact.candidates);
}

const std::vector<int>& NodeContactTerm::gather(const std::vector<int>* candidates,
                                                bool skin) const {
  const std::vector<int>& list = candidates ? *candidates : kin_.surfaceNodes();
  if (list.empty()) return list;
  if (kin_.reduced() && skin) kin_.skinNodes(list);  // the ROM's prepare() skins the mass nodes
  const int V = int(list.size());
  const MatX3& x = kin_.x();
  x_.resize(V, 3);
  node_areas_.resize(V);
  for (int k = 0; k < V; ++k) {
    x_.row(k) = x.row(list[k]);
    node_areas_[k] = areas_[list[k]];
  }
  return list;
}

double NodeContactTerm::evaluate(const std::vector<Collider>& colliders, double time,
                                 const ContactOptions& options, VecX* g, std::vector<Triplet>* H,
                                 int offset, bool psd, int* active,
                                 const std::vector<int>* candidates, bool skin) const {
  if (active) *active = 0;
  if (colliders.empty()) return 0.0;
  const std::vector<int>& list = gather(candidates, skin);
  if (list.empty()) return 0.0;
  const int V = int(list.size());
  ContactOptions contact_options = options;
  contact_options.exact_hessian = !psd;
  VecX gradient = VecX::Zero(3 * V);
  std::vector<Mat3> node_hessian;
  std::vector<ContactPoint> points;
  const double E = H ? colliderContactBlocks(x_, node_areas_, colliders, time, contact_options,
                                             &gradient, node_hessian, &points)
                     : colliderContactEnergy(x_, node_areas_, colliders, time, contact_options,
                                             &gradient, nullptr, 0, &points);
  if (active) *active = int(points.size());
  if (!g && !H) return E;
  // The touching vertices, their forces and (for H) their 3 × 3 blocks (p.vertex indexes list).
  std::vector<int> nodes;
  std::vector<Vec3> forces;
  std::vector<int> slot(V, -1);
  for (const ContactPoint& p : points)
    if (slot[p.vertex] < 0) {
      slot[p.vertex] = int(nodes.size());
      nodes.push_back(list[p.vertex]);
      forces.push_back(gradient.segment<3>(3 * p.vertex));
    }
  if (g) kin_.mapForces(nodes, forces, *g, offset);
  if (H) {
    std::vector<Mat3> K(nodes.size());
    for (int i = 0; i < V; ++i)
      if (slot[i] >= 0) K[size_t(slot[i])] = node_hessian[size_t(i)];
    kin_.mapHessian(nodes, &K, &forces, *H, offset, psd, 1);
  }
  return E;
}

// g = Σ_j J_jᵀ g_x,j (J_j: node j's row block of ∂x/∂q, a SkinnedPoint with its soft DoFs).
// g_x is linear in the contact stiffness, and depends on x − o_k for collider k: ∂g_x/∂o_k =
// −H_x,k (the exact node Hessian against collider k alone). The rest joint J_b moves x_j by
// −w_jb R_b and turns the lever arm of bone b's rotation rows (as the skeleton's contact).
template <class Sink>
void NodeContactTerm::parameterBlocks(const TermContext& c, Sink& sink) const {
  const bool stiffness = sink.wants(SimParameter::Stiffnesses);
  const bool offsets = sink.wants(SimParameter::ColliderOffsets);
  const bool joints = sink.wants(SimParameter::RestJoints);
  const bool shape = sink.wants(SimParameter::Shape);  // the areas' share (the rest nodes': Y)
  if (!(stiffness || offsets || joints || shape) || c.colliders.empty()) return;
  const std::vector<int>& list = gather(&c.contact.candidates, true);
  const int V = int(list.size());
  if (V == 0) return;
  VecX unit_gradient;  // g_x at unit contact stiffness
  if (stiffness) {
    ContactOptions unit = c.options.contact;
    unit.stiffness = 1.0;
    unit_gradient = VecX::Zero(3 * V);
    colliderContactEnergy(x_, node_areas_, c.colliders, c.time, unit, &unit_gradient);
  }
  ContactOptions exact = c.options.contact;
  exact.exact_hessian = true;
  VecX gradient;              // g_x (joints, shape)
  std::vector<Mat3> H_total;  // the exact node Hessian against every collider (joints, shape)
  if (joints || shape) {
    gradient = VecX::Zero(3 * V);
    colliderContactBlocks(x_, node_areas_, c.colliders, c.time, exact, &gradient, H_total);
  }
  const int nc = int(c.colliders.size());
  std::vector<std::vector<Mat3>> H(offsets ? size_t(nc) : 0);  // per collider, per candidate
  for (int k = 0; k < int(H.size()); ++k)
    colliderContactBlocks(x_, node_areas_, {c.colliders[size_t(k)]}, c.time, exact, nullptr,
                          H[size_t(k)]);
  SkinnedPoint point;
  const Mat3 I3 = Mat3::Identity();
  for (int idx = 0; idx < V; ++idx) {
    const bool unit_touching = stiffness && !unit_gradient.segment<3>(3 * idx).isZero(0.0);
    bool touching = false;
    for (const std::vector<Mat3>& Hk : H) touching = touching || !Hk[size_t(idx)].isZero(0.0);
    const bool gradient_touching =
        (joints || shape) &&
        !(gradient.segment<3>(3 * idx).isZero(0.0) && H_total[size_t(idx)].isZero(0.0));
    const bool joint_touching = joints && gradient_touching;
    if (!unit_touching && !touching && !gradient_touching) continue;
    kin_.point(list[size_t(idx)], point);
    point.id = idx;
    if (unit_touching)
      sink.add(SimParameter::Stiffnesses, point, 3, unit_gradient.segment<3>(3 * idx),
               Eigen::Matrix<double, 1, 1>::Ones());
    for (int k = 0; k < int(H.size()); ++k)
      if (!H[size_t(k)][size_t(idx)].isZero(0.0))
        sink.add(SimParameter::ColliderOffsets, point, 3 * k,
                 -H[size_t(k)][size_t(idx)].transpose(), I3);
    // g_x is linear in the node's area a_j(β): ∂g_x/∂β = g_x / a_j ∂a_j/∂β.
    const int node = list[size_t(idx)];
    if (shape && gradient_touching && node_areas_[idx] > 0.0)
      sink.add(SimParameter::Shape, point, 0, Vec3(gradient.segment<3>(3 * idx) / node_areas_[idx]),
               c.avatar.vertexAreasShapeJacobian().row(node));
    // J_b moves x_j by −w R_b and turns the lever arm of bone b's rotation rows.
    if (joint_touching) {
      const Mat3 turn = skew(Vec3(gradient.segment<3>(3 * idx)));
      const Mat3 Ht = H_total[size_t(idx)].transpose();
      for (int a = 0; a < point.count; ++a) {
        const int b = point.bone[a];
        const double w = point.weight[a];
        sink.add(SimParameter::RestJoints, rotationRow(b), 3 * b, w * turn * c.R[b]);
        sink.add(SimParameter::RestJoints, point, 3 * b, Ht, -w * c.R[b]);
      }
    }
  }
}

// g = Σ_j J_jᵀ g_x,j: an offset d_j of Y_j moves x_j by M_j d_j (the force by H_x,j M_j d_j,
// the exact node Hessian) and turns the lever arms of J_jᵀ's rotation rows (−w_jb [g_x,j]× R_b).
template <class Sink>
void NodeContactTerm::nodeOffsetBlocks(const TermContext& c, Sink& sink) const {
  if (c.colliders.empty()) return;
  const std::vector<int>& list = gather(&c.contact.candidates, true);
  const int V = int(list.size());
  if (V == 0) return;
  ContactOptions exact = c.options.contact;
  exact.exact_hessian = true;
  VecX gradient = VecX::Zero(3 * V);
  std::vector<Mat3> H;
  colliderContactBlocks(x_, node_areas_, c.colliders, c.time, exact, &gradient, H);
  SkinnedPoint point;
  for (int idx = 0; idx < V; ++idx) {
    const Vec3 f = gradient.segment<3>(3 * idx);
    if (f.isZero(0.0) && H[size_t(idx)].isZero(0.0)) continue;
    const int j = list[size_t(idx)];
    kin_.point(j, point);
    point.id = idx;
    sink.add(point, j, H[size_t(idx)] * kin_.M(j));
    const Mat3 turn = skew(f);
    for (int a = 0; a < point.count; ++a)
      sink.addRotation(point.bone[a], j, -point.weight[a] * turn * c.R[point.bone[a]]);
  }
}

}  // namespace flsh::detail

template class flsh::TermWithParameterBlocks<flsh::detail::NodeContactTerm>;
template class flsh::detail::WithNodeOffsetBlocks<flsh::detail::NodeContactTerm>;
