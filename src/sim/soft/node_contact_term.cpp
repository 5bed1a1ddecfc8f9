#include "sim/soft/node_contact_term.h"

namespace flsh::detail {

void NodeContactTerm::addHessianBlocks(const TermContext& c, std::vector<Triplet>& H,
                                       std::vector<FixedHessianBlocks>* blocks, int offset,
                                       bool psd) const {
  evaluate(c.colliders, c.time, c.options.contact, nullptr, &H, offset, psd, nullptr,
           &c.contact.candidates);
}

double NodeContactTerm::evaluate(const std::vector<Collider>& colliders, double time,
                                 const ContactOptions& options, VecX* g, std::vector<Triplet>* H,
                                 int offset, bool psd, int* active,
                                 const std::vector<int>* candidates, bool skin) const {
  if (active) *active = 0;
  if (colliders.empty()) return 0.0;
  const std::vector<int>& list = candidates ? *candidates : kin_.surfaceNodes();
  if (list.empty()) return 0.0;
  if (kin_.reduced() && skin) kin_.skinNodes(list);  // the ROM's prepare() skins the mass nodes
  const int V = int(list.size());
  const MatX3& x = kin_.x();
  x_.resize(V, 3);
  node_areas_.resize(V);
  for (int k = 0; k < V; ++k) {
    x_.row(k) = x.row(list[k]);
    node_areas_[k] = areas_[list[k]];
  }
  ContactOptions contact_options = options;
  contact_options.exact_hessian = !psd;
  VecX gradient = VecX::Zero(3 * V);
  std::vector<Triplet> node_hessian;
  std::vector<ContactPoint> points;
  const double E = colliderContactEnergy(x_, node_areas_, colliders, time, contact_options,
                                         &gradient, H ? &node_hessian : nullptr, 0, &points);
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
    std::vector<Mat3> K(nodes.size(), Mat3::Zero());
    for (const Triplet& t : node_hessian) {
      const int i = t.row() / 3;
      if (slot[i] >= 0) K[slot[i]](t.row() - 3 * i, t.col() - 3 * i) += t.value();
    }
    kin_.mapHessian(nodes, &K, &forces, *H, offset, psd, 1);
  }
  return E;
}

}  // namespace flsh::detail
