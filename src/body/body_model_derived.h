// Internal acceleration data of a BodyModel (built by BodyModel::finalize()).
#pragma once

#include <vector>

#include "flsh/body/body_model.h"
#include "flsh/body/skinned_surface.h"

namespace flsh {

struct BodyModel::Derived {
  /// Per vertex, the joints with a nonzero weight and their weights.
  SparseSkinWeights weights;
  /// Pose blend shapes as a column-major sparse matrix (3#V × 207) when less than half of
  /// posedirs is nonzero; empty otherwise (the dense posedirs is used).
  SpMat posedirs_sparse;
  bool use_sparse_posedirs = false;
  /// Per joint, its ancestors from the root down to and including itself.
  std::vector<std::vector<int>> chain;
  /// 3J template joint centres J_regressor · v_template, flattened (entry 3j + c), m.
  VecX joints_template;
  /// 3J × K joint shape directions dJ/dβ = J_regressor · shapedirs (row 3j + c), so that
  /// J(β) = joints_template + joint_shapedirs β without touching the vertices.
  MatX joint_shapedirs;
};

}  // namespace flsh
