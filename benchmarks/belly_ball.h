// The benchmarks' "ball" scenario (issue 26's comparison, issue 29's per-motion report): a ball
// of radius 12 cm starts 2 cm in front of the belly of a standing body, presses 4 cm past its
// rest surface at 0.3 m/s and goes back. (At 3 m/s the FEM's Newton fails to converge on the
// impact step and the FEM blows up a few steps later: docs/benchmarks.md.)
#pragma once

#include "flsh/solve/scene.h"

namespace flsh::bench {

inline Collider bellyBall() {
  const double radius = 0.12, speed = 0.3, travel = 0.06;
  const Vec3 belly(0.0, 0.05, 0.11);
  const Vec3 start = belly + Vec3(0.0, 0.0, radius + 0.02);
  const double turn = travel / speed;
  Collider ball = Collider::sphere(start, radius);
  ball.path =
      ColliderPath{{0.0, turn, 2 * turn}, {Vec3::Zero(), Vec3(0.0, 0.0, -travel), Vec3::Zero()}};
  return ball;
}

}  // namespace flsh::bench
