// The state of the solver tests' objectives: a vector x that Newton's steps move, with the
// push/pop stack of its line search (tests/solve/*_test.cpp).
#pragma once

#include <utility>
#include <vector>

#include "flsh/solve/newton.h"

namespace flsh::test {

/// x and its stack; `can_discard`: discardPushed is supported (else Newton falls back to pop
/// and re-applying the accepted step).
class VectorStateObjective : public Objective {
 public:
  explicit VectorStateObjective(VecX x0, bool can_discard = false)
      : x(std::move(x0)), can_discard_(can_discard) {}
  void step(const VecX& dq) override { x += dq; }
  void push() override { stack_.push_back(x); }
  void pop() override {
    x = stack_.back();
    stack_.pop_back();
  }
  bool discardPushed() override {
    if (!can_discard_) return false;
    stack_.pop_back();
    return true;
  }
  /// Pushed states not yet popped or discarded.
  size_t stackDepth() const { return stack_.size(); }

  VecX x;

 private:
  bool can_discard_;
  std::vector<VecX> stack_;
};

}  // namespace flsh::test
