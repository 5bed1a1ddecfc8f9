// Simulable: its skinned surface (body/skinned_surface.h) and the exact contact broad phase
// that keeps TermContext::contact up to date.
#include <algorithm>
#include <cmath>
#include <limits>

#include "flsh/body/smpl_skeleton.h"
#include "flsh/contact/contact_energy.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "flsh/energy/skeleton_energies.h"
#include "flsh/sim/simulable.h"
#include "sim/simulable_impl.h"

namespace flsh {

using detail::BoneStates;
using detail::kDofsPerBone;

void Simulable::Impl::buildSkinning() {
  surface = SkinnedSurface::build(avatar->body().weights, avatar->restVertices(), J,
                                  kSurfaceClusterVertices);
}

// ---- contact -----------------------------------------------------------------------------

namespace {

// The smallest signed distance from x to any collider at time t (∞ without colliders):
// 1-Lipschitz, as each collider's is.
double nearestColliderDistance(const std::vector<Collider>& colliders, const Vec3& x, double t) {
  double d = std::numeric_limits<double>::infinity();
  for (const Collider& collider : colliders) d = std::min(d, collider.signedDistance(x, t));
  return d;
}

}  // namespace

// Broad phase, then the contact energy and its node gradient at the current state. A vertex i
// dominated by bone b is x_i = x_ib + Σ_{c≠b} w_ic (x_ic − x_ib) with x_ib its rigid position
// on b, and x_ic − x_ib = (R_c − R_b)(X_i − J_b) + (R_c(J_b − J_c) + t_c − t_b), so
// |x_i − x_ib| ≤ Σ_c W_bc (‖R_c − R_b‖₂ e_b + |R_c(J_b − J_c) + t_c − t_b|). Signed distances
// are 1-Lipschitz, so bone b's vertices can only touch a collider if d(centre) < radius of this
// bound: the skipped vertices have exactly zero contact energy. With soft tissue the skinned
// point is Y_i = X_i + D_i (pose blend and displacement) instead of X_i, which moves x_i by
// ‖Σ_k w_k R_k D_i‖ ≤ ‖D_i‖ more: the bone's margin grows by the largest bound on ‖D_i‖ over its
// vertices (ModelKinematics::contactMargins).
void Simulable::Impl::broadPhase(const double* extra_margin, std::vector<int>& candidates) const {
  candidates.clear();
  if (colliders.empty()) return;
  for (int b = 0; b < num_bones; ++b) {
    const std::vector<int>& dominated = surface.dominated[b];
    if (dominated.empty()) continue;
    const SurfaceBound& bound = surface.bone_bound[b];
    double margin = extra_margin[b];
    for (const SurfaceBound::CoInfluence& co : bound.co) {
      const int c = co.bone;
      const double rotation_gap =
          std::sqrt(std::max(0.0, 3.0 - (q.R[b].transpose() * q.R[c]).trace()));
      const Vec3 joint_gap = q.R[c] * (J.row(b) - J.row(c)).transpose() + q.t.row(c).transpose() -
                             q.t.row(b).transpose();
      margin += co.weight * (rotation_gap * bound.extent + joint_gap.norm());
    }
    const Vec3 centre = q.R[b] * bound.center + q.t.row(b).transpose();
    const double radius = bound.radius + margin;
    if (nearestColliderDistance(colliders, centre, time) >= radius) continue;
    // The same bound per vertex cluster: |x_i − cluster centre| ≤ cluster radius + margin.
    for (int k = surface.bone_clusters[b]; k < surface.bone_clusters[b + 1]; ++k) {
      const SkinnedSurface::Cluster& cluster = surface.clusters[k];
      const Vec3 cluster_centre = q.R[b] * cluster.bound.center + q.t.row(b).transpose();
      if (nearestColliderDistance(colliders, cluster_centre, time) < cluster.bound.radius + margin)
        candidates.insert(candidates.end(), dominated.begin() + cluster.begin,
                          dominated.begin() + cluster.end);
    }
  }
}

// The kinematics' margins (pose blend and soft displacement), the broad phase, then the model's
// contact term at the candidates.
void Simulable::Impl::ensureContact() const {
  ContactCache& cc = contact;
  if (cc.version == state_version) return;
  prepare();
  double margin[kNumJoints];
  kinematics->contactMargins(margin);
  broadPhase(margin, cc.candidates);
  if (!cc.candidates.empty())
    kinematics->pruneCandidates(
        [&](const Vec3& x) { return nearestColliderDistance(colliders, x, time); }, cc.candidates);
  model_contact->refresh(context(), cc);
  cc.version = state_version;
}

}  // namespace flsh
