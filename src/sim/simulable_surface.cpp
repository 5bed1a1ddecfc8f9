// Simulable: the skinned surface (sparse skinning weights, each bone's dominated vertices and
// their clusters) and the exact contact broad phase that keeps TermContext::contact up to date.
#include <algorithm>
#include <cmath>

#include "flsh/body/smpl_skeleton.h"
#include "flsh/contact/contact_energy.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "flsh/sim/simulable.h"
#include "flsh/sim/skeleton_energies.h"
#include "sim/simulable_impl.h"

namespace flsh {

using detail::BoneStates;
using detail::kDofsPerBone;

void Simulable::Impl::buildSkinning() {
  const MatX& W = avatar->body().weights;  // #V × 24
  const MatX3& X = avatar->restVertices();
  const int nv = int(X.rows());
  skin.start.assign(nv + 1, 0);
  skin.entries.clear();
  dominated.assign(num_bones, {});
  std::vector<int> dominant(nv, 0);
  for (int i = 0; i < nv; ++i) {
    int best = 0;
    for (int b = 0; b < num_bones; ++b) {
      if (W(i, b) != 0.0) skin.entries.push_back({b, W(i, b)});
      if (W(i, b) > W(i, best)) best = b;
    }
    skin.start[i + 1] = int(skin.entries.size());
    dominant[i] = best;
    dominated[best].push_back(i);
  }
  sphere_center.assign(num_bones, Vec3::Zero());
  sphere_radius.assign(num_bones, 0.0);
  sphere_extent.assign(num_bones, 0.0);
  co_influence.assign(num_bones, {});
  for (int b = 0; b < num_bones; ++b) {
    if (dominated[b].empty()) continue;
    Vec3 lo = Vec3::Constant(1e300), hi = Vec3::Constant(-1e300);
    for (int i : dominated[b]) {
      const Vec3 p = X.row(i).transpose() - J.row(b).transpose();
      lo = lo.cwiseMin(p);
      hi = hi.cwiseMax(p);
    }
    sphere_center[b] = 0.5 * (lo + hi);
    std::vector<double> max_weight(num_bones, 0.0);
    for (int i : dominated[b]) {
      const Vec3 p = X.row(i).transpose() - J.row(b).transpose();
      sphere_radius[b] = std::max(sphere_radius[b], (p - sphere_center[b]).norm());
      sphere_extent[b] = std::max(sphere_extent[b], p.norm());
      for (int k = skin.start[i]; k < skin.start[i + 1]; ++k)
        if (skin.entries[k].bone != b)
          max_weight[skin.entries[k].bone] =
              std::max(max_weight[skin.entries[k].bone], skin.entries[k].weight);
    }
    for (int c = 0; c < num_bones; ++c)
      if (max_weight[c] > 0.0) co_influence[b].push_back({c, max_weight[c]});
  }
  buildClusters();
}

// Median splits along the longest box side until at most kClusterVertices vertices remain.
void Simulable::Impl::buildClusters() {
  constexpr int kClusterVertices = 48;
  const MatX3& X = avatar->restVertices();
  clusters.assign(num_bones, {});
  for (int b = 0; b < num_bones; ++b) {
    std::vector<int>& verts = dominated[b];
    auto local = [&](int i) -> Vec3 { return (X.row(i) - J.row(b)).transpose(); };
    std::vector<std::pair<int, int>> pending;
    if (!verts.empty()) pending.emplace_back(0, int(verts.size()));
    while (!pending.empty()) {
      const auto [begin, end] = pending.back();
      pending.pop_back();
      Vec3 lo = Vec3::Constant(1e300), hi = Vec3::Constant(-1e300);
      for (int k = begin; k < end; ++k) {
        lo = lo.cwiseMin(local(verts[k]));
        hi = hi.cwiseMax(local(verts[k]));
      }
      if (end - begin > kClusterVertices) {
        int axis = 0;
        (hi - lo).maxCoeff(&axis);
        const int mid = (begin + end) / 2;
        std::nth_element(verts.begin() + begin, verts.begin() + mid, verts.begin() + end,
                         [&](int i, int j) { return X(i, axis) < X(j, axis); });
        pending.emplace_back(begin, mid);
        pending.emplace_back(mid, end);
        continue;
      }
      VertexCluster cluster{0.5 * (lo + hi), 0.0, begin, end};
      for (int k = begin; k < end; ++k)
        cluster.radius = std::max(cluster.radius, (local(verts[k]) - cluster.center).norm());
      clusters[b].push_back(cluster);
    }
  }
}

// ---- contact -----------------------------------------------------------------------------

// Broad phase, then the contact energy and its node gradient at the current state. A vertex i
// dominated by bone b is x_i = x_ib + Σ_{c≠b} w_ic (x_ic − x_ib) with x_ib its rigid position
// on b, and x_ic − x_ib = (R_c − R_b)(X_i − J_b) + (R_c(J_b − J_c) + t_c − t_b), so
// |x_i − x_ib| ≤ Σ_c W_bc (‖R_c − R_b‖₂ e_b + |R_c(J_b − J_c) + t_c − t_b|). Signed distances
// are 1-Lipschitz, so bone b's vertices can only touch a collider if d(centre) < radius of this
// bound: the skipped vertices have exactly zero contact energy. With soft tissue the skinned
// point is Y_i = X_i + D_i (pose blend and displacement) instead of X_i, which moves x_i by
// ‖Σ_k w_k R_k D_i‖ ≤ ‖D_i‖ more: the bone's margin grows by the largest bound on ‖D_i‖ over its
// vertices (SoftTissue::blendBound, displacementWeight).
void Simulable::Impl::broadPhase(const double* extra_margin, std::vector<int>& candidates) const {
  candidates.clear();
  if (colliders.empty()) return;
  for (int b = 0; b < num_bones; ++b) {
    if (dominated[b].empty()) continue;
    double margin = extra_margin ? extra_margin[b] : 0.0;
    for (const Influence& co : co_influence[b]) {
      const int c = co.bone;
      const double rotation_gap =
          std::sqrt(std::max(0.0, 3.0 - (q.R[b].transpose() * q.R[c]).trace()));
      const Vec3 joint_gap = q.R[c] * (J.row(b) - J.row(c)).transpose() + q.t.row(c).transpose() -
                             q.t.row(b).transpose();
      margin += co.weight * (rotation_gap * sphere_extent[b] + joint_gap.norm());
    }
    const Vec3 centre = q.R[b] * sphere_center[b] + q.t.row(b).transpose();
    const double radius = sphere_radius[b] + margin;
    bool near = false;
    for (const Collider& collider : colliders)
      near = near || collider.signedDistance(centre, time) < radius;
    if (!near) continue;
    // The same bound per vertex cluster: |x_i − cluster centre| ≤ cluster radius + margin.
    for (const VertexCluster& cluster : clusters[b]) {
      const Vec3 cluster_centre = q.R[b] * cluster.center + q.t.row(b).transpose();
      bool cluster_near = false;
      for (const Collider& collider : colliders)
        cluster_near =
            cluster_near || collider.signedDistance(cluster_centre, time) < cluster.radius + margin;
      if (cluster_near)
        candidates.insert(candidates.end(), dominated[b].begin() + cluster.begin,
                          dominated[b].begin() + cluster.end);
    }
  }
}

void Simulable::Impl::ensureContact() const {
  ContactCache& cc = contact;
  if (cc.version == state_version) return;
  if (soft) {
    prepareSoft();
    double extra[kNumJoints];
    const double feature = soft->poseFeatureNorm(), largest = soft->largestSoftState();
    for (int b = 0; b < num_bones; ++b)
      extra[b] = soft_blend_bound[b] * feature + soft_weight_bound[b] * largest;
    broadPhase(extra, cc.candidates);
    cc.energy = soft->contact(colliders, time, options.contact, nullptr, nullptr, 0, true,
                              &cc.active, &cc.candidates);
    cc.version = state_version;
    return;
  }
  cc.points.clear();
  cc.energy = 0.0;
  cc.active = 0;
  broadPhase(nullptr, cc.candidates);
  const int n = int(cc.candidates.size());
  cc.nodes.resize(n, 3);
  cc.areas.resize(n);
  const VecX& areas = avatar->vertexAreas();
  if (n > 0) {
    // node(i) with each bone's translation t_b − R_b J_b formed once per state, not per vertex.
    Vec3 bone_shift[kNumJoints];
    for (int b = 0; b < num_bones; ++b)
      bone_shift[b] = q.t.row(b).transpose() - q.R[b] * J.row(b).transpose();
    const MatX3& X = avatar->restVertices();
    for (int j = 0; j < n; ++j) {
      const int i = cc.candidates[j];
      const Vec3 Xi = X.row(i).transpose();
      Vec3 x = Vec3::Zero();
      for (int k = skin.start[i]; k < skin.start[i + 1]; ++k) {
        const int b = skin.entries[k].bone;
        x += skin.entries[k].weight * (q.R[b] * Xi + bone_shift[b]);
      }
      cc.nodes.row(j) = x.transpose();
      cc.areas[j] = areas[i];
    }
  }
  cc.gradient.setZero(3 * n);
  if (n > 0)
    cc.energy = colliderContactEnergy(cc.nodes, cc.areas, colliders, time, options.contact,
                                      &cc.gradient, nullptr, 0, &cc.points);
  cc.active = int(cc.points.size());
  cc.version = state_version;
}

}  // namespace flsh
