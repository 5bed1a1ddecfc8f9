// Internal: the data of one Simulable (Simulable::Impl), shared by the files that implement it:
// simulable.cpp (construction, targets, stepping, state), simulable_outputs.cpp (poses, meshes,
// Jacobians, soft-tissue accessors), simulable_surface.cpp (the skinned surface and the contact
// broad phase), simulable_energy.cpp (the energy terms' sums and Hessians) and
// simulable_parameters.cpp (parameter groups and the adjoint's products).
#pragma once

#include <memory>
#include <vector>

#include "flsh/sim/simulable.h"
#include "sim/block_hessian_term.h"
#include "sim/contact_term.h"
#include "sim/hessian_blocks.h"
#include "sim/model_kinematics.h"
#include "sim/skeleton_kinematics.h"
#include "sim/soft_tissue.h"
#include "sim/terms/bone_gravity_term.h"
#include "sim/terms/joint_spring_term.h"
#include "sim/terms/rigid_inertia_term.h"
#include "sim/terms/surface_contact_term.h"
#include "sim/terms/tracking_spring_term.h"

namespace flsh {

namespace detail {

constexpr int kDofsPerBone = 6;

// Rigid transforms of all bones: rotation R_b and joint centre t_b (row b of t).
struct BoneStates {
  std::vector<Mat3> R;
  MatX3 t;
};

}  // namespace detail

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

  // The skinned surface: sparse weights, each bone's dominated vertices in clusters of at most
  // kSurfaceClusterVertices, and their rest bounds (body/skinned_surface.h), for the broad
  // phase of collider contact.
  static constexpr int kSurfaceClusterVertices = 48;
  using Influence = SparseSkinWeights::Influence;
  SkinnedSurface surface;

  // ---- mutable data ----
  detail::BoneStates q, q_n, q_nm1;
  // Saved states: entries [0, stack_depth) are live; the rest keep their storage for reuse
  // (push/pop/discard then allocate nothing).
  std::vector<detail::BoneStates> stack;
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
  };
  mutable ContactCache contact;
  // Scratch of getHessianTripletVector: the ROM's inertia and gravity triplets, summed on two
  // threads.
  mutable std::vector<Triplet> hessian_scratch[2];

  // FEM soft skeleton (null for the articulated skeleton): node data, displacements u.
  std::unique_ptr<detail::SoftTissue> soft;
  std::vector<VecX> u_stack;  // displacements saved with `stack` (same depth)

  // The model's kinematics (the skeleton's skinned surface, or soft->kinematics()) and its
  // collider-contact term, as the model-independent code asks them (contact broad phase,
  // surface outputs).
  std::unique_ptr<detail::SkeletonKinematics> skeleton_kinematics;
  const detail::ModelKinematics* kinematics = nullptr;
  const detail::ContactTerm* model_contact = nullptr;
  /// The model's own two-thread schedule of its node terms (the ROM's; null: none).
  const detail::TwoThreadSchedule* schedule = nullptr;

  void touch() { ++state_version; }
  int boneDofs() const { return detail::kDofsPerBone * num_bones; }
  int dofs() const { return boneDofs() + kinematics->numSoftDofs(); }
  /// Prepares the kinematics at the current state (cached by state_version).
  void prepare() const {
    if (frames_only)
      kinematics->prepareFrames(state_version, frames(q));
    else
      kinematics->prepare(state_version, frames(q));
  }
  /// Set while the bones' presolve evaluates (getBoneEnergyAndGradientVector,
  /// getBoneHessianTripletVector): prepare() sets the frames and may defer the skinning
  /// (ModelKinematics::prepareFrames).
  mutable bool frames_only = false;
  detail::BoneFrames frames(const detail::BoneStates& s) const { return {s.R, s.t}; }
  void setSoftPrediction() { soft->setPrediction(frames(q_n), frames(q_nm1)); }

  void validateOptions() const;
  void buildSkinning();
  void buildStiffnesses();
  void updateTargets(double t);
  void placeKinematicBones();
  void ensureContact() const;
  /// Surface vertices that may touch a collider (see ensureContact); `extra_margin`: per bone,
  /// added to its bound.
  void broadPhase(const double* extra_margin, std::vector<int>& candidates) const;

  // ---- energy terms (energy_term.h) ----
  // The articulated skeleton's energy is the sum of these terms; with soft tissue the bones
  // keep their springs (joint_term, tracking_term) and SoftTissue's node terms (inertia,
  // gravity, elasticity, contact on the tet nodes) replace the rest.
  detail::RigidInertiaTerm inertia_term;
  detail::BoneGravityTerm gravity_term;
  detail::JointSpringTerm joint_term;
  std::unique_ptr<detail::TrackingSpringTerm> tracking_term;
  std::unique_ptr<detail::SurfaceContactTerm> contact_term;
  /// The model's terms by part (dynamic: inertia; potential: the rest), with their block
  /// forms where they have one, and the value lists they sum into (null: none, the skeleton);
  /// all of them in `terms`; the bone springs alone in `spring_terms`.
  std::vector<detail::TermEntry> dynamic_terms, potential_terms;
  const detail::HessianValueLists* value_lists = nullptr;
  std::vector<const EnergyTerm*> terms, spring_terms;
  /// The skeleton's terms; useSoftTerms: the bones' springs and `soft`'s node terms.
  void buildTerms();
  void useSoftTerms();
  /// The model's two-thread schedule applies (it has one, inertia is on, two threads).
  bool runsOnTwoThreads() const;
  /// The view the terms read at the current state, the soft kinematics prepared (call
  /// ensureContact first for contact).
  TermContext context() const;
};

}  // namespace flsh
