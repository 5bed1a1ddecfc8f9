// Simulable for the articulated skeleton: 24 rigid bones in maximal coordinates, joint springs,
// mocap tracking springs, gravity, backward-Euler inertia and collider contact on the skinned
// surface (ARCHITECTURE.md §4–5). The energy kernels live in skeleton_energies.cpp; this file
// holds the state, the mocap targets and the assembly.
//
// Not thread-safe per instance: const evaluations share a mutable contact cache.
#include "flsh/sim/simulable.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

#include "core/first_failure.h"
#include "flsh/body/body_forward.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "flsh/sim/skeleton_energies.h"
#include "hessian_blocks.h"
#include "sim/terms/bone_gravity_term.h"
#include "sim/terms/joint_spring_term.h"
#include "sim/terms/rigid_inertia_term.h"
#include "sim/terms/surface_contact_term.h"
#include "sim/terms/tracking_spring_term.h"
#include "soft_tissue.h"

namespace flsh {

namespace {

constexpr int kDofsPerBone = 6;

// Rigid transforms of all bones: rotation R_b and joint centre t_b (row b of t).
struct BoneStates {
  std::vector<Mat3> R;
  MatX3 t;
};

BoneStates restBones(const MatX3& joints) {
  BoneStates s;
  s.R.assign(joints.rows(), Mat3::Identity());
  s.t = joints;
  return s;
}

// Bones posed by an SMPL pose (72) and root translation, like poseBody's transforms:
// R_b = R_p rodrigues(θ_b), t_b = R_p (J_b − J_p) + t_p, t_0 = J_0 + trans.
BoneStates bonesFromPose(const Eigen::Ref<const VecX>& pose, const Vec3& trans,
                         const MatX3& joints, const std::vector<int>& parents) {
  BoneStates s;
  const int n = int(parents.size());
  s.R.resize(n);
  s.t.resize(n, 3);
  for (int b = 0; b < n; ++b) {
    const Mat3 local = rodrigues(pose.segment<3>(3 * b));
    const int p = parents[b];
    if (p < 0) {
      s.R[b] = local;
      s.t.row(b) = joints.row(b) + trans.transpose();
    } else {
      s.R[b] = s.R[p] * local;
      s.t.row(b) = (s.R[p] * (joints.row(b) - joints.row(p)).transpose() +
                    s.t.row(p).transpose()).transpose();
    }
  }
  return s;
}

using detail::addBlock;

std::string motionName(const Motion& m) {
  return m.source.empty() ? std::string("mocap") : "mocap '" + m.source + "'";
}

std::string number(double value) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.6g", value);
  return text;
}

/// Throws InputError (`fn` and `name` in the message) unless every value of the state-sized
/// vector `x` is finite and within its bound: for a state (`velocity` false) positions and
/// soft-tissue displacements within ±kMaxStatePosition m and rotation vectors of angle at most
/// kMaxRotationAngle; for a velocity every entry within ±kMaxStateVelocity (m/s, rad/s).
void checkStateValues(const VecX& x, int num_bones, bool velocity, const std::string& fn,
                      const char* name) {
  const char* unit = velocity ? " m/s or rad/s" : " m";
  const double bound = velocity ? kMaxStateVelocity : kMaxStatePosition;
  for (Eigen::Index k = 0; k < x.size(); ++k) {
    if (!std::isfinite(x[k]))
      throw InputError(fn + name + "[" + std::to_string(k) + "] is NaN or Inf (" + number(x[k]) +
                       "), expected a finite value");
    const bool rotation = k < 6 * num_bones && k % 6 >= 3;
    if (rotation && !velocity) continue;  // checked as a whole vector below
    if (std::abs(x[k]) > bound)
      throw InputError(fn + name + "[" + std::to_string(k) + "] = " + number(x[k]) + unit +
                       ", expected within [-" + number(bound) + ", " + number(bound) + "]" +
                       (k < 6 * num_bones ? " (bone " + std::to_string(k / 6) + ")"
                                          : std::string(" (soft-tissue values)")));
  }
  if (velocity) return;
  for (int b = 0; b < num_bones; ++b) {
    const double angle = x.segment<3>(6 * b + 3).stableNorm();
    if (angle > kMaxRotationAngle)
      throw InputError(fn + name + ": bone " + std::to_string(b) +
                       " has a rotation vector of "
                       "angle " +
                       number(angle) + " rad, expected at most " + number(kMaxRotationAngle) +
                       " rad");
  }
}

}  // namespace

struct Simulable::Impl {
  // ---- model data (immutable after construction) ----
  std::shared_ptr<const SoftAvatar> avatar;
  std::shared_ptr<const Motion> mocap;
  SimulableOptions options;
  int num_bones = 0;
  std::vector<int> parents;
  MatX3 J;  // 24 × 3 rest joint centres
  std::vector<BoneInertia> inertia;
  std::vector<double> tracking_k;  // N·m/rad² per bone (root unused)
  double root_k_pos = 0.0, root_k_rot = 0.0;
  std::vector<char> kinematic;  // per bone

  // Skinning weights as (bone, weight) lists per vertex (the nonzero entries only).
  using Influence = SparseSkinWeights::Influence;
  SparseSkinWeights skin;

  // Broad phase: per bone, the vertices it dominates (largest weight), a sphere bounding their
  // rest offsets X − J_b (centre s_b in the bone frame, radius ρ_b about s_b, extent e_b = max
  // |X − J_b|), and W_bc = max over those vertices of w_ic for each other bone c that
  // influences them.
  std::vector<std::vector<int>> dominated;
  std::vector<Vec3> sphere_center;
  std::vector<double> sphere_radius, sphere_extent;
  // Spatial clusters of each bone's dominated vertices (contiguous ranges of dominated[b]), for
  // a finer broad phase than the bone sphere; centres are relative to J_b in the rest frame.
  struct VertexCluster {
    Vec3 center;
    double radius;
    int begin, end;
  };
  std::vector<std::vector<VertexCluster>> clusters;
  std::vector<std::vector<Influence>> co_influence;

  // ---- mutable data ----
  BoneStates q, q_n, q_nm1;
  // Saved states: entries [0, stack_depth) are live; the rest keep their storage for reuse
  // (push/pop/discard then allocate nothing).
  std::vector<BoneStates> stack;
  size_t stack_depth = 0;
  std::vector<Collider> colliders;
  double time = 0.0;
  bool is_static = false;
  std::vector<Mat3> target_R;  // per bone: R_target,rel (root: the global target rotation)
  Vec3 target_t0 = Vec3::Zero();
  long state_version = 0;

  // Contact cache, valid while cache_version == state_version.
  // The candidates are the vertices dominated by bones near colliders (broadPhase).
  struct ContactCache : SurfaceContactState {
    long version = -1;
    std::vector<ContactPoint> points;
  };
  mutable ContactCache contact;
  // Scratch of getHessianTripletVector: the ROM's inertia and gravity triplets, summed on two
  // threads.
  mutable std::vector<Triplet> hessian_scratch[2];

  // FEM soft skeleton (null for the articulated skeleton): node data, displacements u.
  std::unique_ptr<detail::SoftTissue> soft;
  std::vector<VecX> u_stack;  // displacements saved with `stack` (same depth)

  void touch() { ++state_version; }
  int boneDofs() const { return kDofsPerBone * num_bones; }
  int dofs() const { return boneDofs() + (soft ? soft->numSoftDofs() : 0); }
  detail::BoneFrames frames(const BoneStates& s) const { return {s.R, s.t}; }
  // Node positions of the current state (soft tissue only).
  void prepareSoft() const { soft->prepare(state_version, frames(q)); }
  /// prepareSoft, the contact broad phase and the skinning of its candidates, before terms run
  /// on two threads (skinning writes node rows inertia reads); true if contact has candidates
  /// (then call SoftTissue::contact with skin = false).
  bool prepareSoftForThreads() const {
    prepareSoft();
    ensureContact();
    const bool any = !colliders.empty() && !contact.candidates.empty();
    if (any) soft->skinSurfaceNodes(contact.candidates);
    return any;
  }
  void setSoftPrediction() {
    soft->setPrediction(frames(q_n), frames(q_nm1));
  }

  void validateOptions() const;
  void buildSkinning();
  void buildStiffnesses();
  void updateTargets(double t);
  void placeKinematicBones();
  void ensureContact() const;
  /// Surface vertices that may touch a collider (see ensureContact); `extra_margin`: per bone,
  /// added to its bound (null: none).
  void broadPhase(const double* extra_margin, std::vector<int>& candidates) const;
  // Soft tissue: per bone, the largest blendBound and displacementWeight of its vertices.
  std::vector<double> soft_blend_bound, soft_weight_bound;
  void buildClusters();
  Vec3 node(int i) const;
  double contactEnergy() const {
    ensureContact();
    return contact.energy;
  }

  // ---- energy terms (energy_term.h) ----
  // The articulated skeleton's energy is the sum of these terms; with soft tissue the bones
  // keep their springs (joint_term, tracking_term) and SoftTissue carries inertia, gravity,
  // elasticity and contact on the tet nodes.
  detail::RigidInertiaTerm inertia_term;
  detail::BoneGravityTerm gravity_term;
  detail::JointSpringTerm joint_term;
  std::unique_ptr<detail::TrackingSpringTerm> tracking_term;
  std::unique_ptr<detail::SurfaceContactTerm> contact_term;
  /// The skeleton's terms by part (dynamic: inertia; potential: the rest), all of them in
  /// `terms`; the bone springs alone in `spring_terms` (with soft tissue too).
  std::vector<const EnergyTerm*> dynamic_terms, potential_terms, terms, spring_terms;
  void buildTerms();
  /// The view the terms read at the current state (call ensureContact first for contact).
  TermContext context() const;
};

// ---- construction ------------------------------------------------------------------------

void Simulable::Impl::validateOptions() const {
  const std::string fn = "Simulable: ";
  if (!(options.time_step > 0.0) || !std::isfinite(options.time_step))
    throw InputError(fn + "options.time_step = " + std::to_string(options.time_step) +
                     ", expected finite and > 0 s");
  if (!options.gravity.allFinite()) throw InputError(fn + "options.gravity contains NaN or Inf");
  const std::pair<const char*, double> stiffnesses[] = {
      {"joint_stiffness", options.joint_stiffness},
      {"tracking_stiffness", options.tracking_stiffness},
      {"root_stiffness", options.root_stiffness},
      {"tracking_inertia_floor", options.tracking_inertia_floor},
      {"contact.stiffness", options.contact.stiffness}};
  for (const auto& [name, value] : stiffnesses)
    if (!(value >= 0.0) || !std::isfinite(value))
      throw InputError(fn + "options." + name + " = " + std::to_string(value) +
                       ", expected finite and >= 0");
  for (int b : options.kinematic_bones)
    if (b < 0 || b >= num_bones)
      throw InputError(fn + "options.kinematic_bones contains " + std::to_string(b) +
                       ", expected bone indices in [0, " + std::to_string(num_bones) + ")");
}

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

// Tracking stiffness k_b = ω_T² (I_b + I_floor) and the root springs (whole body, no floor):
// the tracking term's, whose parameter products differentiate the same formula.
void Simulable::Impl::buildStiffnesses() {
  tracking_term->stiffnesses(J, inertia, options, tracking_k, root_k_pos, root_k_rot);
}

void Simulable::Impl::buildTerms() {
  tracking_term = std::make_unique<detail::TrackingSpringTerm>(parents);
  contact_term = std::make_unique<detail::SurfaceContactTerm>(num_bones);
  spring_terms = {&joint_term, tracking_term.get()};
  dynamic_terms = {&inertia_term};
  potential_terms = {&gravity_term, &joint_term, tracking_term.get(), contact_term.get()};
  terms = dynamic_terms;
  terms.insert(terms.end(), potential_terms.begin(), potential_terms.end());
}

TermContext Simulable::Impl::context() const {
  return {num_bones, parents,  J,         inertia,    options,    mocap && options.track_mocap,
          is_static, q.R,      q.t,       q_n.R,      q_n.t,      q_nm1.R,
          q_nm1.t,   target_R, target_t0, tracking_k, root_k_pos, root_k_rot,
          colliders, time,     *avatar,   skin,       contact};
}

Simulable::Simulable(std::shared_ptr<const SoftAvatar> avatar,
                     std::shared_ptr<const Motion> mocap, const SimulableOptions& options)
    : impl_(std::make_unique<Impl>()) {
  Impl& m = *impl_;
  const std::string fn = "Simulable: ";
  if (!avatar) throw InputError(fn + "avatar is null, expected a SoftAvatar");
  if (!avatar->initialized())
    throw InputError(fn + "the avatar is not initialized (call SoftAvatar::initVolumetricData())");
  const BodyModel& body = avatar->body();
  if (body.numJoints() != kNumJoints)
    throw InputError(fn + "the avatar's body model has " + std::to_string(body.numJoints()) +
                     " joints, expected SMPL's " + std::to_string(kNumJoints));
  if (int(avatar->boneInertia().size()) != kNumJoints ||
      avatar->restJoints().rows() != kNumJoints ||
      avatar->restVertices().rows() != body.numVertices() ||
      avatar->vertexAreas().size() != body.numVertices())
    throw InputError(fn + "the avatar's data does not match its body model (" +
                     std::to_string(avatar->boneInertia().size()) + " bone inertias, " +
                     std::to_string(avatar->restJoints().rows()) + " joints, " +
                     std::to_string(avatar->restVertices().rows()) + " vertices; expected 24, " +
                     "24 and " + std::to_string(body.numVertices()) + ")");
  if (mocap) {
    const Motion& mo = *mocap;
    if (mo.numFrames() < 1)
      throw InputError(fn + motionName(mo) + " has no frames, expected at least 1");
    if (mo.poses.cols() != kSmplPoseSize || mo.trans.rows() != mo.poses.rows() ||
        mo.trans.cols() != 3)
      throw InputError(fn + motionName(mo) + ": poses " +
                       shapeString({long(mo.poses.rows()), long(mo.poses.cols())}) + " and trans " +
                       shapeString({long(mo.trans.rows()), long(mo.trans.cols())}) +
                       ", expected (T, 72) and (T, 3)");
    if (!mo.poses.allFinite() || !mo.trans.allFinite())
      throw InputError(fn + motionName(mo) + " contains NaN or Inf in poses or trans");
    for (Eigen::Index t = 0; t < mo.poses.rows(); ++t)
      checkPoseAngles(mo.poses.row(t).transpose(),
                      fn + motionName(mo) + ": poses: frame " + std::to_string(t));
    if (mo.trans.size() > 0 && mo.trans.cwiseAbs().maxCoeff() > kMaxStatePosition)
      throw InputError(fn + motionName(mo) + ": trans reaches " +
                       number(mo.trans.cwiseAbs().maxCoeff()) + " m, expected within [-" +
                       number(kMaxStatePosition) + ", " + number(kMaxStatePosition) + "] m");
    if (!(mo.fps > 0.0) || !std::isfinite(mo.fps))
      throw InputError(fn + motionName(mo) + " has fps = " + std::to_string(mo.fps) +
                       ", expected finite and > 0");
  }
  m.avatar = std::move(avatar);
  m.mocap = std::move(mocap);
  m.options = options;
  m.num_bones = kNumJoints;
  m.validateOptions();
  m.parents = body.parents;
  m.J = m.avatar->restJoints();
  m.inertia = m.avatar->boneInertia();
  m.kinematic.assign(m.num_bones, 0);
  for (int b : m.options.kinematic_bones) m.kinematic[b] = 1;
  m.buildSkinning();
  m.buildTerms();
  m.buildStiffnesses();
  m.q = m.q_n = m.q_nm1 = restBones(m.J);
  if (m.avatar->softTissueEnabled()) {
    if (!m.avatar->hasVolumetricData())
      throw InputError(fn + "the avatar has soft tissue enabled but no volumetric data "
                            "(call SoftAvatar::initVolumetricData())");
    m.soft = std::make_unique<detail::SoftTissue>(*m.avatar, m.J, m.parents,
                                                  m.options.time_step);
    m.soft->setPoseBlend(m.q.R);
    m.setSoftPrediction();
    m.soft_blend_bound.assign(m.num_bones, 0.0);
    m.soft_weight_bound.assign(m.num_bones, 0.0);
    for (int b = 0; b < m.num_bones; ++b)
      for (int i : m.dominated[b]) {
        m.soft_blend_bound[b] = std::max(m.soft_blend_bound[b], m.soft->blendBound(i));
        m.soft_weight_bound[b] = std::max(m.soft_weight_bound[b], m.soft->displacementWeight(i));
      }
  }
  m.updateTargets(0.0);
}

Simulable::Simulable(std::shared_ptr<const SoftAvatar> avatar,
                     std::shared_ptr<const BodyModel> body, std::shared_ptr<const Motion> mocap,
                     const SimulableOptions& options)
    : Simulable(avatar, std::move(mocap), options) {
  if (!body || body.get() != &avatar->body())
    throw InputError(
        "Simulable: the body model passed is not the avatar's (a SoftAvatar is built for one "
        "body model; pass avatar->bodyPtr())");
}

Simulable::~Simulable() = default;

// ---- targets and stepping ----------------------------------------------------------------

// Mocap targets at time t: frame t·fps, slerp between neighbouring frames for rotations,
// linear for the root translation, held at the first/last frame outside the clip.
void Simulable::Impl::updateTargets(double t) {
  target_R.resize(num_bones);
  if (!mocap) {
    // No mocap: the rest pose is the target (used by kinematic bones only).
    std::fill(target_R.begin(), target_R.end(), Mat3::Identity());
    target_t0 = J.row(0).transpose();
    return;
  }
  const Motion& mo = *mocap;
  const int last = mo.numFrames() - 1;
  const double frame = std::clamp(t * mo.fps, 0.0, double(last));
  const int f0 = std::min(int(std::floor(frame)), last);
  const int f1 = std::min(f0 + 1, last);
  const double alpha = frame - f0;
  for (int b = 0; b < num_bones; ++b) {
    const Vec3 a = mo.poses.row(f0).segment<3>(3 * b).transpose();
    const Vec3 c = mo.poses.row(f1).segment<3>(3 * b).transpose();
    target_R[b] = rodrigues(alpha == 0.0 ? a : slerpRotationVector(a, c, alpha));
  }
  const Vec3 trans = ((1.0 - alpha) * mo.trans.row(f0) + alpha * mo.trans.row(f1)).transpose();
  target_t0 = J.row(0).transpose() + trans;
}

// Kinematic bones follow their targets, carried by their (possibly simulated) parents.
void Simulable::Impl::placeKinematicBones() {
  for (int b = 0; b < num_bones; ++b) {
    if (!kinematic[b]) continue;
    const int p = parents[b];
    if (p < 0) {
      q.R[b] = target_R[b];
      q.t.row(b) = target_t0.transpose();
    } else {
      q.R[b] = q.R[p] * target_R[b];
      q.t.row(b) = (q.R[p] * (J.row(b) - J.row(p)).transpose() + q.t.row(p).transpose())
                       .transpose();
    }
  }
}

void Simulable::initialize() {
  Impl& m = *impl_;
  m.time = 0.0;
  m.updateTargets(0.0);
  m.stack_depth = 0;
  if (m.soft) {
    m.soft->u.setZero();
    m.soft->u_n.setZero();
    m.soft->u_nm1.setZero();
  }
  if (!m.mocap) {
    m.q = m.q_n = m.q_nm1 = restBones(m.J);
    if (m.soft) {
      m.soft->setPoseBlend(m.q.R);
      m.setSoftPrediction();
    }
    m.touch();
    return;
  }
  const Motion& mo = *m.mocap;
  m.q = bonesFromPose(mo.poses.row(0).transpose(), mo.trans.row(0).transpose(), m.J, m.parents);
  m.q_n = m.q;
  m.q_nm1 = m.q;
  if (m.soft) {
    m.soft->setPoseBlend(m.q.R);
    m.setSoftPrediction();
  }
  m.touch();
  if (mo.numFrames() > 1) {
    // Initial velocity from the first two frames; q_{n−1} = q_n ⊖ h v.
    const BoneStates next =
        bonesFromPose(mo.poses.row(1).transpose(), mo.trans.row(1).transpose(), m.J, m.parents);
    VecX v = VecX::Zero(m.dofs());  // soft tissue starts at rest
    for (int b = 0; b < m.num_bones; ++b) {
      v.segment<3>(6 * b) = (next.t.row(b) - m.q.t.row(b)).transpose() * mo.fps;
      v.segment<3>(6 * b + 3) = logSO3(next.R[b] * m.q.R[b].transpose()) * mo.fps;
    }
    setVelocity(v);
  }
}

void Simulable::preUpdate() {
  Impl& m = *impl_;
  m.time += m.options.time_step;
  m.updateTargets(m.time);
  if (m.soft) {
    // Pose blend offsets of the last converged pose, held during the step.
    m.soft->setPoseBlend(m.q_n.R);
    m.setSoftPrediction();
  }
  setStepStart(StepStart::Prediction);
}

void Simulable::setStepStart(StepStart start) {
  Impl& m = *impl_;
  if (start == StepStart::Prediction) {
    // The inertial prediction: q_n extrapolated with the current velocity; displacements from
    // their extrapolation like the bones.
    for (int b = 0; b < m.num_bones; ++b) {
      m.q.t.row(b) = 2.0 * m.q_n.t.row(b) - m.q_nm1.t.row(b);
      m.q.R[b] = rodrigues(logSO3(m.q_n.R[b] * m.q_nm1.R[b].transpose())) * m.q_n.R[b];
    }
    if (m.soft) m.soft->u = 2.0 * m.soft->u_n - m.soft->u_nm1;
  } else {
    m.q.t = m.q_n.t;
    m.q.R = m.q_n.R;
    if (m.soft) m.soft->u = m.soft->u_n;
  }
  m.placeKinematicBones();
  m.touch();
}

void Simulable::postUpdate() {
  Impl& m = *impl_;
  m.q_nm1 = m.q_n;
  m.q_n = m.q;
  if (m.soft) {
    m.soft->u_nm1 = m.soft->u_n;
    m.soft->u_n = m.soft->u;
  }
}

// ---- state -------------------------------------------------------------------------------

int Simulable::numDofs() const { return impl_->dofs(); }

VecX Simulable::getState() const {
  const Impl& m = *impl_;
  VecX q(m.dofs());
  for (int b = 0; b < m.num_bones; ++b) {
    q.segment<3>(6 * b) = m.q.t.row(b).transpose();
    q.segment<3>(6 * b + 3) = logSO3(m.q.R[b]);
  }
  if (m.soft) q.tail(m.soft->numSoftDofs()) = m.soft->u;
  return q;
}

void Simulable::setState(const VecX& q) {
  Impl& m = *impl_;
  if (q.size() != m.dofs())
    throw InputError("Simulable::setState: q has " + std::to_string(q.size()) +
                     " values, expected numDofs() = " + std::to_string(m.dofs()) +
                     " (6 per bone: t, rotation vector; then 3 per soft-tissue node, or per handle of the "
                     "reduced model)");
  checkStateValues(q, m.num_bones, false, "Simulable::setState: ", "q");
  for (int b = 0; b < m.num_bones; ++b) {
    m.q.t.row(b) = q.segment<3>(6 * b).transpose();
    m.q.R[b] = rodrigues(q.segment<3>(6 * b + 3));
  }
  if (m.soft) m.soft->u = q.tail(m.soft->numSoftDofs());
  m.touch();
}

void Simulable::updateState(const VecX& dq) {
  Impl& m = *impl_;
  if (dq.size() != m.dofs())
    throw InputError("Simulable::updateState: dq has " + std::to_string(dq.size()) +
                     " values, expected numDofs() = " + std::to_string(m.dofs()));
  if (!dq.allFinite()) throw InputError("Simulable::updateState: dq contains NaN or Inf");
  for (int b = 0; b < m.num_bones; ++b) {
    m.q.t.row(b) += dq.segment<3>(6 * b).transpose();
    m.q.R[b] = rodrigues(dq.segment<3>(6 * b + 3)) * m.q.R[b];
  }
  if (m.soft) m.soft->u += dq.tail(m.soft->numSoftDofs());
  m.touch();
}

void Simulable::pushState() {
  Impl& m = *impl_;
  if (m.stack.size() <= m.stack_depth) m.stack.push_back(m.q);
  else m.stack[m.stack_depth] = m.q;
  if (m.soft) {
    if (m.u_stack.size() <= m.stack_depth) m.u_stack.push_back(m.soft->u);
    else m.u_stack[m.stack_depth] = m.soft->u;
  }
  ++m.stack_depth;
}

void Simulable::popState() {
  Impl& m = *impl_;
  if (m.stack_depth == 0)
    throw Error("Simulable::popState: the state stack is empty (popState without pushState)");
  m.q = m.stack[--m.stack_depth];
  if (m.soft) m.soft->u = m.u_stack[m.stack_depth];
  m.touch();
}

void Simulable::discardState() {
  Impl& m = *impl_;
  if (m.stack_depth == 0)
    throw Error(
        "Simulable::discardState: the state stack is empty (discardState without pushState)");
  --m.stack_depth;
}

void Simulable::setVelocity(const VecX& v) {
  Impl& m = *impl_;
  if (v.size() != m.dofs())
    throw InputError("Simulable::setVelocity: v has " + std::to_string(v.size()) +
                     " values, expected numDofs() = " + std::to_string(m.dofs()));
  checkStateValues(v, m.num_bones, true, "Simulable::setVelocity: ", "v");
  const double h = m.options.time_step;
  for (int b = 0; b < m.num_bones; ++b) {
    m.q_nm1.t.row(b) = m.q_n.t.row(b) - h * v.segment<3>(6 * b).transpose();
    m.q_nm1.R[b] = rodrigues(-h * v.segment<3>(6 * b + 3)) * m.q_n.R[b];
  }
  if (m.soft) {
    m.soft->u_nm1 = m.soft->u_n - h * v.tail(m.soft->numSoftDofs());
    m.setSoftPrediction();  // the current state (and its caches) is unchanged
  }
}

VecX Simulable::getVelocity() const {
  const Impl& m = *impl_;
  const double h = m.options.time_step;
  VecX v(m.dofs());
  for (int b = 0; b < m.num_bones; ++b) {
    v.segment<3>(6 * b) = (m.q_n.t.row(b) - m.q_nm1.t.row(b)).transpose() / h;
    v.segment<3>(6 * b + 3) = logSO3(m.q_n.R[b] * m.q_nm1.R[b].transpose()) / h;
  }
  if (m.soft) v.tail(m.soft->numSoftDofs()) = (m.soft->u_n - m.soft->u_nm1) / h;
  return v;
}

double Simulable::time() const { return impl_->time; }

SimulableStep Simulable::saveStep() const {
  const Impl& m = *impl_;
  SimulableStep s;
  s.R = m.q.R;
  s.t = m.q.t;
  s.R_n = m.q_n.R;
  s.t_n = m.q_n.t;
  s.R_nm1 = m.q_nm1.R;
  s.t_nm1 = m.q_nm1.t;
  s.time = m.time;
  s.target_R = m.target_R;
  s.target_t0 = m.target_t0;
  s.colliders = m.colliders;
  s.is_static = m.is_static;
  if (m.soft) {
    s.u = m.soft->u;
    s.u_n = m.soft->u_n;
    s.u_nm1 = m.soft->u_nm1;
    s.pose_blend = m.soft->poseBlend();
  }
  return s;
}

void Simulable::restoreStep(const SimulableStep& s) {
  Impl& m = *impl_;
  const size_t n = size_t(m.num_bones);
  for (const auto* R : {&s.R, &s.R_n, &s.R_nm1, &s.target_R})
    if (R->size() != n)
      throw InputError("Simulable::restoreStep: the snapshot has " + std::to_string(R->size()) +
                       " rotations per state, expected " + std::to_string(n) + " bones");
  for (const auto* t : {&s.t, &s.t_n, &s.t_nm1})
    if (size_t(t->rows()) != n)
      throw InputError("Simulable::restoreStep: the snapshot has " + std::to_string(t->rows()) +
                       " positions per state, expected " + std::to_string(n) + " bones");
  if (m.soft) {
    const Eigen::Index nu = m.soft->numSoftDofs();
    if (s.u.size() != nu || s.u_n.size() != nu || s.u_nm1.size() != nu ||
        s.pose_blend.rows() != m.soft->numNodes())
      throw InputError("Simulable::restoreStep: the snapshot's soft-tissue displacements have " +
                       std::to_string(s.u.size()) + " values, expected " + std::to_string(nu));
  }
  // Finite values only: a NaN or Inf restored here would be stepped on (every setter refuses
  // them, so this was the one way in). Names the first non-finite value found.
  const auto requireFinite = [](const std::string& name, const auto& values) {
    for (Eigen::Index i = 0; i < values.rows(); ++i)
      for (Eigen::Index j = 0; j < values.cols(); ++j)
        if (!std::isfinite(values(i, j))) {
          const std::string at = values.size() == 1 ? ""
                                 : values.cols() == 1
                                     ? "[" + std::to_string(i) + "]"
                                     : "(" + std::to_string(i) + ", " + std::to_string(j) + ")";
          throw InputError("Simulable::restoreStep: the snapshot's " + name + at + " is " +
                           number(values(i, j)) + ", expected finite values; nothing restored");
        }
  };
  const auto scalar = [](double value) { return Eigen::Matrix<double, 1, 1>::Constant(value); };
  const auto requireFiniteRotations = [&](const std::string& name, const std::vector<Mat3>& R) {
    for (size_t b = 0; b < R.size(); ++b) requireFinite(name + "[" + std::to_string(b) + "]", R[b]);
  };
  requireFiniteRotations("R", s.R);
  requireFiniteRotations("R_n", s.R_n);
  requireFiniteRotations("R_nm1", s.R_nm1);
  requireFiniteRotations("target_R", s.target_R);
  requireFinite("t", s.t);
  requireFinite("t_n", s.t_n);
  requireFinite("t_nm1", s.t_nm1);
  requireFinite("target_t0", s.target_t0);
  requireFinite("time", scalar(s.time));
  for (size_t c = 0; c < s.colliders.size(); ++c) {
    const Collider& collider = s.colliders[c];
    const std::string name = "colliders[" + std::to_string(c) + "]";
    requireFinite(name + ".p0", collider.p0());
    requireFinite(name + ".p1", collider.p1());
    requireFinite(name + ".radius", scalar(collider.radius()));
    for (size_t k = 0; k < collider.path.times.size(); ++k)
      requireFinite(name + ".path.times[" + std::to_string(k) + "]",
                    scalar(collider.path.times[k]));
    for (size_t k = 0; k < collider.path.offsets.size(); ++k)
      requireFinite(name + ".path.offsets[" + std::to_string(k) + "]", collider.path.offsets[k]);
  }
  if (m.soft) {
    requireFinite("u", s.u);
    requireFinite("u_n", s.u_n);
    requireFinite("u_nm1", s.u_nm1);
    requireFinite("pose_blend", s.pose_blend);
  }
  m.q.R = s.R;
  m.q.t = s.t;
  m.q_n.R = s.R_n;
  m.q_n.t = s.t_n;
  m.q_nm1.R = s.R_nm1;
  m.q_nm1.t = s.t_nm1;
  m.time = s.time;
  m.target_R = s.target_R;
  m.target_t0 = s.target_t0;
  m.colliders = s.colliders;
  m.is_static = s.is_static;
  if (m.soft) {
    m.soft->u = s.u;
    m.soft->u_n = s.u_n;
    m.soft->u_nm1 = s.u_nm1;
    m.soft->setPoseBlendOffsets(s.pose_blend);
    m.setSoftPrediction();
  }
  m.touch();
  m.ensureContact();  // stats() then report this step's contacts, as after its evaluation
}

// initialize(): t_0 = J_0 + trans, t_b = R_p (J_b − J_p) + t_p for the first frame's rotations
// (rest pose: t_b = J_b), velocity (t(frame 1) − t(frame 0))·fps.
void Simulable::getInitialStateRestJointsJacobian(MatX* state_jacobian,
                                                  MatX* velocity_jacobian) const {
  const Impl& m = *impl_;
  if (m.soft)
    throw Error(
        "Simulable::getInitialStateRestJointsJacobian: available for the articulated skeleton "
        "only (the adjoint layer does not cover the soft-tissue models, FEM or ROM)");
  const int nb = m.num_bones;
  auto translationJacobian = [&](const std::vector<Mat3>& R) {
    MatX T = MatX::Zero(3 * nb, 3 * nb);
    for (int b = 0; b < nb; ++b) {
      const int p = m.parents[b];
      if (p < 0) {
        T.block<3, 3>(3 * b, 3 * b) = Mat3::Identity();
        continue;
      }
      T.middleRows<3>(3 * b) = T.middleRows<3>(3 * p);
      T.block<3, 3>(3 * b, 3 * b) += R[p];
      T.block<3, 3>(3 * b, 3 * p) -= R[p];
    }
    return T;
  };
  auto toState = [&](const MatX& T) {
    MatX D = MatX::Zero(m.dofs(), 3 * nb);
    for (int b = 0; b < nb; ++b) D.middleRows<3>(6 * b) = T.middleRows<3>(3 * b);
    return D;
  };
  if (!m.mocap) {
    if (state_jacobian) *state_jacobian = toState(MatX::Identity(3 * nb, 3 * nb));
    if (velocity_jacobian) *velocity_jacobian = MatX::Zero(m.dofs(), 3 * nb);
    return;
  }
  const Motion& mo = *m.mocap;
  const MatX T0 =
      translationJacobian(bonesFromPose(mo.poses.row(0).transpose(), Vec3::Zero(), m.J, m.parents).R);
  if (state_jacobian) *state_jacobian = toState(T0);
  if (velocity_jacobian) {
    if (mo.numFrames() > 1) {
      const MatX T1 = translationJacobian(
          bonesFromPose(mo.poses.row(1).transpose(), Vec3::Zero(), m.J, m.parents).R);
      *velocity_jacobian = toState((T1 - T0) * mo.fps);
    } else {
      *velocity_jacobian = MatX::Zero(m.dofs(), 3 * nb);
    }
  }
}

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

Vec3 Simulable::getTrans() const {
  return (impl_->q.t.row(0) - impl_->J.row(0)).transpose();
}

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
  for (int k = skin.start[i]; k < skin.start[i + 1]; ++k) {
    const int b = skin.entries[k].bone;
    x += skin.entries[k].weight * (q.R[b] * (X - J.row(b).transpose()) + q.t.row(b).transpose());
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
  triplets.reserve(m.skin.entries.size() * 9);
  for (int i = 0; i < X.rows(); ++i) {
    for (int k = m.skin.start[i]; k < m.skin.start[i + 1]; ++k) {
      const int b = m.skin.entries[k].bone;
      const double w = m.skin.entries[k].weight;
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
      const Vec3 joint_gap = q.R[c] * (J.row(b) - J.row(c)).transpose() +
                             q.t.row(c).transpose() - q.t.row(b).transpose();
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
        cluster_near = cluster_near ||
                       collider.signedDistance(cluster_centre, time) < cluster.radius + margin;
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

// ---- energies ----------------------------------------------------------------------------
// The skeleton sums its terms (Impl::dynamic_terms, potential_terms); with soft tissue the
// bones' springs are terms and SoftTissue carries the rest.

double Simulable::getDynamicEnergyScalar() const {
  const Impl& m = *impl_;
  if (m.is_static) return 0.0;
  if (m.soft) {
    m.prepareSoft();
    return m.soft->inertia(nullptr, nullptr, 0, true);
  }
  const TermContext c = m.context();
  double E = 0.0;
  for (const EnergyTerm* term : m.dynamic_terms) E += term->evaluate(c, nullptr, 0);
  return E;
}

void Simulable::getDynamicGradientVector(VecX& g, int offset) const { dynamicGradient(g, offset); }

double Simulable::dynamicGradient(VecX& g, int offset) const {
  const Impl& m = *impl_;
  if (m.is_static) return 0.0;
  if (m.soft) {
    m.prepareSoft();
    return m.soft->inertia(&g, nullptr, offset, true);
  }
  const TermContext c = m.context();
  double E = 0.0;
  for (const EnergyTerm* term : m.dynamic_terms) E += term->evaluate(c, &g, offset);
  return E;
}

void Simulable::getDynamicHessianTripletVector(std::vector<Triplet>& H, int offset,
                                               bool psd) const {
  dynamicHessian(H, nullptr, offset, psd);
}

void Simulable::getDynamicHessianTripletVector(std::vector<Triplet>& H,
                                               std::vector<FixedHessianBlocks>& blocks,
                                               int offset, bool psd) const {
  dynamicHessian(H, &blocks, offset, psd);
}

void Simulable::dynamicHessian(std::vector<Triplet>& H, std::vector<FixedHessianBlocks>* blocks,
                               int offset, bool psd) const {
  const Impl& m = *impl_;
  if (m.is_static) return;
  if (m.soft) {
    m.prepareSoft();
    m.soft->beginReduced(0);
    FixedHessianBlocks inertia_blocks;
    m.soft->inertia(nullptr, &H, offset, psd, blocks ? &inertia_blocks : nullptr);
    if (blocks && !inertia_blocks.empty()) blocks->push_back(inertia_blocks);
    m.soft->flushReduced(0, H, offset, blocks);
    return;
  }
  const TermContext c = m.context();
  for (const EnergyTerm* term : m.dynamic_terms) term->addHessian(c, H, offset, psd);
}

double Simulable::getPotentialEnergyScalar() const {
  const Impl& m = *impl_;
  const TermContext c = m.context();
  double E = 0.0;
  if (!m.soft) {
    m.ensureContact();
    for (const EnergyTerm* term : m.potential_terms) E += term->evaluate(c, nullptr, 0);
    return E;
  }
  for (const EnergyTerm* term : m.spring_terms) E += term->evaluate(c, nullptr, 0);
  m.prepareSoft();
  E += m.soft->gravity(m.options.gravity, nullptr, nullptr, 0, true) +
       m.soft->elastic(nullptr, nullptr, 0, true);
  return E + m.contactEnergy();
}

double Simulable::boneSpringGradient(VecX& g, int offset) const {
  const Impl& m = *impl_;
  const TermContext c = m.context();
  double E = 0.0;
  for (const EnergyTerm* term : m.spring_terms) E += term->evaluate(c, &g, offset);
  return E;
}

double Simulable::potentialGradient(VecX& g, int offset) const {
  const Impl& m = *impl_;
  if (!m.soft) {
    m.ensureContact();
    const TermContext c = m.context();
    double E = 0.0;
    for (const EnergyTerm* term : m.potential_terms) E += term->evaluate(c, &g, offset);
    return E;
  }
  double E = boneSpringGradient(g, offset);
  m.prepareSoft();
  E += m.soft->gravity(m.options.gravity, &g, nullptr, offset, true) +
       m.soft->elastic(&g, nullptr, offset, true);
  m.ensureContact();
  return E + m.soft->contact(m.colliders, m.time, m.options.contact, &g, nullptr, offset, true,
                             nullptr, &m.contact.candidates);
}

void Simulable::getPotentialGradientVector(VecX& g, int offset) const {
  potentialGradient(g, offset);
}

void Simulable::getGradientVector(VecX& g, int offset) const {
  getEnergyAndGradientVector(g, offset);
}

double Simulable::getEnergyAndGradientVector(VecX& g, int offset) const {
  const Impl& m = *impl_;
  if (!m.soft || !m.soft->reduced() || m.is_static || omp_get_max_threads() < 2)
    return dynamicGradient(g, offset) + potentialGradient(g, offset);
  // ROM: as getHessianTripletVector.
  const bool contact = m.prepareSoftForThreads();
  double contact_energy = 0.0;
  const double E = m.soft->reducedGradient(m.options.gravity, g, offset, [&](VecX& part) {
    if (contact)
      contact_energy = m.soft->contact(m.colliders, m.time, m.options.contact, &part, nullptr,
                                       offset, true, nullptr, &m.contact.candidates, false);
  });
  return E + contact_energy + boneSpringGradient(g, offset);
}

void Simulable::getPotentialHessianTripletVector(std::vector<Triplet>& H, int offset,
                                                 bool psd) const {
  potentialHessian(H, nullptr, offset, psd);
}

void Simulable::getPotentialHessianTripletVector(std::vector<Triplet>& H,
                                                 std::vector<FixedHessianBlocks>& blocks,
                                                 int offset, bool psd) const {
  potentialHessian(H, &blocks, offset, psd);
}

void Simulable::potentialHessian(std::vector<Triplet>& H, std::vector<FixedHessianBlocks>* blocks,
                                 int offset, bool psd, bool soft_done) const {
  const Impl& m = *impl_;
  const TermContext c = m.context();
  if (!m.soft) {
    m.ensureContact();
    for (const EnergyTerm* term : m.potential_terms) term->addHessian(c, H, offset, psd);
    return;
  }
  for (const EnergyTerm* term : m.spring_terms) term->addHessian(c, H, offset, psd);
  m.prepareSoft();
  // With soft_done the ROM's gravity, elastic and contact blocks are already in value list
  // 1, their bone triplets in getHessianTripletVector's scratch.
  FixedHessianBlocks gravity_blocks, elastic_blocks;
  if (!soft_done) {
    m.soft->beginReduced(1);
    m.soft->gravity(m.options.gravity, nullptr, &H, offset, psd,
                    blocks ? &gravity_blocks : nullptr);
    m.soft->elastic(nullptr, &H, offset, psd, blocks ? &elastic_blocks : nullptr);
  }
  if (blocks)
    for (const FixedHessianBlocks& list : {elastic_blocks, gravity_blocks})
      if (!list.empty()) blocks->push_back(list);
  if (!soft_done) {
    m.ensureContact();
    m.soft->contact(m.colliders, m.time, m.options.contact, nullptr, &H, offset, psd, nullptr,
                    &m.contact.candidates);
  }
  m.soft->flushReduced(1, H, offset, blocks);
}

size_t Simulable::getHessianTripletVector(std::vector<Triplet>& H,
                                          std::vector<FixedHessianBlocks>& blocks, int offset,
                                          bool psd) const {
  const Impl& m = *impl_;
  if (!m.soft || !m.soft->reduced() || m.is_static || omp_get_max_threads() < 2) {
    dynamicHessian(H, &blocks, offset, psd);
    const size_t potential_start = H.size();
    potentialHessian(H, &blocks, offset, psd);
    return potential_start;
  }
  // ROM: inertia beside contact and gravity on two threads, the elastic tets split between
  // them (SoftTissue::reducedHessians); then the bones' springs.
  const bool contact = m.prepareSoftForThreads();
  std::vector<Triplet>& dynamic = m.hessian_scratch[0];
  std::vector<Triplet>& potential = m.hessian_scratch[1];
  dynamic.clear();
  potential.clear();
  m.soft->reducedHessians(m.options.gravity, dynamic, potential, offset, psd, [&] {
    if (contact)
      m.soft->contact(m.colliders, m.time, m.options.contact, nullptr, &potential, offset, psd,
                      nullptr, &m.contact.candidates, false);
  });
  H.insert(H.end(), dynamic.begin(), dynamic.end());
  m.soft->flushReduced(0, H, offset, &blocks);
  const size_t potential_start = H.size();
  potentialHessian(H, &blocks, offset, psd, true);
  H.insert(H.end(), potential.begin(), potential.end());
  return potential_start;
}

void Simulable::fixVectorKinematic(VecX& g, int offset) const {
  const Impl& m = *impl_;
  for (int b = 0; b < m.num_bones; ++b)
    if (m.kinematic[b]) g.segment<6>(offset + 6 * b).setZero();
}

void Simulable::fixMatrixKinematic(std::vector<Triplet>& H, int offset) const {
  const Impl& m = *impl_;
  if (m.options.kinematic_bones.empty()) return;
  auto isKinematic = [&](int index) {
    const int local = index - offset;
    return local >= 0 && local < m.boneDofs() && m.kinematic[local / kDofsPerBone];
  };
  H.erase(std::remove_if(H.begin(), H.end(),
                         [&](const Triplet& t) { return isKinematic(t.row()) || isKinematic(t.col()); }),
          H.end());
  for (int b = 0; b < m.num_bones; ++b)
    if (m.kinematic[b])
      for (int k = 0; k < kDofsPerBone; ++k)
        H.emplace_back(offset + 6 * b + k, offset + 6 * b + k, 1.0);
}

std::vector<const EnergyTerm*> Simulable::energyTerms() const {
  const Impl& m = *impl_;
  return m.soft ? m.spring_terms : m.terms;
}

TermContext Simulable::termContext() const {
  impl_->ensureContact();
  return impl_->context();
}

// ---- scene hooks -------------------------------------------------------------------------

void Simulable::setColliders(std::vector<Collider> colliders) {
  impl_->colliders = std::move(colliders);
  impl_->touch();
}

const std::vector<Collider>& Simulable::colliders() const { return impl_->colliders; }
void Simulable::setStatic(bool on) { impl_->is_static = on; }
bool Simulable::isStatic() const { return impl_->is_static; }
const SoftAvatar& Simulable::avatar() const { return *impl_->avatar; }
std::shared_ptr<const Motion> Simulable::mocap() const { return impl_->mocap; }
const SimulableOptions& Simulable::options() const { return impl_->options; }

SimulableStats Simulable::stats() const {
  SimulableStats s;
  s.active_contacts = impl_->contact.active;
  return s;
}

}  // namespace flsh

// ---- parameter derivatives (each term's products, energy_term.h) ---------------------------

namespace flsh {

namespace {

void requireSkeleton(const Simulable::Impl& m, const char* who);

void checkStateSized(const VecX& x, int n, const char* who, const char* name) {
  if (x.size() != n)
    throw InputError(std::string("Simulable::") + who + ": " + name + " has " +
                     std::to_string(x.size()) +
                     " values, expected numDofs() = " + std::to_string(n));
}

}  // namespace

/// Λᵀ ∂g/∂p for each group, summed over the terms (Λ: a vector or numDofs × m), with the β
/// chain through the rest joints and bone inertias unless `shape_surface_only`.
template <class Lambda, class Block>
std::vector<Block> parameterProducts(const Simulable& s, const Simulable::Impl& m,
                                     const Lambda& lambda, const std::vector<SimParameter>& groups,
                                     bool shape_surface_only) {
  ParameterProducts<Block> products;
  bool shape = false;
  const auto want = [&](SimParameter p) {
    Block& block = products[p];
    if (block.rows() == 0) block = Block::Zero(s.parameterSize(p), lambda.cols());
  };
  for (SimParameter p : groups) {
    simParameterInfo(p);  // throws for a value outside the enum
    want(p);
    shape = shape || p == SimParameter::Shape;
  }
  const bool chain = shape && !shape_surface_only;
  if (chain) {
    want(SimParameter::RestJoints);
    want(SimParameter::BoneInertia);
  }
  m.ensureContact();
  const TermContext c = m.context();
  for (const EnergyTerm* term : m.terms) term->addParameterProducts(c, lambda, products);
  Block shape_products;
  if (chain) {
    shape_products = products[SimParameter::Shape];
    chainShapeCotangent(*m.avatar, products[SimParameter::RestJoints],
                        products[SimParameter::BoneInertia], shape_products);
  }
  std::vector<Block> out;
  out.reserve(groups.size());
  for (SimParameter p : groups)
    out.push_back(p == SimParameter::Shape && chain ? shape_products : products[p]);
  return out;
}

namespace {

void requireSkeleton(const Simulable::Impl& m, const char* who) {
  if (m.soft)
    throw Error(std::string("Simulable::") + who +
                ": parameter derivatives (the adjoint layer) are available for the articulated "
                "skeleton only; this avatar has soft tissue (the FEM or ROM soft skeleton)");
}

}  // namespace

int Simulable::parameterSize(SimParameter p) const {
  return simParameterSize(p, int(impl_->colliders.size()), int(impl_->avatar->betas().size()));
}

MatX Simulable::getGradientParameterJacobian(SimParameter p) const {
  return getGradientParameterJacobians({p}).front();
}

// The Jacobians are the products with Λ = I, transposed.
std::vector<MatX> Simulable::getGradientParameterJacobians(
    const std::vector<SimParameter>& groups, bool shape_surface_only) const {
  const Impl& m = *impl_;
  requireSkeleton(m, "getGradientParameterJacobians");
  const MatX identity = MatX::Identity(numDofs(), numDofs());
  std::vector<MatX> out =
      parameterProducts<MatX, MatX>(*this, m, identity, groups, shape_surface_only);
  for (MatX& D : out) D.transposeInPlace();
  return out;
}

std::vector<VecX> Simulable::getGradientParameterVJPs(const VecX& lambda,
                                                     const std::vector<SimParameter>& groups,
                                                     bool shape_surface_only) const {
  const Impl& m = *impl_;
  requireSkeleton(m, "getGradientParameterVJPs");
  checkStateSized(lambda, numDofs(), "getGradientParameterVJPs", "lambda");
  return parameterProducts<VecX, VecX>(*this, m, lambda, groups, shape_surface_only);
}

MatX Simulable::getGradientPreviousStateJacobian(int which) const {
  const Impl& m = *impl_;
  requireSkeleton(m, "getGradientPreviousStateJacobian");
  if (which != 1 && which != 2)
    throw InputError("Simulable::getGradientPreviousStateJacobian: which = " +
                     std::to_string(which) + ", expected 1 (q_n) or 2 (q_{n-1})");
  MatX D = MatX::Zero(numDofs(), numDofs());
  const TermContext c = m.context();
  for (const EnergyTerm* term : m.terms)
    if (term->dependsOnPreviousStates()) term->addPreviousStateJacobian(c, which, D);
  return D;
}

void Simulable::getGradientPreviousStatesVJP(const VecX& lambda, VecX* a_n, VecX* a_nm1) const {
  const Impl& m = *impl_;
  requireSkeleton(m, "getGradientPreviousStatesVJP");
  checkStateSized(lambda, numDofs(), "getGradientPreviousStatesVJP", "lambda");
  if (a_n) a_n->setZero(lambda.size());
  if (a_nm1) a_nm1->setZero(lambda.size());
  const TermContext c = m.context();
  for (const EnergyTerm* term : m.terms)
    if (term->dependsOnPreviousStates()) term->addPreviousStatesProducts(c, lambda, a_n, a_nm1);
}

VecX Simulable::getGradientPreviousStatesJVP(const VecX& dq_n, const VecX& dq_nm1) const {
  const Impl& m = *impl_;
  requireSkeleton(m, "getGradientPreviousStatesJVP");
  checkStateSized(dq_n, numDofs(), "getGradientPreviousStatesJVP", "dq_n");
  checkStateSized(dq_nm1, numDofs(), "getGradientPreviousStatesJVP", "dq_nm1");
  VecX out = VecX::Zero(dq_n.size());
  const TermContext c = m.context();
  for (const EnergyTerm* term : m.terms)
    if (term->dependsOnPreviousStates()) term->addPreviousStatesTangent(c, dq_n, dq_nm1, out);
  return out;
}

VecX Simulable::getParameter(SimParameter p) const {
  const Impl& m = *impl_;
  VecX value(parameterSize(p));
  switch (p) {
    case SimParameter::RestJoints:
      for (int b = 0; b < m.num_bones; ++b) value.segment<3>(3 * b) = m.J.row(b).transpose();
      break;
    case SimParameter::BoneInertia:
      for (int b = 0; b < m.num_bones; ++b) {
        const BoneInertia& in = m.inertia[b];
        const Mat3& S = in.second_moment;
        value.segment<10>(10 * b) << in.mass, in.first_moment, S(0, 0), S(1, 1), S(2, 2),
            S(0, 1), S(0, 2), S(1, 2);
      }
      break;
    case SimParameter::PoseTargets:
      for (int b = 0; b < m.num_bones; ++b) value.segment<3>(3 * b) = logSO3(m.target_R[b]);
      break;
    case SimParameter::RootTranslationTarget: value = m.target_t0; break;
    case SimParameter::Stiffnesses:
      value << m.options.joint_stiffness, m.options.tracking_stiffness, m.options.root_stiffness,
          m.options.contact.stiffness;
      break;
    case SimParameter::ColliderOffsets:
      for (size_t k = 0; k < m.colliders.size(); ++k)
        value.segment<3>(3 * k) = m.colliders[k].path.offsetAt(m.time);
      break;
    case SimParameter::Shape: value = m.avatar->betas(); break;
  }
  return value;
}

void Simulable::setParameter(SimParameter p, const VecX& value) {
  Impl& m = *impl_;
  if (p == SimParameter::Shape)
    throw InputError(
        "Simulable::setParameter: Shape (β) is fixed by the SoftAvatar the simulable was built "
        "with; build a new SoftAvatar with the new β and a new Simulable on it");
  if (value.size() != parameterSize(p))
    throw InputError("Simulable::setParameter: value has " + std::to_string(value.size()) +
                     " entries, expected parameterSize() = " + std::to_string(parameterSize(p)));
  if (!value.allFinite()) throw InputError("Simulable::setParameter: value contains NaN or Inf");
  switch (p) {
    case SimParameter::RestJoints: {
      const Vec3 root_shift = value.head<3>() - m.J.row(0).transpose();
      for (int b = 0; b < m.num_bones; ++b) m.J.row(b) = value.segment<3>(3 * b).transpose();
      m.target_t0 += root_shift;  // the root target is J_0 + trans
      m.buildSkinning();
      m.buildStiffnesses();
      break;
    }
    case SimParameter::BoneInertia:
      for (int b = 0; b < m.num_bones; ++b)
        if (!(value[10 * b] > 0.0))
          throw InputError("Simulable::setParameter: BoneInertia of bone " + std::to_string(b) +
                           " has mass " + std::to_string(value[10 * b]) + ", expected > 0 kg");
      for (int b = 0; b < m.num_bones; ++b) {
        const auto v = value.segment<10>(10 * b);
        BoneInertia& in = m.inertia[b];
        in.mass = v[0];
        in.first_moment = v.segment<3>(1);
        in.second_moment << v[4], v[7], v[8], v[7], v[5], v[9], v[8], v[9], v[6];
      }
      m.buildStiffnesses();
      break;
    case SimParameter::PoseTargets:
      for (int b = 0; b < m.num_bones; ++b) m.target_R[b] = rodrigues(value.segment<3>(3 * b));
      break;
    case SimParameter::RootTranslationTarget: m.target_t0 = value; break;
    case SimParameter::Stiffnesses: {
      SimulableOptions previous = m.options;
      m.options.joint_stiffness = value[0];
      m.options.tracking_stiffness = value[1];
      m.options.root_stiffness = value[2];
      m.options.contact.stiffness = value[3];
      try {
        m.validateOptions();
      } catch (...) {
        m.options = previous;
        throw;
      }
      m.buildStiffnesses();
      break;
    }
    case SimParameter::ColliderOffsets:
      for (size_t k = 0; k < m.colliders.size(); ++k) {
        ColliderPath& path = m.colliders[k].path;
        const Vec3 shift = value.segment<3>(3 * k) - path.offsetAt(m.time);
        if (path.times.empty()) {
          path.times = {0.0};
          path.offsets = {Vec3::Zero()};
        }
        for (Vec3& o : path.offsets) o += shift;
      }
      break;
    case SimParameter::Shape: break;  // rejected above
  }
  m.touch();
}

}  // namespace flsh
