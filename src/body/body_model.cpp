#include "flsh/body/body_model.h"

#include <cmath>
#include <cstdio>
#include <string>

#include "body/body_model_derived.h"
#include "flsh/core/error.h"

namespace flsh {

namespace {

std::string prefix(const BodyModel& m) {
  return (m.source.empty() ? std::string("body model") : m.source) + ": ";
}

void expectShape(const BodyModel& m, const char* key, long rows, long cols, long erows,
                 long ecols, const char* meaning) {
  if (rows != erows || cols != ecols)
    throw InputError(prefix(m) + "array '" + key + "' has shape " + shapeString({rows, cols}) +
                     ", expected " + shapeString({erows, ecols}) + " (" + meaning + ")");
}

std::string number(double value) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.6g", value);
  return text;
}

/// Throws unless every entry of `a` is finite and within ±kMaxBodyModelValue; names the entry.
template <class M>
void expectSane(const BodyModel& m, const char* key, const M& a, const char* meaning) {
  for (Eigen::Index c = 0; c < a.cols(); ++c)
    for (Eigen::Index r = 0; r < a.rows(); ++r) {
      const double value = a(r, c);
      if (!std::isfinite(value))
        throw InputError(prefix(m) + "array '" + key + "' contains NaN or Inf (at [" +
                         std::to_string(r) + ", " + std::to_string(c) + "])");
      if (std::abs(value) > kMaxBodyModelValue)
        throw InputError(prefix(m) + "array '" + key + "': entry [" + std::to_string(r) + ", " +
                         std::to_string(c) + "] = " + number(value) + " is outside [-" +
                         number(kMaxBodyModelValue) + ", " + number(kMaxBodyModelValue) + "] (" +
                         meaning + ")");
    }
}

/// Throws unless the regressed rest joints J_regressor · v_template and their shape directions
/// are within ±kMaxBodyModelValue (m, m per unit β): a regressor of sane entries can still
/// place a joint anywhere.
void expectSaneJoints(const BodyModel& m, const VecX& joints, const MatX& joint_shapedirs) {
  for (Eigen::Index r = 0; r < joints.size(); ++r)
    if (!(std::abs(joints[r]) <= kMaxBodyModelValue))
      throw InputError(prefix(m) + "array 'J_regressor' places joint " + std::to_string(r / 3) +
                       " at coordinate " + number(joints[r]) +
                       " m (J_regressor · v_template), "
                       "expected within [-" +
                       number(kMaxBodyModelValue) + ", " + number(kMaxBodyModelValue) + "] m");
  for (Eigen::Index r = 0; r < joint_shapedirs.rows(); ++r)
    for (Eigen::Index k = 0; k < joint_shapedirs.cols(); ++k)
      if (!(std::abs(joint_shapedirs(r, k)) <= kMaxBodyModelValue))
        throw InputError(prefix(m) + "arrays 'J_regressor' and 'shapedirs' move joint " +
                         std::to_string(r / 3) + " by " + number(joint_shapedirs(r, k)) +
                         " m per unit of shape coefficient " + std::to_string(k) +
                         " (J_regressor · shapedirs), expected within [-" +
                         number(kMaxBodyModelValue) + ", " + number(kMaxBodyModelValue) + "]");
}

/// 3J template joint centres J_regressor · v_template, flattened (entry 3j + c).
VecX regressedJoints(const SpMatR& J_regressor, const MatX3& v_template) {
  VecX joints = VecX::Zero(3 * J_regressor.rows());
  for (int j = 0; j < J_regressor.outerSize(); ++j)
    for (SpMatR::InnerIterator it(J_regressor, j); it; ++it)
      joints.segment<3>(3 * j) += it.value() * v_template.row(it.col()).transpose();
  return joints;
}

/// 3J × K joint shape directions J_regressor · shapedirs (row 3j + c).
MatX regressedJointShapedirs(const SpMatR& J_regressor, const MatX& shapedirs) {
  MatX dirs = MatX::Zero(3 * J_regressor.rows(), shapedirs.cols());
  if (shapedirs.cols() == 0) return dirs;  // no shape components: no rows to take (null data)
  for (int j = 0; j < J_regressor.outerSize(); ++j)
    for (SpMatR::InnerIterator it(J_regressor, j); it; ++it)
      dirs.middleRows<3>(3 * j) += it.value() * shapedirs.middleRows<3>(3 * it.col());
  return dirs;
}

}  // namespace

void BodyModel::validate() const {
  const long V = v_template.rows();
  if (V < 4) throw InputError(prefix(*this) + "array 'v_template' has " + std::to_string(V) +
                              " vertices, expected at least 4");
  const long J = long(parents.size());
  if (J < 1) throw InputError(prefix(*this) + "kintree_table is empty");
  expectShape(*this, "shapedirs", shapedirs.rows(), shapedirs.cols(), 3 * V, shapedirs.cols(),
              "3V x K");
  expectShape(*this, "posedirs", posedirs.rows(), posedirs.cols(), 3 * V, 9 * (J - 1),
              "3V x 9(J-1)");
  expectShape(*this, "J_regressor", J_regressor.rows(), J_regressor.cols(), J, V, "J x V");
  expectShape(*this, "weights", weights.rows(), weights.cols(), V, J, "V x J");
  if (faces.cols() != 3 || faces.rows() < 1)
    throw InputError(prefix(*this) + "array 'f' has shape " +
                     shapeString({long(faces.rows()), long(faces.cols())}) + ", expected (F, 3)");
  expectSane(*this, "v_template", v_template, "a vertex coordinate, m");
  expectSane(*this, "shapedirs", shapedirs, "m per unit of shape coefficient");
  expectSane(*this, "posedirs", posedirs, "m per unit of rotation-matrix entry");
  expectSane(*this, "weights", weights, "a skinning weight");
  for (int k = 0; k < J_regressor.outerSize(); ++k)
    for (SpMatR::InnerIterator it(J_regressor, k); it; ++it) {
      if (!std::isfinite(it.value()))
        throw InputError(prefix(*this) + "array 'J_regressor' contains NaN or Inf (at [" +
                         std::to_string(it.row()) + ", " + std::to_string(it.col()) + "])");
      if (std::abs(it.value()) > kMaxBodyModelValue)
        throw InputError(prefix(*this) + "array 'J_regressor': entry [" + std::to_string(it.row()) +
                         ", " + std::to_string(it.col()) + "] = " + number(it.value()) +
                         " is outside [-" + number(kMaxBodyModelValue) + ", " +
                         number(kMaxBodyModelValue) + "] (a joint regressor weight)");
    }
  if (faces.minCoeff() < 0 || faces.maxCoeff() >= V)
    throw InputError(prefix(*this) + "array 'f' has vertex indices outside [0, " +
                     std::to_string(V - 1) + "] (found " + std::to_string(faces.minCoeff()) +
                     ".." + std::to_string(faces.maxCoeff()) + ")");
  if (parents[0] != -1)
    throw InputError(prefix(*this) + "kintree_table: joint 0 must be the root (parent -1), got " +
                     std::to_string(parents[0]));
  for (long j = 1; j < J; ++j)
    if (parents[j] < 0 || parents[j] >= j)
      throw InputError(prefix(*this) + "kintree_table: parent of joint " + std::to_string(j) +
                       " is " + std::to_string(parents[j]) + ", expected a joint in [0, " +
                       std::to_string(j - 1) + "]");
  const VecX rowsums = weights.rowwise().sum();
  for (long i = 0; i < V; ++i)
    if (std::abs(rowsums[i] - 1.0) > 1e-3)
      throw InputError(prefix(*this) + "array 'weights': row " + std::to_string(i) +
                       " sums to " + std::to_string(rowsums[i]) + ", expected 1");
  const VecX joints = regressedJoints(J_regressor, v_template);
  expectSaneJoints(*this, joints, regressedJointShapedirs(J_regressor, shapedirs));
}

void BodyModel::finalize() {
  validate();
  auto d = std::make_shared<Derived>();
  const int J = numJoints();
  d->weights = SparseSkinWeights::fromDense(weights);
  const long nnz = (posedirs.array() != 0.0).count();
  d->use_sparse_posedirs = nnz * 2 < posedirs.size();
  if (d->use_sparse_posedirs) d->posedirs_sparse = posedirs.sparseView(1.0, 0.0);
  d->chain.resize(J);
  for (int j = 0; j < J; ++j) {
    for (int k = j; k >= 0; k = parents[k]) d->chain[j].insert(d->chain[j].begin(), k);
  }
  // Joint centres are linear in β: regress the template and every shape direction once, so
  // the forward pass and its shape Jacobian need no vertex-sized work for the joints.
  d->joints_template = regressedJoints(J_regressor, v_template);
  d->joint_shapedirs = regressedJointShapedirs(J_regressor, shapedirs);
  derived = std::move(d);
}

}  // namespace flsh
