// The soft skeletons' Shape group (SimParameter::Shape; docs/adjoint.md): how β moves what the
// node and elastic terms read, at the avatar's discretization (SoftAvatar::withShape):
//  - the rest nodes X̄(β) = X̄₀ + S β (S: the interior fields' shape directions, 3 × K per node);
//  - the material coefficient values c(β) (MaterialModel::coefficientValuesShapeJacobian);
//  - every tet's boundary area and volume at X̄(β), which the per-tet material map reads
//    (tet_material_map.h: the skin fraction);
//  - the node masses m_j = Σ w ρ_t vol_t / 4 through all three (node_masses.h).
// The rest joints and bone inertias chain as for the skeleton (sim_parameter.h). The terms
// write ∂g/∂β from these; built on first use and shared by every Simulable of the avatar
// (SoftAvatar::derived). Private to Simulable.
#pragma once

#include <memory>

#include "flsh/core/types.h"
#include "flsh/energy/fem_material.h"
#include "flsh/volume/soft_avatar.h"
#include "flsh/volume/tet_material_map.h"
#include "sim/soft/material_chain.h"

namespace flsh::detail {

class ShapeChain {
 public:
  ShapeChain(const SoftAvatar& avatar, const MaterialChain& materials)
      : avatar_(avatar), materials_(materials) {}
  ShapeChain(const ShapeChain&) = delete;
  ShapeChain& operator=(const ShapeChain&) = delete;

  int numBetas() const { return int(avatar_.betas().size()); }
  /// ∂X̄_j/∂β (3 × K).
  Eigen::Block<const MatX, 3, Eigen::Dynamic> nodeDirections(int j) const;
  /// ADDS Σ_j (∂X̄_j/∂β)ᵀ X_bar_j (X_bar: rows for nodes 0 … rows − 1, at most #N) into
  /// beta_bar (K).
  void addNodeCotangent(const MatX3& X_bar, VecX& beta_bar) const;
  /// ADDS Σ_a (∂X̄_{nodes[a]}/∂β)ᵀ X_bar.col(a) into beta_bar (a tet's four nodes).
  void addTetNodesCotangent(const Eigen::Vector4i& nodes, const Mat34& X_bar, VecX& beta_bar) const;
  /// ADDS tet t's boundary area and volume cotangent's share into beta_bar.
  void addGeometryCotangent(int t, const TetGeometryCotangent& geometry, VecX& beta_bar) const;
  /// dX̄ = S dβ (#N × 3).
  MatX3 nodeTangent(const VecX& dbeta) const;
  /// ∂c/∂β (numCoefficients() × K).
  const MatX& valuesJacobian() const;
  /// ∂(boundary area, |volume|)/∂β of every tet (#T × K each).
  const MatX& areaJacobian() const;
  const MatX& volumeJacobian() const;
  /// ∂m_j/∂β (#N × K) of the node masses: rest volumes, densities through c(β) and the skin
  /// fraction.
  const MatX& massJacobian() const;

 private:
  struct Built {
    MatX values, area, volume, mass;
  };
  const Built& built() const;
  const SoftAvatar& avatar_;
  const MaterialChain& materials_;
  mutable std::shared_ptr<const Built> built_;
};

}  // namespace flsh::detail
