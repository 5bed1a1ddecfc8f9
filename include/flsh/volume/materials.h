// Soft-tissue materials of the volumetric body (ARCHITECTURE.md §3; file format and defaults in
// docs/materials.md): a log-linear model of every coefficient in the body shape β, and its
// evaluation per tet with a local orthotropy frame.
//
// Every coefficient c is c(β) = c₀ · exp(bᵀβ), i.e. log c = a + bᵀβ with a = log c₀: c₀ is the
// value of the mean shape (β = 0) and b (K values) its log-slopes. Two layers carry the
// elastic and inertial coefficients: skin (within skin_thickness of the surface) and the soft
// tissue below; two body-level quantities set the geometry of the layers.
#pragma once

#include <string>
#include <vector>

#include "flsh/core/types.h"
#include "flsh/volume/tet_mesh.h"

namespace flsh {

class MaterialModel {
 public:
  static constexpr int kSkin = 0;        ///< layer index of the skin
  static constexpr int kSoftTissue = 1;  ///< layer index of the tissue below the skin
  static constexpr int kNumLayers = 2;
  static constexpr int kBodyLevel = -1;  ///< "layer" of the body-level quantities
  /// "Layer" of body region r's quantities: kFirstRegion + r, r in [0, numRegions()).
  static constexpr int kFirstRegion = 10;
  static int regionLevel(int region) { return kFirstRegion + region; }

  /// Layered quantities, in file and parameter order: density (kg/m³); Young's moduli E1, E2,
  /// E3 (Pa) along a1 (bone direction), a2 (around the limb), a3 (inward normal); Poisson ratios
  /// nu12, nu13, nu23 (ν_ij = −ε_j/ε_i under uniaxial stress along a_i); shear moduli G12,
  /// G13, G23 (Pa); fung_gamma (dimensionless Fung stiffening exponent).
  static const std::vector<std::string>& layerQuantities();
  /// Body-level quantities: skin_thickness (m) and tissue_fraction (local soft-tissue thickness
  /// over local body radius, dimensionless, < 1).
  static const std::vector<std::string>& bodyQuantities();
  /// "skin", "soft_tissue".
  static const std::vector<std::string>& layerNames();
  /// Body regions (docs/materials.md, "Body regions"), in parameter order: torso, thighs, shins,
  /// feet, head, upper_arms, forearms, hands.
  static const std::vector<std::string>& regionNames();
  static int numRegions() { return int(regionNames().size()); }
  /// Region quantities, in parameter order: tissue_scale (multiplies tissue_fraction) and
  /// stiffness_scale (multiplies the soft-tissue layer's Young's and shear moduli); both
  /// dimensionless, > 0.
  static const std::vector<std::string>& regionQuantities();
  /// Region of an SMPL bone (joint index; the 24 bones of SMPL's kinematic tree): pelvis, spine
  /// and collars → torso, hips → thighs, knees → shins, ankles and toes → feet, neck and head →
  /// head, shoulders → upper_arms, elbows → forearms, wrists and hands → hands. Bones beyond 23
  /// (other skeletons) → torso. InputError for a negative bone.
  static int regionOfBone(int bone);
  /// Region weights of points with skinning weights `bone_weights` (#rows × B, rows ≥ 0 summing
  /// to 1): ω_r = Σ_{b in region r} w_b, #rows × numRegions(), rows sum to 1. As smooth as the
  /// skinning weights.
  static MatX regionWeights(const MatX& bone_weights);

  /// Plausible human defaults (docs/materials.md) for a body with num_betas shape components
  /// (log-slopes only on β₀ and β₁; zero beyond). data/materials/default.json holds the same
  /// coefficients for 10 components. Throws InputError for num_betas < 0.
  static MaterialModel defaults(int num_betas);
  /// Reads a material file for a body with num_betas components. Strict: unknown or missing
  /// keys, wrong types or sizes, non-finite or non-positive values, ν ≥ 0.5, an orthotropic
  /// compliance that is not positive definite, tissue_fraction ≥ 1, or a non-zero log-slope
  /// beyond num_betas → InputError naming the file and the key path; a path that is not a
  /// regular file (a FIFO, a directory) or JSON nested deeper than io::kMaxJsonDepth →
  /// InputError naming the path; missing or unreadable → FileError. Shorter slope lists are
  /// zero padded.
  static MaterialModel load(const std::string& path, int num_betas);
  /// Writes the JSON file atomically (FileError on failure). load(save(m)) == m exactly.
  void save(const std::string& path) const;
  /// Deterministic JSON text (sorted keys, shortest round-trip numbers): the file content of
  /// save(), and what the avatar cache hashes.
  std::string canonicalText() const;
  /// Parses canonical (or any valid) text; `origin` names the source in messages.
  static MaterialModel fromText(const std::string& text, int num_betas,
                                const std::string& origin = "material text");

  int numBetas() const { return num_betas_; }

  /// c(β) of a quantity: layer kSkin / kSoftTissue for layered quantities, kBodyLevel for body
  /// quantities, regionLevel(r) for region quantities. β may be shorter than numBetas() (zero
  /// padded), not longer. InputError on an unknown quantity, a wrong layer or a bad β.
  double value(const std::string& quantity, int layer, const VecX& betas) const;
  /// A region quantity blended at points with region weights ω (#rows × numRegions(), from
  /// regionWeights): s = exp(Σ_r ω_r log s_r(β)) per row, a weighted geometric mean, so that
  /// log s stays linear in every coefficient's (a, b) (∂ log s / ∂a_r = ω_r, ∂ log s / ∂b_r =
  /// ω_r β) and smooth wherever the weights are. InputError on shapes, a non-region quantity or
  /// a bad β.
  VecX blendedRegionValue(const std::string& quantity, const MatX& region_weights,
                          const VecX& betas) const;
  /// d c(β) / d(a, b) (1 + K values): c(β) · [1, β] (β zero padded to K).
  VecX valueGradient(const std::string& quantity, int layer, const VecX& betas) const;

  /// All coefficients as one vector for fitting: per coefficient (layered quantities for skin,
  /// then soft tissue, then body quantities, then region quantities region by region, each in
  /// the order above) a = log c₀ followed by its K log-slopes b.
  /// numParameters() = (2·11 + 2 + 8·2)(1 + K).
  VecX parameters() const;
  /// Inverse of parameters(); then validates like load() (InputError naming "parameters").
  void setParameters(const VecX& parameters);
  int numParameters() const;
  /// Offset of (quantity, layer)'s a in parameters(); its b follows.
  int parameterOffset(const std::string& quantity, int layer) const;
  /// Names of parameters()' entries: "<key>.log_value" for a = log c₀ and "<key>.log_slopes[k]"
  /// for b_k, with <key> the file's key path ("layers.skin.E1", "body.skin_thickness",
  /// "regions.thighs.stiffness_scale").
  std::vector<std::string> parameterNames() const;

  /// The coefficients' values at β in parameters()' coefficient order (numCoefficients()
  /// values c_i(β) = c₀ exp(bᵀβ); β zero padded): what the per-tet material map reads
  /// (tet_material_map.h). InputError on a bad β.
  VecX coefficientValues(const VecX& betas) const;
  static int numCoefficients();
  /// Index of (quantity, layer) in coefficientValues(); InputError as value().
  int coefficientIndex(const std::string& quantity, int layer) const {
    return index(quantity, layer);
  }
  /// The chain between the two: a cotangent of the values (numCoefficients()) to one of
  /// parameters() (∂c_i/∂a_i = c_i, ∂c_i/∂b_i = c_i β), and a direction of parameters() to one
  /// of the values. InputError on sizes that do not match.
  VecX parametersCotangent(const VecX& values_bar, const VecX& betas) const;
  VecX coefficientValuesTangent(const VecX& parameters_direction, const VecX& betas) const;
  /// d coefficientValues / dβ (numCoefficients() × K): row i = c_i(β) b_iᵀ. InputError on a bad
  /// β.
  MatX coefficientValuesShapeJacobian(const VecX& betas) const;

  /// Value at β = 0 (c₀) and log-slopes (K) of one coefficient.
  double baseValue(const std::string& quantity, int layer) const;
  const VecX& logSlopes(const std::string& quantity, int layer) const;
  void setCoefficient(const std::string& quantity, int layer, double base_value,
                      const VecX& log_slopes);

  /// Throws InputError (prefixed by `origin`) unless every coefficient is finite and positive,
  /// the Poisson ratios are < 0.5, each layer's orthotropic compliance at β (or β = 0 when
  /// empty) is positive definite and tissue_fraction × every region's tissue_scale is < 1.
  void validate(const std::string& origin, const VecX& betas = VecX()) const;

  bool operator==(const MaterialModel& other) const;
  bool operator!=(const MaterialModel& other) const { return !(*this == other); }

 private:
  struct Coefficient {
    double base = 1.0;  ///< c₀ > 0
    VecX slopes;        ///< K
  };
  int index(const std::string& quantity, int layer) const;  // into coefficients_
  int num_betas_ = 0;
  /// layered (skin, soft tissue), then body-level, then per region its region quantities
  std::vector<Coefficient> coefficients_;
};

/// The normal block of an orthotropic compliance (docs/materials.md): [[1/E1, −ν12/E1, −ν13/E1],
/// [−ν12/E1, 1/E2, −ν23/E2], [−ν13/E1, −ν23/E2, 1/E3]] for young = (E1, E2, E3), poisson =
/// (ν12, ν13, ν23). No checks.
Mat3 normalCompliance(const Vec3& young, const Vec3& poisson);

/// Materials of every tet of the body at one β.
struct TetMaterials {
  VecX density;   ///< #T, kg/m³
  MatX3 young;    ///< #T × 3: E1, E2, E3, Pa (along a1, a2, a3)
  MatX3 poisson;  ///< #T × 3: ν12, ν13, ν23
  MatX3 shear;    ///< #T × 3: G12, G13, G23, Pa
  VecX fung;      ///< #T: Fung exponent γ (dimensionless)
  /// #T frames; columns a1 (bone axis projected on the tangent plane), a2 = a3 × a1, a3 (inward
  /// normal of the nearest surface point); orthonormal, det +1.
  std::vector<Mat3> frame;
  /// #T: the layer holding most of the tet's volume, 0 skin, 1 soft tissue.
  VecXi layer;
  /// #T: fraction of the tet's volume that is skin, in [0, 1]: min(1, A_b·t / vol) with A_b the
  /// tet's area on the surface and t = skin_thickness(β), so that the skin volume over all tets
  /// is the surface area times t. Tets are much thicker than skin at the default resolution, so
  /// boundary tets are mixtures: density and Fung exponent are volume averages, the stiffness
  /// tensor the volume average (Voigt) of the two layers' orthotropic stiffness tensors in the
  /// tet's frame, converted back to E, ν, G. A tet with fraction 0 (1) has the soft-tissue
  /// (skin) coefficients exactly.
  VecX skin_fraction;
  /// #T: the factor on the soft-tissue layer's Young's and shear moduli in this tet (before the
  /// skin mixture): the regions' stiffness_scale blended at the mean of the tet's four node
  /// weights (MaterialModel::blendedRegionValue). Empty in data built before body regions.
  VecX tissue_stiffness_scale;
};

/// Per-tet materials of the body shape β:
///   mesh: the tet mesh (nodes 0..V−1 on the surface), shaped_nodes: #N × 3 rest nodes X̄(β), m,
///   node_weights: #N × B skinning weights, joints: B × 3 rest joints J(β), m, parents: B,
///   model: the material model, betas: ≤ K values.
/// a3 is the inward normal (interpolated vertex normal) at the surface point nearest to the tet
/// centroid; a1 is the axis of the tet's dominant bone (largest summed node weight; the axis of
/// fitBoneCapsules) projected on the tangent plane; where that projection is shorter than 0.2
/// (axis within ~11° of the normal: head top, soles, finger tips) the world axis least aligned
/// with a3 is projected instead, so a frame is always defined. A tet inverted by the shape
/// (X̄₀ + S β can flip a sliver at large β) gets materials from its |volume|; detecting it is the
/// simulation's job. Throws InputError on shapes or when the model is not physical at β.
TetMaterials computeTetMaterials(const TetMesh& mesh, const MatX3& shaped_nodes,
                                 const MatX& node_weights, const MatX3& joints,
                                 const std::vector<int>& parents, const MaterialModel& model,
                                 const VecX& betas);

/// Per tet (#T) the factor on the soft-tissue layer's moduli: the regions' stiffness_scale at β
/// blended (MaterialModel::blendedRegionValue) at the mean of the tet's four rows of
/// node_weights (#N × B). Throws InputError on shapes.
VecX tetTissueStiffnessScale(const TetMesh& mesh, const MatX& node_weights,
                             const MaterialModel& model, const VecX& betas);

/// Local soft-tissue thickness per surface vertex (V, m): tissue_fraction(β) × the regions'
/// tissue_scale blended at the vertex's skinning weights (MaterialModel::blendedRegionValue) ×
/// the local body radius, the distance of the vertex to its dominant bone's axis segment
/// (fitBoneCapsules).
///   surface_vertices: V × 3 shaped rest vertices (m), surface_weights: V × B, joints: B × 3,
///   parents: B.
VecX surfaceTissueThickness(const MatX3& surface_vertices, const MatX& surface_weights,
                            const MatX3& joints, const std::vector<int>& parents,
                            const MaterialModel& model, const VecX& betas);

}  // namespace flsh
