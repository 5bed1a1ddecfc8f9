// A model's kinematics (issue 24 item 3), private to Simulable: the map from the state q to the
// positions of the nodes its terms read, and the chain rule that takes node derivatives back to
// q. Two models of it: SkeletonKinematics (the articulated skeleton: surface vertices skinned by
// the bones, no state of their own) and SoftKinematics (the FEM and ROM soft skeletons: tet
// nodes skinned by the bones plus a soft state). Simulable asks this interface what every model
// answers; the terms use their own model's kinematics directly.
#pragma once

#include <functional>
#include <vector>

#include "flsh/core/types.h"

namespace flsh::detail {

/// Bone transforms an evaluation reads (borrowed).
struct BoneFrames {
  const std::vector<Mat3>& R;  ///< 24 rotations
  const MatX3& t;              ///< 24 × 3 joint positions, m
};

struct SkinnedPoint;

class ModelKinematics {
 public:
  virtual ~ModelKinematics() = default;
  /// Values of the state beyond the bones' 6 per bone (0 for the skeleton).
  virtual int numSoftDofs() const = 0;
  /// Skins the nodes every evaluation reads at the current state (bones + soft state); cached
  /// by `version`.
  virtual void prepare(long version, const BoneFrames& bones) const = 0;
  /// As prepare, for evaluations that read the bones' frames but not the nodes prepare skins
  /// (the bones' presolve: Simulable's bone-only energy and Hessian). A kinematics may defer the
  /// skinning until something asks for it (the ROM's: SoftKinematics::ensurePrepared); the next
  /// prepare() skins.
  virtual void prepareFrames(long version, const BoneFrames& bones) const {
    prepare(version, bones);
  }
  /// For the contact broad phase, at the prepared state: per bone b (`margin`, 24 values), a
  /// bound on how far the surface nodes b dominates are from their skinned rest positions
  /// beyond what the bones' motion explains (pose blend and soft displacement; 0 for the
  /// skeleton).
  virtual void contactMargins(double* margin) const = 0;
  /// After the broad phase, at the prepared state: drops from `candidates` (surface nodes, order
  /// kept) those that provably touch nothing, from a cheap position x̃_i and a bound s_i ≥
  /// ‖x_i − x̃_i‖: node i stays when distance(x̃_i) < s_i (`distance`: the smallest signed
  /// distance to any collider, 1-Lipschitz, so a dropped node has no contact energy). The
  /// default keeps every candidate (its nodes cost no more to skin than to bound).
  virtual void pruneCandidates(const std::function<double(const Vec3&)>& distance,
                               std::vector<int>& candidates) const {}
  /// Surface nodes (the mesh's vertices, in its order).
  virtual int numSurface() const = 0;
  /// World positions and unposed nodes of every surface node (#V × 3) at the prepared state
  /// (either may be null).
  virtual void surface(MatX3* x, MatX3* Y) const = 0;
  /// d(surface nodes)/dq rows (3#V × numDofs) at the prepared state, as triplets.
  virtual void surfaceJacobian(std::vector<Triplet>& triplets) const = 0;
  /// Surface node i at the prepared state as a SkinnedPoint (sim/terms/term_blocks.h: its
  /// bones' weights and lever arms; id set by the caller). The ROM's after surface().
  /// `soft_blocks` false leaves p.soft empty (a caller that reads the bones' part alone: the
  /// ROM with modes forms M_i Ψ_i for them).
  virtual void surfacePoint(int i, SkinnedPoint& p, bool soft_blocks = true) const = 0;
  /// Adds Σ_i J_iᵀ f_i over every surface node (f: #V × 3) into g (numDofs): surfaceJacobian's
  /// transpose product without forming it. The ROM's after surface().
  virtual void surfaceForces(const MatX3& forces, VecX& g) const = 0;
};

}  // namespace flsh::detail
