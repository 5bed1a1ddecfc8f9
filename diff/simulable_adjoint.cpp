// A Simulable (the articulated skeleton, the FEM or the ROM soft skeleton) as an AdjointModel:
// snapshots, exact Hessian, the bones as coarse DoFs, Jacobians and products of the total
// gradient, and the chart maps of its [t, rotation vector] bone state.
#include "flsh/diff/simulable_adjoint.h"

#include <algorithm>
#include <numeric>
#include <string>

#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "flsh/volume/soft_avatar.h"

namespace flsh {

namespace {

struct SimulableSnapshot final : StepSnapshot {
  SimulableStep step;
};

// The adjoint's groups: the registry's, in SimParameter order (every model differentiates
// every group; a group of size 0, the skeleton's Material, is empty).
std::vector<SimParameter> allGroups() {
  std::vector<SimParameter> groups;
  for (const SimParameterInfo& info : simParameters()) groups.push_back(info.id);
  return groups;
}

void checkSize(const VecX& v, int n, const char* who, const char* what) {
  if (v.size() != n)
    throw InputError(std::string("SimulableAdjointModel::") + who + ": " + what + " has " +
                     std::to_string(v.size()) +
                     " values, expected numDofs() = " + std::to_string(n));
}

}  // namespace

SimulableAdjointModel::SimulableAdjointModel(std::shared_ptr<Simulable> simulable)
    : simulable_(std::move(simulable)), wanted_(allGroups()) {
  if (!simulable_) throw InputError("SimulableAdjointModel: simulable is null");
  if (!simulable_->options().kinematic_bones.empty())
    throw Error(
        "SimulableAdjointModel: the simulable has kinematic bones (options.kinematic_bones, " +
        std::to_string(simulable_->options().kinematic_bones.size()) +
        " bones); their DoFs are placed from the parents' predicted state and are not "
        "differentiated: use a simulable without kinematic bones (e.g. stiff tracking instead)");
}

int SimulableAdjointModel::numDofs() const { return simulable_->numDofs(); }

std::vector<ParameterGroupInfo> SimulableAdjointModel::parameterGroups() const {
  std::vector<ParameterGroupInfo> groups;
  for (const SimParameterInfo& info : simParameters())
    groups.push_back({info.name, simulable_->parameterSize(info.id), info.per_step});
  return groups;
}

std::unique_ptr<StepSnapshot> SimulableAdjointModel::saveStep() const {
  auto snapshot = std::make_unique<SimulableSnapshot>();
  snapshot->step = simulable_->saveStep();
  return snapshot;
}

void SimulableAdjointModel::restoreStep(const StepSnapshot& snapshot) {
  const auto* s = dynamic_cast<const SimulableSnapshot*>(&snapshot);
  if (!s)
    throw InputError(
        "SimulableAdjointModel::restoreStep: the snapshot was not made by a "
        "SimulableAdjointModel");
  simulable_->restoreStep(s->step);
}

void SimulableAdjointModel::exactHessian(SpMat& H) const {
  // The FEM's elastic, inertia and gravity blocks come as fixed lists: on the cached pattern the
  // 26 k-DoF walk's Hessian takes ~30 ms, against ~96 ms for 2 M triplets through
  // setFromTriplets. No kinematic rows to fix: the constructor refuses kinematic bones, and a
  // simulable's options do not change after construction.
  triplets_.clear();
  blocks_.clear();
  simulable_->getHessianTripletVector(triplets_, blocks_, 0, false);
  assembler_.assemble(triplets_, {}, blocks_, numDofs(), H);
}

void SimulableAdjointModel::coarseDofs(std::vector<int>& dofs) const {
  dofs.resize(size_t(simulable_->numBoneDofs()));
  std::iota(dofs.begin(), dofs.end(), 0);
}

SpMat SimulableAdjointModel::previousStateJacobian(int which) const {
  // The skeleton's is block diagonal (one 6 × 6 inertia block per bone): sparse for products.
  return simulable_->getGradientPreviousStateJacobian(which).sparseView(1.0, 0.0);
}

void SimulableAdjointModel::parameterJacobians(std::vector<MatX>& out) const {
  out = simulable_->getGradientParameterJacobians(allGroups());
}

void SimulableAdjointModel::previousStatesVJP(const VecX& lambda, VecX& a_n, VecX& a_nm1) const {
  simulable_->getGradientPreviousStatesVJP(lambda, &a_n, &a_nm1);
}

VecX SimulableAdjointModel::previousStatesJVP(const VecX& dq_n, const VecX& dq_nm1) const {
  return simulable_->getGradientPreviousStatesJVP(dq_n, dq_nm1);
}

void SimulableAdjointModel::setWantedGroups(const std::vector<SimParameter>& groups) {
  if (groups.empty()) {
    wanted_ = allGroups();
    return;
  }
  std::vector<bool> on(size_t(kNumSimParameters), false);
  for (SimParameter p : groups) on[size_t(p)] = true;
  if (on[size_t(SimParameter::Shape)])
    on[size_t(SimParameter::RestJoints)] = on[size_t(SimParameter::BoneInertia)] = true;
  wanted_.clear();
  for (SimParameter p : allGroups())
    if (on[size_t(p)]) wanted_.push_back(p);
}

void SimulableAdjointModel::parameterVJPs(const VecX& lambda, std::vector<VecX>& out) const {
  const auto has = [&](SimParameter p) {
    return std::find(wanted_.begin(), wanted_.end(), p) != wanted_.end();
  };
  const bool material =
      simulable_->hasSoftTissue() && (has(SimParameter::Material) || has(SimParameter::Shape));
  std::vector<VecX> got = simulable_->getGradientParameterVJPs(
      lambda, wanted_, /*shape_surface_only=*/true, material ? &material_sum_ : nullptr);
  if (wanted_.size() == size_t(kNumSimParameters)) {
    out = std::move(got);
  } else {  // the groups not wanted: zero products of their size
    out.assign(size_t(kNumSimParameters), VecX());
    for (SimParameter p : allGroups()) out[size_t(p)] = VecX::Zero(simulable_->parameterSize(p));
    for (size_t k = 0; k < wanted_.size(); ++k) out[size_t(wanted_[k])] = std::move(got[k]);
  }
  material_pending_ = material_pending_ || material;
}

// p̄_β = Σ_t (dJ/dβ)ᵀ (∂g_t/∂J)ᵀ λ_t + (dI/dβ)ᵀ (∂g_t/∂I)ᵀ λ_t + surface: the first two sums are
// the RestJoints and BoneInertia cotangents themselves (dJ/dβ, dI/dβ do not change over steps).
void SimulableAdjointModel::finishParameterVJPs(std::vector<VecX>& global) const {
  const size_t shape = size_t(SimParameter::Shape), joints = size_t(SimParameter::RestJoints),
               inertia = size_t(SimParameter::BoneInertia);
  if (material_pending_) {  // global holds −Σ_t products (the sweep's sign)
    if (global.size() == size_t(kNumSimParameters)) {
      VecX shape_share;
      global[size_t(SimParameter::Material)] -=
          simulable_->finishMaterialProducts(material_sum_, &shape_share);
      if (global[shape].size() == shape_share.size()) global[shape] -= shape_share;
    }
    material_sum_ = Simulable::MaterialProducts();
    material_pending_ = false;
  }
  if (global.size() != size_t(kNumSimParameters) || global[shape].size() == 0) return;
  chainShapeCotangent(simulable_->avatar(), global[joints], global[inertia], global[shape]);
}

// The groups are in SimParameter order (allGroups), so a direction's pointers carry over; β's
// chain through the rest joints and bone inertias is the simulable's (shape_surface_only off).
void SimulableAdjointModel::parameterJVPs(const std::vector<std::vector<const VecX*>>& directions,
                                          std::vector<VecX>& out) const {
  std::vector<ParameterDirection> given(directions.size());
  for (size_t d = 0; d < directions.size(); ++d) {
    given[d].fill(nullptr);
    for (size_t g = 0; g < directions[d].size() && g < given[d].size(); ++g)
      given[d][g] = directions[d][g];
  }
  out = simulable_->getGradientParameterJVPs(given);
}

VecX SimulableAdjointModel::state() const { return simulable_->getState(); }

// Per bone: dt = δt, dr = J_l(r)⁻¹ δω with r = log(R_b) (the state vector's rotation).
VecX SimulableAdjointModel::incrementToStateTangent(const VecX& dq) const {
  checkSize(dq, numDofs(), "incrementToStateTangent", "dq");
  const VecX s = state();
  VecX out = dq;
  for (int b = 0; b < simulable_->numBoneDofs() / 6; ++b)
    out.segment<3>(6 * b + 3) =
        leftJacobianInverseSO3(s.segment<3>(6 * b + 3)) * dq.segment<3>(6 * b + 3);
  return out;
}

VecX SimulableAdjointModel::stateToIncrementTangent(const VecX& ds) const {
  checkSize(ds, numDofs(), "stateToIncrementTangent", "ds");
  const VecX s = state();
  VecX out = ds;
  for (int b = 0; b < simulable_->numBoneDofs() / 6; ++b)
    out.segment<3>(6 * b + 3) = leftJacobianSO3(s.segment<3>(6 * b + 3)) * ds.segment<3>(6 * b + 3);
  return out;
}

VecX SimulableAdjointModel::stateToIncrementCotangent(const VecX& a) const {
  return stateToIncrementCotangentAt(state(), a);
}

VecX SimulableAdjointModel::stateToIncrementCotangentAt(const VecX& s, const VecX& a) const {
  checkSize(a, numDofs(), "stateToIncrementCotangent", "a");
  checkSize(s, numDofs(), "stateToIncrementCotangentAt", "state");
  VecX out = a;
  for (int b = 0; b < simulable_->numBoneDofs() / 6; ++b)
    out.segment<3>(6 * b + 3) =
        leftJacobianInverseSO3(s.segment<3>(6 * b + 3)).transpose() * a.segment<3>(6 * b + 3);
  return out;
}

VecX SimulableAdjointModel::incrementToStateCotangent(const VecX& a) const {
  return incrementToStateCotangentAt(state(), a);
}

VecX SimulableAdjointModel::incrementToStateCotangentAt(const VecX& s, const VecX& a) const {
  checkSize(a, numDofs(), "incrementToStateCotangent", "a");
  checkSize(s, numDofs(), "incrementToStateCotangentAt", "state");
  VecX out = a;
  for (int b = 0; b < simulable_->numBoneDofs() / 6; ++b)
    out.segment<3>(6 * b + 3) =
        leftJacobianSO3(s.segment<3>(6 * b + 3)).transpose() * a.segment<3>(6 * b + 3);
  return out;
}

// q_{−1} = (t_0 − h v_t, exp(−h[v_ω]×) R_0): increments δt_{−1} = δt_0 − h δv_t and
// δω_{−1} = exp(−h[v_ω]×) δω_0 − h J_l(−h v_ω) δv_ω (left Jacobian: exp(θ + ε) ≈
// exp([J_l(θ)ε]×) exp(θ)). Evaluated at the restored initial snapshot (q_n = q_0).
VecX SimulableAdjointModel::initialPreviousStateTangent(const VecX& dq0, const VecX& dv0) const {
  checkSize(dq0, numDofs(), "initialPreviousStateTangent", "dq0");
  checkSize(dv0, numDofs(), "initialPreviousStateTangent", "dv0");
  const SimulableStep s = simulable_->saveStep();
  const double h = simulable_->options().time_step;
  const VecX v = simulable_->getVelocity();
  VecX out(dq0.size());
  const int nb = simulable_->numBoneDofs(), nu = numDofs() - nb;
  // Soft state: u_{−1} = u_0 − h v_u.
  out.tail(nu) = dq0.tail(nu) - h * dv0.tail(nu);
  for (int b = 0; b < int(s.R_n.size()); ++b) {
    const Mat3 back = s.R_nm1[b] * s.R_n[b].transpose();  // exp(−h[v_ω]×)
    out.segment<3>(6 * b) = dq0.segment<3>(6 * b) - h * dv0.segment<3>(6 * b);
    out.segment<3>(6 * b + 3) =
        back * dq0.segment<3>(6 * b + 3) -
        h * leftJacobianSO3(-h * v.segment<3>(6 * b + 3)) * dv0.segment<3>(6 * b + 3);
  }
  return out;
}

VecX SimulableAdjointModel::initialPreviousStateCotangent(const VecX& a_previous, VecX& a0) const {
  checkSize(a_previous, numDofs(), "initialPreviousStateCotangent", "a_previous");
  checkSize(a0, numDofs(), "initialPreviousStateCotangent", "a0");
  const SimulableStep s = simulable_->saveStep();
  const double h = simulable_->options().time_step;
  const VecX v = simulable_->getVelocity();
  VecX dv(a0.size());
  const int nb = simulable_->numBoneDofs(), nu = numDofs() - nb;
  a0.tail(nu) += a_previous.tail(nu);
  dv.tail(nu) = -h * a_previous.tail(nu);
  for (int b = 0; b < int(s.R_n.size()); ++b) {
    const Mat3 back = s.R_nm1[b] * s.R_n[b].transpose();
    a0.segment<3>(6 * b) += a_previous.segment<3>(6 * b);
    dv.segment<3>(6 * b) = -h * a_previous.segment<3>(6 * b);
    a0.segment<3>(6 * b + 3) += back.transpose() * a_previous.segment<3>(6 * b + 3);
    dv.segment<3>(6 * b + 3) = -h * leftJacobianSO3(-h * v.segment<3>(6 * b + 3)).transpose() *
                               a_previous.segment<3>(6 * b + 3);
  }
  return dv;
}

}  // namespace flsh
