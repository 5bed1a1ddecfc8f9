// The parameter derivatives of a ROM's elastic element in nodal form; see
// nodal_element_derivatives.h for the formulas.
#include "sim/soft/nodal_element_derivatives.h"

#include <cmath>

namespace flsh::detail {

namespace {

// The weights of d(λᵀ∇f_e) on d(λᵀ∇ψ), d(λᵀb), dψ and dq (the header's formula); w on the
// first alone without the split.
struct SplitWeights {
  double gpsi = 0.0, gq = 0.0, psi = 0.0, q = 0.0;
};

// F = I + u Gᵀ (G: the tet's shape gradients g_a, column a).
Mat3 displacementGradient(const TetElementRest& rest, const Mat34& u) {
  return u * tetShapeGradients(rest).transpose();
}

SplitWeights splitWeights(const SampleElement& s, const Mat3& F, const Mat3& dF, const Vec6& ez,
                          const Vec6& el) {
  const double w = s.weight;
  SplitWeights out;
  out.gpsi = w;
  if (s.floor == 0.0) return out;
  const double V = s.rest.volume;
  const Mat6& C = s.material.C_world;
  const double q = 0.5 * V * ez.dot(C * ez), gq = V * el.dot(C * ez);
  Mat3 P;
  const double psi = V * fungEnergyDensity(F, s.material, &P);
  const double r = psi - q, x = q > 0.0 ? -w * r / q : -1.0;
  if (x <= 1.0) {
    out.gq = -w;
    return out;
  }
  const double gpsi = V * P.cwiseProduct(dF).sum();
  const double c = s.floor, decay = std::exp(-(x - 1.0) / (c - 1.0));
  const double h = c - (c - 1.0) * decay, f_r = w * decay, f_q = x * decay - h;
  const double coef = decay / ((c - 1.0) * q) * (w * (gpsi - gq) + x * gq);
  out.gpsi = f_r;
  out.gq = f_q - f_r;
  out.psi = coef * w;
  out.q = coef * (x - w);
  return out;
}

void addScaled(double a, const FemMaterialDerivative& x, FemMaterialDerivative& y) {
  y.C_world += a * x.C_world;
  y.modulus += a * x.modulus;
  y.gamma += a * x.gamma;
}

}  // namespace

void sampleProducts(const SampleElement& s, const Mat34& u, const Mat34& lu,
                    FemMaterialDerivative* d, Mat34* X_bar) {
  if (!d && !X_bar) return;
  const Mat3 H = displacementGradient(s.rest, u), dF = displacementGradient(s.rest, lu);
  const Mat3 F = Mat3::Identity() + H;
  const Vec6 ez = voigtLinearStrain(H), el = voigtLinearStrain(dF);
  const SplitWeights a = splitWeights(s, F, dF, ez, el);
  if (d) {
    const double V = s.rest.volume;
    FemMaterialDerivative part;
    *d = FemMaterialDerivative();
    addStressMaterialGradient(F, s.material, dF, V, part);
    addScaled(a.gpsi, part, *d);
    d->C_world += (a.gq * V) * el * ez.transpose() + (0.5 * a.q * V) * ez * ez.transpose();
    if (a.psi != 0.0) addEnergyDensityMaterialGradient(F, s.material, a.psi * V, *d);
  }
  if (X_bar) {
    const Mat6& C = s.material.C_world;
    addTetGradientRestCotangent(s.rest, s.material, u, lu, a.gpsi, *X_bar);
    if (a.gq != 0.0) addTetLinearFormRestCotangent(s.rest, C, u, lu, a.gq, *X_bar);
    if (a.psi != 0.0) addTetEnergyRestCotangent(s.rest, s.material, u, a.psi, *X_bar);
    if (a.q != 0.0) addTetLinearFormRestCotangent(s.rest, C, u, u, 0.5 * a.q, *X_bar);
  }
}

FemMaterialDerivative restFormMaterialGradient(const TetElementRest& rest, const Mat34& u,
                                               const Mat34& lu) {
  FemMaterialDerivative d;
  d.C_world = rest.volume * voigtLinearStrain(displacementGradient(rest, lu)) *
              voigtLinearStrain(displacementGradient(rest, u)).transpose();
  return d;
}

}  // namespace flsh::detail
