// Evaluates a flsh Ceres cost through the installed flsh::ceres target.
#include <cstdio>

#include "flsh/ceres/smpl_costs.h"

int main() {
  const flsh::ceres_costs::ShapePriorCost cost(10, 2.0);
  double betas[10] = {1.0};
  const double* parameters[] = {betas};
  double residuals[10];
  if (!cost.Evaluate(parameters, residuals, nullptr)) return 1;
  std::printf("residual %.1f\n", residuals[0]);
  return residuals[0] == 2.0 ? 0 : 1;
}
