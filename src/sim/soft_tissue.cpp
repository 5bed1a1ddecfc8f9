// The soft tissue's parts for one avatar, and the ROM's evaluations on two threads; see
// soft_tissue.h.
#include "sim/soft_tissue.h"

#include <omp.h>

#include "flsh/core/error.h"
#include "sim/soft/fem_elasticity_term.h"
#include "sim/soft/on_two_threads.h"
#include "sim/terms/term_blocks.h"

namespace flsh::detail {

namespace {
// reducedGradient runs this share of the elastic tets beside inertia's and gravity's force
// mapping (about as costly as contact). reducedHessians maps NodalInertiaTerm::
// kShareBesidePotential of inertia's mass nodes beside the potential terms: on the full
// synthetic body (684 mass nodes, ~390 elastic tets) the other 90 % of inertia's blocks cost
// about as much as contact, gravity, every elastic tet and the rest-stiffness term (265 against
// 260–290 µs per Hessian; scene Hessian 0.42–0.46 ms against 0.50 with the elastic tets split
// instead).
constexpr double kGradientTetsBesideInertia = 0.5;
}  // namespace

SoftTissue::SoftTissue(const SoftAvatar& avatar, const MatX3& joints,
                       const std::vector<int>& parents, double time_step)
    : kin_(avatar, joints, parents),
      u(kin_.u),
      u_n(kin_.u_n),
      u_nm1(kin_.u_nm1),
      masses_(nodeMasses(avatar)),
      held_moments_(kin_, masses_),
      material_chain_(avatar),
      shape_chain_(avatar, material_chain_) {
  kin_.setMassNodes(masses_.nodes);
  ElasticElements elements = elasticElements(avatar);
  if (kin_.reduced() && kin_.numModes() > 0) {
    auto modal =
        std::make_unique<ModalElasticityTerm>(avatar, kin_, material_chain_, std::move(elements));
    kin_.buildReducedPattern(modal->groupPairs());
    reduced_elastic_ = modal.get();
    elastic_ = std::move(modal);
  } else if (kin_.reduced()) {
    auto reduced =
        std::make_unique<ReducedElasticityTerm>(avatar, kin_, material_chain_, std::move(elements));
    kin_.buildReducedPattern(reduced->handlePairs());
    reduced_elastic_ = reduced.get();
    elastic_ = std::move(reduced);
  } else {
    elastic_ = std::make_unique<FemElasticityTerm>(kin_, material_chain_, std::move(elements));
  }
  inertia_ = std::make_unique<NodalInertiaTerm>(kin_, masses_, held_moments_, material_chain_,
                                                shape_chain_, time_step);
  gravity_ = std::make_unique<NodalGravityTerm>(kin_, masses_, held_moments_, material_chain_,
                                                shape_chain_);
  contact_ = std::make_unique<NodeContactTerm>(kin_, avatar.vertexAreas());
}

const MatX3& SoftTissue::nodeOffsetCotangent(const TermContext& c, const VecX& lambda,
                                             long version) const {
  if (version == offset_version_ && lambda.size() == offset_lambda_.size() &&
      lambda == offset_lambda_)
    return offset_cotangent_;
  offset_cotangent_ = MatX3::Zero(numNodes(), 3);
  for (const NodeOffsetDerivatives* term : nodeOffsetTerms())
    term->addNodeOffsetProducts(c, lambda, offset_cotangent_);
  offset_lambda_ = lambda;
  offset_version_ = version;
  return offset_cotangent_;
}

void SoftTissue::addPoseBlendProducts(const TermContext& c, const VecX& lambda, VecX& a_n,
                                      long version) const {
  addPoseBlendCotangent(c.R_n, nodeOffsetCotangent(c, lambda, version), a_n);
}

void SoftTissue::addPoseBlendCotangent(const std::vector<Mat3>& R_n, const MatX3& offsets,
                                       VecX& a_n) const {
  std::vector<int> nodes;
  std::vector<Vec3> mu;
  for (int j = 0; j < int(offsets.rows()); ++j)
    if (!offsets.row(j).isZero(0.0)) {
      nodes.push_back(j);
      mu.push_back(offsets.row(j).transpose());
    }
  VecX rotations = VecX::Zero(3 * kin_.numBones());
  kin_.poseBlendCotangent(R_n, nodes, mu, rotations);
  for (int b = 0; b < kin_.numBones(); ++b)
    a_n.segment<3>(rotationRow(b)) += rotations.segment<3>(3 * b);
}

void SoftTissue::addPoseBlendTangent(const TermContext& c, const VecX& dq_n, VecX& out) const {
  VecX rotations(3 * kin_.numBones());
  for (int b = 0; b < kin_.numBones(); ++b)
    rotations.segment<3>(3 * b) = dq_n.segment<3>(rotationRow(b));
  if (rotations.isZero(0.0)) return;
  // The nodes the terms read: the mass nodes and contact's candidates.
  std::vector<char> read(size_t(numNodes()), 0);
  for (int j : masses_.nodes) read[size_t(j)] = 1;
  for (int j : c.contact.candidates) read[size_t(j)] = 1;
  std::vector<int> nodes;
  for (int j = 0; j < numNodes(); ++j)
    if (read[size_t(j)]) nodes.push_back(j);
  MatX3 dP;
  kin_.poseBlendTangent(c.R_n, rotations, nodes, dP);
  MatX3 dY = MatX3::Zero(numNodes(), 3);
  for (size_t k = 0; k < nodes.size(); ++k) dY.row(nodes[k]) = dP.row(Eigen::Index(k));
  addNodeOffsetTangent(c, dY, out);
}

void SoftTissue::addNodeOffsetTangent(const TermContext& c, const MatX3& dY, VecX& out) const {
  for (const NodeOffsetDerivatives* term : nodeOffsetTerms())
    term->addNodeOffsetTangent(c, dY, out);
}

void SoftTissue::addShapeProducts(const TermContext& c, const VecX& lambda, VecX& beta_bar,
                                  long version, bool summed) const {
  shape_chain_.addNodeCotangent(nodeOffsetCotangent(c, lambda, version), beta_bar);
  if (!summed) elastic_->addShapeProducts(lambda, shape_chain_, beta_bar);
}

void SoftTissue::addShapeTangent(const TermContext& c, const VecX& dbeta, VecX& out) const {
  addNodeOffsetTangent(c, shape_chain_.nodeTangent(dbeta), out);
  elastic_->addShapeTangent(dbeta, shape_chain_, out);
}

void SoftTissue::addShapeJacobian(const TermContext& c, MatX& J) const {
  for (int k = 0; k < shape_chain_.numBetas(); ++k) {
    VecX column = VecX::Zero(J.rows());
    addNodeOffsetTangent(c, shape_chain_.nodeTangent(VecX::Unit(shape_chain_.numBetas(), k)),
                         column);
    J.col(k) += column;
  }
  elastic_->addShapeJacobian(shape_chain_, J);
}

std::vector<const EnergyTerm*> SoftTissue::terms() const {
  return {inertia_.get(), gravity_.get(), elastic_.get(), contact_.get()};
}

double SoftTissue::gradient(const TermContext& c, VecX& g, int offset) const {
  // Contact's surface nodes skinned here, not on the thread beside inertia (skinning writes
  // node rows inertia reads).
  const bool contact = !c.colliders.empty() && !c.contact.candidates.empty();
  if (contact && kin_.reduced()) kin_.skinNodes(c.contact.candidates);
  double contact_energy = 0.0;
  const double E = reducedGradient(c.options.gravity, g, offset, [&](VecX& part) {
    if (contact)
      contact_energy = contact_->evaluate(c.colliders, c.time, c.options.contact, &part, nullptr,
                                          offset, true, nullptr, &c.contact.candidates, false);
  });
  return E + contact_energy;
}

void SoftTissue::hessians(const TermContext& c, std::vector<Triplet>& H_dynamic,
                          std::vector<Triplet>& H_potential, int offset, bool psd) const {
  scheduledHessians(c, H_dynamic, H_potential, offset, psd, false);
}

void SoftTissue::scheduledHessians(const TermContext& c, std::vector<Triplet>& H_dynamic,
                                   std::vector<Triplet>& H_potential, int offset, bool psd,
                                   bool approximate) const {
  const bool contact = !c.colliders.empty() && !c.contact.candidates.empty();
  if (contact && kin_.reduced()) kin_.skinNodes(c.contact.candidates);
  reducedHessians(
      c.options.gravity, H_dynamic, H_potential, offset, psd,
      [&] {
        if (contact)
          contact_->evaluate(c.colliders, c.time, c.options.contact, nullptr, &H_potential, offset,
                             psd, nullptr, &c.contact.candidates, false);
      },
      approximate);
}

bool SoftTissue::approximateHessians(const TermContext& c, std::vector<Triplet>& H_dynamic,
                                     std::vector<Triplet>& H_potential, int offset) const {
  if (!hasApproximateHessians() || c.is_static) return false;
  scheduledHessians(c, H_dynamic, H_potential, offset, false, true);
  return true;
}

double SoftTissue::reducedGradient(const Vec3& gravity, VecX& g, int offset,
                                   const std::function<void(VecX&)>& potential_first) const {
  if (!reduced_elastic_) throw Error("SoftTissue::reducedGradient: the ROM only");
  const ReducedElasticity& elastic = *reduced_elastic_;
  const int T = elastic.numElements();
  const int base = offset + kin_.boneDofs();
  const double h = inertia_->timeStep(), k = 1.0 / (h * h);
  const std::vector<int>& nodes = masses_.nodes;
  const MatX3& x = kin_.x();
  const MatX3& x_hat = inertia_->prediction();
  const int split = int(kGradientTetsBesideInertia * T);
  forces_.resize(nodes.size());
  gradient_scratch_.setZero(g.size());
  double energies[2] = {0.0, 0.0};
  onTwoThreads([&](int part) {
    if (part == 0) {
      // ∂/∂x_j of inertia plus gravity: m_j ((x_j − x̂_j) / h² − g); their energies
      // m_j (‖x_j − x̂_j‖² / (2h²) − g · x_j).
      double E = 0.0;
      for (size_t idx = 0; idx < nodes.size(); ++idx) {
        const int j = nodes[idx];
        const Vec3 xj = x.row(j).transpose(), d = xj - x_hat.row(j).transpose();
        E += masses_.mass[j] * (0.5 * k * d.squaredNorm() - gravity.dot(xj));
        forces_[idx] = masses_.mass[j] * (k * d - gravity);
      }
      kin_.mapForces(nodes, forces_, g, offset);
      energies[0] = E + elastic.elements(0, split, g.data() + base, nullptr, true);
    } else {
      if (potential_first) potential_first(gradient_scratch_);
      energies[1] = elastic.elements(split, T, gradient_scratch_.data() + base, nullptr, true) +
                    elastic.restStiffness(&gradient_scratch_, nullptr, offset);
    }
  });
  g += gradient_scratch_;
  return energies[0] + energies[1];
}

void SoftTissue::addConstantSoftBlock(const MatX& C, Mat3* values) const {
  const int groups = kin_.numGroups();
  for (int b = 0; b < groups; ++b)
    for (int a = 0; a <= b; ++a)
      if (kin_.zzSlot(a, b) >= 0) values[kin_.zzSlot(a, b)] += C.block<3, 3>(3 * a, 3 * b);
}

void SoftTissue::reducedHessians(const Vec3& gravity, std::vector<Triplet>& H_dynamic,
                                 std::vector<Triplet>& H_potential, int offset, bool psd,
                                 const std::function<void()>& potential_first,
                                 bool approximate) const {
  if (!reduced_elastic_) throw Error("SoftTissue::reducedHessians: the ROM only");
  const ReducedElasticity& elastic = *reduced_elastic_;
  const int T = elastic.numElements();
  kin_.setMirrored(false);
  onTwoThreads([&](int part) {
    kin_.beginList(part);
    if (part == 0) {
      inertia_->hessianPart(0, H_dynamic, offset, psd, approximate);
      if (approximate) addConstantSoftBlock(inertia_->constantSoftBlock(), kin_.reducedValues(0));
    } else {
      if (potential_first) potential_first();
      Mat3* values = kin_.reducedValues(1);
      gravity_->reducedHessian(gravity, H_potential, offset, psd);
      if (!approximate) elastic.elements(0, T, nullptr, values, psd);
      elastic.restStiffness(nullptr, values, 0);
      inertia_->hessianPart(1, H_potential, offset, psd, approximate);
    }
  });
  onTwoThreads([&](int list) { kin_.mirrorReduced(list); });
  kin_.setMirrored(true);
}

}  // namespace flsh::detail
