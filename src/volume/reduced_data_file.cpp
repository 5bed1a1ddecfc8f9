#include "volume/reduced_data_file.h"

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "flsh/core/error.h"

namespace flsh::detail {

namespace {

std::string str(double v) {
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), "%g", v);
  return buffer;
}

void addIntegers(io::NpzWriter& w, const std::string& key, const std::vector<int64_t>& values) {
  w.add(key, values.data(), {long(values.size())});
}

std::vector<int64_t> toInt64(const VecXi& v) {
  return std::vector<int64_t>(v.data(), v.data() + v.size());
}

void storeCubature(io::NpzWriter& w, const std::string& name, const Cubature& c,
                   double test_error) {
  addIntegers(w, name + "_elements", toInt64(c.elements));
  w.add(name + "_weights", c.weights);
  w.add(name + "_figures",
        VecX((VecX(3) << c.training_error, double(c.rounds), test_error).finished()));
}

}  // namespace

void checkModes(const VolumetricData& data, const MatX& modes, const std::string& where) {
  const int n = data.numNodes();
  if (modes.rows() != 3 * n || modes.cols() < 3 || modes.cols() % 3 != 0 || !modes.allFinite())
    throw InputError(where + " is " + std::to_string(modes.rows()) + " × " +
                     std::to_string(modes.cols()) + (modes.allFinite() ? "" : " with NaN or Inf") +
                     ", expected 3·#nodes × r = " + std::to_string(3 * n) +
                     " × r, finite, r a positive multiple of 3");
  for (int j = 0; j < n; ++j)
    if (data.bone_of_node[j] >= 0 && !modes.middleRows<3>(3 * j).isZero(0.0))
      throw InputError(where + ": rows of bone node " + std::to_string(j) +
                       " are not zero, expected zero (bone nodes do not move)");
}

io::NpzWriter reducedDataArrays(const ReducedData& d) {
  io::NpzWriter w;
  if (d.basis_kind != ReducedBasisKind::Handles) {
    addIntegers(w, "basis_kind", {int64_t(d.basis_kind)});
    w.add("modes", d.modes);
  }
  addIntegers(w, "handles", toInt64(d.handles));
  std::vector<int64_t> rows, cols;
  std::vector<double> values;
  for (int h = 0; h < d.basis.outerSize(); ++h)
    for (SpMat::InnerIterator it(d.basis, h); it; ++it) {
      rows.push_back(it.row());
      cols.push_back(h);
      values.push_back(it.value());
    }
  addIntegers(w, "basis_rows", rows);
  addIntegers(w, "basis_cols", cols);
  w.add("basis_values", values.data(), {long(values.size())});
  w.add("basis_report", VecX((VecX(3) << d.basis_max_bound_violation, d.basis_max_constraint_error,
                              d.basis_converged ? 1.0 : 0.0)
                                 .finished()));
  storeCubature(w, "elastic", d.elastic, d.elastic_test_error);
  storeCubature(w, "inertial", d.inertial, d.inertial_test_error);
  w.add("inertial_rigid_error", VecX::Constant(1, d.inertial_rigid_error));
  if (d.elastic_rest_stiffness.size() > 0)
    w.add("elastic_rest_stiffness", d.elastic_rest_stiffness);
  return w;
}

namespace {

// Reads and checks one cubature: ascending element indices in [0, T), finite weights > 0, at
// most `count` points, empty when the cubature is off.
Cubature loadCubature(const io::NpzFile& f, const std::string& name, bool built, int count, int T,
                      double* test_error) {
  const std::string where = f.path() + ": key '" + name;
  const std::vector<int64_t> elements = f.integers(name + "_elements", {-1});
  const long n = long(elements.size());
  Cubature c;
  c.weights = f.vector(name + "_weights", n);
  const VecX figures = f.vector(name + "_figures", 3);
  if (!built && n != 0)
    throw InputError(where + "_elements': " + std::to_string(n) +
                     " elements for a cubature that is switched off, expected none");
  if (built && (n < 1 || n > count))
    throw InputError(where + "_elements': " + std::to_string(n) + " elements, expected 1.." +
                     std::to_string(count));
  c.elements.resize(n);
  for (long k = 0; k < n; ++k) {
    if (elements[size_t(k)] < 0 || elements[size_t(k)] >= T ||
        (k > 0 && elements[size_t(k)] <= elements[size_t(k - 1)]))
      throw InputError(where + "_elements': entry " + std::to_string(k) + " = " +
                       std::to_string(elements[size_t(k)]) +
                       ", expected ascending tet indices in [0, " + std::to_string(T) + ")");
    c.elements[k] = int(elements[size_t(k)]);
    if (!(c.weights[k] > 0))
      throw InputError(where + "_weights': entry " + std::to_string(k) + " = " + str(c.weights[k]) +
                       ", expected > 0");
  }
  if (!(figures.array() >= 0).all())
    throw InputError(where + "_figures': expected errors and rounds ≥ 0");
  c.training_error = figures[0];
  c.rounds = int(figures[1]);
  *test_error = figures[2];
  return c;
}

}  // namespace

ReducedData readReducedData(const io::NpzFile& f, const VolumetricData& data, const BodyModel& body,
                            const ReducedSettings& settings, bool elastic, bool inertial) {
  const int N = data.numNodes(), V = body.numVertices(), T = data.numTets();
  const bool modal = settings.basis_kind != ReducedBasisKind::Handles;
  const int H = settings.basis_kind == ReducedBasisKind::Modes ? 0 : settings.num_handles;
  ReducedData d;
  d.basis_kind = settings.basis_kind;
  if (modal) {
    const int64_t kind = f.integers("basis_kind", {1})[0];
    if (kind != int64_t(settings.basis_kind))
      throw InputError(f.path() + ": key 'basis_kind': " + std::to_string(kind) + ", expected " +
                       std::to_string(int(settings.basis_kind)) + " (" +
                       reducedBasisKindName(settings.basis_kind) + ")");
    d.modes = f.matrix("modes", 3L * N, -1);
    checkModes(data, d.modes, f.path() + ": key 'modes'");
  } else if (f.has("modes")) {
    throw InputError(f.path() + ": key 'modes' in data of the handle basis kind");
  }
  const std::vector<int64_t> handles = f.integers("handles", {H});
  d.handles.resize(H);
  std::vector<char> seen(size_t(V), 0);
  for (int h = 0; h < H; ++h) {
    const int64_t i = handles[size_t(h)];
    if (i < 0 || i >= V || seen[size_t(i)] || data.bone_of_node[int(i)] >= 0)
      throw InputError(f.path() + ": key 'handles': entry " + std::to_string(h) + " = " +
                       std::to_string(i) + ", expected distinct soft-tissue surface nodes in [0, " +
                       std::to_string(V) + ")");
    seen[size_t(i)] = 1;
    d.handles[h] = int(i);
  }
  const std::vector<int64_t> rows = f.integers("basis_rows", {-1});
  const long nnz = long(rows.size());
  const std::vector<int64_t> cols = f.integers("basis_cols", {nnz});
  const VecX values = f.vector("basis_values", nnz);
  std::vector<Triplet> entries;
  entries.reserve(size_t(nnz));
  for (long k = 0; k < nnz; ++k) {
    const int64_t r = rows[size_t(k)], c = cols[size_t(k)];
    // Column-major order without repeats: the compressed matrix is rebuilt exactly as stored.
    const bool ordered =
        k == 0 || c > cols[size_t(k - 1)] || (c == cols[size_t(k - 1)] && r > rows[size_t(k - 1)]);
    if (r < 0 || r >= N || c < 0 || c >= H || !ordered)
      throw InputError(f.path() + ": keys 'basis_rows'/'basis_cols': entry " + std::to_string(k) +
                       " = (" + std::to_string(r) + ", " + std::to_string(c) +
                       "), expected column-major ordered indices in [0, " + std::to_string(N) +
                       ") × [0, " + std::to_string(H) + ")");
    if (!(values[k] >= kBasisDropThreshold && values[k] <= 1 + 1e-6) ||
        data.bone_of_node[int(r)] >= 0)
      throw InputError(f.path() + ": key 'basis_values': entry " + std::to_string(k) + " = " +
                       str(values[k]) + " at node " + std::to_string(r) +
                       ", expected a weight in [0, 1] on a soft-tissue node");
    entries.emplace_back(int(r), int(c), values[k]);
  }
  d.basis.resize(N, H);
  d.basis.setFromTriplets(entries.begin(), entries.end());
  d.basis.makeCompressed();
  const VecX report = f.vector("basis_report", 3);
  d.basis_max_bound_violation = report[0];
  d.basis_max_constraint_error = report[1];
  d.basis_converged = report[2] != 0;
  d.elastic = loadCubature(f, "elastic", elastic, settings.elastic_cubature_points, T,
                           &d.elastic_test_error);
  d.inertial = loadCubature(f, "inertial", inertial, settings.inertial_cubature_points, T,
                            &d.inertial_test_error);
  d.inertial_rigid_error = f.vector("inertial_rigid_error", 1)[0];
  if (!(d.inertial_rigid_error >= 0 && std::isfinite(d.inertial_rigid_error)))
    throw InputError(f.path() + ": key 'inertial_rigid_error': " + str(d.inertial_rigid_error) +
                     ", expected a finite error ≥ 0");
  if (elastic) {
    const long m = 3L * H + d.numModes();
    d.elastic_rest_stiffness = f.matrix("elastic_rest_stiffness", m, m);
    if (!d.elastic_rest_stiffness.allFinite())
      throw InputError(f.path() + ": key 'elastic_rest_stiffness': NaN or Inf");
  }
  return d;
}

}  // namespace flsh::detail
