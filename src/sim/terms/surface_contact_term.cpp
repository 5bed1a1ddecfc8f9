#include "sim/terms/surface_contact_term.h"

#include "flsh/body/smpl_skeleton.h"
#include "flsh/contact/contact_energy.h"
#include "flsh/core/rotation.h"
#include "flsh/energy/skeleton_energies.h"
#include "sim/terms/term_blocks.h"

namespace flsh::detail {

namespace {

// Exact contact node Hessians (3 × 3 per candidate) against the given colliders.
std::vector<Mat3> nodeHessians(const TermContext& c, const std::vector<Collider>& colliders) {
  const SurfaceContactState& s = c.contact;
  const int n = int(s.candidates.size());
  std::vector<Mat3> H(size_t(n), Mat3::Zero());
  if (n == 0) return H;
  ContactOptions options = c.options.contact;
  options.exact_hessian = true;
  colliderContactBlocks(s.nodes, s.areas, colliders, c.time, options, nullptr, H);
  return H;
}

}  // namespace

SurfaceContactTerm::SurfaceContactTerm(const SkeletonKinematics& kinematics, int num_bones)
    : kin_(kinematics), pair_blocks_(num_bones) {}

void SurfaceContactTerm::refresh(const TermContext& c, SurfaceContactState& s) const {
  points_.clear();
  s.energy = 0.0;
  s.active = 0;
  const int n = int(s.candidates.size());
  kin_.positions(s.candidates, {c.R, c.t}, s.nodes);
  s.areas.resize(n);
  const VecX& areas = c.avatar.vertexAreas();
  for (int j = 0; j < n; ++j) s.areas[j] = areas[s.candidates[size_t(j)]];
  s.gradient.setZero(3 * n);
  if (n > 0)
    s.energy = colliderContactEnergy(s.nodes, s.areas, c.colliders, c.time, c.options.contact,
                                     &s.gradient, nullptr, 0, &points_);
  s.active = int(points_.size());
}

double SurfaceContactTerm::evaluate(const TermContext& c, VecX* g, int offset) const {
  const SurfaceContactState& s = c.contact;
  if (g) kin_.mapForces(s.candidates, s.gradient, c.R, *g, offset);
  return s.energy;
}

void SurfaceContactTerm::addHessian(const TermContext& c, std::vector<Triplet>& H, int offset,
                                    bool psd) const {
  const SurfaceContactState& s = c.contact;
  if (s.active == 0) return;
  ContactOptions contact_options = c.options.contact;
  contact_options.exact_hessian = !psd;
  node_hessian_.clear();
  colliderContactEnergy(s.nodes, s.areas, c.colliders, c.time, contact_options, nullptr,
                        &node_hessian_, 0, nullptr);
  // colliderContactEnergy emits 9 consecutive triplets (one 3 × 3 block) per active pair.
  node_blocks_.clear();
  for (size_t start = 0; start + 9 <= node_hessian_.size(); start += 9) {
    const int j = node_hessian_[start].row() / 3;
    Mat3 Hx;
    for (int e = 0; e < 9; ++e) {
      const Triplet& t = node_hessian_[start + e];
      Hx(t.row() - 3 * j, t.col() - 3 * j) = t.value();
    }
    node_blocks_.emplace_back(j, Hx);
  }
  kin_.mapHessian(s.candidates, node_blocks_, s.gradient, c.R, psd, pair_blocks_);
  pair_blocks_.emit(H, offset);
}

// The node gradient g_x(x, a, k, o) of candidate j reaches the bones as g_t,b += w g_x,
// g_ω,b += w y_ib × g_x (a SkinnedPoint), so ∂g/∂p = C ∂g_x/∂p + (what turns y_ib).
// ∂g_x/∂x = H_x (exact); x moves with J_b by −w_ib R_b and with the rest vertex by Σ_b w_ib R_b;
// y_ib by −R_b dJ_b and R_b dX_i. g_x is linear in the area and in the stiffness, and depends
// on x − o_k for collider k.
template <class Sink>
void SurfaceContactTerm::parameterBlocks(const TermContext& c, Sink& sink) const {
  const SurfaceContactState& s = c.contact;
  const int n = int(s.candidates.size());
  const bool joints = sink.wants(SimParameter::RestJoints);
  const bool stiffness = sink.wants(SimParameter::Stiffnesses);
  const bool offsets = sink.wants(SimParameter::ColliderOffsets);
  const bool shape = sink.wants(SimParameter::Shape);
  if (n == 0 || !(joints || stiffness || offsets || shape)) return;
  const std::vector<Mat3> H = nodeHessians(c, c.colliders);
  const int nc = int(c.colliders.size());
  std::vector<std::vector<Mat3>> H_per_collider;  // with one collider, H itself
  if (offsets && nc > 1)
    for (int k = 0; k < nc; ++k) H_per_collider.push_back(nodeHessians(c, {c.colliders[k]}));
  VecX unit_gradient;  // g_x at unit contact stiffness
  if (stiffness) {
    ContactOptions unit = c.options.contact;
    unit.stiffness = 1.0;
    unit_gradient = VecX::Zero(3 * Eigen::Index(n));
    colliderContactEnergy(s.nodes, s.areas, c.colliders, c.time, unit, &unit_gradient);
  }
  const MatX& shapedirs = c.avatar.body().shapedirs;
  const MatX& areas_jacobian = c.avatar.vertexAreasShapeJacobian();
  const Mat3 I3 = Mat3::Identity();
  SkinnedPoint point;
  for (int j = 0; j < n; ++j) {
    const Vec3 gx = s.gradient.segment<3>(3 * j);
    // A zero contact stiffness leaves g_x = 0 and H_x = 0 (not touching), but not the unit
    // gradient.
    const bool touching = !(gx.isZero(0.0) && H[size_t(j)].isZero(0.0));
    const bool unit_touching = stiffness && !unit_gradient.segment<3>(3 * j).isZero(0.0);
    if (!touching && !unit_touching) continue;
    const int i = s.candidates[size_t(j)];
    point.id = j;
    kin_.point(i, c.R, point);
    if (unit_touching)
      sink.add(SimParameter::Stiffnesses, point, 3, unit_gradient.segment<3>(3 * j),
               Eigen::Matrix<double, 1, 1>::Ones());
    if (!touching) continue;
    const Mat3 Ht = H[size_t(j)].transpose();
    const Mat3 turn = skew(gx);  // ∂(y × g_x)/∂y = −[g_x]×
    if (joints)
      for (int a = 0; a < point.count; ++a) {
        const int b = point.bone[a];
        const double w = point.weight[a];
        sink.add(SimParameter::RestJoints, rotationRow(b), 3 * b, w * turn * c.R[b]);
        sink.add(SimParameter::RestJoints, point, 3 * b, Ht, -w * c.R[b]);
      }
    if (offsets)
      for (int k = 0; k < nc; ++k) {
        const Mat3& Hk = nc == 1 ? H[size_t(j)] : H_per_collider[size_t(k)][size_t(j)];
        if (!Hk.isZero(0.0))
          sink.add(SimParameter::ColliderOffsets, point, 3 * k, -Hk.transpose(), I3);
      }
    if (shape) {
      const auto S = shapedirs.middleRows<3>(3 * i);  // ∂X_i/∂β
      Mat3 dx_dX = Mat3::Zero();
      for (int a = 0; a < point.count; ++a) {
        const int b = point.bone[a];
        dx_dX += point.weight[a] * c.R[b];
        sink.add(SimParameter::Shape, rotationRow(b), 0, -point.weight[a] * turn * c.R[b], S);
      }
      sink.add(SimParameter::Shape, point, 0, Ht * dx_dX, S);
      if (s.areas[j] > 0.0)
        sink.add(SimParameter::Shape, point, 0, gx / s.areas[j], areas_jacobian.row(i));
    }
  }
}

}  // namespace flsh::detail

template class flsh::TermWithParameterBlocks<flsh::detail::SurfaceContactTerm>;
