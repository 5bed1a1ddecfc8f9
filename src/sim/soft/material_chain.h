// The soft skeletons' Material group (SimParameter::Material; docs/adjoint.md): what the node
// and elastic terms need to differentiate their gradients with respect to the material file's
// coefficients. The terms write their derivatives with respect to the coefficient VALUES at the
// avatar's β (c_i, MaterialModel::coefficientValues: numCoefficients() entries); Simulable
// chains those to the file's parameters (a = log c₀, b the log-slopes) once. Built on first use
// and shared by every Simulable of the avatar (SoftAvatar::derived): the per-tet material map's
// geometry costs a pass over the tet mesh and its faces. Private to Simulable.
#pragma once

#include <array>
#include <memory>

#include "flsh/core/types.h"
#include "flsh/volume/cubature.h"
#include "flsh/volume/soft_avatar.h"
#include "flsh/volume/tet_material_map.h"

namespace flsh::detail {

class MaterialChain {
 public:
  explicit MaterialChain(const SoftAvatar& avatar) : avatar_(avatar) {}
  MaterialChain(const MaterialChain&) = delete;
  MaterialChain& operator=(const MaterialChain&) = delete;

  /// The per-tet material map of the avatar's tets at its β.
  const TetMaterialMap& map() const;
  /// The coefficients a node mass depends on (densities of skin and soft tissue, skin
  /// thickness), as indices into the coefficient values.
  const std::array<int, 3>& massCoefficients() const;
  /// ∂m_j/∂c_k (#N × 3, kg per unit of coefficient k of massCoefficients()) of the node masses
  /// (node_masses.h: the same cubature and volumes).
  const MatX3& massDerivatives() const;
  /// numCoefficients().
  int numValues() const;
  /// The chain to and from the file's parameters at the avatar's β.
  VecX parametersCotangent(const VecX& values_bar) const;
  VecX valuesTangent(const VecX& parameters_direction) const;

 private:
  struct Built {
    std::unique_ptr<TetMaterialMap> map;
    std::array<int, 3> mass_coefficients{};
    MatX3 mass_derivatives;
  };
  const Built& built() const;
  const SoftAvatar& avatar_;
  mutable std::shared_ptr<const Built> built_;
};

}  // namespace flsh::detail
