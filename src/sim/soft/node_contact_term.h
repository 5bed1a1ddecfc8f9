// Collider contact of a soft skeleton's surface nodes (ARCHITECTURE.md §5): the penalty energy
// of contact_energy.h on the skinned surface nodes (the broad phase's candidates), its node
// forces and 3 × 3 node Hessians taken to the state by the kinematics. Private to Simulable.
// Parameter derivatives: Stiffnesses[3] (the contact stiffness, linear), the collider offsets,
// the rest joints, Shape through the nodes' areas a_j(β) (the rest nodes' share of β goes
// through the nodes' unposed positions, nodeOffsetBlocks).
#pragma once

#include <vector>

#include "flsh/contact/collider.h"
#include "flsh/contact/contact_energy.h"
#include "flsh/sim/energy_term.h"
#include "sim/block_hessian_term.h"
#include "sim/contact_term.h"
#include "sim/soft/node_offset_derivatives.h"
#include "sim/soft/node_term.h"
#include "sim/soft/soft_kinematics.h"

namespace flsh::detail {

class NodeContactTerm final : public NodeTerm<1, TermWithParameterBlocks<NodeContactTerm>>,
                              public WithNodeOffsetBlocks<NodeContactTerm>,
                              public ContactTerm {
 public:
  /// `areas`: the surface nodes' vertex areas, m².
  NodeContactTerm(const SoftKinematics& kinematics, VecX areas)
      : NodeTerm(kinematics), areas_(std::move(areas)) {}
  /// ∂g/∂p as local blocks (term_blocks.h), at the broad phase's candidates.
  template <class Sink>
  void parameterBlocks(const TermContext& c, Sink& sink) const;
  /// ∂g/∂Y as local blocks (node_offset_blocks.h), at the broad phase's candidates.
  template <class Sink>
  void nodeOffsetBlocks(const TermContext& c, Sink& sink) const;

  const char* name() const override { return "node contact"; }
  /// The energy and the touching pairs at the broad phase's candidates (skinning them first in
  /// the ROM).
  void refresh(const TermContext& c, SurfaceContactState& s) const override {
    s.energy = evaluate(c.colliders, c.time, c.options.contact, nullptr, nullptr, 0, true,
                        &s.active, &s.candidates);
  }
  /// At the context's colliders, time and broad-phase candidates; the energy alone is the one
  /// the simulable's broad phase evaluated with them (c.contact.energy).
  double evaluate(const TermContext& c, VecX* g, int offset) const override {
    if (!g) return c.contact.energy;
    return evaluate(c.colliders, c.time, c.options.contact, g, nullptr, offset, true, nullptr,
                    &c.contact.candidates);
  }
  /// Triplets (FEM) or bone triplets and the handle blocks into list 1 (ROM).
  void addHessianBlocks(const TermContext& c, std::vector<Triplet>& H,
                        std::vector<FixedHessianBlocks>* blocks, int offset,
                        bool psd) const override;

  /// Penalty contact of the surface nodes against colliders at time t: of `candidates`
  /// (surface node indices; a broad phase's: the others must be out of contact) or, null, every
  /// one. The ROM skins the nodes first unless `skin` is false (skinned before, e.g. ahead of a
  /// two-thread evaluation). Hessian: FEM triplets into H, ROM blocks into value list 1.
  double evaluate(const std::vector<Collider>& colliders, double time,
                  const ContactOptions& options, VecX* g, std::vector<Triplet>* H, int offset,
                  bool psd, int* active = nullptr, const std::vector<int>* candidates = nullptr,
                  bool skin = true) const;

 private:
  /// The candidates' positions and areas into x_, node_areas_ (skinning them in the ROM).
  const std::vector<int>& gather(const std::vector<int>* candidates, bool skin) const;
  VecX areas_;
  mutable MatX3 x_;
  mutable VecX node_areas_;
};

}  // namespace flsh::detail
