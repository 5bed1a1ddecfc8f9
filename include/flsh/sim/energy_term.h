// One energy term of a simulable's backward-Euler objective (ARCHITECTURE.md §4, §6): its
// value, gradient and Hessian at the current state, and the products the adjoint needs, written
// once beside the energy.
//
// A term sees the state through a TermContext (a read-only view the simulable fills before
// each call) and adds into the caller's vectors at `offset` (the simulable's first DoF in a
// scene). Increments are the bones' chart of simulable.h: 6 values per bone, [δt_b, δω_b].
//
// Parameter derivatives. ∂g/∂p is sparse: a term's gradient on a few bones depends on a few
// parameters. So each term writes it once, as local dense blocks (a few DoF rows × a few
// parameter columns, term_blocks.h), and the three uses derive from those blocks: the
// vector–Jacobian products λᵀ ∂g/∂p of the adjoint's reverse sweep, the Jacobian–vector products
// ∂g/∂p ṗ of the forward (tangent) sweep and the dense Jacobians ∂g/∂p. None of them forms a
// dense identity or a second formula. Previous states (q_n, q_{n−1}) are handled likewise, from
// the term's own 6 × 6 blocks.
//
// Terms are built by the simulable for one avatar and hold no state of the simulation; the
// scratch some keep for assembly is mutable, so a term is not thread-safe per instance.
#pragma once

#include <array>
#include <vector>

#include "flsh/body/skinned_surface.h"
#include "flsh/contact/collider.h"
#include "flsh/core/types.h"
#include "flsh/sim/sim_parameter.h"
#include "flsh/sim/simulable_options.h"
#include "flsh/volume/soft_avatar.h"

namespace flsh {

/// Collider contact on the skinned surface at the current state: the broad phase's candidate
/// vertices, their positions and areas, and the node gradient ∂E/∂x (3 per candidate).
struct SurfaceContactState {
  std::vector<int> candidates;
  MatX3 nodes;
  VecX areas;
  VecX gradient;
  double energy = 0.0;
  int active = 0;  ///< vertex–collider pairs in contact
};

/// What a term reads at the current state. References stay owned by the simulable.
struct TermContext {
  int num_bones;
  const std::vector<int>& parents;          ///< root −1
  const MatX3& J;                           ///< rest joint centres, m
  const std::vector<BoneInertia>& inertia;  ///< per bone
  const SimulableOptions& options;
  bool tracking;   ///< tracking and root springs active (a mocap and options.track_mocap)
  bool is_static;  ///< no inertia term
  const std::vector<Mat3>& R;  ///< current state q
  const MatX3& t;
  const std::vector<Mat3>& R_n;  ///< q_n
  const MatX3& t_n;
  const std::vector<Mat3>& R_nm1;  ///< q_{n−1}
  const MatX3& t_nm1;
  const std::vector<Mat3>& target_R;      ///< tracking targets (root: global)
  const Vec3& target_t0;                  ///< root position target, m
  const std::vector<double>& tracking_k;  ///< N·m/rad² per bone (root unused)
  double root_k_pos, root_k_rot;          ///< N/m, N·m/rad²
  const std::vector<Collider>& colliders;
  double time;
  const SoftAvatar& avatar;
  const SparseSkinWeights& skin;
  /// Up to date (the simulable runs its broad phase before contact terms are called).
  const SurfaceContactState& contact;
  /// Only the bones' rows of the gradient and the bones' block of the Hessian are asked for
  /// (Simulable::getBoneEnergyAndGradientVector and getBoneHessianTripletVector, for Newton's
  /// coarse presolve); a term may leave out its other entries and blocks (the soft tissue's
  /// node terms do). Terms that ignore it stay correct.
  bool bone_block_only = false;
};

/// One block per parameter group, empty (0 rows) where the group is not asked for; terms ADD
/// into the non-empty ones. Vector–Jacobian products: VecX of parameterSize(p). Jacobians: MatX
/// of numDofs × parameterSize(p).
template <class Block>
struct ParameterProducts {
  std::array<Block, kNumSimParameters> groups;
  bool wants(SimParameter p) const { return groups[size_t(p)].rows() > 0; }
  Block& operator[](SimParameter p) { return groups[size_t(p)]; }
  const Block& operator[](SimParameter p) const { return groups[size_t(p)]; }
};

/// A direction in parameter space: one pointer per group (null or empty: no change of it).
using ParameterDirection = std::array<const VecX*, kNumSimParameters>;

class EnergyTerm {
 public:
  virtual ~EnergyTerm() = default;
  /// Short name, for messages and tests ("joint springs").
  virtual const char* name() const = 0;
  /// The energy (J); with g not null its gradient is ADDED into g at offset.
  virtual double evaluate(const TermContext& c, VecX* g, int offset) const = 0;
  /// Hessian triplets APPENDED with indices shifted by offset; psd: the positive-semidefinite
  /// form Newton uses, else the exact Hessian of the chart.
  virtual void addHessian(const TermContext& c, std::vector<Triplet>& H, int offset,
                          bool psd) const = 0;
  /// ADDS λᵀ ∂g/∂p into out[p] for each group out asks for (λ: numDofs). Groups that do not
  /// enter this term's gradient are left alone. Shape: only this term's direct dependence on β
  /// (e.g. the contact surface X(β)); what goes through the rest joints and bone inertias is
  /// chained by chainShape (sim_parameter.h).
  virtual void addParameterProducts(const TermContext& c, const VecX& lambda,
                                    ParameterProducts<VecX>& out) const {}
  /// ADDS Σ_p ∂g/∂p ṗ_p into out[d] for each direction d (out[d]: numDofs); Shape as above.
  virtual void addParameterTangents(const TermContext& c,
                                    const std::vector<ParameterDirection>& directions,
                                    std::vector<VecX>& out) const {}
  /// ADDS ∂g/∂p into out[p] (numDofs × parameterSize(p)) for each group out asks for.
  virtual void addParameterJacobians(const TermContext& c, ParameterProducts<MatX>& out) const {}
  /// Terms whose gradient depends on q_n and q_{n−1} (inertia): ADDS (∂g/∂q_n)ᵀ λ into a_n and
  /// (∂g/∂q_{n−1})ᵀ λ into a_nm1 (either may be null), the tangent ∂g/∂q_n dq_n +
  /// ∂g/∂q_{n−1} dq_{n−1} into out, and the dense blocks into D (which = 1: q_n, 2: q_{n−1}).
  virtual bool dependsOnPreviousStates() const { return false; }
  /// False for a term that reads the soft state alone (the soft tissue's elasticity): with the
  /// soft state held it is constant, and the bones' presolve (Simulable::
  /// getBoneEnergyAndGradientVector) leaves it out.
  virtual bool dependsOnBones() const { return true; }
  virtual void addPreviousStatesProducts(const TermContext& c, const VecX& lambda, VecX* a_n,
                                         VecX* a_nm1) const {}
  virtual void addPreviousStatesTangent(const TermContext& c, const VecX& dq_n, const VecX& dq_nm1,
                                        VecX& out) const {}
  virtual void addPreviousStateJacobian(const TermContext& c, int which, MatX& D) const {}
};

/// A term whose parameter derivatives are one template `template <class Sink> void
/// parameterBlocks(const TermContext&, Sink&) const` in Derived, which hands ∂g/∂p to the sink
/// as local blocks (src/sim/terms/term_blocks.h); the three products are that template with
/// three sinks.
template <class Derived>
class TermWithParameterBlocks : public EnergyTerm {
 public:
  void addParameterProducts(const TermContext& c, const VecX& lambda,
                            ParameterProducts<VecX>& out) const final;
  void addParameterTangents(const TermContext& c, const std::vector<ParameterDirection>& directions,
                            std::vector<VecX>& out) const final;
  void addParameterJacobians(const TermContext& c, ParameterProducts<MatX>& out) const final;
};

}  // namespace flsh
