// The stiffnesses and physical settings of a simulable (Simulable, simulable.h), which its energy
// terms read too (TermContext::options, energy_term.h).
#pragma once

#include <vector>

#include "flsh/contact/contact_energy.h"
#include "flsh/core/types.h"

namespace flsh {

/// Stiffnesses and physical settings of a simulable; every default has its unit.
struct SimulableOptions {
  double time_step = 1.0 / 60.0;         ///< h, s
  Vec3 gravity = Vec3(0.0, -9.81, 0.0);  ///< m/s²
  double joint_stiffness = 1.0e5;        ///< k_J, N/m: ½k_J‖R_p(J_b − J_p) + t_p − t_b‖²
  /// Tracking springs ½k_b‖log(R_target,bᵀ R_rel,b)‖² with k_b = ω_T² (I_b + I_floor), where
  /// I_b = Σ m‖X − J_b‖² over the bone's subtree (kg·m²) and I_floor = tracking_inertia_floor:
  /// the joints then track with about the same natural frequency ω_T = sqrt(tracking_stiffness)
  /// (the light distal ones faster). Unit 1/s²; default (2π·3 Hz)².
  double tracking_stiffness = 355.0;
  /// I_floor, kg·m²: the tracking spring of every bone but the root has k_b = ω_T² (I_b + I_floor).
  /// Without it the light distal bones get almost no stiffness (toes and hands of an adult:
  /// I_b ≈ 5e-4 kg·m², k_b ≈ 0.16 N·m/rad, against 640 at the hips) and flap under small
  /// loads: on the FEM walk over a ground plane a toe folded to 115° from its target of 0 as
  /// the foot pushed off. The default 0.01 (about an adult's ankle subtree) gives toes, hands
  /// and wrists 3.7–4.8 N·m/rad (the toe stays within 0.02 rad on that walk) and moves the hips,
  /// spine, knees and shoulders by < 4 %. 0 = the pure inertia scaling.
  double tracking_inertia_floor = 0.01;
  /// Root springs to the mocap root position and orientation, same scaling with the whole
  /// body's mass M and polar inertia about the root: k = root_stiffness · M (N/m) and
  /// root_stiffness · I_0 (N·m/rad²). Unit 1/s²; default (2π·4 Hz)²: the static sag of a body
  /// hanging on its root spring is g/root_stiffness ≈ 1.5 cm (2 Hz sagged 6 cm).
  double root_stiffness = 630.0;
  bool track_mocap = true;  ///< off: no tracking springs (a passive ragdoll)
  /// Bones whose state is prescribed by the mocap (kinematic), e.g. {0} pins the root.
  std::vector<int> kinematic_bones;
  ContactOptions contact;  ///< collider contact on surface vertices
};

}  // namespace flsh
