// Simulable: the energy, gradient and Hessian as sums of its terms (with soft tissue: the bones'
// springs and SoftTissue's node terms), and the scene hooks.
#include <omp.h>

#include <algorithm>

#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "flsh/sim/simulable.h"
#include "flsh/sim/skeleton_energies.h"
#include "sim/simulable_impl.h"

namespace flsh {

using detail::BoneStates;
using detail::kDofsPerBone;

// ---- energies ----------------------------------------------------------------------------
// The skeleton sums its terms (Impl::dynamic_terms, potential_terms); with soft tissue the
// bones' springs are terms and SoftTissue carries the rest.

double Simulable::getDynamicEnergyScalar() const {
  const Impl& m = *impl_;
  if (m.is_static) return 0.0;
  if (m.soft) {
    m.prepareSoft();
    return m.soft->inertia(nullptr, nullptr, 0, true);
  }
  const TermContext c = m.context();
  double E = 0.0;
  for (const EnergyTerm* term : m.dynamic_terms) E += term->evaluate(c, nullptr, 0);
  return E;
}

void Simulable::getDynamicGradientVector(VecX& g, int offset) const { dynamicGradient(g, offset); }

double Simulable::dynamicGradient(VecX& g, int offset) const {
  const Impl& m = *impl_;
  if (m.is_static) return 0.0;
  if (m.soft) {
    m.prepareSoft();
    return m.soft->inertia(&g, nullptr, offset, true);
  }
  const TermContext c = m.context();
  double E = 0.0;
  for (const EnergyTerm* term : m.dynamic_terms) E += term->evaluate(c, &g, offset);
  return E;
}

void Simulable::getDynamicHessianTripletVector(std::vector<Triplet>& H, int offset,
                                               bool psd) const {
  dynamicHessian(H, nullptr, offset, psd);
}

void Simulable::getDynamicHessianTripletVector(std::vector<Triplet>& H,
                                               std::vector<FixedHessianBlocks>& blocks, int offset,
                                               bool psd) const {
  dynamicHessian(H, &blocks, offset, psd);
}

void Simulable::dynamicHessian(std::vector<Triplet>& H, std::vector<FixedHessianBlocks>* blocks,
                               int offset, bool psd) const {
  const Impl& m = *impl_;
  if (m.is_static) return;
  if (m.soft) {
    m.prepareSoft();
    m.soft->beginReduced(0);
    FixedHessianBlocks inertia_blocks;
    m.soft->inertia(nullptr, &H, offset, psd, blocks ? &inertia_blocks : nullptr);
    if (blocks && !inertia_blocks.empty()) blocks->push_back(inertia_blocks);
    m.soft->flushReduced(0, H, offset, blocks);
    return;
  }
  const TermContext c = m.context();
  for (const EnergyTerm* term : m.dynamic_terms) term->addHessian(c, H, offset, psd);
}

double Simulable::getPotentialEnergyScalar() const {
  const Impl& m = *impl_;
  const TermContext c = m.context();
  double E = 0.0;
  if (!m.soft) {
    m.ensureContact();
    for (const EnergyTerm* term : m.potential_terms) E += term->evaluate(c, nullptr, 0);
    return E;
  }
  for (const EnergyTerm* term : m.spring_terms) E += term->evaluate(c, nullptr, 0);
  m.prepareSoft();
  E += m.soft->gravity(m.options.gravity, nullptr, nullptr, 0, true) +
       m.soft->elastic(nullptr, nullptr, 0, true);
  return E + m.contactEnergy();
}

double Simulable::boneSpringGradient(VecX& g, int offset) const {
  const Impl& m = *impl_;
  const TermContext c = m.context();
  double E = 0.0;
  for (const EnergyTerm* term : m.spring_terms) E += term->evaluate(c, &g, offset);
  return E;
}

double Simulable::potentialGradient(VecX& g, int offset) const {
  const Impl& m = *impl_;
  if (!m.soft) {
    m.ensureContact();
    const TermContext c = m.context();
    double E = 0.0;
    for (const EnergyTerm* term : m.potential_terms) E += term->evaluate(c, &g, offset);
    return E;
  }
  double E = boneSpringGradient(g, offset);
  m.prepareSoft();
  E += m.soft->gravity(m.options.gravity, &g, nullptr, offset, true) +
       m.soft->elastic(&g, nullptr, offset, true);
  m.ensureContact();
  return E + m.soft->contact(m.colliders, m.time, m.options.contact, &g, nullptr, offset, true,
                             nullptr, &m.contact.candidates);
}

void Simulable::getPotentialGradientVector(VecX& g, int offset) const {
  potentialGradient(g, offset);
}

void Simulable::getGradientVector(VecX& g, int offset) const {
  getEnergyAndGradientVector(g, offset);
}

double Simulable::getEnergyAndGradientVector(VecX& g, int offset) const {
  const Impl& m = *impl_;
  if (!m.soft || !m.soft->reduced() || m.is_static || omp_get_max_threads() < 2)
    return dynamicGradient(g, offset) + potentialGradient(g, offset);
  // ROM: as getHessianTripletVector.
  const bool contact = m.prepareSoftForThreads();
  double contact_energy = 0.0;
  const double E = m.soft->reducedGradient(m.options.gravity, g, offset, [&](VecX& part) {
    if (contact)
      contact_energy = m.soft->contact(m.colliders, m.time, m.options.contact, &part, nullptr,
                                       offset, true, nullptr, &m.contact.candidates, false);
  });
  return E + contact_energy + boneSpringGradient(g, offset);
}

void Simulable::getPotentialHessianTripletVector(std::vector<Triplet>& H, int offset,
                                                 bool psd) const {
  potentialHessian(H, nullptr, offset, psd);
}

void Simulable::getPotentialHessianTripletVector(std::vector<Triplet>& H,
                                                 std::vector<FixedHessianBlocks>& blocks,
                                                 int offset, bool psd) const {
  potentialHessian(H, &blocks, offset, psd);
}

void Simulable::potentialHessian(std::vector<Triplet>& H, std::vector<FixedHessianBlocks>* blocks,
                                 int offset, bool psd, bool soft_done) const {
  const Impl& m = *impl_;
  const TermContext c = m.context();
  if (!m.soft) {
    m.ensureContact();
    for (const EnergyTerm* term : m.potential_terms) term->addHessian(c, H, offset, psd);
    return;
  }
  for (const EnergyTerm* term : m.spring_terms) term->addHessian(c, H, offset, psd);
  m.prepareSoft();
  // With soft_done the ROM's gravity, elastic and contact blocks are already in value list
  // 1, their bone triplets in getHessianTripletVector's scratch.
  FixedHessianBlocks gravity_blocks, elastic_blocks;
  if (!soft_done) {
    m.soft->beginReduced(1);
    m.soft->gravity(m.options.gravity, nullptr, &H, offset, psd,
                    blocks ? &gravity_blocks : nullptr);
    m.soft->elastic(nullptr, &H, offset, psd, blocks ? &elastic_blocks : nullptr);
  }
  if (blocks)
    for (const FixedHessianBlocks& list : {elastic_blocks, gravity_blocks})
      if (!list.empty()) blocks->push_back(list);
  if (!soft_done) {
    m.ensureContact();
    m.soft->contact(m.colliders, m.time, m.options.contact, nullptr, &H, offset, psd, nullptr,
                    &m.contact.candidates);
  }
  m.soft->flushReduced(1, H, offset, blocks);
}

size_t Simulable::getHessianTripletVector(std::vector<Triplet>& H,
                                          std::vector<FixedHessianBlocks>& blocks, int offset,
                                          bool psd) const {
  const Impl& m = *impl_;
  if (!m.soft || !m.soft->reduced() || m.is_static || omp_get_max_threads() < 2) {
    dynamicHessian(H, &blocks, offset, psd);
    const size_t potential_start = H.size();
    potentialHessian(H, &blocks, offset, psd);
    return potential_start;
  }
  // ROM: inertia beside contact and gravity on two threads, the elastic tets split between
  // them (SoftTissue::reducedHessians); then the bones' springs.
  const bool contact = m.prepareSoftForThreads();
  std::vector<Triplet>& dynamic = m.hessian_scratch[0];
  std::vector<Triplet>& potential = m.hessian_scratch[1];
  dynamic.clear();
  potential.clear();
  m.soft->reducedHessians(m.options.gravity, dynamic, potential, offset, psd, [&] {
    if (contact)
      m.soft->contact(m.colliders, m.time, m.options.contact, nullptr, &potential, offset, psd,
                      nullptr, &m.contact.candidates, false);
  });
  H.insert(H.end(), dynamic.begin(), dynamic.end());
  m.soft->flushReduced(0, H, offset, &blocks);
  const size_t potential_start = H.size();
  potentialHessian(H, &blocks, offset, psd, true);
  H.insert(H.end(), potential.begin(), potential.end());
  return potential_start;
}

void Simulable::fixVectorKinematic(VecX& g, int offset) const {
  const Impl& m = *impl_;
  for (int b = 0; b < m.num_bones; ++b)
    if (m.kinematic[b]) g.segment<6>(offset + 6 * b).setZero();
}

void Simulable::fixMatrixKinematic(std::vector<Triplet>& H, int offset) const {
  const Impl& m = *impl_;
  if (m.options.kinematic_bones.empty()) return;
  auto isKinematic = [&](int index) {
    const int local = index - offset;
    return local >= 0 && local < m.boneDofs() && m.kinematic[local / kDofsPerBone];
  };
  H.erase(std::remove_if(
              H.begin(), H.end(),
              [&](const Triplet& t) { return isKinematic(t.row()) || isKinematic(t.col()); }),
          H.end());
  for (int b = 0; b < m.num_bones; ++b)
    if (m.kinematic[b])
      for (int k = 0; k < kDofsPerBone; ++k)
        H.emplace_back(offset + 6 * b + k, offset + 6 * b + k, 1.0);
}

std::vector<const EnergyTerm*> Simulable::energyTerms() const {
  const Impl& m = *impl_;
  if (!m.soft) return m.terms;
  std::vector<const EnergyTerm*> terms = m.spring_terms;
  for (const EnergyTerm* term : m.soft->terms()) terms.push_back(term);
  return terms;
}

TermContext Simulable::termContext() const {
  const Impl& m = *impl_;
  m.ensureContact();
  if (m.soft) m.prepareSoft();
  return m.context();
}

// ---- scene hooks -------------------------------------------------------------------------

void Simulable::setColliders(std::vector<Collider> colliders) {
  impl_->colliders = std::move(colliders);
  impl_->touch();
}

const std::vector<Collider>& Simulable::colliders() const { return impl_->colliders; }
void Simulable::setStatic(bool on) { impl_->is_static = on; }
bool Simulable::isStatic() const { return impl_->is_static; }
const SoftAvatar& Simulable::avatar() const { return *impl_->avatar; }
std::shared_ptr<const Motion> Simulable::mocap() const { return impl_->mocap; }
const SimulableOptions& Simulable::options() const { return impl_->options; }

SimulableStats Simulable::stats() const {
  SimulableStats s;
  s.active_contacts = impl_->contact.active;
  return s;
}

}  // namespace flsh
