#include "sim/soft/modal_elasticity_term.h"

#include <algorithm>
#include <string>

#include "flsh/core/error.h"
#include "flsh/volume/reduced_data.h"
#include "flsh/volume/volumetric_data.h"
#include "volume/subspace_tets.h"

namespace flsh::detail {

ModalElasticityTerm::ModalElasticityTerm(const SoftAvatar& avatar, const SoftKinematics& kinematics,
                                         const MaterialChain& chain, ElasticElements elements)
    : ElasticityTerm(kinematics, chain), elements_(std::move(elements)) {
  const ReducedData& rom = avatar.reducedData();
  const VolumetricData& data = avatar.volumetricData();
  const int T = elements_.size();
  const SpMat rows = rom.basis.transpose();  // φ by rows
  dofs_.resize(size_t(T));
  D_.resize(size_t(T));
#pragma omp parallel for schedule(dynamic, 64) if (T > 256)
  for (int e = 0; e < T; ++e) {
    SubspaceTet st =
        subspaceTet(data, rom, rows, elements_.rest[size_t(e)], elements_.tet[size_t(e)]);
    dofs_[size_t(e)] = std::move(st.dofs);
    D_[size_t(e)] = std::move(st.D);
  }
  for (const auto& d : dofs_) max_dofs_ = std::max(max_dofs_, int(d.size()));
  if (rom.elastic_rest_stiffness.size() == 0) return;
  const int m = kin_.numSoftDofs();
  rest_stiffness_ = rom.elastic_rest_stiffness;
  if (rest_stiffness_.rows() != m || rest_stiffness_.cols() != m)
    throw InputError("Simulable: the avatar's elastic rest stiffness is " +
                     std::to_string(rest_stiffness_.rows()) + " × " +
                     std::to_string(rest_stiffness_.cols()) +
                     ", expected (3·#handles + #modes) square (" + std::to_string(m) + ")");
  rest_tangent_.resize(size_t(T));
  for (int e = 0; e < T; ++e)
    rest_tangent_[size_t(e)] =
        elements_.rest[size_t(e)].volume * restTangent(elements_.materials[size_t(e)]);
  rest_floors_ = elementRestFloors(rom, elements_);
}

std::vector<std::pair<int, int>> ModalElasticityTerm::groupPairs() const {
  std::vector<std::pair<int, int>> pairs;
  const int groups = kin_.numGroups();
  if (rest_stiffness_.size() > 0)
    for (int a = 0; a < groups; ++a)
      for (int b = 0; b < groups; ++b)
        if (!rest_stiffness_.block<3, 3>(3 * a, 3 * b).isZero(0.0)) pairs.emplace_back(a, b);
  for (const std::vector<int>& dofs : dofs_)
    for (size_t s = 0; s < dofs.size(); s += 3)
      for (size_t r = 0; r < dofs.size(); r += 3) pairs.emplace_back(dofs[s] / 3, dofs[r] / 3);
  return pairs;
}

double ModalElasticityTerm::element(int e, const VecX& z_e, Eigen::Ref<VecX>* gradient,
                                    Eigen::Ref<MatX>* hessian, bool psd, bool* bounded) const {
  const MatX& D = D_[size_t(e)];
  const double w = elements_.weights[e];
  const double V = elements_.rest[size_t(e)].volume;
  const FemMaterialPoint& material = elements_.materials[size_t(e)];
  if (rest_stiffness_.size() == 0) {
    const double psi = subspaceTetElasticEnergy(V, material, D, z_e, gradient, hessian, psd);
    if (gradient) *gradient *= w;
    if (hessian) *hessian *= w;
    return w * psi;
  }
  // The excess over the rest quadratic, in the 9 values f = D z_e (restSplitExcess).
  const Vec9 f = D * z_e;
  const Mat3 F = Mat3::Identity() + Eigen::Map<const Mat3>(f.data());
  const bool derivatives = gradient || hessian;  // the Hessian needs the gradient
  Mat3 P;
  Mat9 A;
  const double psi =
      V * fungEnergyDensity(F, material, derivatives ? &P : nullptr, hessian ? &A : nullptr, psd);
  Vec9 g9 = Vec9::Zero();
  Mat9 H9 = Mat9::Zero();
  if (derivatives) g9 = V * Eigen::Map<const Vec9>(P.data());
  if (hessian) H9 = V * A;
  Eigen::Ref<VecX> g9_view = g9;
  Eigen::Ref<MatX> H9_view = H9;
  const double excess =
      restSplitExcess(psi, f, rest_tangent_[size_t(e)], w, derivatives ? &g9_view : nullptr,
                      hessian ? &H9_view : nullptr, psd, bounded, rest_floors_[e]);
  if (gradient) gradient->noalias() = D.transpose() * g9;
  if (hessian) {
    const MatX HD = H9 * D;
    hessian->noalias() = D.transpose() * HD;
  }
  return excess;
}

double ModalElasticityTerm::elements(int first, int last, double* gz, Mat3* values,
                                     bool psd) const {
  double E = 0.0;
  VecX z_e(max_dofs_), ge(max_dofs_);
  MatX He(values ? max_dofs_ : 0, values ? max_dofs_ : 0);
  for (int e = first; e < last; ++e) {
    const std::vector<int>& dofs = dofs_[size_t(e)];
    const int m = int(dofs.size());
    if (m == 0) continue;
    for (int k = 0; k < m; ++k) z_e[k] = kin_.u[dofs[size_t(k)]];
    Eigen::Ref<VecX> gradient = ge.head(m);
    Eigen::Ref<MatX> hessian = He.topLeftCorner(values ? m : 0, values ? m : 0);
    E += element(e, z_e.head(m), gz ? &gradient : nullptr, values ? &hessian : nullptr, psd);
    if (gz)
      for (int k = 0; k < m; ++k) gz[dofs[size_t(k)]] += gradient[k];
    if (values)  // upper triangle of group pairs (dofs ascending, in whole groups)
      for (int s = 0; s < m; s += 3)
        for (int r = s; r < m; r += 3)
          values[kin_.zzSlot(dofs[size_t(s)] / 3, dofs[size_t(r)] / 3)] +=
              hessian.block<3, 3>(s, r);
  }
  return E;
}

double ModalElasticityTerm::restStiffness(VecX* g, Mat3* values, int offset) const {
  if (rest_stiffness_.size() == 0) return 0.0;
  const VecX Kz = rest_stiffness_ * kin_.u;
  if (g) g->segment(offset + kin_.boneDofs(), Kz.size()) += Kz;
  if (values) {
    const int groups = kin_.numGroups();
    for (int b = 0; b < groups; ++b)
      for (int a = 0; a <= b; ++a)
        if (kin_.zzSlot(a, b) >= 0)
          values[kin_.zzSlot(a, b)] += rest_stiffness_.block<3, 3>(3 * a, 3 * b);
  }
  return 0.5 * kin_.u.dot(Kz);
}

double ModalElasticityTerm::evaluate(VecX* g, std::vector<Triplet>* H, int offset, bool psd,
                                     FixedHessianBlocks*) const {
  return evaluateElements(kin_, g, H != nullptr, offset, psd, 64);
}

int ModalElasticityTerm::boundedSamples() const {
  if (rest_stiffness_.size() == 0) return 0;
  int count = 0;
  for (int e = 0; e < elements_.size(); ++e) {
    const std::vector<int>& dofs = dofs_[size_t(e)];
    if (dofs.empty()) continue;
    VecX z_e(Eigen::Index(dofs.size()));
    for (size_t k = 0; k < dofs.size(); ++k) z_e[Eigen::Index(k)] = kin_.u[dofs[k]];
    bool bounded = false;
    element(e, z_e, nullptr, nullptr, false, &bounded);
    count += bounded ? 1 : 0;
  }
  return count;
}

// ---- the Material and Shape groups: not yet for modal bases ----------------------------------

namespace {

[[noreturn]] void notYet() {
  throw InputError(
      "Simulable: the Material and Shape parameter groups are not available yet for a reduced "
      "basis with modes (ReducedBasisKind 'modes' / 'modes+handles'); use the handle basis or "
      "the FEM for them");
}

}  // namespace

int ModalElasticityTerm::numMaterialElements() const { notYet(); }
int ModalElasticityTerm::materialElementTet(int) const { notYet(); }
void ModalElasticityTerm::materialElementDofs(int, std::vector<int>&) const { notYet(); }
FemMaterialDerivative ModalElasticityTerm::materialElementGradient(int, const Mat3X&) const {
  notYet();
}
Eigen::Vector4i ModalElasticityTerm::materialElementNodes(int) const { notYet(); }
void ModalElasticityTerm::materialElementRestCotangent(int, const Mat3X&, Mat34&) const {
  notYet();
}

}  // namespace flsh::detail
