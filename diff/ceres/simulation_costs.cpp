// Ceres cost over a simulated sequence (include/flsh/ceres/simulation_costs.h).
#include "flsh/ceres/simulation_costs.h"

#include <algorithm>
#include <cmath>
#include <exception>
#include <string>
#include <utility>
#include <vector>

#include "flsh/body/body_forward.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "flsh/volume/materials.h"

namespace flsh::ceres_costs {

namespace {

constexpr const char* kWho = "SimulationSequenceCost";

std::string count(long n) { return std::to_string(n); }

const char* parameterName(SequenceParameter p) {
  switch (p) {
    case SequenceParameter::Shape:
      return "Shape";
    case SequenceParameter::Stiffnesses:
      return "Stiffnesses";
    case SequenceParameter::InitialVelocity:
      return "InitialVelocity";
    case SequenceParameter::PoseTargets:
      return "PoseTargets";
    case SequenceParameter::Material:
      return "Material";
  }
  return "?";
}

bool allFinite(const double* values, int n) {
  for (int i = 0; i < n; ++i)
    if (!std::isfinite(values[i])) return false;
  return true;
}

}  // namespace

// Unweighted simulated points and their Jacobians with respect to each parameter block.
struct SimulationSequenceCost::Evaluation {
  VecX points;                     // T·3N, row-major T × 3N
  std::vector<RowMatX> jacobians;  // per block: T·3N × size (empty if not requested)
  bool converged = true;
};

SimulationSequenceCost::SimulationSequenceCost(std::shared_ptr<const SoftAvatar> avatar,
                                               std::shared_ptr<const Motion> mocap,
                                               const SimulableOptions& sim_options,
                                               std::vector<Collider> colliders, int steps,
                                               SequenceObservations observations,
                                               std::vector<SequenceParameter> blocks,
                                               const SimulationCostOptions& options)
    : avatar_(std::move(avatar)),
      mocap_(std::move(mocap)),
      sim_options_(sim_options),
      colliders_(std::move(colliders)),
      steps_(steps),
      observations_(std::move(observations)),
      blocks_(std::move(blocks)),
      options_(options) {
  const std::string who = kWho;
  if (!avatar_) throw InputError(who + ": avatar is null");
  if (!avatar_->initialized())
    throw InputError(who + ": avatar is not initialized (call initVolumetricData() first)");
  if (steps_ < 1) throw InputError(who + ": steps = " + count(steps_) + ", expected ≥ 1");
  if (!sim_options_.kinematic_bones.empty())
    throw InputError(
        who + ": sim_options.kinematic_bones has " + count(sim_options_.kinematic_bones.size()) +
        " bones, expected none (the rollout adjoint does not support kinematic bones)");
  const int K = avatar_->body().numBetas();
  num_betas_ = options_.num_betas == -1 ? K : options_.num_betas;
  if (num_betas_ < 1 || num_betas_ > K)
    throw InputError(who + ": options.num_betas = " + count(options_.num_betas) + ", expected 1.." +
                     count(K) + " (or −1 for all)");

  // Observations.
  const SequenceObservations& obs = observations_;
  const int N = obs.numPoints();
  if (N == 0) throw InputError(who + ": observations select no joint and no vertex");
  for (size_t k = 0; k < obs.joints.size(); ++k)
    if (obs.joints[k] < 0 || obs.joints[k] >= 24)
      throw InputError(who + ": observations.joints[" + count(k) + "] = " + count(obs.joints[k]) +
                       ", expected 0..23");
  const int V = avatar_->body().numVertices();
  for (size_t k = 0; k < obs.vertices.size(); ++k)
    if (obs.vertices[k] < 0 || obs.vertices[k] >= V)
      throw InputError(who + ": observations.vertices[" + count(k) +
                       "] = " + count(obs.vertices[k]) + ", expected 0.." + count(V - 1));
  if (obs.observed.rows() != steps_ || obs.observed.cols() != 3 * N)
    throw InputError(who + ": observations.observed has shape " +
                     shapeString({long(obs.observed.rows()), long(obs.observed.cols())}) +
                     ", expected " + shapeString({steps_, 3L * N}) +
                     " (steps × 3 per observed point)");
  if (!obs.observed.allFinite())
    throw InputError(who + ": observations.observed contains NaN or Inf");
  if (obs.step_weights.size() == 0) {
    step_weights_ = VecX::Ones(steps_);
  } else {
    if (obs.step_weights.size() != steps_)
      throw InputError(who + ": observations.step_weights has " + count(obs.step_weights.size()) +
                       " values, expected one per step (" + count(steps_) + ") or none");
    for (int t = 0; t < steps_; ++t)
      if (!(std::isfinite(obs.step_weights[t]) && obs.step_weights[t] >= 0.0))
        throw InputError(who + ": observations.step_weights[" + count(t) +
                         "] must be finite and ≥ 0, got " + std::to_string(obs.step_weights[t]));
    step_weights_ = obs.step_weights;
  }

  // Blocks.
  if (blocks_.empty()) throw InputError(who + ": blocks is empty, expected at least one");
  for (size_t i = 0; i < blocks_.size(); ++i)
    for (size_t j = 0; j < i; ++j)
      if (blocks_[i] == blocks_[j])
        throw InputError(who + ": blocks lists " + parameterName(blocks_[i]) + " twice (entries " +
                         count(j) + " and " + count(i) + ")");
  const bool tracking = mocap_ && sim_options_.track_mocap;
  if (blockIndex(SequenceParameter::PoseTargets) >= 0 && !tracking)
    throw InputError(who +
                     ": blocks lists PoseTargets, but the simulation does not track "
                     "(mocap is null or sim_options.track_mocap is false)");

  // The Material block's entries.
  if (avatar_->hasVolumetricData()) {
    const MaterialModel& model = avatar_->volumetricData().material_model;
    base_material_ = model.parameters();
    const std::vector<std::string> names = model.parameterNames();
    if (options_.material_names.empty()) {
      for (int i = 0; i < int(names.size()); ++i) material_index_.push_back(i);
    } else {
      for (size_t k = 0; k < options_.material_names.size(); ++k) {
        const std::string& name = options_.material_names[k];
        const auto it = std::find(names.begin(), names.end(), name);
        if (it == names.end())
          throw InputError(
              who + ": options.material_names[" + count(k) + "] = '" + name +
              "' is not a material parameter (MaterialModel::parameterNames(), e.g. '" +
              names.front() + "')");
        const int index = int(it - names.begin());
        if (std::find(material_index_.begin(), material_index_.end(), index) !=
            material_index_.end())
          throw InputError(who + ": options.material_names lists '" + name + "' twice");
        material_index_.push_back(index);
      }
    }
  } else if (blockIndex(SequenceParameter::Material) >= 0) {
    throw InputError(who +
                     ": blocks lists Material, but the avatar has no soft tissue (the "
                     "skeleton model has no material)");
  }

  // The defaults of the inputs (also validates the options and colliders by building once).
  auto sim = std::make_shared<Simulable>(avatar_, mocap_, sim_options_);
  sim->setColliders(colliders_);
  num_dofs_ = sim->numDofs();
  sim->initialize();
  default_velocity_ = sim->getVelocity();
  if (tracking) {
    default_targets_.resize(steps_, 72);
    for (int t = 0; t < steps_; ++t) {
      sim->preUpdate();
      default_targets_.row(t) = sim->getParameter(SimParameter::PoseTargets).transpose();
      sim->postUpdate();
    }
  }

  set_num_residuals(steps_ * 3 * N);
  for (SequenceParameter p : blocks_) mutable_parameter_block_sizes()->push_back(blockSize(p));
}

int SimulationSequenceCost::blockSize(SequenceParameter p) const {
  switch (p) {
    case SequenceParameter::Shape:
      return num_betas_;
    case SequenceParameter::Stiffnesses:
      return 4;
    case SequenceParameter::InitialVelocity:
      return num_dofs_;
    case SequenceParameter::PoseTargets:
      return 72 * steps_;
    case SequenceParameter::Material:
      return int(material_index_.size());
  }
  return 0;
}

int SimulationSequenceCost::blockIndex(SequenceParameter p) const {
  const auto it = std::find(blocks_.begin(), blocks_.end(), p);
  return it == blocks_.end() ? -1 : int(it - blocks_.begin());
}

VecX SimulationSequenceCost::defaultValue(SequenceParameter p) const {
  switch (p) {
    case SequenceParameter::Shape:
      return avatar_->betas().head(num_betas_);
    case SequenceParameter::Stiffnesses:
      return Vec4(sim_options_.joint_stiffness, sim_options_.tracking_stiffness,
                  sim_options_.root_stiffness, sim_options_.contact.stiffness);
    case SequenceParameter::InitialVelocity:
      return default_velocity_;
    case SequenceParameter::PoseTargets:
      if (default_targets_.size() == 0)
        throw InputError(std::string(kWho) +
                         "::defaultValue: PoseTargets has no default (the simulation does not "
                         "track a mocap)");
      return Eigen::Map<const VecX>(default_targets_.data(), default_targets_.size());
    case SequenceParameter::Material: {
      if (material_index_.empty())
        throw InputError(std::string(kWho) +
                         "::defaultValue: Material has no default (the avatar has no soft tissue)");
      VecX values(material_index_.size());
      for (size_t j = 0; j < material_index_.size(); ++j)
        values[j] = base_material_[material_index_[j]];
      return values;
    }
  }
  return VecX();
}

void SimulationSequenceCost::evaluate(double const* const* parameters, Evaluation& out,
                                      const std::vector<bool>& wanted,
                                      bool want_convergence) const {
  const std::string who = std::string(kWho) + "::evaluate";
  for (size_t i = 0; i < blocks_.size(); ++i)
    if (!allFinite(parameters[i], blockSize(blocks_[i])))
      throw InputError(who + ": parameter block " + count(i) + " (" + parameterName(blocks_[i]) +
                       ") contains NaN or Inf");
  const int T = steps_, n = num_dofs_, N = observations_.numPoints();
  const int nj = int(observations_.joints.size()), nv = int(observations_.vertices.size());
  const int K = avatar_->body().numBetas();
  const bool want_jacobians = std::find(wanted.begin(), wanted.end(), true) != wanted.end();

  // The avatar of the shape block's β and the material block's coefficients, with the base
  // avatar's discretization (the base avatar itself when neither changes).
  std::shared_ptr<const SoftAvatar> avatar = avatar_;
  const int shape_block = blockIndex(SequenceParameter::Shape);
  if (shape_block >= 0) {
    VecX betas = avatar_->betas();
    betas.head(num_betas_) = Eigen::Map<const VecX>(parameters[shape_block], num_betas_);
    if (betas != avatar_->betas()) avatar = avatar_->withShape(betas);
  }
  const int material_block = blockIndex(SequenceParameter::Material);
  if (material_block >= 0) {
    VecX material = base_material_;
    for (size_t j = 0; j < material_index_.size(); ++j)
      material[material_index_[j]] = parameters[material_block][j];
    if (material != base_material_) {
      MaterialModel model = avatar->volumetricData().material_model;
      model.setParameters(material);
      avatar = avatar->withMaterial(model);
    }
  }

  // Forward rollout with the blocks as inputs.
  auto sim = std::make_shared<Simulable>(avatar, mocap_, sim_options_);
  sim->setColliders(colliders_);
  Rollout rollout(sim, options_.rollout);
  RolloutInputs inputs;
  const int stiffness_block = blockIndex(SequenceParameter::Stiffnesses);
  const int velocity_block = blockIndex(SequenceParameter::InitialVelocity);
  const int targets_block = blockIndex(SequenceParameter::PoseTargets);
  if (stiffness_block >= 0)
    inputs.stiffnesses = Eigen::Map<const VecX>(parameters[stiffness_block], 4);
  if (velocity_block >= 0)
    inputs.initial_velocity = Eigen::Map<const VecX>(parameters[velocity_block], n);
  if (targets_block >= 0)
    inputs.pose_targets = Eigen::Map<const RowMatX>(parameters[targets_block], T, 72);
  rollout.run(T, inputs);
  out.converged = true;
  for (int t = 1; t <= T; ++t)
    out.converged = out.converged && rollout.tape().stepInfo(t).converged;
  if (want_convergence && !out.converged) return;

  // Points per step and, for the Jacobians, their derivatives with respect to the state vector
  // (C_t, 3N × n), for the soft surface also to the previous state vector (P_t, 3N × n: the pose
  // blend held from q_{t−1}), and for vertices directly to β (D_t, 3N × K).
  const bool soft = sim->hasSoftTissue();
  const RowMatX& states = rollout.states();
  out.points.resize(T * 3 * N);
  std::vector<MatX> C(want_jacobians ? T : 0), P(want_jacobians && soft && nv ? T : 0),
      D(want_jacobians && nv ? T : 0);
  std::unique_ptr<Simulable> probe;  // poses the skeleton's skin at a recorded state
  if (nv && !soft) probe = std::make_unique<Simulable>(avatar, nullptr, sim_options_);
  const MatX& joints_shape = avatar->restJointsShapeJacobian();
  const long num_vertices = avatar->body().numVertices();
  for (int t = 0; t < T; ++t) {
    double* points = out.points.data() + t * 3 * N;
    for (int k = 0; k < nj; ++k)
      for (int c = 0; c < 3; ++c) points[3 * k + c] = states(t, 6 * observations_.joints[k] + c);
    if (want_jacobians) {
      C[t] = MatX::Zero(3 * N, n);
      for (int k = 0; k < nj; ++k)
        for (int c = 0; c < 3; ++c) C[t](3 * k + c, 6 * observations_.joints[k] + c) = 1.0;
    }
    if (!nv) continue;
    if (soft) {
      const MatX3 surface = rollout.vertices(t + 1);
      for (int k = 0; k < nv; ++k)
        for (int c = 0; c < 3; ++c)
          points[3 * (nj + k) + c] = surface(observations_.vertices[k], c);
      if (!want_jacobians) continue;
      // One pull-back of the surface per observed coordinate.
      P[t] = MatX::Zero(3 * N, n);
      D[t] = MatX::Zero(3 * N, K);
      MatX3 unit = MatX3::Zero(num_vertices, 3);
      for (int k = 0; k < nv; ++k)
        for (int c = 0; c < 3; ++c) {
          const int row = 3 * (nj + k) + c;
          unit(observations_.vertices[k], c) = 1.0;
          const Rollout::VerticesCotangent pulled = rollout.verticesCotangent(t + 1, unit);
          unit(observations_.vertices[k], c) = 0.0;
          C[t].row(row) = pulled.state.transpose();
          if (pulled.previous_state.size()) P[t].row(row) = pulled.previous_state.transpose();
          if (pulled.direct.shape.size()) D[t].row(row) = pulled.direct.shape.transpose();
        }
      continue;
    }
    probe->setState(states.row(t).transpose());
    PosedBodyJacobians jac;
    const PosedBody posed = poseBody(avatar->body(), avatar->betas(), probe->getPose(),
                                     probe->getTrans(), want_jacobians ? &jac : nullptr);
    for (int k = 0; k < nv; ++k)
      for (int c = 0; c < 3; ++c)
        points[3 * (nj + k) + c] = posed.vertices(observations_.vertices[k], c);
    if (!want_jacobians) continue;
    // d vertices / d(pose, trans), then through d(pose, trans)/d increments and the chart
    // (δt = dt, δω = J_l(r) dr per bone) to the state vector.
    MatX pose_trans(3 * nv, 75);
    D[t] = MatX::Zero(3 * N, K);
    for (int k = 0; k < nv; ++k)
      for (int c = 0; c < 3; ++c) {
        const int row = 3 * observations_.vertices[k] + c;
        pose_trans.row(3 * k + c) << jac.vertices_pose.row(row), jac.vertices_trans.row(row);
        // β moves the vertex directly and through trans = t_0 − J_0(β).
        D[t].row(3 * (nj + k) + c) =
            jac.vertices_betas.row(row) - jac.vertices_trans.row(row) * joints_shape.topRows<3>();
      }
    MatX increments = pose_trans.lazyProduct(probe->getStateJacobian());  // 3nv × n
    for (int b = 0; b < n / 6; ++b) {
      const Vec3 r = states.row(t).segment<3>(6 * b + 3).transpose();
      increments.middleCols<3>(6 * b + 3) =
          increments.middleCols<3>(6 * b + 3) * leftJacobianSO3(r);
    }
    C[t].bottomRows(3 * nv) = increments;
  }
  if (!want_jacobians) return;

  out.jacobians.assign(blocks_.size(), RowMatX());
  for (size_t i = 0; i < blocks_.size(); ++i)
    if (wanted[i]) out.jacobians[i] = RowMatX::Zero(T * 3 * N, blockSize(blocks_[i]));
  const int P_all = int(base_material_.size());

  if (options_.jacobians == SequenceJacobians::ForwardSensitivities) {
    // One unit direction per column of every block.
    std::vector<RolloutVariables> directions;
    std::vector<std::pair<int, int>> columns;  // (block, column) of each direction
    for (size_t i = 0; i < blocks_.size(); ++i)
      for (int j = 0; wanted[i] && j < blockSize(blocks_[i]); ++j) {
        RolloutVariables d;
        switch (blocks_[i]) {
          case SequenceParameter::Shape:
            d.shape = VecX::Unit(K, j);
            break;
          case SequenceParameter::Stiffnesses:
            d.stiffnesses = VecX::Unit(4, j);
            break;
          case SequenceParameter::InitialVelocity:
            d.initial_velocity = VecX::Unit(n, j);
            break;
          case SequenceParameter::PoseTargets:
            d.pose_targets = RowMatX::Zero(T, 72);
            d.pose_targets(j / 72, j % 72) = 1.0;
            break;
          case SequenceParameter::Material:
            d.material = VecX::Unit(P_all, material_index_[size_t(j)]);
            break;
        }
        directions.push_back(std::move(d));
        columns.emplace_back(int(i), j);
      }
    std::vector<VecX> initial;  // dq_0 per direction
    const std::vector<RowMatX> tangents = rollout.forwardSensitivities(directions, &initial);
    const int num_directions = int(tangents.size());
    MatX Q(n, num_directions), Q_previous(n, num_directions);  // column d: dq along direction d
    for (int d = 0; d < num_directions; ++d) Q.col(d) = initial[size_t(d)];
    for (int t = 0; t < T; ++t) {
      Q_previous.swap(Q);
      for (int d = 0; d < num_directions; ++d) Q.col(d) = tangents[size_t(d)].row(t).transpose();
      // Coefficient-based product: Eigen's GEMM would open an OpenMP region per step, which
      // waits for a descheduled thread on a busy machine (docs/benchmarks.md, Adjoint).
      MatX rows = C[t].lazyProduct(Q);  // 3N × directions
      if (!P.empty()) rows += P[t].lazyProduct(Q_previous);
      for (int d = 0; d < num_directions; ++d) {
        const auto [block, column] = columns[size_t(d)];
        out.jacobians[block].block(t * 3 * N, column, 3 * N, 1) = rows.col(d);
        if (blocks_[block] == SequenceParameter::Shape && nv)
          out.jacobians[block].block(t * 3 * N, column, 3 * N, 1) += D[t].col(column);
      }
    }
    return;
  }

  // Adjoint: one reverse sweep per residual row of a weighted step, for the blocks' groups only
  // (the initial velocity's cotangent comes with every sweep).
  std::vector<SimParameter> groups;
  for (size_t i = 0; i < blocks_.size(); ++i) {
    if (!wanted[i]) continue;
    switch (blocks_[i]) {
      case SequenceParameter::Shape:
        groups.push_back(SimParameter::Shape);
        break;
      case SequenceParameter::Stiffnesses:
        groups.push_back(SimParameter::Stiffnesses);
        break;
      case SequenceParameter::PoseTargets:
        groups.push_back(SimParameter::PoseTargets);
        break;
      case SequenceParameter::Material:
        groups.push_back(SimParameter::Material);
        break;
      case SequenceParameter::InitialVelocity:
        break;
    }
  }
  if (groups.empty()) groups.push_back(SimParameter::Stiffnesses);  // empty would mean all
  RowMatX cotangent = RowMatX::Zero(T, n);
  for (int t = 0; t < T; ++t) {
    if (step_weights_[t] == 0.0) continue;  // rows that Evaluate zeroes anyway
    for (int r = 0; r < 3 * N; ++r) {
      cotangent.row(t) = C[t].row(r);
      RolloutVariables direct;
      if (nv) direct.shape = D[t].row(r).transpose();
      if (!P.empty()) {  // the pose blend held from the previous state
        if (t > 0)
          cotangent.row(t - 1) = P[t].row(r);
        else
          direct.initial_state = P[t].row(r).transpose();
      }
      const RolloutVariables g = rollout.backward(cotangent, direct, groups);
      cotangent.row(t).setZero();
      if (t > 0) cotangent.row(t - 1).setZero();
      const int row = t * 3 * N + r;
      for (size_t i = 0; i < blocks_.size(); ++i) {
        if (!wanted[i]) continue;
        RowMatX& J = out.jacobians[i];
        switch (blocks_[i]) {
          case SequenceParameter::Shape:
            J.row(row) = g.shape.head(num_betas_).transpose();
            break;
          case SequenceParameter::Stiffnesses:
            J.row(row) = g.stiffnesses.transpose();
            break;
          case SequenceParameter::InitialVelocity:
            J.row(row) = g.initial_velocity.transpose();
            break;
          case SequenceParameter::PoseTargets:
            J.row(row) = Eigen::Map<const VecX>(g.pose_targets.data(), 72 * T).transpose();
            break;
          case SequenceParameter::Material:
            for (size_t j = 0; j < material_index_.size(); ++j)
              J(row, Eigen::Index(j)) = g.material[material_index_[j]];
            break;
        }
      }
    }
  }
}

bool SimulationSequenceCost::Evaluate(double const* const* parameters, double* residuals,
                                      double** jacobians) const {
  std::vector<bool> wanted(blocks_.size(), false);
  bool want_jacobians = false;
  if (jacobians)
    for (size_t i = 0; i < blocks_.size(); ++i) {
      wanted[i] = jacobians[i] != nullptr;  // null: a block Ceres holds constant
      want_jacobians = want_jacobians || wanted[i];
    }
  Evaluation e;
  try {
    evaluate(parameters, e, wanted, options_.require_convergence);
  } catch (const std::exception&) {
    return false;  // invalid parameters, a failed step or a singular step Hessian
  }
  if (options_.require_convergence && !e.converged) return false;
  const int N3 = 3 * observations_.numPoints();
  for (int t = 0; t < steps_; ++t) {
    const double w = step_weights_[t];
    Eigen::Map<VecX>(residuals + t * N3, N3) =
        w * (e.points.segment(t * N3, N3) - observations_.observed.row(t).transpose());
  }
  if (!want_jacobians) return true;
  for (size_t i = 0; i < blocks_.size(); ++i) {
    if (!wanted[i]) continue;
    Eigen::Map<RowMatX> J(jacobians[i], num_residuals(), blockSize(blocks_[i]));
    for (int t = 0; t < steps_; ++t)
      J.middleRows(t * N3, N3) = step_weights_[t] * e.jacobians[i].middleRows(t * N3, N3);
  }
  return true;
}

RowMatX SimulationSequenceCost::simulate(double const* const* parameters) const {
  Evaluation e;
  evaluate(parameters, e, std::vector<bool>(blocks_.size(), false), false);
  if (options_.require_convergence && !e.converged)
    throw Error(std::string(kWho) +
                "::simulate: Newton did not converge at some step (options.rollout.newton)");
  const int N3 = 3 * observations_.numPoints();
  return Eigen::Map<const RowMatX>(e.points.data(), steps_, N3);
}

}  // namespace flsh::ceres_costs
