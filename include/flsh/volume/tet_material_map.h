// The per-tet material map of one tet mesh at one shape (docs/materials.md; the adjoint's
// Material group, docs/adjoint.md): from the material model's coefficient values at β
// (MaterialModel::coefficientValues, one value c_i per coefficient) to every tet's density, Fung
// exponent and stiffness, and the reverse-mode derivative of that map.
//
// What stays fixed is the tets' geometry: their orthotropy frames, the skin area they own on the
// surface and their volume (skin fraction f = min(1, A_b · skin_thickness / |vol|)) and their
// region weights (the soft-tissue stiffness factor s = exp(Σ_r ω_r log stiffness_scale_r)). Per
// tet, with the layers' normal stiffness blocks N = S(E, ν)⁻¹ (S the compliance of
// orthotropicStiffness) and shear moduli G:
//   N_tet = f N_skin + (1 − f) s N_tissue,   G_tet = f G_skin + (1 − f) s G_tissue,
//   ρ_tet = f ρ_skin + (1 − f) ρ_tissue,     γ_tet = f γ_skin + (1 − f) γ_tissue,
// and the tet's E_i = 1 / (N_tet⁻¹)_ii, ν from N_tet⁻¹ (computeTetMaterials' Voigt mixture), so
// that its material point (makeFemMaterialPoint) has C = [N_tet, diag(G23, G13, G12)], modulus
// μ = (E1 + E2 + E3)/3 and γ_tet. tissue_fraction and the regions' tissue_scale select the bone
// nodes, a discrete choice made when the avatar is built: the map does not depend on them.
#pragma once

#include <vector>

#include "flsh/core/types.h"
#include "flsh/volume/materials.h"
#include "flsh/volume/tet_mesh.h"

namespace flsh {

struct VolumetricData;

/// What the map keeps of the tets' geometry (one entry per tet).
struct TetMaterialGeometry {
  VecX boundary_area;       ///< area of the tet's faces on the body surface, m² (0 inside)
  VecX volume;              ///< |volume| at the rest nodes, m³
  MatX region_weights;      ///< #T × numRegions(): mean of the four nodes' region weights
  std::vector<Mat3> frame;  ///< orthotropy frames (TetMaterials::frame)
  int size() const { return int(volume.size()); }
};

/// The geometry of `mesh` at `shaped_nodes` (#N × 3) with skinning weights `node_weights`
/// (#N × B) and the tets' frames. InputError on shapes that do not match.
TetMaterialGeometry tetMaterialGeometry(const TetMesh& mesh, const MatX3& shaped_nodes,
                                        const MatX& node_weights, std::vector<Mat3> frames);
/// The same for an avatar's volumetric body (its rest nodes, weights and the frames of its
/// materials).
TetMaterialGeometry tetMaterialGeometry(const VolumetricData& data);

/// Derivative of every tet's boundary area and volume (TetMaterialGeometry) in the rest nodes,
/// for the adjoint's Shape group: d_area, d_volume (#T × D) for D directions of the nodes
/// `shaped_nodes` (#N × 3) of `mesh`, `directions` 3#N × D (row 3j + c: coordinate c of node j;
/// e.g. the shape directions S). InputError on shapes that do not match.
void tetMaterialGeometryTangent(const TetMesh& mesh, const MatX3& shaped_nodes,
                                const MatX& directions, MatX& d_area, MatX& d_volume);

/// Cotangent of one tet's boundary area and volume (the geometry the map reads).
struct TetGeometryCotangent {
  double area = 0.0, volume = 0.0;
};

/// Cotangent (or direction) of one tet's material: its material point's C_world (all 36 entries
/// taken as independent), modulus μ and Fung exponent γ, and its density ρ.
struct TetMaterialCotangent {
  Mat6 C_world = Mat6::Zero();
  double modulus = 0.0, gamma = 0.0, density = 0.0;
};

class TetMaterialMap {
 public:
  /// values: MaterialModel::numCoefficients() coefficient values (MaterialModel::
  /// coefficientValues). InputError on a size that does not match or a value that is not finite
  /// and > 0.
  TetMaterialMap(TetMaterialGeometry geometry, const VecX& values);

  int numTets() const { return geometry_.size(); }
  const VecX& values() const { return values_; }
  const TetMaterialGeometry& geometry() const { return geometry_; }

  /// Every tet's materials (TetMaterials, with the geometry's frames).
  TetMaterials materials() const;
  /// Skin fraction f and soft-tissue stiffness factor s of tet t.
  double skinFraction(int t) const;
  double stiffnessScale(int t) const;

  /// ADDS into values_bar (numCoefficients()) the cotangent of the coefficient values for a
  /// cotangent `bar` of tet t's material point and density.
  /// `geometry_bar` (may be null): ADDS the cotangent of the tet's boundary area and volume too
  /// (through the skin fraction f = A · skin_thickness / |vol| below its cap).
  void addCotangent(int t, const TetMaterialCotangent& bar, VecX& values_bar,
                    TetGeometryCotangent* geometry_bar = nullptr) const;
  /// Direction of tet t's density for directions of the coefficient values (numCoefficients())
  /// and of its boundary area and volume.
  double densityTangent(int t, const VecX& values_direction, double d_area, double d_volume) const;

 private:
  struct Layer {
    double density, fung;
    Vec3 young, poisson, shear;
    Mat3 normal_stiffness;  // N = S(E, ν)⁻¹
  };
  TetMaterialGeometry geometry_;
  VecX values_;
  Layer layers_[MaterialModel::kNumLayers];
  double skin_thickness_ = 0.0;
  VecX log_stiffness_scale_;  // per region
};

}  // namespace flsh
