// Simulable: construction, mocap targets, stepping and the state (the runtime API of the FLSH
// paper, ARCHITECTURE.md §4–5). The data is Simulable::Impl (simulable_impl.h); the energy is a
// sum of terms (src/sim/terms/, summed in simulable_energy.cpp).
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
#include "flsh/energy/skeleton_energies.h"
#include "sim/simulable_impl.h"

namespace flsh {

using detail::BoneStates;
using detail::kDofsPerBone;

namespace {

BoneStates restBones(const MatX3& joints) {
  BoneStates s;
  s.R.assign(joints.rows(), Mat3::Identity());
  s.t = joints;
  return s;
}

// Bones posed by an SMPL pose (72) and root translation, like poseBody's transforms:
// R_b = R_p rodrigues(θ_b), t_b = R_p (J_b − J_p) + t_p, t_0 = J_0 + trans.
BoneStates bonesFromPose(const Eigen::Ref<const VecX>& pose, const Vec3& trans, const MatX3& joints,
                         const std::vector<int>& parents) {
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
      s.t.row(b) = (s.R[p] * (joints.row(b) - joints.row(p)).transpose() + s.t.row(p).transpose())
                       .transpose();
    }
  }
  return s;
}

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

// Tracking stiffness k_b = ω_T² (I_b + I_floor) and the root springs (whole body, no floor):
// the tracking term's, whose parameter products differentiate the same formula.
void Simulable::Impl::buildStiffnesses() {
  tracking_term->stiffnesses(J, inertia, options, tracking_k, root_k_pos, root_k_rot);
}

void Simulable::Impl::buildTerms() {
  tracking_term = std::make_unique<detail::TrackingSpringTerm>(parents);
  contact_term = std::make_unique<detail::SurfaceContactTerm>(*skeleton_kinematics, num_bones);
  kinematics = skeleton_kinematics.get();
  model_contact = contact_term.get();
  spring_terms = {&joint_term, tracking_term.get()};
  dynamic_terms = {{&inertia_term}};
  potential_terms = {{&gravity_term}, {&joint_term}, {tracking_term.get()}, {contact_term.get()}};
  value_lists = nullptr;
  terms.clear();
  for (const auto* part : {&dynamic_terms, &potential_terms})
    for (const detail::TermEntry& entry : *part) terms.push_back(entry.term);
}

void Simulable::Impl::useSoftTerms() {
  dynamic_terms = soft->dynamicTerms();
  potential_terms.clear();
  for (const EnergyTerm* spring : spring_terms) potential_terms.push_back({spring});
  for (const detail::TermEntry& entry : soft->potentialTerms()) potential_terms.push_back(entry);
  value_lists = &soft->valueLists();
  kinematics = &soft->kinematics();
  model_contact = &soft->contactTerm();
  schedule = soft->reduced() ? soft.get() : nullptr;
  soft->setContactBones(surface.dominated);
  terms = spring_terms;
  for (const EnergyTerm* term : soft->terms()) terms.push_back(term);
}

bool Simulable::Impl::runsOnTwoThreads() const {
  return schedule && !is_static && omp_get_max_threads() >= 2;
}

TermContext Simulable::Impl::context() const {
  prepare();
  return {num_bones, parents,  J,         inertia,         options,    mocap && options.track_mocap,
          is_static, q.R,      q.t,       q_n.R,           q_n.t,      q_nm1.R,
          q_nm1.t,   target_R, target_t0, tracking_k,      root_k_pos, root_k_rot,
          colliders, time,     *avatar,   surface.weights, contact};
}

Simulable::Simulable(std::shared_ptr<const SoftAvatar> avatar, std::shared_ptr<const Motion> mocap,
                     const SimulableOptions& options)
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
  m.skeleton_kinematics =
      std::make_unique<detail::SkeletonKinematics>(m.surface, m.avatar->restVertices(), m.J);
  m.buildTerms();
  m.buildStiffnesses();
  m.q = m.q_n = m.q_nm1 = restBones(m.J);
  if (m.avatar->softTissueEnabled()) {
    if (!m.avatar->hasVolumetricData())
      throw InputError(fn +
                       "the avatar has soft tissue enabled but no volumetric data "
                       "(call SoftAvatar::initVolumetricData())");
    m.soft = std::make_unique<detail::SoftTissue>(*m.avatar, m.J, m.parents, m.options.time_step);
    m.useSoftTerms();
    m.soft->setPoseBlend(m.q.R);
    m.setSoftPrediction();
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
      q.t.row(b) =
          (q.R[p] * (J.row(b) - J.row(p)).transpose() + q.t.row(p).transpose()).transpose();
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
    throw InputError(
        "Simulable::setState: q has " + std::to_string(q.size()) +
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
  if (m.stack.size() <= m.stack_depth)
    m.stack.push_back(m.q);
  else
    m.stack[m.stack_depth] = m.q;
  if (m.soft) {
    if (m.u_stack.size() <= m.stack_depth)
      m.u_stack.push_back(m.soft->u);
    else
      m.u_stack[m.stack_depth] = m.soft->u;
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
    if (const std::vector<Mat3>* held = m.soft->heldPoseRotations()) {
      s.pose_blend_R = *held;
      m.soft->evaluatedPoseBlend(s.pose_blend_nodes, s.pose_blend_rows);
    } else
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
        (s.pose_blend.rows() != m.soft->numNodes() && s.pose_blend.rows() != 0))
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
    if (!s.pose_blend_R.empty() && s.pose_blend_R.size() != n)
      throw InputError("Simulable::restoreStep: the snapshot has " +
                       std::to_string(s.pose_blend_R.size()) + " pose blend rotations, expected " +
                       std::to_string(n) + " bones (or none)");
    requireFiniteRotations("pose_blend_R", s.pose_blend_R);
    if (s.pose_blend_rows.rows() != Eigen::Index(s.pose_blend_nodes.size()))
      throw InputError("Simulable::restoreStep: the snapshot has " +
                       std::to_string(s.pose_blend_rows.rows()) + " rows of pose_blend_rows for " +
                       std::to_string(s.pose_blend_nodes.size()) + " pose_blend_nodes");
    for (size_t k = 0; k < s.pose_blend_nodes.size(); ++k)
      if (s.pose_blend_nodes[k] < 0 || s.pose_blend_nodes[k] >= m.soft->numNodes())
        throw InputError("Simulable::restoreStep: the snapshot's pose_blend_nodes[" +
                         std::to_string(k) + "] is " + std::to_string(s.pose_blend_nodes[k]) +
                         ", expected a node in [0, " + std::to_string(m.soft->numNodes()) + ")");
    requireFinite("pose_blend_rows", s.pose_blend_rows);
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
    if (s.pose_blend.rows())
      m.soft->setPoseBlendOffsets(s.pose_blend);
    else if (!s.pose_blend_R.empty()) {
      m.soft->setPoseBlend(s.pose_blend_R);
      m.soft->seedPoseBlend(s.pose_blend_nodes, s.pose_blend_rows);
    } else
      m.soft->setPoseBlend(m.q_n.R);  // held from q_n, as preUpdate holds it
    m.setSoftPrediction();
  }
  m.touch();
  m.ensureContact();  // stats() then report this step's contacts, as after its evaluation
}

// initialize(): t_0 = J_0 + trans, t_b = R_p (J_b − J_p) + t_p for the first frame's rotations
// (rest pose: t_b = J_b), velocity (t(frame 1) − t(frame 0))·fps.
void Simulable::getInitialStateRestJointsJacobian(MatX* state_jacobian,
                                                  MatX* velocity_jacobian) const {
  const Impl& m = *impl_;  // soft tissue starts at rest (u = 0, no velocity): zero rows
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
  const MatX T0 = translationJacobian(
      bonesFromPose(mo.poses.row(0).transpose(), Vec3::Zero(), m.J, m.parents).R);
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

}  // namespace flsh
