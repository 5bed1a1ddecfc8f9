#include "sim/soft/reduced_elasticity_term.h"

#include <omp.h>

#include <algorithm>
#include <string>

#include "flsh/core/error.h"
#include "flsh/volume/reduced_data.h"
#include "sim/soft/on_two_threads.h"

namespace flsh::detail {

ReducedElasticityTerm::ReducedElasticityTerm(const SoftAvatar& avatar,
                                             const SoftKinematics& kinematics,
                                             ElasticElements elements)
    : ElasticityTerm(kinematics), elements_(std::move(elements)) {
  const ReducedData& rom = avatar.reducedData();
  const int H = kin_.numHandles();
  if (rom.elastic_rest_stiffness.size() > 0) {
    rest_stiffness_ = rom.elastic_rest_stiffness;
    if (rest_stiffness_.rows() != 3 * H || rest_stiffness_.cols() != 3 * H)
      throw InputError("Simulable: the avatar's elastic rest stiffness is " +
                       std::to_string(rest_stiffness_.rows()) + " × " +
                       std::to_string(rest_stiffness_.cols()) + ", expected 3·#handles square (" +
                       std::to_string(3 * H) + ")");
    for (int a = 0; a < H; ++a)
      for (int b = 0; b < H; ++b)
        if (!rest_stiffness_.block<3, 3>(3 * a, 3 * b).isZero(0.0))
          rest_stiffness_blocks_.emplace_back(a, b);
  }
  // Each element's handles and its shape gradients through the basis.
  const MatX4i& tets = elements_.tets;
  handle_start_.assign(1, 0);
  std::vector<Mat3X> gradients;
  int columns = 0;
  for (Eigen::Index e = 0; e < tets.rows(); ++e) {
    std::vector<int> handles;
    for (int a = 0; a < 4; ++a)
      for (auto* phi = kin_.basisBegin(tets(e, a)); phi != kin_.basisEnd(tets(e, a)); ++phi)
        handles.push_back(phi->first);
    std::sort(handles.begin(), handles.end());
    handles.erase(std::unique(handles.begin(), handles.end()), handles.end());
    Mat4X Phi = Mat4X::Zero(4, Eigen::Index(handles.size()));
    for (size_t s = 0; s < handles.size(); ++s) {
      handles_.push_back(handles[s]);
      for (int a = 0; a < 4; ++a)
        for (auto* phi = kin_.basisBegin(tets(e, a)); phi != kin_.basisEnd(tets(e, a)); ++phi)
          if (phi->first == handles[s]) Phi(a, Eigen::Index(s)) = phi->second;
    }
    gradients.push_back(reducedShapeGradients(elements_.rest[size_t(e)], Phi));
    columns += int(handles.size());
    handle_start_.push_back(int(handles_.size()));
    max_handles_ = std::max(max_handles_, int(handles.size()));
  }
  gradients_.resize(3, columns);
  for (size_t e = 0; e < gradients.size(); ++e)
    gradients_.middleCols(handle_start_[e], gradients[e].cols()) = gradients[e];
  if (rest_stiffness_.size() > 0) {  // each sample tet's own rest quadratic K̃_e
    rest_hessian_start_.assign(1, 0);
    for (size_t e = 0; e < gradients.size(); ++e) {
      const int m = 3 * int(gradients[e].cols());
      rest_hessian_start_.push_back(rest_hessian_start_.back() + m * m);
    }
    rest_hessians_.resize(rest_hessian_start_.back());
    for (size_t e = 0; e < gradients.size(); ++e) {
      const int count = int(gradients[e].cols()), m = 3 * count;
      if (count == 0) continue;
      Eigen::Map<MatX> K(rest_hessians_.data() + rest_hessian_start_[e], m, m);
      Eigen::Ref<MatX> view = K;
      reducedTetElasticEnergy(elements_.rest[e].volume, elements_.materials[e], gradients[e],
                              Mat3X::Zero(3, count), nullptr, &view, false);
    }
    rest_floors_ = restSplitFloors();
  }
}

std::vector<std::pair<int, int>> ReducedElasticityTerm::handlePairs() const {
  std::vector<std::pair<int, int>> pairs = rest_stiffness_blocks_;
  for (size_t e = 0; e + 1 < handle_start_.size(); ++e)
    for (int s = handle_start_[e]; s < handle_start_[e + 1]; ++s)
      for (int r = handle_start_[e]; r < handle_start_[e + 1]; ++r)
        pairs.emplace_back(handles_[s], handles_[r]);
  return pairs;
}

double ReducedElasticityTerm::elements(int first, int last, double* gz, Mat3* values,
                                       bool psd) const {
  // Per elastic tet, F = I + Z G̃ᵀ on the tet's handles (reducedTetElasticEnergy): gradient
  // and Hessian come straight in the handles' coordinates, one 3 × 3 block per handle pair.
  const bool hessian = values != nullptr;
  double E = 0.0;
  Mat3X Z(3, max_handles_);
  VecX ge(3 * max_handles_);
  MatX He(hessian ? 3 * max_handles_ : 0, hessian ? 3 * max_handles_ : 0);
  for (int e = first; e < last; ++e) {
    const int begin = handle_start_[e], count = handle_start_[e + 1] - begin;
    if (count == 0) continue;
    const int* tet_handles = &handles_[size_t(begin)];
    for (int s = 0; s < count; ++s) Z.col(s) = kin_.u.segment<3>(3 * tet_handles[s]);
    Eigen::Ref<VecX> gradient = ge.head(3 * count);
    Eigen::Ref<MatX> tet_hessian =
        He.topLeftCorner(hessian ? 3 * count : 0, hessian ? 3 * count : 0);
    double w = elements_.weights[e];
    if (rest_stiffness_.size() == 0) {
      E += w *
           reducedTetElasticEnergy(elements_.rest[size_t(e)].volume, elements_.materials[size_t(e)],
                                   gradients_.middleCols(begin, count), Z.leftCols(count),
                                   gz ? &gradient : nullptr, hessian ? &tet_hessian : nullptr, psd);
    } else {
      E += sampleExcess(e, count, w, Z.leftCols(count), gz != nullptr, hessian, psd, gradient,
                        tet_hessian);
      w = 1.0;  // the excess comes weighted
    }
    if (gz)
      for (int s = 0; s < count; ++s)
        Eigen::Map<Vec3>(gz + 3 * tet_handles[s]) += w * gradient.segment<3>(3 * s);
    if (hessian)  // upper triangle of handle pairs (handles_ ascending)
      for (int s = 0; s < count; ++s) {
        for (int r = s; r < count; ++r)
          values[kin_.zzSlot(tet_handles[s], tet_handles[r])] +=
              w * tet_hessian.block<3, 3>(3 * s, 3 * r);
      }
  }
  return E;
}

double ReducedElasticityTerm::sampleExcess(int e, int count, double w,
                                           const Eigen::Ref<const Mat3X>& Z, bool want_gradient,
                                           bool want_hessian, bool psd, Eigen::Ref<VecX> gradient,
                                           Eigen::Ref<MatX> hessian) const {
  // restSplitExcess (fem_material.h) of the tet's energy, with its stored rest Hessian.
  const int m = 3 * count, begin = handle_start_[e];
  const Eigen::Map<const MatX> K(rest_hessians_.data() + rest_hessian_start_[e], m, m);
  const bool derivatives = want_gradient || want_hessian;  // the Hessian needs the gradient
  const double psi = reducedTetElasticEnergy(
      elements_.rest[size_t(e)].volume, elements_.materials[size_t(e)],
      gradients_.middleCols(begin, count), Z, derivatives ? &gradient : nullptr,
      want_hessian ? &hessian : nullptr, psd);
  return restSplitExcess(psi, Eigen::Map<const VecX>(Z.data(), m), K, w,
                         derivatives ? &gradient : nullptr, want_hessian ? &hessian : nullptr, psd,
                         nullptr, rest_floors_[e]);
}

VecX ReducedElasticityTerm::restSplitFloors() const {
  // The sample tets' rest Hessians assembled in the subspace, without and with their weights.
  const int H = kin_.numHandles(), T = int(elements_.tets.rows());
  MatX unit = MatX::Zero(3 * H, 3 * H), weighted = MatX::Zero(3 * H, 3 * H);
  VecX weights(T);
  for (int e = 0; e < T; ++e) {
    weights[e] = elements_.weights[e];
    const int begin = handle_start_[e], count = handle_start_[e + 1] - begin;
    const Eigen::Map<const MatX> K(rest_hessians_.data() + rest_hessian_start_[e], 3 * count,
                                   3 * count);
    for (int s = 0; s < count; ++s)
      for (int r = 0; r < count; ++r) {
        const int a = handles_[size_t(begin + s)], b = handles_[size_t(begin + r)];
        unit.block<3, 3>(3 * a, 3 * b) += K.block<3, 3>(3 * s, 3 * r);
        weighted.block<3, 3>(3 * a, 3 * b) += weights[e] * K.block<3, 3>(3 * s, 3 * r);
      }
  }
  try {
    return flsh::restSplitFloors(rest_stiffness_, unit, weighted, weights);
  } catch (const InputError& error) {
    throw InputError(std::string("Simulable: the avatar's elastic cubature (ReducedData): ") +
                     error.what());
  }
}

double ReducedElasticityTerm::restStiffness(VecX* g, Mat3* values, int offset) const {
  if (rest_stiffness_.size() == 0) return 0.0;
  // ½ zᵀ K z, K the exact rest stiffness of the subspace (positive definite).
  const VecX Kz = rest_stiffness_ * kin_.u;
  if (g) g->segment(offset + kin_.boneDofs(), Kz.size()) += Kz;
  if (values)
    for (const auto& [a, b] : rest_stiffness_blocks_)
      if (a <= b) values[kin_.zzSlot(a, b)] += rest_stiffness_.block<3, 3>(3 * a, 3 * b);
  return 0.5 * kin_.u.dot(Kz);
}

double ReducedElasticityTerm::evaluate(VecX* g, std::vector<Triplet>* H, int offset, bool psd,
                                       FixedHessianBlocks*) const {
  Mat3* values = H ? kin_.reducedValues(1) : nullptr;
  const int T = int(elements_.tets.rows());
  const int base = offset + kin_.boneDofs();
  const bool hessian = values != nullptr;
  double E = 0.0;
  const int threads = std::min(2, omp_get_max_threads());
  if (hessian || T < 256 || threads < 2 || omp_in_parallel()) {
    // The Hessian's block sums stay on one thread (Simulable runs them beside inertia's).
    E = elements(0, T, g ? g->data() + base : nullptr, values, psd);
  } else {
    // Energy or gradient alone: the tets in two halves, the second half's gradient apart.
    VecX second = g ? VecX::Zero(3 * kin_.numHandles()) : VecX();
    double energies[2] = {0.0, 0.0};
    onTwoThreads([&](int part) {
      energies[part] = part == 0 ? elements(0, T / 2, g ? g->data() + base : nullptr, nullptr, psd)
                                 : elements(T / 2, T, g ? second.data() : nullptr, nullptr, psd);
    });
    E = energies[0] + energies[1];
    if (g) g->segment(base, second.size()) += second;
  }
  return E + restStiffness(g, values, offset);
}

}  // namespace flsh::detail
