// Elastic kernel of the FEM soft skeleton (ARCHITECTURE.md §4): orthotropic St. Venant–Kirchhoff
// with Fung saturation, per material point and per linear tet, as pure functions on fixed-size
// Eigen types (no heap). The energy layer (below volume/ and sim/): it knows no avatar; a tet's
// material point comes from its coefficients (makeFemMaterialPoint, or femMaterialPoint in
// flsh/volume/material_point.h from an avatar's TetMaterials). The simulable's elastic terms
// assemble them per tet; the ROM's precomputation and the adjoint reuse them.
//
// Conventions.
// - F (3 × 3) deformation gradient, E = ½(FᵀF − I) Green strain, A (3 × 3, columns a1 a2 a3,
//   orthonormal, det +1) the material frame, Ê = Aᵀ E A the strain in the frame.
// - Voigt order 11, 22, 33, 23, 13, 12 with engineering shear: ε = (E11, E22, E33, 2E23, 2E13,
//   2E12). The stiffness C (6 × 6, Pa) maps ε̂ to the stress (Ŝ11, Ŝ22, Ŝ33, Ŝ23, Ŝ13, Ŝ12), so
//   Ψ_S = ½ ε̂ᵀ C ε̂ (Pa = J/m³) and ∂Ψ_S/∂ε̂ = C ε̂.
// - vec(·) is column-major: vec(F)[i + 3j] = F(i, j). dP/dF (9 × 9) has entry
//   (i + 3j, k + 3l) = ∂P_ij/∂F_kl.
// - Element vectors are node-major: entry 3a + k is component k of node a (a = 0..3).
//
// Fung saturation: Ψ = (μ/γ)(exp(γ Ψ_S/μ) − 1) with γ ≥ 0 dimensionless (the `fung_gamma` of
// docs/materials.md) and μ = (E1 + E2 + E3)/3, the mean Young's modulus of the element: the
// modulus scale of every strain direction, so γ Ψ_S/μ ≈ γ·(strain)²/2 whatever the anisotropy.
// It is evaluated as Ψ_S · expm1(x)/x, x = γΨ_S/μ (series for |x| < 1e-5), so γ = 0 gives Ψ_S
// exactly and nothing divides by γ.
// Overflow guard: for x > kFungExponentCap = 50 the exponential is continued by its second-order
// Taylor polynomial at the cap, expm1(x) → expm1(x_c) + e^{x_c}(d + d²/2), d = x − x_c. Value,
// gradient and Hessian are those of this continued function (C² at the cap, convex and
// increasing in Ψ_S like the exponential), so they stay mutually consistent and finite for any
// F with |F_ij| ≲ 1e12 (the energy grows like |F|⁸ there).
#pragma once

#include <Eigen/Core>

#include "flsh/core/types.h"

namespace flsh {

// Vec6, Mat6, Mat9, Vec12, Mat12: flsh/core/types.h.
/// Nodal values of one tet (3 × 4): column a is node a.
using Mat34 = Eigen::Matrix<double, 3, 4>;
using Mat3X = Eigen::Matrix<double, 3, Eigen::Dynamic>;
using Mat4X = Eigen::Matrix<double, 4, Eigen::Dynamic>;

/// Exponent x = γΨ_S/μ beyond which the Fung exponential is continued quadratically.
constexpr double kFungExponentCap = 50.0;

/// Inversion guard. StVK (and its Fung map) is zero at every reflection (FᵀF = I with det F = −1),
/// so a tet pushed through flat (a ball at 3 m/s into the belly) can stay inverted at no cost,
/// and inverted tets spread until the body crumples. Below the volume ratio J = det F =
/// kInversionOnset the energy density gets Ψ_J = (κ/2)(kInversionOnset − J)², κ =
/// kInversionStiffness · μ (μ the tet's mean Young's modulus): C¹ at the onset, zero for every
/// deformation of soft tissue short of halving a tet's volume, so the StVK–Fung law is unchanged
/// there. PSD tangents keep its Gauss–Newton part κ cof(F) ⊗ cof(F).
constexpr double kInversionOnset = 0.5;
constexpr double kInversionStiffness = 100.0;

/// Orthotropic stiffness (6 × 6, Pa, Voigt order above) as the inverse of the compliance of
/// docs/materials.md: normal block [[1/E1, −ν12/E1, −ν13/E1], [−ν12/E1, 1/E2, −ν23/E2],
/// [−ν13/E1, −ν23/E2, 1/E3]], shear diag(1/G23, 1/G13, 1/G12) (in Voigt order 23, 13, 12).
///   young: E1 E2 E3 (Pa), poisson: ν12 ν13 ν23, shear: G12 G13 G23 (Pa).
/// Throws InputError on non-finite or non-positive moduli, or a compliance that is not positive
/// definite (message names the arguments and their values).
Mat6 orthotropicStiffness(const Vec3& young, const Vec3& poisson, const Vec3& shear);

/// T(A) (6 × 6): maps the Voigt strain ε of E (world axes) to the Voigt strain ε̂ of Aᵀ E A
/// (the frame's axes), both with engineering shear.
Mat6 frameStrainMap(const Mat3& frame);

/// The same elastic law expressed on world-axis strains: T(A)ᵀ C T(A) (frameStrainMap).
/// Symmetric positive definite when C is.
Mat6 stiffnessInWorldAxes(const Mat6& C, const Mat3& frame);

/// Material of one element (model data, immutable during a simulation).
struct FemMaterialPoint {
  Mat6 C;                ///< stiffness in the frame (6 × 6, Pa)
  Mat3 frame;            ///< A: columns a1 a2 a3, orthonormal, det +1
  Mat6 C_world;          ///< stiffnessInWorldAxes(C, frame): what the kernels use (Pa)
  double modulus = 1.0;  ///< μ = (E1 + E2 + E3)/3 (Pa), normalizes Ψ_S in the Fung exponent
  double gamma = 0.0;    ///< Fung exponent γ ≥ 0 (dimensionless); 0 is pure StVK
};

/// Material point from E (Pa), ν (ν12 ν13 ν23), G (G12 G13 G23, Pa), frame and γ.
/// InputError on a bad stiffness (see orthotropicStiffness), a frame that is not orthonormal
/// with det +1 (tolerance 1e-6) or γ not finite and ≥ 0.
FemMaterialPoint makeFemMaterialPoint(const Vec3& young, const Vec3& poisson, const Vec3& shear,
                                      const Mat3& frame, double gamma);

/// Energy density Ψ(F) (Pa = J/m³). When not null: P (3 × 3, Pa) = ∂Ψ/∂F = F S with S the second
/// Piola–Kirchhoff stress; dPdF (9 × 9, Pa) = ∂vec(P)/∂vec(F).
/// psd = false: exact dPdF. psd = true: (∂ε/∂F)ᵀ Ψ_εε (∂ε/∂F) + S⁺ ⊗ I₃ (entry (i + 3j, i + 3l)
/// = S⁺_jl) where Ψ_εε = f′C_world + f″ σσᵀ (f′ ≥ 1, f″ ≥ 0 the derivatives of the Fung map, σ =
/// C_world ε) is positive definite and S⁺ is S with its negative eigenvalues set to 0 (a 3 × 3
/// eigensolve, skipped when S ⪰ 0). The result is PSD (the first term is Bᵀ·PD·B, the second
/// has the eigenvalues of S⁺, each three times) and equals the exact dPdF where S ⪰ 0.
/// Plus the inversion guard Ψ_J (see kInversionOnset) when det F < kInversionOnset. Any finite F
/// is valid (flat, inverted). InputError on a non-finite F.
double fungEnergyDensity(const Mat3& F, const FemMaterialPoint& material, Mat3* P = nullptr,
                         Mat9* dPdF = nullptr, bool psd = false);

/// Derivatives with respect to a material point's parameters (the adjoint's Material group,
/// chained to the material file's coefficients by the per-tet material map,
/// flsh/volume/tet_material_map.h): its C_world (the 36 entries taken as independent), modulus
/// μ and Fung exponent γ. The frame enters through C_world only.
struct FemMaterialDerivative {
  Mat6 C_world = Mat6::Zero();
  double modulus = 0.0, gamma = 0.0;
};

/// ADDS scale · ∂Ψ(F)/∂(C_world, μ, γ) into out (Ψ of fungEnergyDensity, guard included).
/// InputError on a non-finite F.
void addEnergyDensityMaterialGradient(const Mat3& F, const FemMaterialPoint& material, double scale,
                                      FemMaterialDerivative& out);
/// ADDS scale · ∂⟨P(F), dF⟩/∂(C_world, μ, γ) into out, P = ∂Ψ/∂F: an element's λᵀ g is
/// volume · ⟨P, δF⟩ with δF the deformation gradient of the nodal direction λ, so this is
/// the material cotangent of λᵀ g. InputError on a non-finite F.
void addStressMaterialGradient(const Mat3& F, const FemMaterialPoint& material, const Mat3& dF,
                               double scale, FemMaterialDerivative& out);
/// Voigt strain (engineering shear) of sym(H): the linear strain of a displacement gradient H.
Vec6 voigtLinearStrain(const Mat3& H);
/// The same as a matrix on vec(H) (column-major, entry i + 3j = H(i, j)):
/// voigtLinearStrain(H) = L vec(H), L 6 × 9.
const Eigen::Matrix<double, 6, 9>& voigtLinearStrainMatrix();

/// Rest geometry of a linear tet.
struct TetElementRest {
  Mat3 Dm_inv;          ///< inverse of Dm = [X1 − X0, X2 − X0, X3 − X0] (1/m)
  double volume = 0.0;  ///< det(Dm)/6 > 0 (m³)
};

/// Signed volume det[X1 − X0, X2 − X0, X3 − X0] / 6 of a tet's four nodes (columns of X, m³).
double tetSignedVolume(const Mat34& X);

/// Rest data of tet `tet_index` from its four rest nodes (columns of X, m). InputError naming
/// the tet if a node is not finite, or the tet is inverted (det Dm < 0) or degenerate
/// (|det Dm| ≤ 1e-12 · (longest edge)³).
TetElementRest tetElementRest(const Mat34& X, int tet_index);

/// F = I + Du · Dm_inv, Du = [u1 − u0, u2 − u0, u3 − u0] from the nodal displacements (columns
/// of u, m).
Mat3 tetDeformationGradient(const TetElementRest& rest, const Mat34& u);

/// Elastic energy volume · Ψ(F(u)) (J) of one tet. When not null: gradient (12) and Hessian
/// (12 × 12) with respect to the nodal displacements (node-major). psd as fungEnergyDensity:
/// the PSD tangent maps to a PSD element Hessian (Bᵀ · PSD · B), exact Hessian otherwise.
/// Formed directly on the 6 × 12 strain map (no 9 × 9 intermediate). InputError on non-finite u.
double tetElasticEnergy(const TetElementRest& rest, const FemMaterialPoint& material,
                        const Mat34& u, Vec12* gradient = nullptr, Mat12* hessian = nullptr,
                        bool psd = false);

/// What the nodal element loops read of one tet, packed in one place (FemElasticityTerm keeps
/// an array of them, one per element, streamed in order): its material point's C_world, μ and γ
/// (not the frame and C of FemMaterialPoint), its shape-function gradients and its weighted
/// volume.
struct PackedTet {
  Mat6 C_world;  ///< as FemMaterialPoint::C_world (Pa)
  Mat34 G;       ///< shape-function gradients g_a as columns (1/m; g_0 = −g_1 − g_2 − g_3)
  double volume = 0.0;   ///< weight · rest volume (m³)
  double modulus = 1.0;  ///< μ (Pa)
  double gamma = 0.0;    ///< Fung exponent γ
};

/// The packed form of a tet with rest data `rest`, material point `material` and weight w
/// (1, or a cubature weight).
PackedTet packTet(const TetElementRest& rest, const FemMaterialPoint& material, double weight);

/// w · tetElasticEnergy(rest, material, u, …) of the tet packTet(rest, material, w), the same
/// law and options (the same arithmetic up to the weight's rounding).
double tetElasticEnergy(const PackedTet& tet, const Mat34& u, Vec12* gradient = nullptr,
                        Mat12* hessian = nullptr, bool psd = false);

/// The rest shape's derivative of an element's gradient (the adjoint's Shape group, through the
/// rest nodes X̄(β)): ADDS scale · ∂(λᵀ g)/∂X (3 × 4, column a: rest node a) into X_bar, where
/// λᵀ g = volume · ⟨P(F), Dλ Dm⁻¹⟩ is the product of tetElasticEnergy's gradient with the nodal
/// direction `lambda` (3 × 4) at the displacements u, the material point held. With W = Dm⁻¹,
/// G = Dλ W and A the law's exact tangent dPdF:
///   ∂(λᵀ g)/∂Dm = volume (⟨P, G⟩ Wᵀ − (F − I)ᵀ A[G] Wᵀ − Gᵀ P Wᵀ),
/// column k to node k + 1 and minus their sum to node 0. InputError on non-finite u.
void addTetGradientRestCotangent(const TetElementRest& rest, const FemMaterialPoint& material,
                                 const Mat34& u, const Mat34& lambda, double scale, Mat34& X_bar);

/// The rest shape's derivative of an element's energy: ADDS scale · ∂(volume · Ψ(F))/∂X (3 × 4)
/// into X_bar at the displacements u, the material point held:
///   ∂/∂Dm = volume (Ψ Wᵀ − (F − I)ᵀ P Wᵀ). InputError on non-finite u.
void addTetEnergyRestCotangent(const TetElementRest& rest, const FemMaterialPoint& material,
                               const Mat34& u, double scale, Mat34& X_bar);

/// The rest shape's derivative of the linear-elastic bilinear form of a tet (its rest Hessian:
/// λᵀ K_tet u = volume · ε(Dλ W)ᵀ C_world ε(Du W), ε the linear Voigt strain, W = Dm⁻¹): ADDS
/// scale · ∂(λᵀ K_tet u)/∂X (3 × 4) into X_bar, with σ(G) the symmetric stress of C_world ε(G):
///   ∂/∂Dm = volume (⟨σ(Gu), Gλ⟩ Wᵀ − Guᵀ σ(Gλ) Wᵀ − Gλᵀ σ(Gu) Wᵀ),  Gu = Du W, Gλ = Dλ W.
void addTetLinearFormRestCotangent(const TetElementRest& rest, const Mat6& C_world, const Mat34& u,
                                   const Mat34& lambda, double scale, Mat34& X_bar);
/// The same for a sum of such forms, given by T = Σ vec(Gλ) vec(Gu)ᵀ (9 × 9, vec column-major):
/// the form is bilinear, so a sum over many (λ, u) (a reverse sweep's steps) needs only T.
void addTetLinearFormRestCotangent(const TetElementRest& rest, const Mat6& C_world, const Mat9& T,
                                   double scale, Mat34& X_bar);

/// The shape-function gradients g_a of a tet as the columns of a 3 × 4 matrix (g_0 = −g_1 − g_2
/// − g_3): F = I + u Gᵀ for nodal displacements u (columns).
Mat34 tetShapeGradients(const TetElementRest& rest);

/// Reduced tets (the ROM's elastic term): the tet's nodal displacements are a linear map of n
/// reduced 3-vectors z_s, u_a = Σ_s Φ(a, s) z_s (Φ: the 4 × n basis rows of the tet's nodes).
/// Then F = I + Z G̃ᵀ with Z (3 × n, columns z_s) and G̃ = G Φ (3 × n), G the shape-function
/// gradients (columns g_a, g_0 = −g_1 − g_2 − g_3): this returns G̃.
Mat3X reducedShapeGradients(const TetElementRest& rest, const Eigen::Ref<const Mat4X>& Phi);

/// Up to this many columns reducedTetElasticEnergy works in stack storage (more: on the heap).
constexpr int kMaxBoundedReducedColumns = 16;

/// volume · Ψ(I + Z G̃ᵀ) (J) and, when not null, its gradient (3n, entry 3s + k = ∂/∂Z(k, s))
/// and Hessian (3n × 3n) with respect to Z, written into the given views (sized 3n). The same
/// law, PSD projection (psd) and inversion guard as tetElasticEnergy, whose value, gradient and
/// Hessian at u = Z Φᵀ these are chained through Φ — formed directly on the 6 × 3n strain map of
/// the reduced columns instead of through the 12 × 12 element Hessian. InputError on sizes that
/// do not match or a non-finite Z.
double reducedTetElasticEnergy(double volume, const FemMaterialPoint& material,
                               const Eigen::Ref<const Mat3X>& G, const Eigen::Ref<const Mat3X>& Z,
                               Eigen::Ref<VecX>* gradient = nullptr,
                               Eigen::Ref<MatX>* hessian = nullptr, bool psd = false);

/// The rest-stiffness split of a sample tet of the ROM's elastic cubature
/// (ReducedData::elastic_rest_stiffness; docs/rom.md): with psi = V Ψ(I + Z G̃ᵀ) of the reduced
/// tet at z (= Z flattened column by column, 3n), `rest_hessian` K̃ its Hessian at z = 0 and
/// q = ½ zᵀ K̃ z, the weighted excess of the energy over its rest quadratic,
///   f = w (psi − q)                     while x = −w (psi − q)/q ≤ 1 (always for w ≤ 1, since
///                                       psi ≥ 0),
///   f = −q (c − (c−1) e^{−(x−1)/(c−1)}) beyond, with the floor c > 1 (f ≥ −c q: a heavily
///                                       weighted tet in compression or inversion lowers the
///                                       energy by at most c times its own rest quadratic), C¹
///                                       where the branches meet.
/// `gradient` / `hessian` hold psi's on entry (reducedTetElasticEnergy's, of the same form) and
/// f's on return; the Hessian needs the gradient. The PSD form is PSD when psi's is: w H_psd in
/// the first branch, w h′(x) H_psd plus a rank-one PSD term in the second (the negative
/// semi-definite K̃ terms dropped). `bounded` (if not null) tells whether the second branch was
/// taken. InputError on sizes that do not match, a weight that is not finite and > 0 or a floor
/// that is not finite and > 1 (`lowest`, the floor c).
double restSplitExcess(double psi, const Eigen::Ref<const VecX>& z,
                       const Eigen::Ref<const MatX>& rest_hessian, double weight,
                       Eigen::Ref<VecX>* gradient = nullptr, Eigen::Ref<MatX>* hessian = nullptr,
                       bool psd = false, bool* bounded = nullptr, double lowest = 2.0);

/// The share of the subspace's rest stiffness that restSplitFloors keeps in every direction.
constexpr double kRestSplitStiffnessKept = 0.5;

/// Floors c_e of restSplitExcess for the sample tets of an elastic cubature, from the subspace's
/// exact rest stiffness K (ReducedData::elastic_rest_stiffness), K_unit = Σ_e K̃_e and
/// K_weighted = Σ_e w_e K̃_e (the sample tets' rest Hessians assembled in the subspace, without
/// and with their weights) and the weights w_e. With λ₁ = λ_max(K⁻¹ K_unit), λ_w =
/// λ_max(K⁻¹ K_weighted) and α = `kept`:
///   c_e = 1 + s w_e, s = (1 − α − λ₁) / λ_w      when λ₁ < 1 − α,
/// so that Σ_e c_e K̃_e ≼ (λ₁ + s λ_w) K = (1 − α) K and the split energy ½ zᵀ K z + Σ_e f_e is
/// at least α ½ zᵀ K z: the cubature may soften the subspace to α of its rest stiffness, never
/// further, whatever the state. A floor that grows with the weight spreads a heavy tet's
/// saturation over a range of its excess as wide as that of a light one (a fixed floor
/// saturates a tet of weight w within about 1/w of its rest quadratic, a kink Newton meets at
/// every step). Otherwise (the unweighted samples alone hold 1 − α of K in some direction, e.g.
/// every tet with unit weights) every floor is max(1.05, 0.95/λ₁): bounded below when λ₁ < 0.95.
/// InputError on sizes that do not match, non-finite or non-positive weights, α outside (0, 1) or
/// a K that is not symmetric positive definite.
VecX restSplitFloors(const MatX& rest_stiffness, const MatX& unit_rest_stiffness,
                     const MatX& weighted_rest_stiffness, const VecX& weights,
                     double kept = kRestSplitStiffnessKept);

}  // namespace flsh
