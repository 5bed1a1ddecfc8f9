#include "flsh/energy/fem_material.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <cmath>
#include <sstream>
#include <string>

#include "flsh/core/error.h"
#include "flsh/core/rotation.h"

namespace flsh {

namespace {

using Mat6x9 = Eigen::Matrix<double, 6, 9>;
using Mat6x12 = Eigen::Matrix<double, 6, 12>;

std::string numberText(double x) {
  std::ostringstream s;
  s.precision(6);
  s << x;
  return s.str();
}

std::string vecText(const Vec3& v) {
  return "(" + numberText(v[0]) + ", " + numberText(v[1]) + ", " + numberText(v[2]) + ")";
}

/// Voigt strain (11, 22, 33, 23, 13, 12; engineering shear) of E = ½(FᵀF − I).
Vec6 voigtGreenStrain(const Mat3& F) {
  const Mat3 FtF = F.transpose() * F;
  Vec6 eps;
  eps << 0.5 * (FtF(0, 0) - 1.0), 0.5 * (FtF(1, 1) - 1.0), 0.5 * (FtF(2, 2) - 1.0), FtF(1, 2),
      FtF(0, 2), FtF(0, 1);
  return eps;
}

/// Symmetric 3 × 3 tensor of a Voigt stress (11, 22, 33, 23, 13, 12; no factor 2).
Mat3 stressTensor(const Vec6& s) {
  Mat3 S;
  S << s[0], s[5], s[4],  //
      s[5], s[1], s[3],   //
      s[4], s[3], s[2];
  return S;
}

/// Voigt strain of sym(f gᵀ): the strain variation δε of δE = sym(Fᵀ δF) for δF = e_k gᵀ, with
/// f = row k of F. Every column of ∂ε/∂vec(F) and of ∂ε/∂u is one of these.
Vec6 symmetricProductStrain(const Vec3& f, const Vec3& g) {
  Vec6 e;
  e << f[0] * g[0], f[1] * g[1], f[2] * g[2], f[1] * g[2] + f[2] * g[1], f[0] * g[2] + f[2] * g[0],
      f[0] * g[1] + f[1] * g[0];
  return e;
}

/// Ψ and its first two derivatives with respect to Ψ_S of the (capped) Fung map.
struct FungMap {
  double psi;    ///< Ψ (Pa)
  double d1;     ///< dΨ/dΨ_S (dimensionless, ≥ 1)
  double d2;     ///< d²Ψ/dΨ_S² (1/Pa, ≥ 0)
  double x;      ///< the exponent γΨ_S/μ
  double e1;     ///< ∂d1/∂x (d2 = (γ/μ) e1)
  double ratio;  ///< Ψ/Ψ_S = φ(x)/x (1 at x = 0)
};

FungMap fungMap(double psi_s, double gamma, double modulus) {
  const double k = gamma / modulus;  // 1/Pa
  const double x = k * psi_s;
  if (x <= kFungExponentCap) {
    const double ex = std::exp(x);
    // expm1(x)/x → 1 as x → 0; the series keeps γ = 0 (x = 0) exact and avoids 0/0.
    const double ratio = std::abs(x) < 1e-5 ? 1.0 + x * (0.5 + x / 6.0) : std::expm1(x) / x;
    return {psi_s * ratio, ex, k * ex, x, ex, ratio};
  }
  // Beyond the cap: the second-order Taylor continuation of expm1 at the cap (x > 50, so x ≠ 0).
  const double ec = std::exp(kFungExponentCap), d = x - kFungExponentCap;
  const double g = std::expm1(kFungExponentCap) + ec * (d + 0.5 * d * d);
  return {psi_s * (g / x), ec * (1.0 + d), k * ec, x, ec, g / x};
}

/// The stress-dependent state shared by the density and the element kernels.
struct FungState {
  Vec6 sigma_s;  ///< C_world ε: the StVK stress in Voigt form (Pa)
  FungMap map;
  Mat3 S;  ///< second Piola–Kirchhoff stress d1 · σ_s as a tensor (Pa)
};

/// Any material with C_world, modulus and gamma (FemMaterialPoint, PackedTet).
template <class Material>
FungState fungState(const Mat3& F, const Material& material) {
  const Vec6 eps = voigtGreenStrain(F);
  FungState state;
  state.sigma_s.noalias() = material.C_world * eps;
  const double psi_s = 0.5 * eps.dot(state.sigma_s);
  state.map = fungMap(psi_s, material.gamma, material.modulus);
  state.S = state.map.d1 * stressTensor(state.sigma_s);
  return state;
}

/// Ψ_εε = f′ C_world + f″ σσᵀ: positive definite (C ≻ 0, f′ ≥ 1, f″ ≥ 0).
template <class Material>
Mat6 strainHessian(const FungState& state, const Material& material) {
  return state.map.d1 * material.C_world + state.map.d2 * state.sigma_s * state.sigma_s.transpose();
}

/// S with its negative eigenvalues set to 0. The principal-minor test (all ≥ 0 ⇔ PSD) skips
/// the eigensolve in the common stretched case.
Mat3 clampedStress(const Mat3& S) {
  const double m01 = S(0, 0) * S(1, 1) - S(0, 1) * S(0, 1);
  const double m02 = S(0, 0) * S(2, 2) - S(0, 2) * S(0, 2);
  const double m12 = S(1, 1) * S(2, 2) - S(1, 2) * S(1, 2);
  if (S(0, 0) >= 0 && S(1, 1) >= 0 && S(2, 2) >= 0 && m01 >= 0 && m02 >= 0 && m12 >= 0 &&
      S.determinant() >= 0)
    return S;
  Eigen::SelfAdjointEigenSolver<Mat3> eigen;
  eigen.computeDirect(S);
  const Vec3 lambda = eigen.eigenvalues().cwiseMax(0.0);
  const Mat3& V = eigen.eigenvectors();
  return V * lambda.asDiagonal() * V.transpose();
}

void requireFinite(const Mat3& F, const char* who) {
  if (!F.allFinite())
    throw InputError(std::string(who) + ": deformation gradient F has a non-finite entry");
}

}  // namespace

Mat6 orthotropicStiffness(const Vec3& young, const Vec3& poisson, const Vec3& shear) {
  // Formatted only for an error (every tet's material point comes through here).
  const auto args = [&] {
    return "orthotropicStiffness: young (E1, E2, E3) = " + vecText(young) +
           " Pa, poisson (ν12, ν13, ν23) = " + vecText(poisson) +
           ", shear (G12, G13, G23) = " + vecText(shear) + " Pa";
  };
  if (!young.allFinite() || !poisson.allFinite() || !shear.allFinite())
    throw InputError(args() + ": expected finite values");
  if ((young.array() <= 0).any() || (shear.array() <= 0).any())
    throw InputError(args() + ": expected positive moduli");
  Mat3 normal_compliance;
  normal_compliance << 1 / young[0], -poisson[0] / young[0], -poisson[1] / young[0],  //
      -poisson[0] / young[0], 1 / young[1], -poisson[2] / young[1],                   //
      -poisson[1] / young[0], -poisson[2] / young[1], 1 / young[2];
  // Scaled by the mean modulus so the test does not depend on the magnitude of the units.
  const Mat3 scaled = normal_compliance * (young.sum() / 3.0);
  const Eigen::LLT<Mat3> llt(scaled);
  if (llt.info() != Eigen::Success || !(llt.matrixLLT().diagonal().minCoeff() > 1e-8))
    throw InputError(args() +
                     ": orthotropic compliance is not positive definite, expected ν12² < E1/E2, "
                     "ν13² < E1/E3, ν23² < E2/E3 and a positive determinant");
  Mat6 C = Mat6::Zero();
  C.topLeftCorner<3, 3>() = normal_compliance.inverse();
  // Voigt order 23, 13, 12 of the shear block against the argument order G12, G13, G23.
  C(3, 3) = shear[2];
  C(4, 4) = shear[1];
  C(5, 5) = shear[0];
  return C;
}

Mat6 frameStrainMap(const Mat3& frame) {
  // T (6 × 6): column k is the frame strain ε̂ of the unit world strain e_k.
  Mat6 T;
  for (int k = 0; k < 6; ++k) {
    Vec6 unit = Vec6::Zero();
    unit[k] = 1.0;
    // Engineering shear: a unit ε_23 is E23 = E32 = ½, which stressTensor's layout matches
    // after halving the shear entries.
    Vec6 tensor_entries = unit;
    tensor_entries.tail<3>() *= 0.5;
    const Mat3 E = stressTensor(tensor_entries);
    const Mat3 E_frame = frame.transpose() * E * frame;
    T.col(k) << E_frame(0, 0), E_frame(1, 1), E_frame(2, 2), 2 * E_frame(1, 2), 2 * E_frame(0, 2),
        2 * E_frame(0, 1);
  }
  return T;
}

Mat6 stiffnessInWorldAxes(const Mat6& C, const Mat3& frame) {
  const Mat6 T = frameStrainMap(frame);
  const Mat6 C_world = T.transpose() * C * T;
  return 0.5 * (C_world + C_world.transpose());
}

FemMaterialPoint makeFemMaterialPoint(const Vec3& young, const Vec3& poisson, const Vec3& shear,
                                      const Mat3& frame, double gamma) {
  FemMaterialPoint material;
  material.C = orthotropicStiffness(young, poisson, shear);
  if (!frame.allFinite() ||
      (frame.transpose() * frame - Mat3::Identity()).cwiseAbs().maxCoeff() > 1e-6 ||
      std::abs(frame.determinant() - 1.0) > 1e-6) {
    std::ostringstream s;
    s.precision(6);
    s << "makeFemMaterialPoint: frame (columns a1 a2 a3) = [" << frame.row(0) << "; "
      << frame.row(1) << "; " << frame.row(2)
      << "], expected orthonormal with det +1 (tolerance 1e-6)";
    throw InputError(s.str());
  }
  if (!(std::isfinite(gamma) && gamma >= 0))
    throw InputError("makeFemMaterialPoint: Fung exponent gamma = " + numberText(gamma) +
                     ", expected finite and ≥ 0");
  material.frame = frame;
  material.C_world = stiffnessInWorldAxes(material.C, frame);
  material.modulus = young.sum() / 3.0;
  material.gamma = gamma;
  return material;
}

// Inversion guard (fem_material.h): ∂J/∂F = cof(F), columns f1 × f2, f2 × f0, f0 × f1;
// ∂²J/∂F_ki∂F_lj = ε_klm ε_ijn F_mn.
Mat3 cofactor(const Mat3& F) {
  Mat3 C;
  C.col(0) = F.col(1).cross(F.col(2));
  C.col(1) = F.col(2).cross(F.col(0));
  C.col(2) = F.col(0).cross(F.col(1));
  return C;
}

// (κ, depth) of the guard at F: κ = kInversionStiffness · μ, depth = kInversionOnset − det F
// (> 0 when active).
struct InversionGuard {
  double kappa = 0.0, depth = 0.0;
  bool active() const { return depth > 0.0; }
  double energy() const { return active() ? 0.5 * kappa * depth * depth : 0.0; }
};

template <class Material>
InversionGuard inversionGuard(const Mat3& F, const Material& material) {
  return {kInversionStiffness * material.modulus, kInversionOnset - F.determinant()};
}

double fungEnergyDensity(const Mat3& F, const FemMaterialPoint& material, Mat3* P, Mat9* dPdF,
                         bool psd) {
  requireFinite(F, "fungEnergyDensity");
  const FungState state = fungState(F, material);
  const InversionGuard guard = inversionGuard(F, material);
  const Mat3 cof = guard.active() ? cofactor(F) : Mat3::Zero();
  if (P) {
    P->noalias() = F * state.S;
    if (guard.active()) *P -= guard.kappa * guard.depth * cof;
  }
  if (dPdF) {
    // ∂ε/∂vec(F): column k + 3i is the strain of δF = e_k e_iᵀ.
    Mat6x9 B;
    for (int i = 0; i < 3; ++i)
      for (int k = 0; k < 3; ++k)
        B.col(k + 3 * i) = symmetricProductStrain(F.row(k).transpose(), Vec3::Unit(i));
    const Mat6 psi_ee = strainHessian(state, material);
    dPdF->noalias() = B.transpose() * psi_ee * B;
    // Geometric term S : (δFᵀ δF): entry (k + 3i, k + 3j) = S_ij.
    const Mat3 S = psd ? clampedStress(state.S) : state.S;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j)
        for (int k = 0; k < 3; ++k) (*dPdF)(k + 3 * i, k + 3 * j) += S(i, j);
    if (guard.active()) {
      const Eigen::Map<const Eigen::Matrix<double, 9, 1>> c(cof.data());
      dPdF->noalias() += guard.kappa * c * c.transpose();
      if (!psd) {  // −κ (J₀ − J) ∂²J/∂F²: block (i, j) = Σ_n ε_ijn [F.col(n)]×ᵀ… (see cofactor)
        const double scale = -guard.kappa * guard.depth;
        for (int i = 0; i < 3; ++i)
          for (int j = 0; j < 3; ++j) {
            if (i == j) continue;
            const int n = 3 - i - j;
            const double sign = ((j - i + 3) % 3 == 1) ? 1.0 : -1.0;  // ε_ijn
            // ε_klm ε_ijn F_mn summed over m: −sign · [F.col(n)]×_kl.
            dPdF->block<3, 3>(3 * i, 3 * j) += scale * (-sign) * skew(Vec3(F.col(n)));
          }
      }
    }
  }
  return state.map.psi + guard.energy();
}

Vec6 voigtLinearStrain(const Mat3& H) {
  Vec6 e;
  e << H(0, 0), H(1, 1), H(2, 2), H(1, 2) + H(2, 1), H(0, 2) + H(2, 0), H(0, 1) + H(1, 0);
  return e;
}

const Eigen::Matrix<double, 6, 9>& voigtLinearStrainMatrix() {
  static const Eigen::Matrix<double, 6, 9> L = [] {
    Eigen::Matrix<double, 6, 9> m;
    for (int j = 0; j < 3; ++j)
      for (int i = 0; i < 3; ++i) {
        Mat3 unit = Mat3::Zero();
        unit(i, j) = 1.0;
        m.col(i + 3 * j) = voigtLinearStrain(unit);
      }
    return m;
  }();
  return L;
}

namespace {

/// (d1 − ratio) / x = h′(x) for h(x) = φ(x)/x, by its series near 0 (γ = 0 included).
double fungRatioSlope(const FungMap& map) {
  const double x = map.x;
  return std::abs(x) < 1e-5 ? 0.5 + x * (1.0 / 3.0 + x / 8.0) : (map.d1 - map.ratio) / x;
}

}  // namespace

// Ψ = Ψ_S h(x) + Ψ_J with x = (γ/μ) Ψ_S, h = φ(x)/x: ∂Ψ/∂C_world = d1 ½ ε εᵀ, ∂Ψ/∂μ =
// −Ψ_S h′ x/μ + Ψ_J/μ (κ = kInversionStiffness μ), ∂Ψ/∂γ = Ψ_S h′ Ψ_S/μ.
void addEnergyDensityMaterialGradient(const Mat3& F, const FemMaterialPoint& material, double scale,
                                      FemMaterialDerivative& out) {
  requireFinite(F, "addEnergyDensityMaterialGradient");
  const Vec6 eps = voigtGreenStrain(F);
  const double psi_s = 0.5 * eps.dot(material.C_world * eps);
  const FungMap map = fungMap(psi_s, material.gamma, material.modulus);
  const double slope = fungRatioSlope(map);
  out.C_world.noalias() += (0.5 * scale * map.d1) * eps * eps.transpose();
  out.modulus -= scale * psi_s * slope * map.x / material.modulus;
  out.gamma += scale * psi_s * slope * psi_s / material.modulus;
  const InversionGuard guard = inversionGuard(F, material);
  if (guard.active()) out.modulus += scale * guard.energy() / material.modulus;
}

// D = ⟨P, dF⟩ = d1 σ·δε − κ (J₀ − J) ⟨cof F, dF⟩ with δε the strain of sym(Fᵀ dF):
// ∂D/∂C_world = d1 δε εᵀ + d2 (σ·δε) ½ ε εᵀ, ∂D/∂μ = −e1 (σ·δε) x/μ − kInversionStiffness (J₀ −
// J) ⟨cof F, dF⟩, ∂D/∂γ = e1 (σ·δε) Ψ_S/μ.
void addStressMaterialGradient(const Mat3& F, const FemMaterialPoint& material, const Mat3& dF,
                               double scale, FemMaterialDerivative& out) {
  requireFinite(F, "addStressMaterialGradient");
  const Vec6 eps = voigtGreenStrain(F);
  const Vec6 sigma = material.C_world * eps;
  const double psi_s = 0.5 * eps.dot(sigma);
  const FungMap map = fungMap(psi_s, material.gamma, material.modulus);
  const Vec6 deps = voigtLinearStrain(F.transpose() * dF);
  const double work = sigma.dot(deps);
  out.C_world.noalias() += (scale * map.d1) * deps * eps.transpose();
  out.C_world.noalias() += (0.5 * scale * map.d2 * work) * eps * eps.transpose();
  out.modulus -= scale * map.e1 * work * map.x / material.modulus;
  out.gamma += scale * map.e1 * work * psi_s / material.modulus;
  const InversionGuard guard = inversionGuard(F, material);
  if (guard.active())
    out.modulus -= scale * kInversionStiffness * guard.depth * cofactor(F).cwiseProduct(dF).sum();
}

double tetSignedVolume(const Mat34& X) {
  return (X.col(1) - X.col(0)).cross(X.col(2) - X.col(0)).dot(X.col(3) - X.col(0)) / 6;
}

TetElementRest tetElementRest(const Mat34& X, int tet_index) {
  const std::string where = "tetElementRest: tet " + std::to_string(tet_index);
  if (!X.allFinite()) throw InputError(where + ": a rest node is not finite");
  Mat3 Dm;
  Dm << X.col(1) - X.col(0), X.col(2) - X.col(0), X.col(3) - X.col(0);
  double longest = 0.0;
  for (int a = 0; a < 4; ++a)
    for (int b = a + 1; b < 4; ++b) longest = std::max(longest, (X.col(a) - X.col(b)).norm());
  const double det = Dm.determinant();
  const double tolerance = 1e-12 * longest * longest * longest;
  if (std::abs(det) <= tolerance)
    throw InputError(where + ": degenerate rest tet, volume " + numberText(det / 6.0) +
                     " m³ with longest edge " + numberText(longest) +
                     " m, expected det(Dm) > 1e-12 · edge³");
  if (det < 0)
    throw InputError(where + ": inverted rest tet, volume " + numberText(det / 6.0) +
                     " m³, expected > 0 (nodes in positive orientation)");
  return {Dm.inverse(), det / 6.0};
}

Mat3 tetDeformationGradient(const TetElementRest& rest, const Mat34& u) {
  Mat3 Du;
  Du << u.col(1) - u.col(0), u.col(2) - u.col(0), u.col(3) - u.col(0);
  return Mat3::Identity() + Du * rest.Dm_inv;
}

namespace {

/// Adds the cotangent of Dm (3 × 3) to the four rest nodes: column k to node k + 1, minus their
/// sum to node 0.
void addEdgeCotangent(const Mat3& Dm_bar, Mat34& X_bar) {
  X_bar.rightCols<3>() += Dm_bar;
  X_bar.col(0) -= Dm_bar.rowwise().sum();
}

Mat3 edges(const Mat34& x) {
  Mat3 D;
  D << x.col(1) - x.col(0), x.col(2) - x.col(0), x.col(3) - x.col(0);
  return D;
}

}  // namespace

void addTetGradientRestCotangent(const TetElementRest& rest, const FemMaterialPoint& material,
                                 const Mat34& u, const Mat34& lambda, double scale, Mat34& X_bar) {
  if (!u.allFinite())
    throw InputError("addTetGradientRestCotangent: nodal displacements u have a non-finite entry");
  const Mat3& W = rest.Dm_inv;
  const Mat3 F = tetDeformationGradient(rest, u);
  const Mat3 G = edges(lambda) * W;
  Mat3 P;
  Mat9 dPdF;
  fungEnergyDensity(F, material, &P, &dPdF, false);
  const Mat3 AG = Eigen::Map<const Mat3>(Vec9(dPdF * Eigen::Map<const Vec9>(G.data())).data());
  addEdgeCotangent((scale * rest.volume) *
                       (P.cwiseProduct(G).sum() * Mat3::Identity() -
                        (F - Mat3::Identity()).transpose() * AG - G.transpose() * P) *
                       W.transpose(),
                   X_bar);
}

void addTetEnergyRestCotangent(const TetElementRest& rest, const FemMaterialPoint& material,
                               const Mat34& u, double scale, Mat34& X_bar) {
  if (!u.allFinite())
    throw InputError("addTetEnergyRestCotangent: nodal displacements u have a non-finite entry");
  const Mat3& W = rest.Dm_inv;
  const Mat3 F = tetDeformationGradient(rest, u);
  Mat3 P;
  const double psi = fungEnergyDensity(F, material, &P);
  addEdgeCotangent((scale * rest.volume) *
                       (psi * Mat3::Identity() - (F - Mat3::Identity()).transpose() * P) *
                       W.transpose(),
                   X_bar);
}

void addTetLinearFormRestCotangent(const TetElementRest& rest, const Mat6& C_world, const Mat34& u,
                                   const Mat34& lambda, double scale, Mat34& X_bar) {
  if (!u.allFinite() || !lambda.allFinite())
    throw InputError("addTetLinearFormRestCotangent: u or lambda has a non-finite entry");
  const Mat3& W = rest.Dm_inv;
  const Mat3 Gu = edges(u) * W, Gl = edges(lambda) * W;
  const Mat9 T = Eigen::Map<const Vec9>(Gl.data()) * Eigen::Map<const Vec9>(Gu.data()).transpose();
  addTetLinearFormRestCotangent(rest, C_world, T, scale, X_bar);
}

// With L (6 × 9) the linear Voigt strain of vec(G) and Q = Lᵀ C L (LᵀC L vec(G) = vec(σ(G))):
// the form is ⟨T, Q⟩, and Σ Guᵀ σ(Gλ) has entry (a, b) = Σ_i (Q T)[(i, b), (i, a)], Σ Gλᵀ σ(Gu)
// likewise with Tᵀ.
void addTetLinearFormRestCotangent(const TetElementRest& rest, const Mat6& C_world, const Mat9& T,
                                   double scale, Mat34& X_bar) {
  const Eigen::Matrix<double, 6, 9>& L = voigtLinearStrainMatrix();
  const Mat9 Q = L.transpose() * C_world * L;
  const Mat9 QT = Q * T, QTt = Q * T.transpose();
  Mat3 A = Mat3::Zero();
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b)
      for (int i = 0; i < 3; ++i) A(a, b) += QT(i + 3 * b, i + 3 * a) + QTt(i + 3 * b, i + 3 * a);
  const double form = T.cwiseProduct(Q).sum();
  addEdgeCotangent((scale * rest.volume) * (form * Mat3::Identity() - A) * rest.Dm_inv.transpose(),
                   X_bar);
}

namespace {

/// volume · Ψ(F) and its derivatives with respect to n "nodes" whose values enter F linearly,
/// δF = δv_s g_sᵀ for node s with gradient g_s (column s of G, 3 × n): the nodal form of a tet
/// (n = 4, g_a the shape-function gradients) and the reduced form (g̃_s = Σ_a Φ(a, s) g_a).
/// Gradient (3n) and Hessian (3n × 3n) node-major; sizes from G's type (fixed, bounded or
/// dynamic), so the fixed and bounded forms never allocate.
template <class GType, class Gradient, class Hessian, class Material>
double gradientFormEnergy(double volume, const Material& material, const Mat3& F, const GType& G,
                          Gradient* gradient, Hessian* hessian, bool psd) {
  constexpr int N = GType::ColsAtCompileTime, MaxN = GType::MaxColsAtCompileTime;
  constexpr int C = N == Eigen::Dynamic ? Eigen::Dynamic : 3 * N;
  constexpr int MaxC = MaxN == Eigen::Dynamic ? Eigen::Dynamic : 3 * MaxN;
  using StrainMap = Eigen::Matrix<double, 6, C, 0, 6, MaxC>;
  using NodeVector = Eigen::Matrix<double, C, 1, 0, MaxC, 1>;
  using NodeSquare = Eigen::Matrix<double, N, N, 0, MaxN, MaxN>;
  const int n = int(G.cols());
  const FungState state = fungState(F, material);
  const InversionGuard guard = inversionGuard(F, material);
  const double psi = state.map.psi + guard.energy();
  if (!gradient && !hessian) return volume * psi;
  if (gradient) {
    // ∂(VΨ)/∂v_s = V P g_s with P = F S the first Piola–Kirchhoff stress (Bᵀσ d1 below, without
    // forming B: the gradient-only evaluations, line searches' and Newton's, skip it).
    const Mat3 P = volume * (F * state.S);
    for (int s = 0; s < n; ++s) gradient->template segment<3>(3 * s).noalias() = P * G.col(s);
  }
  if (hessian) {
    if constexpr (N != Eigen::Dynamic) {
      // The nodal 12 × 12: Bᵀ (12 × 6, row 3s + k the strain of δF = e_k g_sᵀ) written entry by
      // entry, then (Bᵀ Ψ_εε) Bᵀᵀ as column-major products whose columns are whole packets.
      // Before: B's columns built as 6-vectors and copied (the copies stalled on store
      // forwarding) and Bᵀ (Ψ B) read across B's columns; the FEM walk's elastic Hessian took
      // ~20 ms instead of ~15 ms on two threads.
      Eigen::Matrix<double, C, 6> Bt;
      for (int s = 0; s < n; ++s)
        for (int k = 0; k < 3; ++k) {
          const int c = 3 * s + k;
          const double f0 = F(k, 0), f1 = F(k, 1), f2 = F(k, 2);
          const double g0 = G(0, s), g1 = G(1, s), g2 = G(2, s);
          Bt(c, 0) = f0 * g0;
          Bt(c, 1) = f1 * g1;
          Bt(c, 2) = f2 * g2;
          Bt(c, 3) = f1 * g2 + f2 * g1;
          Bt(c, 4) = f0 * g2 + f2 * g0;
          Bt(c, 5) = f0 * g1 + f1 * g0;
        }
      const Eigen::Matrix<double, C, 6> BtPsi =
          Bt.lazyProduct(volume * strainHessian(state, material));
      hessian->noalias() = BtPsi.lazyProduct(Bt.transpose());
    } else {
      // ∂ε/∂v (6 × 3n): column 3s + k is the strain of δF = e_k g_sᵀ.
      StrainMap B(6, 3 * n);
      for (int s = 0; s < n; ++s)
        for (int k = 0; k < 3; ++k)
          B.col(3 * s + k) = symmetricProductStrain(F.row(k).transpose(), G.col(s));
      const StrainMap psi_ee_B = (volume * strainHessian(state, material)) * B;
      // Bᵀ (Ψ_εε B): the default product of these sizes goes through Eigen's blocked GEMM,
      // packing for every tet; the symmetric triangle, mirrored, is faster.
      for (int j = 0; j < 3 * n; ++j)
        for (int i = 0; i <= j; ++i) {
          const double value = B.col(i).template head<6>().dot(psi_ee_B.col(j).template head<6>());
          (*hessian)(i, j) = value;
          (*hessian)(j, i) = value;
        }
    }
    // Geometric term: block (s, r) = V (g_sᵀ S g_r) I₃.
    const Mat3 S = psd ? clampedStress(state.S) : state.S;
    const NodeSquare GSG = volume * (G.transpose() * S * G);
    for (int s = 0; s < n; ++s)
      for (int r = 0; r < n; ++r)
        for (int k = 0; k < 3; ++k) (*hessian)(3 * s + k, 3 * r + k) += GSG(s, r);
  }
  if (guard.active()) {
    // ∂J/∂v_s = cof g_s; ∂²J/∂v_s∂v_r = −[F (g_s × g_r)]×.
    const Mat3 cof = cofactor(F);
    NodeVector c(3 * n);
    for (int s = 0; s < n; ++s) c.template segment<3>(3 * s) = cof * G.col(s);
    if (gradient) *gradient -= (volume * guard.kappa * guard.depth) * c;
    if (hessian) {
      hessian->noalias() += (volume * guard.kappa) * c * c.transpose();
      if (!psd)
        for (int s = 0; s < n; ++s)
          for (int r = 0; r < n; ++r)
            hessian->template block<3, 3>(3 * s, 3 * r) +=
                (volume * guard.kappa * guard.depth) *
                skew(Vec3(F * Vec3(G.col(s)).cross(Vec3(G.col(r)))));
    }
  }
  return volume * psi;
}

}  // namespace

Mat34 tetShapeGradients(const TetElementRest& rest) {
  Mat34 G;
  G.rightCols<3>() = rest.Dm_inv.transpose();
  G.col(0) = -G.rightCols<3>().rowwise().sum();
  return G;
}

double tetElasticEnergy(const TetElementRest& rest, const FemMaterialPoint& material,
                        const Mat34& u, Vec12* gradient, Mat12* hessian, bool psd) {
  return tetElasticEnergy(packTet(rest, material, 1.0), u, gradient, hessian, psd);
}

PackedTet packTet(const TetElementRest& rest, const FemMaterialPoint& material, double weight) {
  PackedTet tet;
  tet.C_world = material.C_world;
  tet.G = tetShapeGradients(rest);
  tet.volume = weight * rest.volume;
  tet.modulus = material.modulus;
  tet.gamma = material.gamma;
  return tet;
}

double tetElasticEnergy(const PackedTet& tet, const Mat34& u, Vec12* gradient, Mat12* hessian,
                        bool psd) {
  if (!u.allFinite())
    throw InputError("tetElasticEnergy: nodal displacements u have a non-finite entry");
  // F = I + u Gᵀ with G's columns the shape-function gradients g_a.
  const Mat3 F = Mat3::Identity() + u * tet.G.transpose();
  return gradientFormEnergy(tet.volume, tet, F, tet.G, gradient, hessian, psd);
}

Mat3X reducedShapeGradients(const TetElementRest& rest, const Eigen::Ref<const Mat4X>& Phi) {
  return tetShapeGradients(rest) * Phi;
}

double reducedTetElasticEnergy(double volume, const FemMaterialPoint& material,
                               const Eigen::Ref<const Mat3X>& G, const Eigen::Ref<const Mat3X>& Z,
                               Eigen::Ref<VecX>* gradient, Eigen::Ref<MatX>* hessian, bool psd) {
  const Eigen::Index n = G.cols();
  if (Z.cols() != n)
    throw InputError("reducedTetElasticEnergy: Z has " + std::to_string(Z.cols()) +
                     " columns, expected as many as G (" + std::to_string(n) + ")");
  if (gradient && gradient->size() != 3 * n)
    throw InputError("reducedTetElasticEnergy: gradient has size " +
                     std::to_string(gradient->size()) + ", expected 3 · " + std::to_string(n));
  if (hessian && (hessian->rows() != 3 * n || hessian->cols() != 3 * n))
    throw InputError("reducedTetElasticEnergy: Hessian is " + std::to_string(hessian->rows()) +
                     " × " + std::to_string(hessian->cols()) + ", expected 3 · " +
                     std::to_string(n) + " square");
  if (!Z.allFinite())
    throw InputError("reducedTetElasticEnergy: reduced coordinates Z have a non-finite entry");
  const Mat3 F = Mat3::Identity() + Z * G.transpose();
  if (n <= kMaxBoundedReducedColumns) {  // stack storage
    using Bounded = Eigen::Matrix<double, 3, Eigen::Dynamic, 0, 3, kMaxBoundedReducedColumns>;
    return gradientFormEnergy(volume, material, F, Bounded(G), gradient, hessian, psd);
  }
  return gradientFormEnergy(volume, material, F, Mat3X(G), gradient, hessian, psd);
}

namespace {

/// restSplitExcess after its checks; Vec holds the 3n-vectors (fixed-capacity stack storage up to
/// kMaxBoundedReducedColumns handles: this runs per sample tet and evaluation).
template <class Vec>
double splitExcess(double psi, const Eigen::Ref<const VecX>& z,
                   const Eigen::Ref<const MatX>& rest_hessian, double weight,
                   Eigen::Ref<VecX>* gradient, Eigen::Ref<MatX>* hessian, bool psd, bool* bounded,
                   double lowest) {
  const Vec b = rest_hessian * z;  // ∇q
  const double q = 0.5 * z.dot(b), r = psi - q;
  // x ≤ 1 ⇔ w r ≥ −q; always so for w ≤ 1, since Ψ ≥ 0 ⇔ r ≥ −q.
  const double x = q > 0.0 ? -weight * r / q : -1.0;
  if (bounded) *bounded = x > 1.0;
  if (x <= 1.0) {
    if (hessian) {
      if (psd)
        (*hessian) *= weight;  // w H_psd: PSD (subtracting K̃ would make it indefinite)
      else
        (*hessian) = weight * ((*hessian) - rest_hessian);
    }
    if (gradient) (*gradient) = weight * ((*gradient) - b);
    return weight * r;
  }
  // f = −q h(x), h = c − (c − 1) e^{−(x−1)/(c−1)} with c the floor (h′ = e^{−(x−1)/(c−1)},
  // h″ = −h′/(c − 1)), x = −w r / q: f_r = w h′, f_q = x h′ − h, and the second-order terms
  // −(h″/q) v vᵀ with v = w ∇r + x ∇q.
  const double decay = std::exp(-(x - 1.0) / (lowest - 1.0));
  const double h = lowest - (lowest - 1.0) * decay;
  const double f_r = weight * decay, f_q = x * decay - h;
  if (gradient) {
    const Vec v = weight * ((*gradient) - b) + x * b;
    if (hessian) {
      // PSD form: f_r H_psd (f_r > 0) and the rank-one term; f_q ≤ 0 here, so its K̃ term and
      // f_r's −K̃ (both negative semi-definite) are dropped.
      if (psd)
        (*hessian) *= f_r;
      else
        (*hessian) = f_r * ((*hessian) - rest_hessian) + f_q * rest_hessian;
      hessian->noalias() += (decay / ((lowest - 1.0) * q)) * v * v.transpose();
    }
    (*gradient) = f_r * ((*gradient) - b) + f_q * b;
  }
  return -q * h;
}

}  // namespace

double restSplitExcess(double psi, const Eigen::Ref<const VecX>& z,
                       const Eigen::Ref<const MatX>& rest_hessian, double weight,
                       Eigen::Ref<VecX>* gradient, Eigen::Ref<MatX>* hessian, bool psd,
                       bool* bounded, double lowest) {
  const Eigen::Index m = z.size();
  if (rest_hessian.rows() != m || rest_hessian.cols() != m)
    throw InputError("restSplitExcess: rest Hessian is " + std::to_string(rest_hessian.rows()) +
                     " × " + std::to_string(rest_hessian.cols()) + ", expected " +
                     std::to_string(m) + " square (the size of z)");
  if (hessian && !gradient)
    throw InputError("restSplitExcess: the Hessian needs the gradient (pass both)");
  if ((gradient && gradient->size() != m) ||
      (hessian && (hessian->rows() != m || hessian->cols() != m)))
    throw InputError("restSplitExcess: gradient / Hessian sizes do not match z (" +
                     std::to_string(m) + ")");
  if (!(weight > 0.0) || !std::isfinite(weight))
    throw InputError("restSplitExcess: weight must be finite and > 0, got " + numberText(weight));
  if (!(lowest > 1.0) || !std::isfinite(lowest))
    throw InputError("restSplitExcess: lowest (the floor c) must be finite and > 1, got " +
                     numberText(lowest));
  using Bounded = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, 3 * kMaxBoundedReducedColumns, 1>;
  if (m <= 3 * kMaxBoundedReducedColumns)
    return splitExcess<Bounded>(psi, z, rest_hessian, weight, gradient, hessian, psd, bounded,
                                lowest);
  return splitExcess<VecX>(psi, z, rest_hessian, weight, gradient, hessian, psd, bounded, lowest);
}

namespace {
// λ_max(L⁻¹ A L⁻ᵀ) with K = L Lᵀ: the largest generalized eigenvalue of (A, K).
double largestRelativeEigenvalue(const Eigen::LLT<MatX>& K, const MatX& A) {
  MatX M = K.matrixL().solve(A);
  M = K.matrixL().solve(MatX(M.transpose()));
  return Eigen::SelfAdjointEigenSolver<MatX>(0.5 * (M + M.transpose()), Eigen::EigenvaluesOnly)
      .eigenvalues()
      .maxCoeff();
}
}  // namespace

VecX restSplitFloors(const MatX& rest_stiffness, const MatX& unit_rest_stiffness,
                     const MatX& weighted_rest_stiffness, const VecX& weights, double kept) {
  const std::string fn = "restSplitFloors: ";
  const Eigen::Index m = rest_stiffness.rows();
  const auto square = [&](const MatX& A, const char* name) {
    if (A.rows() != m || A.cols() != m)
      throw InputError(fn + name + " is " + std::to_string(A.rows()) + " × " +
                       std::to_string(A.cols()) + ", expected " + std::to_string(m) + " × " +
                       std::to_string(m) + " (the rest stiffness K's size)");
    if (!A.allFinite()) throw InputError(fn + name + " has a non-finite entry");
  };
  square(rest_stiffness, "K");
  square(unit_rest_stiffness, "K_unit");
  square(weighted_rest_stiffness, "K_weighted");
  if (!(kept > 0.0 && kept < 1.0))
    throw InputError(fn + "kept (α) must be in (0, 1), got " + numberText(kept));
  for (Eigen::Index e = 0; e < weights.size(); ++e)
    if (!(weights[e] > 0.0) || !std::isfinite(weights[e]))
      throw InputError(fn + "weights[" + std::to_string(e) + "] = " + numberText(weights[e]) +
                       ", expected finite and > 0");
  const Eigen::LLT<MatX> llt(rest_stiffness);
  if (m == 0 || llt.info() != Eigen::Success)
    throw InputError(fn + "the rest stiffness K is not symmetric positive definite");
  const double unit = largestRelativeEigenvalue(llt, unit_rest_stiffness);
  const double weighted = largestRelativeEigenvalue(llt, weighted_rest_stiffness);
  const double budget = 1.0 - kept - unit;
  if (budget > 0.0 && weighted > 0.0) return (1.0 + (budget / weighted) * weights.array()).matrix();
  return VecX::Constant(weights.size(), unit > 0.0 ? std::max(1.05, 0.95 / unit) : 2.0);
}

}  // namespace flsh
