// A tet's deformation gradient in the ROM's subspace for every basis kind (subspace_tets.h).
#include "volume/subspace_tets.h"

#include <omp.h>

#include <algorithm>
#include <string>
#include <vector>

#include "core/first_failure.h"
#include "flsh/core/error.h"
#include "flsh/volume/modal_basis.h"

namespace flsh::detail {

SubspaceTet subspaceTet(const VolumetricData& data, const ReducedData& rom, const SpMat& basis_rows,
                        const TetElementRest& rest, int t) {
  const MatX4i& tets = data.templ->mesh.tets;
  const Mat34 G = tetShapeGradients(rest);  // g_a, column a
  SubspaceTet out;
  const int H = rom.numHandles(), r = rom.numModes();
  bool moves = false;
  for (int a = 0; a < 4; ++a) {
    const int j = tets(t, a);
    if (data.bone_of_node[j] >= 0) continue;
    moves = true;
    if (H > 0)
      for (SpMat::InnerIterator it(basis_rows, j); it; ++it)
        for (int c = 0; c < 3; ++c) out.dofs.push_back(3 * int(it.row()) + c);
  }
  if (!moves) return out;
  std::sort(out.dofs.begin(), out.dofs.end());
  out.dofs.erase(std::unique(out.dofs.begin(), out.dofs.end()), out.dofs.end());
  const int handle_dofs = int(out.dofs.size());
  for (int k = 0; k < r; ++k) out.dofs.push_back(3 * H + k);
  out.D = MatX::Zero(9, Eigen::Index(out.dofs.size()));
  for (int a = 0; a < 4; ++a) {
    const int j = tets(t, a);
    if (data.bone_of_node[j] >= 0) continue;
    // vec(u_a g_aᵀ): entry i + 3l = u_a(i) g_a(l).
    if (H > 0)
      for (SpMat::InnerIterator it(basis_rows, j); it; ++it) {
        const int col = int(
            std::lower_bound(out.dofs.begin(), out.dofs.begin() + handle_dofs, 3 * int(it.row())) -
            out.dofs.begin());
        for (int l = 0; l < 3; ++l)
          for (int i = 0; i < 3; ++i) out.D(i + 3 * l, col + i) += it.value() * G(l, a);
      }
    if (r > 0)
      for (int l = 0; l < 3; ++l)
        out.D.block(3 * l, handle_dofs, 3, r) += G(l, a) * rom.modes.middleRows<3>(3 * j);
  }
  return out;
}

Mat9 restTangent(const FemMaterialPoint& material) {
  Mat3 P;
  Mat9 A;
  fungEnergyDensity(Mat3::Identity(), material, &P, &A, false);
  return 0.5 * (A + A.transpose());
}

namespace {

// Σ_e Φ̂_eᵀ K_e Φ̂_e over the elastic elements, K_e the element's elastic Hessian at rest
// (12 × 12) and Φ̂_e its nodes' basis rows (3H × 3H, N/m), exactly symmetric.
MatX handleRestStiffness(const VolumetricData& data, const SpMat& basis,
                         const ElasticTets& elements) {
  const int H = int(basis.cols()), E = int(elements.tets.size());
  const MatX4i& tets = data.templ->mesh.tets;
  const SpMat rows = basis.transpose();  // column j = node j's weights
  int threads = 1;
#ifdef _OPENMP
  threads = omp_get_max_threads();
#endif
  std::vector<MatX> partial(size_t(threads), MatX::Zero(3 * H, 3 * H));
  detail::FirstFailure failure;
#pragma omp parallel for schedule(static)
  for (int c = 0; c < E; ++c) {
    failure.run([&] {
      int thread = 0;
#ifdef _OPENMP
      thread = omp_get_thread_num();
#endif
      const int t = elements.tets[size_t(c)];
      Mat12 K;
      tetElasticEnergy(elements.rest[size_t(c)], elements.materials[size_t(c)],
                       Eigen::Matrix<double, 3, 4>::Zero(), nullptr, &K, false);
      MatX& C = partial[size_t(thread)];
      for (int a = 0; a < 4; ++a)
        for (SpMat::InnerIterator ia(rows, tets(t, a)); ia; ++ia)
          for (int b = 0; b < 4; ++b)
            for (SpMat::InnerIterator ib(rows, tets(t, b)); ib; ++ib)
              C.block<3, 3>(3 * ia.row(), 3 * ib.row()) +=
                  (ia.value() * ib.value()) * K.block<3, 3>(3 * a, 3 * b);
    });
  }
  failure.rethrow();
  MatX C = MatX::Zero(3 * H, 3 * H);
  for (const MatX& p : partial) C += p;
  return 0.5 * (C + C.transpose());  // symmetric up to rounding: make it exactly so
}

// The subspace's columns on the soft DoFs of `ops` (3S × numSoftDofs): each handle's φ ⊗ I₃,
// then the modes' rows.
MatX softDofBasis(const SoftTissueRestOperators& ops, const ReducedData& d) {
  const int S = ops.numSoftNodes(), H = d.numHandles();
  MatX B = MatX::Zero(3 * S, d.numSoftDofs());
  for (int h = 0; h < H; ++h)
    for (SpMat::InnerIterator it(d.basis, h); it; ++it) {
      const int dof = ops.dof_of_node[it.row()];
      if (dof < 0) continue;
      for (int c = 0; c < 3; ++c) B(dof + c, 3 * h + c) = it.value();
    }
  for (int i = 0; i < S; ++i)
    B.block(3 * i, 3 * H, 3, d.numModes()) = d.modes.middleRows<3>(3 * ops.soft_nodes[i]);
  return B;
}

}  // namespace

MatX subspaceRestStiffness(const VolumetricData& data, const ReducedData& d,
                           const ElasticTets& elements) {
  if (d.numModes() == 0) return handleRestStiffness(data, d.basis, elements);
  const SoftTissueRestOperators ops = softTissueRestOperators(data);
  const MatX B = softDofBasis(ops, d);
  const MatX KB = ops.stiffness * B;
  const MatX K = B.transpose() * KB;
  return 0.5 * (K + K.transpose());
}

}  // namespace flsh::detail

namespace flsh {

MatX elasticRestStiffness(const VolumetricData& data, const ReducedData& rom) {
  if (rom.basis.rows() != data.numNodes() ||
      (rom.numModes() > 0 && rom.modes.rows() != 3 * data.numNodes()))
    throw InputError("elasticRestStiffness: the basis has " + std::to_string(rom.basis.rows()) +
                     " rows and the modes " + std::to_string(rom.modes.rows()) +
                     ", expected #nodes (" + std::to_string(data.numNodes()) + ") and 3·#nodes");
  return detail::subspaceRestStiffness(data, rom, deformableTets(data));
}

MatX elasticRestStiffness(const VolumetricData& data, const SpMat& basis) {
  if (basis.rows() != data.numNodes())
    throw InputError("elasticRestStiffness: the basis has " + std::to_string(basis.rows()) +
                     " rows, expected one per node (" + std::to_string(data.numNodes()) + ")");
  return detail::handleRestStiffness(data, basis, deformableTets(data));
}

}  // namespace flsh
