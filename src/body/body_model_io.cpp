// Loading and saving SMPL-format body models as `.npz` (ARCHITECTURE.md §2).
#include <algorithm>
#include <cstdint>
#include <string>
#include <vector>

#include "flsh/body/body_model.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/body/smplh.h"
#include "flsh/core/error.h"
#include "flsh/format/npz.h"

namespace flsh {

namespace {

/// Root parents as written by the official files: −1, or −1 stored as uint32 (4294967295) —
/// also found in int64 arrays converted from uint32.
constexpr int64_t kUint32RootParent = 4294967295LL;

/// Shape of `key`, after checking that it has `ndim` dimensions.
std::vector<long> shapeOf(const io::NpzFile& file, const std::string& key, size_t ndim,
                          const std::string& layout) {
  const io::NpyArray& a = file.raw(key);
  if (!a.isFloat() && !a.isInteger())
    throw InputError(file.path() + ": key '" + key + "': expected a numeric array " + layout +
                     ", got dtype '" + a.dtype + "'");
  if (a.shape.size() != ndim)
    throw InputError(file.path() + ": key '" + key + "': expected shape " + layout + ", got " +
                     shapeString(a.shape));
  return a.shape;
}

/// Throws unless extent `axis` of `key` equals `expected`, which `source_key` defines.
void expectExtent(const io::NpzFile& file, const std::string& key, const std::vector<long>& shape,
                  size_t axis, long expected, const std::string& symbol,
                  const std::string& source_key, const std::string& layout) {
  if (shape[axis] != expected)
    throw InputError(file.path() + ": key '" + key + "' has shape " + shapeString(shape) +
                     ", expected " + layout + " with " + symbol + " = " + std::to_string(expected) +
                     " from key '" + source_key + "'");
}

}  // namespace

BodyModel loadBodyModel(const std::string& path) {
  const io::NpzFile file(path);
  BodyModel model;
  model.source = path;

  // Vertex count V from v_template, joint count J from kintree_table; every other array is
  // checked against them.
  const std::vector<long> template_shape = shapeOf(file, "v_template", 2, "(V, 3)");
  const long V = template_shape[0];
  const std::vector<double> v_template = file.doubles("v_template", {V, 3});
  model.v_template = Eigen::Map<const MatX3>(v_template.data(), V, 3);

  const std::vector<long> tree_shape = shapeOf(file, "kintree_table", 2, "(2, J)");
  if (tree_shape[0] != 2)
    throw InputError(path + ": key 'kintree_table': expected shape (2, J), got " +
                     shapeString(tree_shape));
  const long J = tree_shape[1];
  if (J != kNumJoints && J != kNumSmplhJoints)
    throw InputError(path + ": key 'kintree_table' has shape " + shapeString(tree_shape) + ": " +
                     std::to_string(J) + " joints" + (J == 55 ? " (SMPL-X?)" : "") +
                     "; flsh reads SMPL (24 joints) and SMPL-H / SMPL+H (52 joints) models");
  const std::vector<int64_t> tree = file.integers("kintree_table", {2, J});
  model.parents.resize(size_t(J));
  for (long j = 0; j < J; ++j) {
    int64_t parent = tree[size_t(j)];
    if (parent == kUint32RootParent) parent = -1;
    if (parent < -1 || parent >= J)
      throw InputError(path + ": key 'kintree_table': parent of joint " + std::to_string(j) +
                       " is " + std::to_string(parent) + ", expected -1 (root) or a joint in [0, " +
                       std::to_string(J - 1) + "]");
    model.parents[size_t(j)] = int(parent);
  }

  const std::vector<long> shapedirs_shape = shapeOf(file, "shapedirs", 3, "(V, 3, K)");
  expectExtent(file, "shapedirs", shapedirs_shape, 0, V, "V", "v_template", "(V, 3, K)");
  const long K = shapedirs_shape[2];
  const std::vector<double> shapedirs = file.doubles("shapedirs", {V, 3, K});
  // (V, 3, K) in C order is the row-major 3V × K matrix.
  model.shapedirs = Eigen::Map<const RowMatX>(shapedirs.data(), 3 * V, K);

  const long P = 9 * (J - 1);
  const std::vector<long> posedirs_shape = shapeOf(file, "posedirs", 3, "(V, 3, 9(J-1))");
  expectExtent(file, "posedirs", posedirs_shape, 0, V, "V", "v_template", "(V, 3, 9(J-1))");
  expectExtent(file, "posedirs", posedirs_shape, 2, P, "9(J-1)", "kintree_table", "(V, 3, 9(J-1))");
  const std::vector<double> posedirs = file.doubles("posedirs", {V, 3, P});
  model.posedirs = Eigen::Map<const RowMatX>(posedirs.data(), 3 * V, P);

  const std::vector<long> regressor_shape = shapeOf(file, "J_regressor", 2, "(J, V)");
  expectExtent(file, "J_regressor", regressor_shape, 0, J, "J", "kintree_table", "(J, V)");
  expectExtent(file, "J_regressor", regressor_shape, 1, V, "V", "v_template", "(J, V)");
  const std::vector<double> regressor = file.doubles("J_regressor", {J, V});
  model.J_regressor =
      Eigen::Map<const RowMatX>(regressor.data(), J, V).sparseView(1.0, 0.0);  // exact zeros only
  model.J_regressor.makeCompressed();

  const std::vector<long> weights_shape = shapeOf(file, "weights", 2, "(V, J)");
  expectExtent(file, "weights", weights_shape, 0, V, "V", "v_template", "(V, J)");
  expectExtent(file, "weights", weights_shape, 1, J, "J", "kintree_table", "(V, J)");
  const std::vector<double> weights = file.doubles("weights", {V, J});
  model.weights = Eigen::Map<const RowMatX>(weights.data(), V, J);

  const std::vector<long> faces_shape = shapeOf(file, "f", 2, "(F, 3)");
  if (faces_shape[1] != 3)
    throw InputError(path + ": key 'f': expected shape (F, 3), got " + shapeString(faces_shape));
  const long F = faces_shape[0];
  const std::vector<int64_t> faces = file.integers("f", {F, 3});
  model.faces.resize(F, 3);
  for (long k = 0; k < 3 * F; ++k) {
    // Checked here, before narrowing to int, so that a huge index cannot wrap into range.
    if (faces[size_t(k)] < 0 || faces[size_t(k)] >= V)
      throw InputError(path + ": key 'f': vertex index " + std::to_string(faces[size_t(k)]) +
                       " of face " + std::to_string(k / 3) + " is outside [0, " +
                       std::to_string(V - 1) + "] (V = " + std::to_string(V) +
                       " from key 'v_template')");
    model.faces.data()[k] = int(faces[size_t(k)]);
  }

  if (J == kNumSmplhJoints) {
    if (!isSmplhSkeleton(model.parents))
      throw InputError(path + ": key 'kintree_table': 52 joints but not SMPL-H's tree (joint " +
                       std::to_string(std::mismatch(model.parents.begin(), model.parents.end(),
                                                    kSmplhParents.begin())
                                          .first -
                                      model.parents.begin()) +
                       " has another parent)");
    return smplFromSmplh(model);
  }
  model.finalize();
  return model;
}

void saveBodyModel(const BodyModel& model, const std::string& path) {
  model.validate();
  const long V = model.numVertices(), J = model.numJoints(), K = model.numBetas();
  const long P = long(model.posedirs.cols());
  io::NpzWriter writer;
  writer.add("v_template", RowMatX(model.v_template));
  // 3V × K row-major is (V, 3, K) in C order.
  const RowMatX shapedirs = model.shapedirs;
  writer.add("shapedirs", shapedirs.data(), {V, 3, K});
  const RowMatX posedirs = model.posedirs;
  writer.add("posedirs", posedirs.data(), {V, 3, P});
  writer.add("J_regressor", RowMatX(MatX(model.J_regressor)));
  writer.add("weights", RowMatX(model.weights));
  std::vector<int64_t> tree(size_t(2 * J));
  for (long j = 0; j < J; ++j) {
    tree[size_t(j)] = model.parents[size_t(j)];
    tree[size_t(J + j)] = j;
  }
  writer.add("kintree_table", tree.data(), {2, J});
  std::vector<int64_t> faces(model.faces.data(), model.faces.data() + model.faces.size());
  writer.add("f", faces.data(), {long(model.faces.rows()), 3});
  writer.save(path);
}

}  // namespace flsh
