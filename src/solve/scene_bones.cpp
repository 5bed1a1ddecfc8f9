// The scene's objective on its avatars' bones with the soft tissue held: Newton's coarse
// presolve (NewtonOptions::coarse_presolve, src/solve/coarse_presolve.h). The bones' DoFs are
// the scene's coarse DoFs (Scene::coarseDofs); their energy leaves out the terms that read the
// soft state alone (the elasticity), which the presolve cannot change.
#include "flsh/solve/scene.h"

namespace flsh {

bool Scene::coarseEnergyAndGradient(double& energy, VecX& g) {
  if (!hasSoftTissue()) return false;
  bone_gradient_.setZero(num_dofs_);
  energy = 0.0;
  for (size_t i = 0; i < simulables_.size(); ++i)
    energy += simulables_[i]->getBoneEnergyAndGradientVector(bone_gradient_, offsets_[i]);
  if (avatarContactActive()) energy += avatarContactEnergy(&bone_gradient_, nullptr, true);
  for (size_t i = 0; i < simulables_.size(); ++i)
    simulables_[i]->fixVectorKinematic(bone_gradient_, offsets_[i]);
  std::vector<int> dofs;
  coarseDofs(dofs);
  g.resize(Eigen::Index(dofs.size()));
  for (size_t k = 0; k < dofs.size(); ++k) g[Eigen::Index(k)] = bone_gradient_[dofs[k]];
  return true;
}

void Scene::coarseHessian(MatX& H, bool psd) {
  std::vector<int> dofs;
  coarseDofs(dofs);
  coarse_index_.assign(size_t(num_dofs_), -1);
  for (size_t k = 0; k < dofs.size(); ++k) coarse_index_[size_t(dofs[k])] = int(k);
  bone_triplets_.clear();
  bone_blocks_.clear();
  for (size_t i = 0; i < simulables_.size(); ++i)
    simulables_[i]->getBoneHessianTripletVector(bone_triplets_, bone_blocks_, offsets_[i], psd);
  if (avatarContactActive()) avatarContactEnergy(nullptr, &bone_triplets_, psd);
  const int n = int(dofs.size());
  H.setZero(n, n);
  for (const Triplet& t : bone_triplets_) {
    const int r = coarse_index_[size_t(t.row())], c = coarse_index_[size_t(t.col())];
    if (r >= 0 && c >= 0) H(r, c) += t.value();
  }
  // Fixed blocks are the tissue's (node pairs, bone–node coupling): only a block inside the
  // bones' rows and columns would count; a bone DoF group is 6 wide, so a 3 × 3 block is
  // wholly inside or outside.
  for (const FixedHessianBlocks& list : bone_blocks_)
    for (size_t k = 0; !list.empty() && k < list.positions->size(); ++k) {
      const auto [row, col] = (*list.positions)[k];
      const int r = coarse_index_[size_t(row + list.offset)];
      const int c = coarse_index_[size_t(col + list.offset)];
      if (r >= 0 && c >= 0) H.block<3, 3>(r, c) += (*list.values)[k];
    }
  std::vector<char> kinematic;
  markKinematicBones(kinematic);
  for (int k = 0; k < n; ++k)
    if (kinematic[size_t(dofs[size_t(k)])]) {
      H.row(k).setZero();
      H.col(k).setZero();
      H(k, k) = 1.0;
    }
}

LinearSolver* Scene::coarseSolver() {
  if (!coarse_solver_) coarse_solver_ = makeLinearSolver(LinearSolverType::SparseLLT, 0);
  return coarse_solver_.get();
}

}  // namespace flsh
