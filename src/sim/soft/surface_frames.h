// The soft skeletons' surface for many states at once (Simulable::getNodesOfFrames and
// getNodesCotangentsOfFrames): a rollout's output and its loss's cotangent. Per state the
// surface x_i = Σ_b w_ib (R_b (Y_i − J_b) + t_b) reads, for every surface node, its pose blend
// shapes (207 × 3 values) and its soft basis rows (the ROM's modes: r × 3); over many states
// those reads become two matrix products each way, and only the skinning stays per state:
//   Y = X̄ + P(held R) + u(soft):  P = features · posedirsᵀ, u = z · Ψᵀ (one row per state);
//   dL/dY_i = M_iᵀ dL/dx_i (M_i = Σ_b w_ib R_b) per state, then the soft state's cotangent
//   dL/dY · Ψ and the held rotations' through posedirs, again one product for all states.
#pragma once

#include <vector>

#include "flsh/core/types.h"
#include "flsh/sim/simulable.h"
#include "sim/soft/soft_kinematics.h"

namespace flsh::detail {

/// Surface nodes of each frame: #frames × 3#V (row-major rows: 3i + c).
RowMatX surfaceOfFrames(const SoftKinematics& kin, const std::vector<SurfaceFrame>& frames);

/// The cotangents of a loss on the surface of each frame (dL_dnodes: #frames × 3#V).
struct SurfaceFrameCotangents {
  RowMatX state;      ///< #frames × numDofs: the state's (increments)
  RowMatX rotations;  ///< #frames × 3·#bones: the held rotations' (world increments)
  RowMatX unposed;    ///< #frames × 3#V: dL/dY (the held offsets' and the rest nodes')
  VecX rest_joints;   ///< 3·#bones, summed over the frames
};
SurfaceFrameCotangents surfaceCotangentsOfFrames(const SoftKinematics& kin,
                                                 const std::vector<SurfaceFrame>& frames,
                                                 const RowMatX& dL_dnodes);

}  // namespace flsh::detail
