// Scene: several simulables (avatars) and colliders stepped together. Their states are merged
// into one vector (simulable i at offset(i)) and one sparse Hessian; avatar–avatar contact
// couples them through each avatar's capsules (one per bone, moving with the bone).
#pragma once

#include <memory>
#include <vector>

#include "flsh/contact/collider.h"
#include "flsh/sim/simulable.h"
#include "flsh/solve/newton.h"

namespace flsh {

struct SceneOptions {
  /// newton.linear_solver = Auto gives the scene the simplicial sparse Cholesky (SparseLLT):
  /// its Hessian has a fixed block tree-sparse pattern (see Scene::hessian).
  NewtonOptions newton;
  /// Vertices of each avatar against the other avatars' bone capsules.
  bool avatar_contact = true;
  ContactOptions avatar_contact_options;
};

struct StepStats {
  NewtonResult newton;
  int active_contacts = 0;  ///< vertex–collider and vertex–capsule pairs in contact
  double seconds = 0.0;     ///< wall time of the step
};

class Scene : public Objective {
 public:
  explicit Scene(const SceneOptions& options = {});
  ~Scene() override;

  /// Adds an avatar (initialized or not); all simulables must share one time step.
  void addSimulable(std::shared_ptr<Simulable> simulable);
  /// Adds a collider seen by every avatar.
  void addCollider(const Collider& collider);
  /// Calls initialize() on every simulable.
  void initialize();
  /// One backward-Euler step of every simulable: preUpdate, Newton, postUpdate.
  StepStats step();
  double time() const;
  void setStatic(bool on);

  const std::vector<std::shared_ptr<Simulable>>& simulables() const { return simulables_; }
  const std::vector<Collider>& colliders() const { return colliders_; }
  int offset(int i) const { return offsets_.at(i); }
  const SceneOptions& options() const { return options_; }
  LinearSolver* linearSolver() { return solver_.get(); }

  // Objective (the merged backward-Euler energy, including avatar–avatar contact)
  int numDofs() const override;
  double energy() override;
  void gradient(VecX& g) override;
  void hessian(SpMat& H, bool psd) override;
  void step(const VecX& dq) override;
  void push() override;
  void pop() override;
  bool discardPushed() override;
  void fixKinematic(VecX& g, SpMat* H) override;

  /// Avatar–avatar contact energy at the current states; adds gradient/Hessian when asked.
  /// For every ordered pair (A, B) of different simulables, A's surface vertices x_i (areas
  /// a_i) against B's bone capsules moving with B's bones (a' = R_b(a − J_b) + t_b):
  /// Σ vertexCapsulePenalty(x_i, a', b', r, k·a_i). `g` (size numDofs()) is added to, `H`
  /// triplets (both triangles, merged indices) appended; psd = Gauss–Newton, else exact.
  /// Needs the articulated-skeleton node map x_i = Σ_b w_ib (R_b (X_i − J_b) + t_b).
  double avatarContactEnergy(VecX* g, std::vector<Triplet>* H, bool psd,
                             int* active = nullptr) const;

 private:
  struct AvatarContactData;
  AvatarContactData& contactData(int i) const;
  void poseCluster(int i, int cluster) const;  // skins one vertex cluster of simulable i
  void ensureSolver();
  bool avatarContactActive() const;

  SceneOptions options_;
  std::vector<std::shared_ptr<Simulable>> simulables_;
  std::vector<int> offsets_;
  std::vector<Collider> colliders_;
  std::unique_ptr<LinearSolver> solver_;
  int num_dofs_ = 0;
  int last_solver_dofs_ = -1;
  int stack_depth_ = 0;            // push() levels not yet popped
  std::vector<Triplet> triplets_;  // Hessian assembly buffer, reused
  // Fixed Hessian pattern of whole 6 × 6 bone blocks, a superset of every evaluation's
  // (all bone pairs that share a vertex, so collider contacts never change it): assembly
  // writes values in place and the solver keeps its analysis. block_rank_ (bones² entries):
  // position of block row a within block column b's stored blocks, −1 outside the pattern.
  SpMat hessian_pattern_;
  std::vector<int> block_rank_;
  // Value index in the pattern of each triplet position of the last assembly, with its
  // row · n + col key: the triplet order repeats between calls, so most lookups are skipped.
  mutable std::vector<long long> fill_key_;
  mutable std::vector<int> fill_index_;
  void rebuildHessianPattern();
  bool fillHessian(SpMat& H) const;
  // Per-simulable skinning data and the posed nodes/capsules of the last state seen.
  mutable std::vector<std::unique_ptr<AvatarContactData>> contact_data_;
  struct BlockAccumulator;
  mutable std::unique_ptr<BlockAccumulator> blocks_;
  mutable int avatar_contacts_ = 0;  // active vertex–capsule pairs at the last evaluation
  // Avatar–avatar pairs in contact, (capsule of B, vertex of A) per ordered pair A·n + B, found
  // at the posed-data versions contact_pairs_versions_ (one per simulable).
  mutable std::vector<std::vector<std::pair<int, int>>> contact_pairs_;
  mutable std::vector<long> contact_pairs_versions_;
};

}  // namespace flsh
