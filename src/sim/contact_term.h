// What Simulable's contact broad phase asks of a model's collider-contact term (private):
// SurfaceContactTerm (the skeleton's skinned surface) and NodeContactTerm (a soft skeleton's
// surface nodes) both answer it, so the broad phase runs the same for every model.
#pragma once

#include "flsh/sim/energy_term.h"

namespace flsh::detail {

class ContactTerm {
 public:
  virtual ~ContactTerm() = default;
  /// At the candidates the broad phase put in `s` and the prepared kinematics: sets the energy,
  /// the number of touching vertex–collider pairs (s.active), and whatever the term's later
  /// evaluations at this state read from `s`. `c.contact` is `s`.
  virtual void refresh(const TermContext& c, SurfaceContactState& s) const = 0;
};

}  // namespace flsh::detail
