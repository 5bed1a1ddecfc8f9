// Simulable: the parameter groups (get/setParameter) and the adjoint's derivatives, the energy
// terms' products summed (energy_term.h), with the β chain (sim_parameter.h).
#include <string>

#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "flsh/energy/skeleton_energies.h"
#include "flsh/sim/simulable.h"
#include "sim/simulable_impl.h"
#include "sim/tangent_columns.h"

namespace flsh {

using detail::BoneStates;
using detail::kDofsPerBone;

namespace {

void checkStateSized(const VecX& x, int n, const char* who, const char* name) {
  if (x.size() != n)
    throw InputError(std::string("Simulable::") + who + ": " + name + " has " +
                     std::to_string(x.size()) +
                     " values, expected numDofs() = " + std::to_string(n));
}

}  // namespace

int Simulable::parameterSize(SimParameter p) const {
  return simParameterSize(p, int(impl_->colliders.size()), int(impl_->avatar->betas().size()),
                          impl_->soft != nullptr);
}

MatX Simulable::getGradientParameterJacobian(SimParameter p) const {
  return getGradientParameterJacobians({p}).front();
}

namespace {

/// The groups asked for, checked, and whether Shape is among them (the caller chains it).
template <class Block>
bool askFor(const Simulable& s, const std::vector<SimParameter>& groups, int cols,
            ParameterProducts<Block>& out) {
  bool shape = false;
  for (SimParameter p : groups) {
    simParameterInfo(p);  // throws for a value outside the enum
    if (!out.wants(p)) {
      if constexpr (Block::ColsAtCompileTime == 1)
        out[p] = Block::Zero(s.parameterSize(p));
      else
        out[p] = Block::Zero(cols, s.parameterSize(p));
    }
    shape = shape || p == SimParameter::Shape;
  }
  return shape;
}

// The Material group: the terms write it in the coefficient values at β (MaterialChain); the
// file's parameters (a, b) follow by ∂c_i/∂a_i = c_i, ∂c_i/∂b_i = c_i β, once per call.
template <class Block>
void askForMaterialValues(const Simulable::Impl& m, ParameterProducts<Block>& out) {
  if (!m.soft || !out.wants(SimParameter::Material)) return;
  const int n = m.soft->materialChain().numValues();
  Block& block = out[SimParameter::Material];
  if constexpr (Block::ColsAtCompileTime == 1)
    block = Block::Zero(n);
  else
    block = Block::Zero(block.rows(), n);
}

VecX materialParametersCotangent(const Simulable::Impl& m, const VecX& values_bar) {
  return m.soft->materialChain().parametersCotangent(values_bar);
}

// The chain's matrix (values × parameters) once, then one product.
MatX materialParametersJacobian(const Simulable::Impl& m, const MatX& values_jacobian) {
  const Eigen::Index n = values_jacobian.cols();
  MatX chain(n, m.avatar->volumetricData().material_model.numParameters());
  for (Eigen::Index i = 0; i < n; ++i)
    chain.row(i) = materialParametersCotangent(m, VecX::Unit(n, i)).transpose();
  return values_jacobian * chain;
}

}  // namespace

// The terms' Jacobians (numDofs × size); Shape's chain through the rest joints and bone
// inertias is the cotangent chain applied to the transposed Jacobians.
std::vector<MatX> Simulable::getGradientParameterJacobians(const std::vector<SimParameter>& groups,
                                                           bool shape_surface_only) const {
  const Impl& m = *impl_;
  ParameterProducts<MatX> jacobians;
  const bool chain = askFor(*this, groups, numDofs(), jacobians) && !shape_surface_only;
  if (chain)
    askFor(*this, {SimParameter::RestJoints, SimParameter::BoneInertia}, numDofs(), jacobians);
  askForMaterialValues(m, jacobians);
  m.ensureContact();
  const TermContext c = m.context();
  for (const EnergyTerm* term : m.terms) term->addParameterJacobians(c, jacobians);
  if (m.soft && jacobians.wants(SimParameter::Shape))
    m.soft->addShapeJacobian(c, jacobians[SimParameter::Shape]);
  if (m.soft && jacobians.wants(SimParameter::Material))
    jacobians[SimParameter::Material] =
        materialParametersJacobian(m, jacobians[SimParameter::Material]);
  std::vector<MatX> out;
  out.reserve(groups.size());
  for (SimParameter p : groups) {
    if (p == SimParameter::Shape && chain) {
      MatX shape = jacobians[p].transpose();
      chainShapeCotangent(*m.avatar, MatX(jacobians[SimParameter::RestJoints].transpose()),
                          MatX(jacobians[SimParameter::BoneInertia].transpose()), shape);
      out.push_back(shape.transpose());
    } else {
      out.push_back(jacobians[p]);
    }
  }
  return out;
}

std::vector<VecX> Simulable::getGradientParameterVJPs(const VecX& lambda,
                                                      const std::vector<SimParameter>& groups,
                                                      bool shape_surface_only,
                                                      MaterialProducts* material_sum) const {
  const Impl& m = *impl_;
  checkStateSized(lambda, numDofs(), "getGradientParameterVJPs", "lambda");
  ParameterProducts<VecX> products;
  const bool chain = askFor(*this, groups, 1, products) && !shape_surface_only;
  if (chain) askFor(*this, {SimParameter::RestJoints, SimParameter::BoneInertia}, 1, products);
  askForMaterialValues(m, products);
  const bool material = m.soft && products.wants(SimParameter::Material);
  const bool shape = m.soft && products.wants(SimParameter::Shape);
  // A sweep sums the elastic elements' material-point cotangents (and the ROM's Σ λ zᵀ) over the
  // steps: the Material group and β's share through the materials and every tet of K come
  // from the sums once (finishMaterialProducts).
  const bool summed = material_sum && (material || shape);
  if (summed) material_sum->shape = material_sum->shape || shape;
  m.ensureContact();
  const TermContext c = m.context();
  const EnergyTerm* elastic = m.soft ? &m.soft->elasticTerm() : nullptr;
  for (const EnergyTerm* term : m.terms) {
    if (summed && term == elastic)
      m.soft->elasticTerm().accumulateMaterialProducts(
          lambda, material_sum->elements, material_sum->rest_outer,
          shape ? &m.soft->shapeChain() : nullptr,
          shape ? &products[SimParameter::Shape] : nullptr);
    else
      term->addParameterProducts(c, lambda, products);
  }
  if (shape)
    m.soft->addShapeProducts(c, lambda, products[SimParameter::Shape], m.state_version, summed);
  if (material) {
    VecX& values = products[SimParameter::Material];
    if (material_sum) {  // summed in coefficient values, chained by finishMaterialProducts
      if (material_sum->values.size() == 0)
        material_sum->values = values;
      else
        material_sum->values += values;
      values = VecX::Zero(parameterSize(SimParameter::Material));
    } else {
      values = materialParametersCotangent(m, values);
    }
  }
  std::vector<VecX> out;
  out.reserve(groups.size());
  for (SimParameter p : groups) {
    out.push_back(products[p]);
    if (p == SimParameter::Shape && chain)
      chainShapeCotangent(*m.avatar, products[SimParameter::RestJoints],
                          products[SimParameter::BoneInertia], out.back());
  }
  return out;
}

void Simulable::accumulateMaterialProducts(const VecX& lambda, MaterialProducts& sum) const {
  if (!impl_->soft)
    throw Error("Simulable::accumulateMaterialProducts: the articulated skeleton has no material");
  getGradientParameterVJPs(lambda, {SimParameter::Material}, false, &sum);
}

VecX Simulable::finishMaterialProducts(const MaterialProducts& sum, VecX* shape) const {
  const Impl& m = *impl_;
  if (!m.soft)
    throw Error("Simulable::finishMaterialProducts: the articulated skeleton has no material");
  const bool with_shape = shape && sum.shape;
  if (shape) *shape = VecX::Zero(parameterSize(SimParameter::Shape));
  VecX elastic = VecX::Zero(m.soft->materialChain().numValues());
  m.soft->elasticTerm().addAccumulatedMaterialProducts(sum.elements, sum.rest_outer, elastic,
                                                       with_shape ? &m.soft->shapeChain() : nullptr,
                                                       with_shape ? shape : nullptr);
  // β's share through the elastic materials' coefficient values (the masses' is in their own
  // Shape blocks).
  if (with_shape) shape->noalias() += m.soft->shapeChain().valuesJacobian().transpose() * elastic;
  VecX values = elastic;
  if (sum.values.size() > 0) values += sum.values;
  return materialParametersCotangent(m, values);
}

// A Shape direction moves the rest joints and bone inertias too (shapeTangent): those changes
// join the RestJoints and BoneInertia directions, unless shape_surface_only.
std::vector<VecX> Simulable::getGradientParameterJVPs(
    const std::vector<ParameterDirection>& directions, bool shape_surface_only) const {
  const Impl& m = *impl_;
  std::vector<ParameterDirection> given = directions;
  std::vector<VecX> chained(2 * directions.size());
  for (size_t d = 0; d < directions.size(); ++d)
    for (const SimParameterInfo& info : simParameters()) {
      const VecX* v = directions[d][size_t(info.id)];
      if (v && v->size() && v->size() != parameterSize(info.id))
        throw InputError(
            std::string("Simulable::getGradientParameterJVPs: direction ") + std::to_string(d) +
            ", " + info.name + " has " + std::to_string(v->size()) +
            " values, expected parameterSize() = " + std::to_string(parameterSize(info.id)));
    }
  if (!shape_surface_only)
    for (size_t d = 0; d < directions.size(); ++d) {
      const VecX* dbeta = directions[d][size_t(SimParameter::Shape)];
      if (!dbeta || dbeta->size() == 0) continue;
      VecX& dJ = chained[2 * d];
      VecX& dI = chained[2 * d + 1];
      shapeTangent(*m.avatar, *dbeta, &dJ, &dI);
      for (auto [group, change] :
           {std::pair{SimParameter::RestJoints, &dJ}, std::pair{SimParameter::BoneInertia, &dI}}) {
        const VecX* own = directions[d][size_t(group)];
        if (own && own->size()) *change += *own;
        given[d][size_t(group)] = change;
      }
    }
  // Material directions in the coefficient values the terms read.
  std::vector<VecX> material_values(directions.size());
  for (size_t d = 0; d < directions.size(); ++d) {
    const VecX* dp = directions[d][size_t(SimParameter::Material)];
    if (!m.soft || !dp || dp->size() == 0) continue;
    material_values[d] = m.soft->materialChain().valuesTangent(*dp);
    given[d][size_t(SimParameter::Material)] = &material_values[d];
  }
  std::vector<VecX> out(directions.size(), VecX::Zero(numDofs()));
  m.ensureContact();
  const TermContext c = m.context();
  for (const EnergyTerm* term : m.terms) term->addParameterTangents(c, given, out);
  if (m.soft)
    for (size_t d = 0; d < directions.size(); ++d) {
      const VecX* dbeta = directions[d][size_t(SimParameter::Shape)];
      if (dbeta && dbeta->size()) m.soft->addShapeTangent(c, *dbeta, out[d]);
    }
  return out;
}

// The inertia term's blocks (the skeleton's 6 × 6 per bone; the soft skeletons' prediction
// x̂ = 2 x(q_n) − x(q_{n−1})) and, with soft tissue, the pose blend held from q_n's rotations,
// which moves the node terms' gradients (SoftTissue::addPoseBlendProducts): also when static.
MatX Simulable::getGradientPreviousStateJacobian(int which) const {
  const Impl& m = *impl_;
  if (which != 1 && which != 2)
    throw InputError("Simulable::getGradientPreviousStateJacobian: which = " +
                     std::to_string(which) + ", expected 1 (q_n) or 2 (q_{n-1})");
  const int n = numDofs();
  MatX D = MatX::Zero(n, n);
  if (m.soft) {  // columns of the tangent: n products (small models, tests)
    const VecX zero = VecX::Zero(n);
    detail::addTangentColumns(D, [&](const VecX& unit, VecX& column) {
      column += getGradientPreviousStatesJVP(which == 1 ? unit : zero, which == 2 ? unit : zero);
    });
    return D;
  }
  const TermContext c = m.context();
  for (const EnergyTerm* term : m.terms)
    if (term->dependsOnPreviousStates()) term->addPreviousStateJacobian(c, which, D);
  return D;
}

void Simulable::getGradientPreviousStatesVJP(const VecX& lambda, VecX* a_n, VecX* a_nm1) const {
  const Impl& m = *impl_;
  checkStateSized(lambda, numDofs(), "getGradientPreviousStatesVJP", "lambda");
  if (a_n) a_n->setZero(lambda.size());
  if (a_nm1) a_nm1->setZero(lambda.size());
  if (m.soft) m.ensureContact();
  const TermContext c = m.context();
  for (const EnergyTerm* term : m.terms)
    if (term->dependsOnPreviousStates()) term->addPreviousStatesProducts(c, lambda, a_n, a_nm1);
  if (m.soft && a_n) m.soft->addPoseBlendProducts(c, lambda, *a_n, m.state_version);
}

VecX Simulable::getGradientPreviousStatesJVP(const VecX& dq_n, const VecX& dq_nm1) const {
  const Impl& m = *impl_;
  checkStateSized(dq_n, numDofs(), "getGradientPreviousStatesJVP", "dq_n");
  checkStateSized(dq_nm1, numDofs(), "getGradientPreviousStatesJVP", "dq_nm1");
  VecX out = VecX::Zero(dq_n.size());
  if (m.soft) m.ensureContact();
  const TermContext c = m.context();
  for (const EnergyTerm* term : m.terms)
    if (term->dependsOnPreviousStates()) term->addPreviousStatesTangent(c, dq_n, dq_nm1, out);
  if (m.soft) m.soft->addPoseBlendTangent(c, dq_n, out);
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
        value.segment<10>(10 * b) << in.mass, in.first_moment, S(0, 0), S(1, 1), S(2, 2), S(0, 1),
            S(0, 2), S(1, 2);
      }
      break;
    case SimParameter::PoseTargets:
      for (int b = 0; b < m.num_bones; ++b) value.segment<3>(3 * b) = logSO3(m.target_R[b]);
      break;
    case SimParameter::RootTranslationTarget:
      value = m.target_t0;
      break;
    case SimParameter::Stiffnesses:
      value << m.options.joint_stiffness, m.options.tracking_stiffness, m.options.root_stiffness,
          m.options.contact.stiffness;
      break;
    case SimParameter::ColliderOffsets:
      for (size_t k = 0; k < m.colliders.size(); ++k)
        value.segment<3>(3 * k) = m.colliders[k].path.offsetAt(m.time);
      break;
    case SimParameter::Shape:
      value = m.avatar->betas();
      break;
    case SimParameter::Material:
      if (m.soft) value = m.avatar->volumetricData().material_model.parameters();
      break;
  }
  return value;
}

void Simulable::setParameter(SimParameter p, const VecX& value) {
  Impl& m = *impl_;
  if (p == SimParameter::Shape)
    throw InputError(
        "Simulable::setParameter: Shape (β) is fixed by the SoftAvatar the simulable was built "
        "with; build one with SoftAvatar::withShape(β) (the same discretization) and a new "
        "Simulable on it");
  if (p == SimParameter::Material)
    throw InputError(
        "Simulable::setParameter: Material is fixed by the SoftAvatar the simulable was built "
        "with; build one with SoftAvatar::withMaterial (same discretization, other materials) "
        "and a new Simulable on it");
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
      if (m.soft) {  // the tet nodes' skinning, and x̂ = 2 x(q_n) − x(q_{n−1}) with it
        m.soft->setJoints(m.J);
        m.soft->setContactBones(m.surface.dominated);
        m.setSoftPrediction();
      }
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
    case SimParameter::RootTranslationTarget:
      m.target_t0 = value;
      break;
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
    case SimParameter::Shape:
    case SimParameter::Material:
      break;  // rejected above
  }
  m.touch();
}

}  // namespace flsh
