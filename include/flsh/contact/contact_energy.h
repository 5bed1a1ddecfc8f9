// Penalty contact energies (ARCHITECTURE.md §5):
//   E = k_c/2 Σ_i a_i max(0, −d(x_i))²   over surface vertices x_i with areas a_i.
// Units: k_c in N/m³ (so that k_c a_i d² is an energy in J).
#pragma once

#include <vector>

#include "flsh/contact/collider.h"
#include "flsh/core/types.h"

namespace flsh {

struct ContactOptions {
  double stiffness = 2.0e6;  ///< k_c, N/m³ (1 cm penetration of 1 cm² costs 0.01 J)
  /// Keep the curvature term a_i k d ∇²d of the Hessian (exact, may be indefinite: the adjoint
  /// needs it); off = Gauss–Newton form a_i k ∇d ∇dᵀ (positive semidefinite: Newton uses it).
  bool exact_hessian = false;
};

/// One active contact, for outputs and diagnostics.
struct ContactPoint {
  int vertex = -1;
  int collider = -1;  ///< index in the collider list (or capsule index for avatar contact)
  double distance = 0.0;  ///< signed distance (< 0 when active)
};

/// Per-vertex contact energy of points X (#X × 3, areas #X) against colliders at time t.
/// Adds the gradient w.r.t. X (3#X, row 3i + c) into *gradient and the 3 × 3 diagonal Hessian
/// blocks into *hessian (indices 3i + c, offset by `offset`) when not null. Returns the energy.
double colliderContactEnergy(const Eigen::Ref<const MatX3>& X, const Eigen::Ref<const VecX>& areas,
                             const std::vector<Collider>& colliders, double t,
                             const ContactOptions& options, VecX* gradient = nullptr,
                             std::vector<Triplet>* hessian = nullptr, int offset = 0,
                             std::vector<ContactPoint>* active = nullptr);

/// The same energy with its gradient (optional, ADDED as above) and each point's 3 × 3 Hessian
/// block (`blocks` resized to #X; zero where a point touches nothing; exact or Gauss–Newton as
/// `options` says): the energy couples a point with itself only, so this is the whole Hessian,
/// in the form kinematics that map per-point forces and blocks to a state want.
double colliderContactBlocks(const Eigen::Ref<const MatX3>& X, const Eigen::Ref<const VecX>& areas,
                             const std::vector<Collider>& colliders, double t,
                             const ContactOptions& options, VecX* gradient,
                             std::vector<Mat3>& blocks,
                             std::vector<ContactPoint>* active = nullptr);

/// Penalty of one vertex against one capsule (a, b, r) with weight k·area: value and its
/// derivatives w.r.t. (x, a, b). Returns 0 (and zero derivatives) when not penetrating.
double vertexCapsulePenalty(const Vec3& x, const Vec3& a, const Vec3& b, double r,
                            double stiffness_area, const ContactOptions& options,
                            Eigen::Matrix<double, 9, 1>* gradient = nullptr,
                            Eigen::Matrix<double, 9, 9>* hessian = nullptr);

}  // namespace flsh
