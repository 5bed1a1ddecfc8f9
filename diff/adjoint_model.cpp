// Default products of AdjointModel: from the matrices (models with cheaper products override).
#include "flsh/diff/adjoint_model.h"

namespace flsh {

void AdjointModel::previousStatesVJP(const VecX& lambda, VecX& a_n, VecX& a_nm1) const {
  a_n = previousStateJacobian(1).transpose() * lambda;
  a_nm1 = previousStateJacobian(2).transpose() * lambda;
}

VecX AdjointModel::previousStatesJVP(const VecX& dq_n, const VecX& dq_nm1) const {
  return previousStateJacobian(1) * dq_n + previousStateJacobian(2) * dq_nm1;
}

void AdjointModel::parameterVJPs(const VecX& lambda, std::vector<VecX>& out) const {
  std::vector<MatX> jacobians;
  parameterJacobians(jacobians);
  out.resize(jacobians.size());
  for (size_t g = 0; g < jacobians.size(); ++g) out[g] = jacobians[g].transpose() * lambda;
}

void AdjointModel::parameterJVPs(const std::vector<std::vector<const VecX*>>& directions,
                                 std::vector<VecX>& out) const {
  std::vector<MatX> jacobians;
  parameterJacobians(jacobians);
  out.assign(directions.size(), VecX::Zero(numDofs()));
  for (size_t d = 0; d < directions.size(); ++d)
    for (size_t g = 0; g < jacobians.size() && g < directions[d].size(); ++g)
      if (directions[d][g] && directions[d][g]->size()) out[d] += jacobians[g] * *directions[d][g];
}

}  // namespace flsh
