// Rollout: forward simulation with a recorded tape, reverse pass and forward sensitivities of
// one Simulable (skeleton, FEM or ROM), in the user's coordinates (see rollout.h).
#include "flsh/diff/rollout.h"

#include <algorithm>
#include <string>

#include "flsh/body/body_forward.h"
#include "flsh/core/error.h"
#include "flsh/solve/scene.h"

namespace flsh {

namespace {

void checkVector(const VecX& v, long expected, const std::string& who, const std::string& name,
                 bool empty_ok = true) {
  if (empty_ok && v.size() == 0) return;
  if (v.size() != expected)
    throw InputError(who + ": " + name + " has " + std::to_string(v.size()) + " values, expected " +
                     std::to_string(expected) + (empty_ok ? " (or none)" : ""));
  if (!v.allFinite()) throw InputError(who + ": " + name + " contains NaN or Inf");
}

void checkMatrix(const RowMatX& m, long rows, long cols, const std::string& who,
                 const std::string& name, bool empty_ok = true) {
  if (empty_ok && m.size() == 0) return;
  if (m.rows() != rows || m.cols() != cols)
    throw InputError(who + ": " + name + " has shape " +
                     shapeString({long(m.rows()), long(m.cols())}) + ", expected " +
                     shapeString({rows, cols}) + (empty_ok ? " (or empty)" : ""));
  if (!m.allFinite()) throw InputError(who + ": " + name + " contains NaN or Inf");
}

double dotOrZero(const VecX& a, const VecX& b) { return a.size() && b.size() ? a.dot(b) : 0.0; }
double dotOrZero(const RowMatX& a, const RowMatX& b) {
  return a.size() && b.size() ? (a.array() * b.array()).sum() : 0.0;
}

// Restores the simulable's step data on scope exit.
class RestoreStepOnExit {
 public:
  explicit RestoreStepOnExit(Simulable& s) : s_(s), saved_(s.saveStep()) {}
  ~RestoreStepOnExit() { s_.restoreStep(saved_); }

 private:
  Simulable& s_;
  SimulableStep saved_;
};

}  // namespace

VecX* RolloutVariables::global(SimParameter p) {
  switch (p) {
    case SimParameter::Shape:
      return &shape;
    case SimParameter::RestJoints:
      return &rest_joints;
    case SimParameter::BoneInertia:
      return &bone_inertia;
    case SimParameter::Stiffnesses:
      return &stiffnesses;
    case SimParameter::ColliderOffsets:
      return &collider_offsets;
    case SimParameter::Material:
      return &material;
    case SimParameter::PoseTargets:
    case SimParameter::RootTranslationTarget:
      return nullptr;
  }
  return nullptr;
}

RowMatX* RolloutVariables::perStep(SimParameter p) {
  if (p == SimParameter::PoseTargets) return &pose_targets;
  if (p == SimParameter::RootTranslationTarget) return &root_targets;
  return nullptr;
}

const VecX* RolloutVariables::global(SimParameter p) const {
  return const_cast<RolloutVariables&>(*this).global(p);
}

const RowMatX* RolloutVariables::perStep(SimParameter p) const {
  return const_cast<RolloutVariables&>(*this).perStep(p);
}

double dot(const RolloutVariables& a, const RolloutVariables& b) {
  double sum = 0.0;
  for (const SimParameterInfo& info : simParameters())
    sum += info.per_step ? dotOrZero(*a.perStep(info.id), *b.perStep(info.id))
                         : dotOrZero(*a.global(info.id), *b.global(info.id));
  return sum + dotOrZero(a.initial_state, b.initial_state) +
         dotOrZero(a.initial_velocity, b.initial_velocity);
}

namespace {

template <class M>
void addMember(M& into, const M& add, const char* name) {
  if (add.size() == 0) return;
  if (into.size() == 0) {
    into = add;
    return;
  }
  if (into.rows() != add.rows() || into.cols() != add.cols())
    throw InputError(std::string("accumulate: ") + name + " has shapes " +
                     shapeString({long(into.rows()), long(into.cols())}) + " and " +
                     shapeString({long(add.rows()), long(add.cols())}) + ", expected equal");
  into += add;
}

}  // namespace

void accumulate(RolloutVariables& into, const RolloutVariables& add) {
  for (const SimParameterInfo& info : simParameters()) {
    if (info.per_step)
      addMember(*into.perStep(info.id), *add.perStep(info.id), info.name);
    else
      addMember(*into.global(info.id), *add.global(info.id), info.name);
  }
  addMember(into.initial_state, add.initial_state, "initial_state");
  addMember(into.initial_velocity, add.initial_velocity, "initial_velocity");
}

Rollout::Rollout(std::shared_ptr<Simulable> simulable, const RolloutOptions& options)
    : model_(simulable), simulable_(std::move(simulable)), options_(options) {
  base_stiffnesses_ = simulable_->getParameter(SimParameter::Stiffnesses);
  base_colliders_ = simulable_->colliders();
  tape_.setSolveOptions(options_.tape_solve);  // InputError now, not at the first run
}

Rollout::~Rollout() = default;

int Rollout::numSteps() const { return tape_.hasInitial() ? tape_.numSteps() : 0; }
int Rollout::numDofs() const { return simulable_->numDofs(); }
const RowMatX& Rollout::states() const { return states_; }
const VecX& Rollout::initialState() const { return initial_state_; }

void Rollout::checkVariables(const RolloutVariables& v, const std::string& who) const {
  const int T = numSteps(), n = numDofs();
  const Simulable& sim = *simulable_;
  checkVector(v.shape, sim.parameterSize(SimParameter::Shape), who, "shape");
  checkVector(v.rest_joints, 72, who, "rest_joints");
  checkVector(v.bone_inertia, sim.parameterSize(SimParameter::BoneInertia), who, "bone_inertia");
  checkMatrix(v.pose_targets, T, 72, who, "pose_targets");
  checkMatrix(v.root_targets, T, 3, who, "root_targets");
  checkVector(v.stiffnesses, 4, who, "stiffnesses");
  checkVector(v.collider_offsets, 3 * long(base_colliders_.size()), who, "collider_offsets");
  if (!sim.hasSoftTissue() && v.material.size())
    throw InputError(who +
                     ": material: the articulated skeleton has no soft-tissue material; "
                     "leave material empty");
  checkVector(v.material, sim.parameterSize(SimParameter::Material), who, "material");
  checkVector(v.initial_state, n, who, "initial_state");
  checkVector(v.initial_velocity, n, who, "initial_velocity");
}

void Rollout::requireRun(const char* who) const {
  if (numSteps() == 0)
    throw Error(std::string("Rollout::") + who + ": no rollout recorded (call run() first)");
}

// Derivatives are exact for converged steps only: a step Newton left unconverged is reported,
// never differentiated.
void Rollout::requireConverged(const char* who) const {
  for (int t = 1; t <= numSteps(); ++t) {
    const TapeStepInfo& info = tape_.stepInfo(t);
    if (!info.converged)
      throw Error(std::string("Rollout::") + who + ": step " + std::to_string(t) +
                  " did not converge (" + info.newton_message +
                  "), so its derivatives would not be those of the simulated motion; raise "
                  "RolloutOptions::newton.max_iterations or loosen its gradient_tolerance");
  }
}

void Rollout::run(int steps, const RolloutInputs& in) {
  const std::string who = "Rollout::run";
  Simulable& sim = *simulable_;
  const int n = sim.numDofs(), nc = int(base_colliders_.size());
  if (steps < 1) throw InputError(who + ": steps = " + std::to_string(steps) + ", expected ≥ 1");
  checkMatrix(in.pose_targets, steps, 72, who, "inputs.pose_targets (steps × 72, rad)");
  checkMatrix(in.root_targets, steps, 3, who, "inputs.root_targets (steps × 3, m)");
  checkVector(in.initial_state, n, who, "inputs.initial_state");
  checkVector(in.initial_velocity, n, who, "inputs.initial_velocity");
  checkVector(in.stiffnesses, 4, who, "inputs.stiffnesses");
  checkVector(in.collider_offsets, 3 * nc, who,
              "inputs.collider_offsets (3 per collider, " + std::to_string(nc) + " colliders)");
  const bool tracking = sim.options().track_mocap && sim.mocap();
  if ((in.pose_targets.size() || in.root_targets.size()) && !tracking)
    throw InputError(who +
                     ": pose or root targets given, but the simulable has no tracking springs "
                     "(it was built without mocap or with options.track_mocap = false)");
  const VecX stiffnesses = in.stiffnesses.size() ? in.stiffnesses : base_stiffnesses_;
  sim.setParameter(SimParameter::Stiffnesses, stiffnesses);  // validates (≥ 0) before changes

  // Colliders: the remembered ones, each path shifted as a whole.
  std::vector<Collider> colliders = base_colliders_;
  if (in.collider_offsets.size())
    for (int k = 0; k < nc; ++k) {
      ColliderPath& path = colliders[k].path;
      const Vec3 shift = in.collider_offsets.segment<3>(3 * k);
      if (path.times.empty()) {
        path.times = {0.0};
        path.offsets = {Vec3::Zero()};
      }
      for (Vec3& o : path.offsets) o += shift;
    }
  SceneOptions scene_options;
  scene_options.newton = options_.newton;
  scene_options.soft_tissue_newton = options_.soft_tissue_newton;
  scene_options.reduced_newton = options_.reduced_newton;
  Scene scene(scene_options);
  scene.addSimulable(simulable_);
  for (const Collider& c : colliders) scene.addCollider(c);

  // Initial conditions.
  sim.initialize();
  state_from_initialize_ = in.initial_state.size() == 0;
  velocity_from_initialize_ = in.initial_velocity.size() == 0;
  sim.getInitialStateRestJointsJacobian(&initial_state_joints_jacobian_,
                                        &initial_velocity_joints_jacobian_);
  if (!state_from_initialize_) {
    const VecX v = velocity_from_initialize_ ? sim.getVelocity() : in.initial_velocity;
    sim.setState(in.initial_state);
    sim.postUpdate();           // q_n = q_0
    if (sim.hasSoftTissue()) {  // the pose blend held from q_0, as step 1 will hold it
      SimulableStep step = sim.saveStep();
      step.pose_blend.resize(0, 3);
      sim.restoreStep(step);
    }
    sim.setVelocity(v);
  } else if (!velocity_from_initialize_) {
    sim.setVelocity(in.initial_velocity);
  }
  const bool fem = sim.hasSoftTissue() && !sim.hasReducedModel();
  const bool snapshots = options_.tape_storage == RolloutOptions::TapeStorage::Snapshots ||
                         (options_.tape_storage == RolloutOptions::TapeStorage::Auto && fem);
  tape_.setStorage(snapshots ? Tape::Storage::Snapshots : Tape::Storage::Factors);
  tape_.recordInitial(model_);
  initial_state_ = sim.getState();
  states_.resize(steps, n);

  // Each step is the scene's (its Newton settings per model, its solver kept across steps),
  // with the target overrides after preUpdate and the tape recorded before postUpdate.
  Scene::StepHooks hooks;
  int t = 0;
  hooks.after_pre_update = [&] {
    if (in.pose_targets.size())
      sim.setParameter(SimParameter::PoseTargets, in.pose_targets.row(t - 1).transpose());
    if (in.root_targets.size()) {
      const Vec3 J0 = sim.getParameter(SimParameter::RestJoints).head<3>();
      sim.setParameter(SimParameter::RootTranslationTarget,
                       J0 + in.root_targets.row(t - 1).transpose());
    }
  };
  hooks.before_post_update = [&](const NewtonResult& result) {
    TapeStepInfo info;
    info.converged = result.converged;
    info.newton_iterations = result.iterations;
    info.line_search_steps = result.line_search_steps;
    info.psd_fallbacks = result.psd_fallbacks;
    info.gradient_norm = result.gradient_norm;
    info.newton_message = result.message;
    tape_.recordStep(model_, info);
    states_.row(t - 1) = sim.getState().transpose();
  };
  for (t = 1; t <= steps; ++t) scene.step(hooks);
}

RowMatX Rollout::joints() const {
  RowMatX J(states_.rows(), 72);
  for (int t = 0; t < states_.rows(); ++t)
    for (int b = 0; b < 24; ++b) J.row(t).segment<3>(3 * b) = states_.row(t).segment<3>(6 * b);
  return J;
}

MatX3 Rollout::vertices(int t) const {
  requireRun("vertices");
  if (t < 0 || t > numSteps())
    throw InputError("Rollout::vertices: t = " + std::to_string(t) + ", expected 0.." +
                     std::to_string(numSteps()));
  RestoreStepOnExit restore(*simulable_);
  auto& model = const_cast<SimulableAdjointModel&>(model_);
  model.restoreStep(t == 0 ? tape_.initialSnapshot() : tape_.stepSnapshot(t));
  return simulable_->getVertices();
}

VecX Rollout::jointsCotangent(const MatX3& dL_djoints) const {
  if (dL_djoints.rows() != 24)
    throw InputError("Rollout::jointsCotangent: dL_djoints has shape " +
                     shapeString({long(dL_djoints.rows()), 3}) + ", expected (24, 3)");
  if (!dL_djoints.allFinite())
    throw InputError("Rollout::jointsCotangent: dL_djoints contains NaN or Inf");
  VecX a = VecX::Zero(numDofs());
  for (int b = 0; b < 24; ++b) a.segment<3>(6 * b) = dL_djoints.row(b).transpose();
  return a;
}

// vertices = poseBody(β, θ(q), trans(q)) with trans = t_0 − J_0(β): the state part goes through
// d(θ, trans)/dq (increments) and the chart; β enters directly and through J_0 in trans.
Rollout::VerticesCotangent Rollout::verticesCotangent(int t, const MatX3& dL_dvertices) const {
  requireRun("verticesCotangent");
  const SoftAvatar& avatar = simulable_->avatar();
  const long nv = avatar.body().numVertices();
  if (dL_dvertices.rows() != nv)
    throw InputError("Rollout::verticesCotangent: dL_dvertices has shape " +
                     shapeString({long(dL_dvertices.rows()), 3}) + ", expected " +
                     shapeString({nv, 3}));
  if (!dL_dvertices.allFinite())
    throw InputError("Rollout::verticesCotangent: dL_dvertices contains NaN or Inf");
  if (t < 0 || t > numSteps())
    throw InputError("Rollout::verticesCotangent: t = " + std::to_string(t) + ", expected 0.." +
                     std::to_string(numSteps()));
  RestoreStepOnExit restore(*simulable_);
  auto& model = const_cast<SimulableAdjointModel&>(model_);
  const auto snapshot = [&](int step) -> const StepSnapshot& {
    return step == 0 ? tape_.initialSnapshot() : tape_.stepSnapshot(step);
  };
  model.restoreStep(snapshot(t));
  const Eigen::Map<const VecX> g(dL_dvertices.data(), 3 * nv);  // row-major: 3i + c
  VerticesCotangent out;
  if (simulable_->hasSoftTissue()) {
    // The simulated surface x(q_t), skinned with the pose blend held from q_{t−1} (at t = 0:
    // from q_0 itself).
    VecX increments, previous;
    simulable_->getNodesCotangents(dL_dvertices, &increments, &previous, &out.direct.rest_joints,
                                   &out.direct.shape);
    chainShapeCotangent(avatar, out.direct.rest_joints, VecX(), out.direct.shape);
    if (t == 0) increments += previous;
    out.state = model.incrementToStateCotangent(increments);
    if (t > 0)  // at q_{t−1}, the state recorded before step t
      out.previous_state = model.incrementToStateCotangentAt(
          t == 1 ? initial_state_ : VecX(states_.row(t - 2).transpose()), previous);
    return out;
  }
  PosedBodyJacobians jac;
  poseBody(avatar.body(), avatar.betas(), simulable_->getPose(), simulable_->getTrans(), &jac);
  VecX pose_trans(75);
  pose_trans.head<72>() = jac.vertices_pose.transpose() * g;
  pose_trans.tail<3>() = jac.vertices_trans.transpose() * g;
  out.state =
      model.incrementToStateCotangent(simulable_->getStateJacobian().transpose() * pose_trans);
  // trans = t_0 − J_0 moves with the root joint, and J_0 with β.
  out.direct.rest_joints = VecX::Zero(72);
  out.direct.rest_joints.head<3>() = -pose_trans.tail<3>();
  out.direct.shape = jac.vertices_betas.transpose() * g;
  chainShapeCotangent(avatar, out.direct.rest_joints, VecX(), out.direct.shape);
  return out;
}

Rollout::TrajectoryCotangent Rollout::trajectoryCotangent(const RowMatX& dL_djoints,
                                                          const RowMatX& dL_dvertices) const {
  requireRun("trajectoryCotangent");
  const std::string who = "Rollout::trajectoryCotangent";
  const int T = numSteps();
  const long nv = simulable_->avatar().body().numVertices();
  checkMatrix(dL_djoints, T, 72, who, "dL_djoints (steps × 72)");
  checkMatrix(dL_dvertices, T, 3 * nv, who, "dL_dvertices (steps × 3·#vertices)");
  TrajectoryCotangent out;
  out.states = RowMatX::Zero(T, numDofs());
  for (int t = 1; t <= T && dL_djoints.size(); ++t)
    out.states.row(t - 1) +=
        jointsCotangent(Eigen::Map<const MatX3>(dL_djoints.row(t - 1).data(), 24, 3)).transpose();
  if (dL_dvertices.size() && simulable_->hasSoftTissue()) {
    softSurfaceCotangent(dL_dvertices, out);
    return out;
  }
  for (int t = 1; t <= T && dL_dvertices.size(); ++t) {
    const VerticesCotangent c =
        verticesCotangent(t, Eigen::Map<const MatX3>(dL_dvertices.row(t - 1).data(), nv, 3));
    out.states.row(t - 1) += c.state.transpose();
    if (c.previous_state.size()) {
      if (t > 1)
        out.states.row(t - 2) += c.previous_state.transpose();
      else
        addMember(out.direct.initial_state, c.previous_state, "initial_state");
    }
    accumulate(out.direct, c.direct);
  }
  return out;
}

// verticesCotangent of every step, summed as above, with the surfaces of all steps in one call
// (Simulable::getNodesCotangentsOfFrames: the pose blend shapes and the soft basis are read once
// for all steps, not once per step; ~34 MB and ~12 MB at full size).
void Rollout::softSurfaceCotangent(const RowMatX& dL_dvertices, TrajectoryCotangent& out) const {
  const int T = numSteps();
  auto& model = const_cast<SimulableAdjointModel&>(model_);
  RowMatX state, previous;
  RolloutVariables direct;
  simulable_->getNodesCotangentsOfFrames(surfaceFrames(), dL_dvertices, &state, &previous,
                                         &direct.rest_joints, &direct.shape);
  for (int t = 1; t <= T; ++t) {
    out.states.row(t - 1) += model
                                 .incrementToStateCotangentAt(states_.row(t - 1).transpose(),
                                                              state.row(t - 1).transpose())
                                 .transpose();
    // Step t's pose blend is held from q_{t−1}: its cotangent goes to row t − 2 (q_0: direct).
    const VecX at = t == 1 ? initial_state_ : VecX(states_.row(t - 2).transpose());
    const VecX a = model.incrementToStateCotangentAt(at, previous.row(t - 1).transpose());
    if (t > 1)
      out.states.row(t - 2) += a.transpose();
    else
      addMember(out.direct.initial_state, a, "initial_state");
  }
  chainShapeCotangent(simulable_->avatar(), direct.rest_joints, VecX(), direct.shape);
  accumulate(out.direct, direct);
}

std::vector<SurfaceFrame> Rollout::surfaceFrames() const {
  RestoreStepOnExit restore(*simulable_);
  auto& model = const_cast<SimulableAdjointModel&>(model_);
  std::vector<SurfaceFrame> frames;
  frames.reserve(size_t(numSteps()));
  for (int t = 1; t <= numSteps(); ++t) {
    model.restoreStep(tape_.stepSnapshot(t));
    frames.push_back(simulable_->getSurfaceFrame());
  }
  return frames;
}

RowMatX Rollout::vertexTrajectory() const {
  requireRun("vertexTrajectory");
  if (simulable_->hasSoftTissue()) return simulable_->getNodesOfFrames(surfaceFrames());
  const long nv = simulable_->avatar().body().numVertices();
  RowMatX all(numSteps(), 3 * nv);
  for (int t = 1; t <= numSteps(); ++t) {
    const MatX3 v = vertices(t);
    all.row(t - 1) = Eigen::Map<const Eigen::RowVectorXd>(v.data(), 3 * nv);
  }
  return all;
}

RolloutVariables Rollout::backward(const RowMatX& dL_dstates, const RolloutVariables& direct,
                                   const std::vector<SimParameter>& groups) {
  requireRun("backward");
  requireConverged("backward");
  const std::string who = "Rollout::backward";
  checkMatrix(dL_dstates, numSteps(), numDofs(), who, "dL_dstates (steps × numDofs)", false);
  checkVariables(direct, who + ": direct");
  struct WantedGroups {  // all groups again on exit, also when the sweep throws
    SimulableAdjointModel& model;
    ~WantedGroups() { model.setWantedGroups({}); }
  } wanted{model_};
  model_.setWantedGroups(groups);
  const AdjointResult r = adjointSweep(model_, tape_, dL_dstates);
  RolloutVariables g;
  for (const SimParameterInfo& info : simParameters()) {
    if (info.per_step)
      *g.perStep(info.id) = r.per_step[size_t(info.id)];
    else
      *g.global(info.id) = r.global[size_t(info.id)];
  }
  g.initial_state = r.initial_state;
  g.initial_velocity = r.initial_velocity;
  // The initial conditions initialize() sets move with the rest joints (and so with β), both
  // through the dynamics and through the loss's direct dependence on them (e.g. the soft
  // surface of step 1, skinned with the pose blend of q_0).
  VecX initial_joints = VecX::Zero(72);
  if (state_from_initialize_) {
    VecX a0 = r.initial_state_increment;
    if (direct.initial_state.size())
      a0 += model_.stateToIncrementCotangentAt(initial_state_, direct.initial_state);
    initial_joints += initial_state_joints_jacobian_.transpose() * a0;
  }
  if (velocity_from_initialize_) {
    VecX v0 = r.initial_velocity;
    if (direct.initial_velocity.size()) v0 += direct.initial_velocity;
    initial_joints += initial_velocity_joints_jacobian_.transpose() * v0;
  }
  g.rest_joints += initial_joints;
  if (g.shape.size()) chainShapeCotangent(simulable_->avatar(), initial_joints, VecX(), g.shape);
  accumulate(g, direct);
  if (!groups.empty())
    for (const SimParameterInfo& info : simParameters())
      if (std::find(groups.begin(), groups.end(), info.id) == groups.end()) {
        if (info.per_step)
          *g.perStep(info.id) = RowMatX();
        else
          *g.global(info.id) = VecX();
      }
  return g;
}

std::vector<RowMatX> Rollout::forwardSensitivities(const std::vector<RolloutVariables>& directions,
                                                   std::vector<VecX>* initial_states) {
  requireRun("forwardSensitivities");
  requireConverged("forwardSensitivities");
  const std::vector<ParameterGroupInfo> groups = model_.parameterGroups();
  std::vector<TangentDirection> tangents;
  tangents.reserve(directions.size());
  for (size_t d = 0; d < directions.size(); ++d) {
    const RolloutVariables& v = directions[d];
    checkVariables(v, "Rollout::forwardSensitivities: direction " + std::to_string(d));
    TangentDirection t;
    t.global.resize(groups.size());
    t.per_step.resize(groups.size());
    for (const SimParameterInfo& info : simParameters()) {
      if (info.per_step)
        t.per_step[size_t(info.id)] = *v.perStep(info.id);
      else
        t.global[size_t(info.id)] = *v.global(info.id);
    }
    t.initial_state = v.initial_state;
    t.initial_velocity = v.initial_velocity;
    // The initial conditions initialize() sets move with J (and β).
    VecX dJ = VecX::Zero(72);
    if (v.rest_joints.size()) dJ += v.rest_joints;
    if (v.shape.size()) {
      VecX shape_joints;
      shapeTangent(simulable_->avatar(), v.shape, &shape_joints, nullptr);
      dJ += shape_joints;
    }
    if (state_from_initialize_) t.initial_state_increment = initial_state_joints_jacobian_ * dJ;
    if (velocity_from_initialize_) {
      const VecX dv = initial_velocity_joints_jacobian_ * dJ;
      t.initial_velocity = v.initial_velocity.size() ? VecX(v.initial_velocity + dv) : dv;
    }
    tangents.push_back(std::move(t));
  }
  return tangentSweep(model_, tape_, tangents, initial_states);
}

}  // namespace flsh
