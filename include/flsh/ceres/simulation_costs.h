// A Ceres cost function over a simulated sequence: simulated joint positions and/or SMPL surface
// points of a whole rollout (flsh/diff/rollout.h) against observations, with respect to a few
// rollout inputs. Every model: the articulated skeleton, and the FEM and ROM soft skeletons
// (whose surface moves with the soft tissue). Target flsh_ceres.
//
// Residuals, for steps t = 1..T and observed points k = 0..N−1 (joints first, then vertices),
// coordinate c:  row (t − 1)·3N + 3k + c  =  w_t (x_{k,t} − observed_{t, 3k+c}), metres × weight,
// where x_{k,t} is the simulated position of bone `joints[k]`'s joint centre t_b after step t, or
// of SMPL surface vertex `vertices[k − #joints]` (Simulable::getVertices: the skeleton's skinning
// of the simulated pose; the soft models' simulated surface, skinned with the pose blend held
// from the previous state). Ceres minimizes ½ Σ residual².
//
// Parameter blocks (the `blocks` list at construction picks which, in that order; inputs not
// listed keep the values given at construction):
//   Shape            (num_betas)  β, the first num_betas components (the others keep the base
//                                 avatar's); every evaluation simulates SoftAvatar::withShape of
//                                 that β (rest joints, bone inertias, contact surface and, for
//                                 the soft models, rest nodes, masses and materials all move;
//                                 the discretization is the base avatar's).
//   Stiffnesses      (4)          joint (N/m), tracking (1/s²), root (1/s²), contact (N/m³)
//                                 (SimParameter::Stiffnesses; values < 0 make Evaluate fail).
//   InitialVelocity  (numDofs)    v_0 per DoF, m/s and world-frame rad/s (setVelocity layout);
//                                 the initial state stays what initialize() sets.
//   PoseTargets      (T·72)       the tracking targets of every step, row-major T × 72 rad
//                                 (SMPL layout: bone b ≥ 1 relative to its parent, root global).
//   Material         (P or #names) soft models: the material file's coefficients
//                                 (MaterialModel::parameters(), a = log c₀ and the log-slopes b of
//                                 every coefficient), or only the entries that
//                                 SimulationCostOptions::material_names names, in that order (the
//                                 others keep the base avatar's); every evaluation simulates
//                                 SoftAvatar::withMaterial of them (after withShape).
//
// Jacobians. Forward sensitivities (Rollout::forwardSensitivities) by default: one tangent per
// parameter column, all sharing each step's Jacobian evaluation and factor, so the cost is one
// extra sweep plus one back-substitution per column and step — the right tool for a few
// parameters and many residuals (3N·T), the usual fitting case. The adjoint
// (Rollout::backward) gives one Jacobian ROW per reverse sweep, each sweep re-evaluating every
// step's Jacobians, so it only pays when residuals are far fewer than parameter columns
// (e.g. a final-pose observation against all pose targets); choose it with
// SimulationCostOptions::jacobians. Both are exact for the converged rollout: use a tight Newton
// tolerance (rollout.newton.gradient_tolerance ~1e-10; for the soft models
// rollout.soft_tissue_newton / reduced_newton) when the Jacobians matter. The soft models'
// observed vertices add, per step, one pull-back of the surface per observed coordinate
// (Rollout::verticesCotangent): their Jacobians with respect to the state, the previous state
// and β.
//
// Construction checks every size, index and value and throws flsh::InputError naming the
// argument, the expected and the actual. Evaluate never throws: it returns false (Ceres rejects
// the step) for non-finite parameters, invalid ones (negative stiffness), a step where Newton
// did not converge (when required) or a singular step Hessian. Evaluate builds its own avatar,
// simulable and rollout, so Ceres may evaluate the cost from several threads.
#pragma once

#include <ceres/cost_function.h>

#include <memory>
#include <string>
#include <vector>

#include "flsh/body/motion.h"
#include "flsh/contact/collider.h"
#include "flsh/core/types.h"
#include "flsh/diff/rollout.h"
#include "flsh/sim/simulable.h"
#include "flsh/volume/soft_avatar.h"

namespace flsh::ceres_costs {

/// The rollout inputs a SimulationSequenceCost can expose as parameter blocks.
enum class SequenceParameter { Shape, Stiffnesses, InitialVelocity, PoseTargets, Material };

/// How Evaluate computes Jacobians (see the top of this file).
enum class SequenceJacobians {
  ForwardSensitivities,  ///< one tangent per parameter column (few parameters, many residuals)
  Adjoint,               ///< one reverse sweep per residual (few residuals, many parameters)
};

/// What is observed: points and their positions per step.
struct SequenceObservations {
  std::vector<int> joints;    ///< bones 0..23: the simulated joint centres t_b
  std::vector<int> vertices;  ///< SMPL surface vertices 0..#V−1 (skinned simulated pose)
  /// T × 3N observed positions, m: row t − 1 = step t, columns 3k..3k+2 = point k (joints
  /// first, then vertices), N = joints.size() + vertices.size().
  RowMatX observed;
  /// T weights ≥ 0, one per step (empty: all 1; 0 ignores a step).
  VecX step_weights;
  int numPoints() const { return int(joints.size() + vertices.size()); }
};

struct SimulationCostOptions {
  /// Newton settings of every rollout; the Jacobians are as accurate as its convergence.
  RolloutOptions rollout;
  SequenceJacobians jacobians = SequenceJacobians::ForwardSensitivities;
  /// Size of the Shape block: the first num_betas of β (−1: all K). 1..K.
  int num_betas = -1;
  /// Entries of the Material block, by MaterialModel::parameterNames() (e.g.
  /// "layers.soft_tissue.E1.log_value"), in the block's order; empty: all P of them.
  std::vector<std::string> material_names;
  /// Evaluate fails when Newton did not converge at some step (its Jacobians would not be
  /// those of the residuals). With false, the residuals of such a rollout are still returned,
  /// but never its Jacobians: Rollout refuses to differentiate an unconverged step, so an
  /// evaluation that asks for them fails.
  bool require_convergence = true;
};

/// Simulated points over T steps against observations (see the top of this file).
class SimulationSequenceCost : public ceres::CostFunction {
 public:
  /// avatar: initialized SoftAvatar of the base shape (its body, β and settings); mocap: the
  /// tracked motion (may be null: then no tracking and no PoseTargets block); options: the
  /// simulable's (their stiffnesses are the defaults of the Stiffnesses block); colliders: the
  /// scene's (e.g. a ground plane); steps: T ≥ 1 (observations.observed has T rows); blocks: at
  /// least one, no repeats. Throws InputError on any invalid argument.
  SimulationSequenceCost(std::shared_ptr<const SoftAvatar> avatar,
                         std::shared_ptr<const Motion> mocap, const SimulableOptions& sim_options,
                         std::vector<Collider> colliders, int steps,
                         SequenceObservations observations, std::vector<SequenceParameter> blocks,
                         const SimulationCostOptions& options = {});

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;

  /// The values the inputs take when they are not parameter blocks, in the block layout: the
  /// base avatar's first num_betas β, the options' stiffnesses, the velocity initialize() sets,
  /// the mocap's targets at steps 1..T (T·72), the base avatar's material coefficients (the
  /// block's entries). Good starting values for the blocks.
  VecX defaultValue(SequenceParameter p) const;
  /// Size of a block of this kind (whether or not it is one of the cost's blocks).
  int blockSize(SequenceParameter p) const;
  /// Position of p among the parameter blocks, −1 if it is not one.
  int blockIndex(SequenceParameter p) const;
  const std::vector<SequenceParameter>& blocks() const { return blocks_; }

  /// The simulated points (T × 3N, layout of SequenceObservations::observed) at the given
  /// parameter blocks (one pointer per block, in order): e.g. to make synthetic observations.
  /// Throws InputError on non-finite or invalid values, Error if a rollout step fails.
  RowMatX simulate(double const* const* parameters) const;

  int numSteps() const { return steps_; }
  int numDofs() const { return num_dofs_; }

 private:
  struct Evaluation;
  /// The points and, for the blocks marked in `wanted`, their Jacobians. Throws on failure.
  void evaluate(double const* const* parameters, Evaluation& out, const std::vector<bool>& wanted,
                bool want_convergence) const;

  std::shared_ptr<const SoftAvatar> avatar_;
  std::shared_ptr<const Motion> mocap_;
  SimulableOptions sim_options_;
  std::vector<Collider> colliders_;
  int steps_ = 0;
  int num_dofs_ = 0;
  int num_betas_ = 0;
  SequenceObservations observations_;
  VecX step_weights_;  // T
  std::vector<SequenceParameter> blocks_;
  SimulationCostOptions options_;
  VecX default_velocity_;            // numDofs
  RowMatX default_targets_;          // T × 72 (empty without tracking)
  VecX base_material_;               // P: the base avatar's (soft models)
  std::vector<int> material_index_;  // the Material block's entries in parameters()
};

}  // namespace flsh::ceres_costs
