// A tet's deformation gradient in the ROM's subspace for every basis kind (subspace_tets.h).
#include "volume/subspace_tets.h"

#include <algorithm>
#include <string>

#include "flsh/core/error.h"

namespace flsh::detail {

SubspaceTet subspaceTet(const VolumetricData& data, const ReducedData& rom, const SpMat& basis_rows,
                        const TetElementRest& rest, int t) {
  const MatX4i& tets = data.templ->mesh.tets;
  const Mat3X G = reducedShapeGradients(rest, Mat4X::Identity(4, 4));  // g_a, column a
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

double subspaceTetElasticEnergy(double volume, const FemMaterialPoint& material,
                                const Eigen::Ref<const MatX>& D, const Eigen::Ref<const VecX>& z,
                                Eigen::Ref<VecX>* gradient, Eigen::Ref<MatX>* hessian, bool psd) {
  const Eigen::Index m = D.cols();
  if (D.rows() != 9 || z.size() != m || (gradient && gradient->size() != m) ||
      (hessian && (hessian->rows() != m || hessian->cols() != m)))
    throw InputError("subspaceTetElasticEnergy: D is " + std::to_string(D.rows()) + " × " +
                     std::to_string(m) + ", z has " + std::to_string(z.size()) +
                     " entries, expected 9 × m and m (and views of m)");
  const Vec9 f = D * z;
  const Mat3 F = Mat3::Identity() + Eigen::Map<const Mat3>(f.data());
  Mat3 P;
  Mat9 A;
  const double psi = volume * fungEnergyDensity(F, material, (gradient || hessian) ? &P : nullptr,
                                                hessian ? &A : nullptr, psd);
  if (gradient) gradient->noalias() = volume * (D.transpose() * Eigen::Map<const Vec9>(P.data()));
  if (hessian) {
    const MatX AD = volume * (A * D);
    hessian->noalias() = D.transpose() * AD;
  }
  return psi;
}

Mat9 restTangent(const FemMaterialPoint& material) {
  Mat3 P;
  Mat9 A;
  fungEnergyDensity(Mat3::Identity(), material, &P, &A, false);
  return 0.5 * (A + A.transpose());
}

}  // namespace flsh::detail
