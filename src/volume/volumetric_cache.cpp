// The volumetric body's two levels in the avatar cache: arrays and checks on load
// (volumetric_cache.h).
#include "volumetric_cache.h"

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "flsh/core/error.h"

namespace flsh {

namespace {

std::string str(double x) {
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), "%.17g", x);
  return buffer;
}

// Integer matrices go to the cache as int64 (the npz writer's integer type).
template <class M>
void addIntegers(io::NpzWriter& w, const std::string& key, const M& m) {
  std::vector<int64_t> values(size_t(m.rows() * m.cols()));
  for (Eigen::Index r = 0; r < m.rows(); ++r)
    for (Eigen::Index c = 0; c < m.cols(); ++c) values[size_t(r * m.cols() + c)] = m(r, c);
  if constexpr (M::ColsAtCompileTime == 1)
    w.add(key, values.data(), {long(m.rows())});  // a vector is stored 1-D
  else
    w.add(key, values.data(), {long(m.rows()), long(m.cols())});
}

/// Reads a message prefix "FILE: key 'K'".
std::string keyOf(const io::NpzFile& f, const std::string& key) {
  return f.path() + ": key '" + key + "'";
}

MatX4i readTets(const io::NpzFile& f, long nodes) {
  const std::vector<int64_t> v = f.integers("tets", {-1, 4});
  MatX4i tets(long(v.size() / 4), 4);
  for (size_t i = 0; i < v.size(); ++i) {
    if (v[i] < 0 || v[i] >= nodes)
      throw InputError(keyOf(f, "tets") + ": index " + std::to_string(v[i]) + " outside [0, " +
                       std::to_string(nodes) + ")");
    tets(long(i / 4), long(i % 4)) = int(v[i]);
  }
  return tets;
}

// A float64 array of the cache as a column-major matrix, in one copy (NpzFile::matrix would make
// three: the big pose blend shapes dominate the time to load a cached avatar).
MatX readMatrix(const io::NpzFile& f, const std::string& key, long rows, long cols) {
  const io::NpyArray& a = f.raw(key);
  if (a.dtype != "<f8" || a.shape.size() != 2 || a.shape[0] != rows || a.shape[1] != cols)
    throw InputError(keyOf(f, key) + ": expected float64 " + shapeString({rows, cols}) + ", got " +
                     a.dtype + " " + shapeString(a.shape));
  MatX m = Eigen::Map<const RowMatX>(reinterpret_cast<const double*>(a.bytes.data()), rows, cols);
  if (!m.allFinite()) throw InputError(keyOf(f, key) + ": NaN or Inf");
  return m;
}

/// Rows 0..V−1 (of `rows_per_vertex` rows each) of a field must be the body's own, exactly.
void checkSurfaceRows(const io::NpzFile& f, const std::string& key, const MatX& field,
                      const MatX& body_field, int rows_per_vertex) {
  const long rows = body_field.rows();
  if (field.topRows(rows) != body_field) {
    long r = 0;
    while (r < rows && field.row(r) == body_field.row(r)) ++r;
    throw InputError(keyOf(f, key) + ": row " + std::to_string(r) + " (surface vertex " +
                     std::to_string(r / rows_per_vertex) + ") differs from the body model's");
  }
}

/// |a − b| ≤ 1e-9 · max(|a|, |b|), for values recomputed from the model.
bool close(double a, double b) {
  return std::abs(a - b) <= 1e-9 * std::max(std::abs(a), std::abs(b));
}

}  // namespace

io::NpzWriter templateCacheArrays(const VolumetricTemplate& templ) {
  io::NpzWriter w;
  w.add("nodes", templ.mesh.nodes);
  addIntegers(w, "tets", templ.mesh.tets);
  w.add("weights", RowMatX(templ.fields.weights));
  w.add("shapedirs", RowMatX(templ.fields.shapedirs));
  w.add("posedirs", RowMatX(templ.fields.posedirs));
  const TetMeshQuality& q = templ.quality;
  w.add("quality", VecX((VecX(5) << q.min_dihedral_deg, q.max_dihedral_deg, q.max_radius_edge_ratio,
                         q.mean_radius_edge_ratio, q.min_volume)
                            .finished()));
  return w;
}

void readTemplateCacheArrays(const io::NpzFile& f, const BodyModel& body,
                             VolumetricTemplate& templ) {
  const int V = body.numVertices(), B = body.numJoints();
  TetMesh& mesh = templ.mesh;
  mesh.nodes = f.matrix("nodes", -1, 3);
  const long N = mesh.nodes.rows();
  if (N <= V)
    throw InputError(keyOf(f, "nodes") + ": " + std::to_string(N) + " nodes, expected the body's " +
                     std::to_string(V) + " vertices and interior nodes after them");
  checkSurfaceRows(f, "nodes", MatX(mesh.nodes), MatX(body.v_template), 1);
  mesh.tets = readTets(f, N);
  mesh.num_surface_nodes = V;
  try {
    validateTetMesh(mesh, body.faces);
  } catch (const Error& e) {
    throw InputError(f.path() + ": key 'nodes' or 'tets': not a valid tet mesh of the body (" +
                     e.what() + ")");
  }

  InteriorFields& fields = templ.fields;
  fields.weights = readMatrix(f, "weights", N, B);
  checkSurfaceRows(f, "weights", fields.weights, body.weights, 1);
  for (long i = V; i < N; ++i) {
    const auto row = fields.weights.row(i);
    if (!(row.minCoeff() >= 0) || !(std::abs(row.sum() - 1) <= 1e-9))
      throw InputError(keyOf(f, "weights") + ": row " + std::to_string(i) + " has minimum " +
                       str(row.minCoeff()) + " and sum " + str(row.sum()) +
                       ", expected weights >= 0 summing to 1");
  }
  fields.shapedirs = readMatrix(f, "shapedirs", 3 * N, body.numBetas());
  checkSurfaceRows(f, "shapedirs", fields.shapedirs, body.shapedirs, 3);
  fields.posedirs = readMatrix(f, "posedirs", 3 * N, body.posedirs.cols());
  checkSurfaceRows(f, "posedirs", fields.posedirs, body.posedirs, 3);
  const VecX q = f.vector("quality", 5);  // finite (NpzFile checks)
  templ.quality = {q(0), q(1), q(2), q(3), q(4)};
}

io::NpzWriter dataCacheArrays(const VolumetricData& d) {
  io::NpzWriter w;
  addIntegers(w, "bone_of_node", d.bone_of_node);
  w.add("tissue_thickness", d.tissue_thickness);
  const TetMaterials& m = d.materials;
  w.add("density", m.density);
  w.add("young", RowMatX(m.young));
  w.add("poisson", RowMatX(m.poisson));
  w.add("shear", RowMatX(m.shear));
  w.add("fung", m.fung);
  w.add("skin_fraction", m.skin_fraction);
  RowMatX frames(long(m.frame.size()), 9);
  for (size_t t = 0; t < m.frame.size(); ++t)
    Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(frames.row(long(t)).data()) =
        m.frame[t];
  w.add("frame", frames);
  addIntegers(w, "layer", m.layer);
  return w;
}

void readDataCacheArrays(const io::NpzFile& f, const VecX& betas, VolumetricData& d) {
  if (!d.templ) throw InputError("readDataCacheArrays: the volumetric data has no template");
  const TetMesh& mesh = d.templ->mesh;
  const MatX& weights = d.templ->fields.weights;
  const long N = mesh.numNodes(), T = mesh.numTets(), V = mesh.num_surface_nodes;
  const long B = weights.cols();

  // Bone nodes: a bone node hangs on one of its largest weights (selectBoneNodes).
  const std::vector<int64_t> bones = f.integers("bone_of_node", {N});
  d.bone_of_node.resize(N);
  for (long i = 0; i < N; ++i) {
    const int64_t b = bones[size_t(i)];
    if (b < -1 || b >= B || (b >= 0 && weights(i, long(b)) < weights.row(i).maxCoeff()))
      throw InputError(keyOf(f, "bone_of_node") + ": entry " + std::to_string(i) + " = " +
                       std::to_string(b) + ", expected -1 or a bone in [0, " + std::to_string(B) +
                       ") among the node's largest weights");
    d.bone_of_node(i) = int(b);
  }
  d.tissue_thickness = f.vector("tissue_thickness", V);
  if (!(d.tissue_thickness.array() >= 0).all())
    throw InputError(keyOf(f, "tissue_thickness") + ": expected thicknesses >= 0 m");

  TetMaterials& m = d.materials;
  m.skin_fraction = f.vector("skin_fraction", T);
  const std::vector<int64_t> layer = f.integers("layer", {T});
  m.layer.resize(T);
  for (long t = 0; t < T; ++t) {
    const double s = m.skin_fraction[t];
    if (!(s >= 0 && s <= 1))
      throw InputError(keyOf(f, "skin_fraction") + ": entry " + std::to_string(t) + " = " + str(s) +
                       ", expected a fraction in [0, 1]");
    const int expected = s >= 0.5 ? MaterialModel::kSkin : MaterialModel::kSoftTissue;
    if (layer[size_t(t)] != expected)
      throw InputError(keyOf(f, "layer") + ": entry " + std::to_string(t) + " = " +
                       std::to_string(layer[size_t(t)]) + ", expected " + std::to_string(expected) +
                       " for a skin fraction of " + str(s));
    m.layer(t) = expected;
  }

  // Density, Fung exponent and shear moduli mix the two layers' coefficients linearly in the
  // skin fraction, the soft tissue's moduli scaled by the tet's body-region factor (recomputed
  // from the template's weights, not stored); Young's moduli and Poisson ratios come from the
  // mixed stiffness tensor, so they are only checked for a physical (positive-definite)
  // compliance.
  m.density = f.vector("density", T);
  m.fung = f.vector("fung", T);
  m.young = f.matrix("young", T, 3);
  m.poisson = f.matrix("poisson", T, 3);
  m.shear = f.matrix("shear", T, 3);
  const MaterialModel& model = d.material_model;
  const auto value = [&](const char* q, int l) { return model.value(q, l, betas); };
  const int skin = MaterialModel::kSkin, tissue = MaterialModel::kSoftTissue;
  const double skin_values[5] = {value("density", skin), value("fung_gamma", skin),
                                 value("G12", skin), value("G13", skin), value("G23", skin)};
  const double tissue_values[5] = {value("density", tissue), value("fung_gamma", tissue),
                                   value("G12", tissue), value("G13", tissue),
                                   value("G23", tissue)};
  const char* keys[5] = {"density", "fung", "shear", "shear", "shear"};
  m.tissue_stiffness_scale = tetTissueStiffnessScale(mesh, weights, model, betas);
  for (long t = 0; t < T; ++t) {
    const double s = m.skin_fraction[t];
    const double stored[5] = {m.density[t], m.fung[t], m.shear(t, 0), m.shear(t, 1), m.shear(t, 2)};
    for (int k = 0; k < 5; ++k) {
      const double tissue_value =
          k >= 2 ? m.tissue_stiffness_scale[t] * tissue_values[k] : tissue_values[k];
      const double expected = s * skin_values[k] + (1 - s) * tissue_value;
      if (!close(stored[k], expected))
        throw InputError(keyOf(f, keys[k]) + ": tet " + std::to_string(t) + ": " + str(stored[k]) +
                         ", expected " + str(expected) +
                         " (the material model's value at skin fraction " + str(s) + ")");
    }
    const Vec3 E = m.young.row(t).transpose(), nu = m.poisson.row(t).transpose();
    const auto values = [&] {  // for messages only
      return "E = (" + str(E[0]) + ", " + str(E[1]) + ", " + str(E[2]) + ") Pa, nu = (" +
             str(nu[0]) + ", " + str(nu[1]) + ", " + str(nu[2]) + ")";
    };
    if (!(E.array() > 0).all())
      throw InputError(keyOf(f, "young") + ": tet " + std::to_string(t) + ": " + values() +
                       ", expected moduli > 0");
    Mat3 compliance;  // orthotropic normal block, scaled by E3 (a unit-free test)
    compliance << 1 / E[0], -nu[0] / E[0], -nu[1] / E[0],  //
        -nu[0] / E[0], 1 / E[1], -nu[2] / E[1],            //
        -nu[1] / E[0], -nu[2] / E[1], 1 / E[2];
    compliance *= E[2];
    // (LLT does not fail on NaN: finiteness is checked first.)
    if (!(compliance.allFinite() && Eigen::LLT<Mat3>(compliance).info() == Eigen::Success))
      throw InputError(keyOf(f, "poisson") + " (with key 'young'): tet " + std::to_string(t) +
                       ": " + values() + ", expected a positive-definite compliance");
  }

  const RowMatX frames = f.matrix("frame", T, 9);
  m.frame.resize(size_t(T));
  for (long t = 0; t < T; ++t) {
    const Mat3 R =
        Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(frames.row(t).data());
    if (!((R.transpose() * R - Mat3::Identity()).cwiseAbs().maxCoeff() <= 1e-9 &&
          std::abs(R.determinant() - 1) <= 1e-9))
      throw InputError(keyOf(f, "frame") + ": tet " + std::to_string(t) +
                       ": expected a rotation (orthonormal columns, determinant +1)");
    m.frame[size_t(t)] = R;
  }
}

}  // namespace flsh
