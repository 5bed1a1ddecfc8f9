// The mass properties of one rigid bone, the data the skeleton's energy kernels
// (skeleton_energies.h) read; volume/ computes them per avatar (SoftAvatar::boneInertia).
#pragma once

#include "flsh/core/types.h"

namespace flsh {

/// Mass properties of one bone in the rest pose, about the bone's joint centre J_b, in the
/// world-aligned rest frame: a material point X of the bone moves as x = R_b (X − J_b) + t_b.
struct BoneInertia {
  double mass = 0.0;                  ///< Σ m, kg
  Vec3 first_moment = Vec3::Zero();   ///< Σ m (X − J_b), kg·m
  Mat3 second_moment = Mat3::Zero();  ///< Σ m (X − J_b)(X − J_b)ᵀ, kg·m²
  Vec3 centerOfMass(const Vec3& joint) const { return joint + first_moment / mass; }
};

}  // namespace flsh
