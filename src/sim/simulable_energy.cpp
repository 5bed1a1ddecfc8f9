// Simulable: the energy, gradient and Hessian as sums of its terms (with soft tissue: the bones'
// springs and SoftTissue's node terms), and the scene hooks.
#include <omp.h>

#include <algorithm>

#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "flsh/energy/skeleton_energies.h"
#include "flsh/sim/simulable.h"
#include "sim/simulable_impl.h"

namespace flsh {

using detail::BoneStates;
using detail::kDofsPerBone;

// ---- energies ----------------------------------------------------------------------------
// One loop per quantity over the model's terms (Impl::dynamic_terms, potential_terms: the
// skeleton's, or the bones' springs and the soft tissue's node terms); the Hessian loops take
// the terms' block forms where they have one, between a begin and a flush of the model's value
// lists. A model may have its own schedule of its node terms on two threads (the ROM's:
// TwoThreadSchedule, runsOnTwoThreads).

namespace {

double sumEnergies(const std::vector<detail::TermEntry>& terms, const TermContext& c, VecX* g,
                   int offset, bool bones_only = false) {
  double E = 0.0;
  for (const detail::TermEntry& entry : terms)
    if (!bones_only || entry.term->dependsOnBones()) E += entry.term->evaluate(c, g, offset);
  return E;
}

}  // namespace

double Simulable::getDynamicEnergyScalar() const {
  const Impl& m = *impl_;
  if (m.is_static) return 0.0;
  return sumEnergies(m.dynamic_terms, m.context(), nullptr, 0);
}

void Simulable::getDynamicGradientVector(VecX& g, int offset) const { dynamicGradient(g, offset); }

double Simulable::dynamicGradient(VecX& g, int offset) const {
  const Impl& m = *impl_;
  if (m.is_static) return 0.0;
  return sumEnergies(m.dynamic_terms, m.context(), &g, offset);
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
                               int offset, bool psd, bool bones_only) const {
  const Impl& m = *impl_;
  if (m.is_static) return;
  TermContext c = m.context();
  c.bone_block_only = bones_only;
  if (m.value_lists) m.value_lists->beginList(0);
  for (const detail::TermEntry& entry : m.dynamic_terms)
    if (!bones_only || entry.term->dependsOnBones())
      detail::addTermHessian(entry, c, H, blocks, offset, psd);
  if (m.value_lists) m.value_lists->flushList(0, H, offset, blocks);
}

double Simulable::getPotentialEnergyScalar() const {
  const Impl& m = *impl_;
  m.ensureContact();
  return sumEnergies(m.potential_terms, m.context(), nullptr, 0);
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
  m.ensureContact();
  return sumEnergies(m.potential_terms, m.context(), &g, offset);
}

void Simulable::getPotentialGradientVector(VecX& g, int offset) const {
  potentialGradient(g, offset);
}

void Simulable::getGradientVector(VecX& g, int offset) const {
  getEnergyAndGradientVector(g, offset);
}

double Simulable::getEnergyAndGradientVector(VecX& g, int offset) const {
  const Impl& m = *impl_;
  if (!m.runsOnTwoThreads()) return dynamicGradient(g, offset) + potentialGradient(g, offset);
  // The model's schedule (the ROM: inertia, gravity and the elastic tets beside contact), then
  // the bones' springs.
  m.ensureContact();
  const double E = m.schedule->gradient(m.context(), g, offset);
  return E + boneSpringGradient(g, offset);
}

namespace {
/// Impl::frames_only for the lifetime of a bone-only evaluation.
class FramesOnly {
 public:
  explicit FramesOnly(const Simulable::Impl& m) : m_(m) { m_.frames_only = true; }
  ~FramesOnly() { m_.frames_only = false; }
  FramesOnly(const FramesOnly&) = delete;
  FramesOnly& operator=(const FramesOnly&) = delete;

 private:
  const Simulable::Impl& m_;
};
}  // namespace

double Simulable::getBoneEnergyAndGradientVector(VecX& g, int offset) const {
  const Impl& m = *impl_;
  const FramesOnly frames_only(m);
  m.ensureContact();
  TermContext c = m.context();
  c.bone_block_only = true;  // the presolve reads the bones' rows alone
  const double dynamic = m.is_static ? 0.0 : sumEnergies(m.dynamic_terms, c, &g, offset, true);
  return dynamic + sumEnergies(m.potential_terms, c, &g, offset, true);
}

void Simulable::getBoneHessianTripletVector(std::vector<Triplet>& H,
                                            std::vector<FixedHessianBlocks>& blocks, int offset,
                                            bool psd) const {
  const FramesOnly frames_only(*impl_);
  dynamicHessian(H, &blocks, offset, psd, true);
  potentialHessian(H, &blocks, offset, psd, false, true);
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
                                 int offset, bool psd, bool soft_done, bool bones_only) const {
  const Impl& m = *impl_;
  m.ensureContact();
  TermContext c = m.context();
  c.bone_block_only = bones_only;
  if (soft_done) {
    // The two-thread schedule summed the node terms (value list 1, their bone triplets in its
    // scratch): the bones' springs remain.
    for (const EnergyTerm* term : m.spring_terms) term->addHessian(c, H, offset, psd);
  } else {
    if (m.value_lists) m.value_lists->beginList(1);
    for (const detail::TermEntry& entry : m.potential_terms)
      if (!bones_only || entry.term->dependsOnBones())
        detail::addTermHessian(entry, c, H, blocks, offset, psd);
  }
  if (m.value_lists) m.value_lists->flushList(1, H, offset, blocks);
}

size_t Simulable::getHessianTripletVector(std::vector<Triplet>& H,
                                          std::vector<FixedHessianBlocks>& blocks, int offset,
                                          bool psd) const {
  const Impl& m = *impl_;
  if (!m.runsOnTwoThreads()) {
    dynamicHessian(H, &blocks, offset, psd);
    const size_t potential_start = H.size();
    potentialHessian(H, &blocks, offset, psd);
    return potential_start;
  }
  // ROM: inertia beside contact and gravity on two threads, the elastic tets split between
  // them (SoftTissue::reducedHessians; both value lists come back summed); then the bones'
  // springs.
  m.ensureContact();
  std::vector<Triplet>& dynamic = m.hessian_scratch[0];
  std::vector<Triplet>& potential = m.hessian_scratch[1];
  dynamic.clear();
  potential.clear();
  m.schedule->hessians(m.context(), dynamic, potential, offset, psd);
  return appendScheduledHessian(H, blocks, offset, psd);
}

size_t Simulable::appendScheduledHessian(std::vector<Triplet>& H,
                                         std::vector<FixedHessianBlocks>& blocks, int offset,
                                         bool psd) const {
  const Impl& m = *impl_;
  const std::vector<Triplet>& dynamic = m.hessian_scratch[0];
  const std::vector<Triplet>& potential = m.hessian_scratch[1];
  H.insert(H.end(), dynamic.begin(), dynamic.end());
  m.value_lists->flushList(0, H, offset, &blocks);
  const size_t potential_start = H.size();
  potentialHessian(H, &blocks, offset, psd, true);
  H.insert(H.end(), potential.begin(), potential.end());
  return potential_start;
}

bool Simulable::hasApproximateHessian() const {
  const Impl& m = *impl_;
  // The schedule's form on one thread too (onTwoThreads runs both parts there).
  return m.schedule && !m.is_static && m.schedule->hasApproximateHessians();
}

bool Simulable::getApproximateHessianTripletVector(std::vector<Triplet>& H,
                                                   std::vector<FixedHessianBlocks>& blocks,
                                                   int offset, size_t* potential_start) const {
  const Impl& m = *impl_;
  if (!hasApproximateHessian()) return false;
  m.ensureContact();
  std::vector<Triplet>& dynamic = m.hessian_scratch[0];
  std::vector<Triplet>& potential = m.hessian_scratch[1];
  dynamic.clear();
  potential.clear();
  if (!m.schedule->approximateHessians(m.context(), dynamic, potential, offset)) return false;
  const size_t start = appendScheduledHessian(H, blocks, offset, false);
  if (potential_start) *potential_start = start;
  return true;
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

std::vector<const EnergyTerm*> Simulable::energyTerms() const { return impl_->terms; }

TermContext Simulable::termContext() const {
  impl_->ensureContact();
  return impl_->context();
}

// ---- scene hooks -------------------------------------------------------------------------

void Simulable::setColliders(std::vector<Collider> colliders) {
  impl_->colliders = std::move(colliders);
  impl_->touch();
}

const std::vector<Collider>& Simulable::colliders() const { return impl_->colliders; }
void Simulable::setStatic(bool on) {
  impl_->is_static = on;
  impl_->touch();
}
bool Simulable::isStatic() const { return impl_->is_static; }
const SoftAvatar& Simulable::avatar() const { return *impl_->avatar; }
std::shared_ptr<const Motion> Simulable::mocap() const { return impl_->mocap; }
const SimulableOptions& Simulable::options() const { return impl_->options; }

int Simulable::restSplitBoundedSamples() const {
  const Impl& m = *impl_;
  if (!m.soft) return 0;
  m.prepare();
  return m.soft->restSplitBoundedSamples();
}

SimulableStats Simulable::stats() const {
  SimulableStats s;
  s.active_contacts = impl_->contact.active;
  return s;
}

}  // namespace flsh
