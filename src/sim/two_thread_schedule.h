// A model's own schedule of one evaluation on two threads (private to Simulable): the ROM's node
// terms (SoftTissue) are too small to split one term at a time, so it runs inertia, gravity,
// the elastic elements and contact side by side. Simulable asks it instead of looping over the
// node terms when a model has one, and adds the bones' springs after.
#pragma once

#include <vector>

#include "flsh/sim/energy_term.h"

namespace flsh::detail {

class TwoThreadSchedule {
 public:
  virtual ~TwoThreadSchedule() = default;
  /// The model's node terms' gradient added into g (contact at c.contact's candidates, the
  /// broad phase run); returns their energy.
  virtual double gradient(const TermContext& c, VecX& g, int offset) const = 0;
  /// Both Hessian parts of the node terms: the dynamic one's bone triplets into H_dynamic, the
  /// potential one's into H_potential, their blocks summed into the model's value lists 0 and
  /// 1 (mirrored: a flushList then only hands them over).
  virtual void hessians(const TermContext& c, std::vector<Triplet>& H_dynamic,
                        std::vector<Triplet>& H_potential, int offset, bool psd) const = 0;
  /// A cheaper positive-definite-in-the-soft-state approximation of hessians' exact form, in the
  /// same layout (Simulable::getApproximateHessianTripletVector). False: the model has none
  /// (nothing evaluated).
  virtual bool approximateHessians(const TermContext& c, std::vector<Triplet>& H_dynamic,
                                   std::vector<Triplet>& H_potential, int offset) const {
    return false;
  }
  /// Whether approximateHessians gives one (when not static).
  virtual bool hasApproximateHessians() const { return false; }
};

}  // namespace flsh::detail
