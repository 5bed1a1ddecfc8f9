// Two-level build of the volumetric body with the on-disk cache (volumetric_data.h).
#include "flsh/volume/volumetric_data.h"

#include <chrono>

#include "flsh/body/body_forward.h"
#include "flsh/core/error.h"
#include "flsh/core/sha256.h"

namespace flsh {

namespace {

using Clock = std::chrono::steady_clock;
double secondsSince(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
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

MatX4i readTets(const io::NpzFile& f, long nodes) {
  const std::vector<int64_t> v = f.integers("tets", {-1, 4});
  MatX4i tets(long(v.size() / 4), 4);
  for (size_t i = 0; i < v.size(); ++i) {
    if (v[i] < 0 || v[i] >= nodes)
      throw InputError(f.path() + ": key 'tets': index " + std::to_string(v[i]) +
                       " outside [0, " + std::to_string(nodes) + ")");
    tets(long(i / 4), long(i % 4)) = int(v[i]);
  }
  return tets;
}

// A float64 array of the cache as a column-major matrix, in one copy (NpzFile::matrix would make
// three: the big pose blend shapes dominate the time to load a cached avatar).
MatX readMatrix(const io::NpzFile& f, const std::string& key, long rows, long cols) {
  const io::NpyArray& a = f.raw(key);
  if (a.dtype != "<f8" || a.shape.size() != 2 || a.shape[0] != rows || a.shape[1] != cols)
    throw InputError(f.path() + ": key '" + key + "': expected float64 (" +
                     std::to_string(rows) + ", " + std::to_string(cols) + ")");
  MatX m = Eigen::Map<const RowMatX>(reinterpret_cast<const double*>(a.bytes.data()), rows, cols);
  if (!m.allFinite()) throw InputError(f.path() + ": key '" + key + "': NaN or Inf");
  return m;
}

void hashBody(Sha256& h, const BodyModel& body) {
  h.updateMatrix("v_template", body.v_template);
  h.updateMatrix("shapedirs", body.shapedirs);
  h.updateMatrix("posedirs", body.posedirs);
  h.updateMatrix("J_regressor", MatX(body.J_regressor));
  h.updateMatrix("weights", body.weights);
  h.updateMatrix("faces", body.faces);
  h.updateField("parents", body.parents.data(), body.parents.size() * sizeof(int));
}

std::string dataKey(const std::string& template_key, const VecX& betas,
                    const MaterialModel& materials) {
  Sha256 h;
  h.update("flsh volumetric data");
  const int version = AvatarCache::kFormatVersion;
  h.updateField("version", &version, sizeof(version));
  // Revision of the shape-level rules (2: bones with too few deep nodes get anchor nodes),
  // so that data cached under an older rule is rebuilt rather than reused.
  const int rules = 2;
  h.updateField("shape rules", &rules, sizeof(rules));
  h.update(template_key);
  h.updateMatrix("betas", betas);
  const std::string text = materials.canonicalText();
  h.updateField("materials", text.data(), text.size());
  return h.hexDigest();
}

}  // namespace

int VolumetricData::numBoneNodes() const { return int((bone_of_node.array() >= 0).count()); }

double VolumetricData::totalMass() const {
  if (!templ) return 0.0;
  TetMesh shaped = templ->mesh;
  shaped.nodes = rest_nodes;
  return tetVolumes(shaped).dot(materials.density);
}

std::string volumetricTemplateKey(const BodyModel& body, const TetMeshOptions& options) {
  Sha256 h;
  h.update("flsh volumetric template");
  const int version = AvatarCache::kFormatVersion;
  h.updateField("version", &version, sizeof(version));
  hashBody(h, body);
  h.updateField("resolution", &options.resolution, sizeof(options.resolution));
  h.updateField("seed", &options.seed, sizeof(options.seed));
  const char improve = options.improve_quality ? 1 : 0;
  h.updateField("improve_quality", &improve, 1);
  return h.hexDigest();
}

std::shared_ptr<const VolumetricTemplate> buildVolumetricTemplate(const BodyModel& body,
                                                                  const TetMeshOptions& options,
                                                                  const AvatarCache* cache,
                                                                  VolumetricBuildReport* report) {
  VolumetricBuildReport local;
  VolumetricBuildReport& r = report ? *report : local;
  auto out = std::make_shared<VolumetricTemplate>();
  out->key = volumetricTemplateKey(body, options);
  const int V = body.numVertices();

  if (cache) {
    const auto t0 = Clock::now();
    std::string problem;
    if (auto f = cache->load(out->key, &problem)) {
      try {
        out->mesh.nodes = f->matrix("nodes", -1, 3);
        const long N = out->mesh.nodes.rows();
        out->mesh.tets = readTets(*f, N);
        out->mesh.num_surface_nodes = V;
        out->fields.weights = readMatrix(*f, "weights", N, body.numJoints());
        out->fields.shapedirs = readMatrix(*f, "shapedirs", 3 * N, body.numBetas());
        out->fields.posedirs = readMatrix(*f, "posedirs", 3 * N, body.posedirs.cols());
        const VecX q = f->vector("quality", 5);
        out->quality = {q(0), q(1), q(2), q(3), q(4)};
        r.template_from_cache = true;
        r.seconds_cache_load += secondsSince(t0);
        return out;
      } catch (const Error& e) {
        problem = std::string("avatar cache file ") + cache->pathFor(out->key) +
                  " does not hold a volumetric template (" + e.what() + "); rebuilding it";
      }
    }
    if (!problem.empty()) r.warnings += problem + "\n";
    r.seconds_cache_load += secondsSince(t0);
  }

  auto t0 = Clock::now();
  out->mesh = tetrahedralizeSurface(body.v_template, body.faces, options, &r.meshing);
  r.seconds_meshing = secondsSince(t0);
  t0 = Clock::now();
  const HarmonicExtension harmonic(out->mesh);
  out->fields = extendBodyFields(out->mesh, body, harmonic);
  r.seconds_harmonic = secondsSince(t0);
  t0 = Clock::now();
  out->quality = tetMeshQuality(out->mesh);
  r.seconds_quality = secondsSince(t0);

  if (cache) {
    t0 = Clock::now();
    io::NpzWriter w;
    w.add("nodes", out->mesh.nodes);
    addIntegers(w, "tets", out->mesh.tets);
    w.add("weights", RowMatX(out->fields.weights));
    w.add("shapedirs", RowMatX(out->fields.shapedirs));
    w.add("posedirs", RowMatX(out->fields.posedirs));
    const TetMeshQuality& q = out->quality;
    w.add("quality", VecX((VecX(5) << q.min_dihedral_deg, q.max_dihedral_deg,
                           q.max_radius_edge_ratio, q.mean_radius_edge_ratio, q.min_volume)
                              .finished()));
    cache->store(out->key, w);
    r.seconds_cache_store += secondsSince(t0);
  }
  return out;
}

VolumetricData buildVolumetricData(const BodyModel& body, const VecX& betas_in,
                                   const VolumetricSettings& settings,
                                   VolumetricBuildReport* report) {
  VolumetricBuildReport local;
  VolumetricBuildReport& r = report ? *report : local;
  const auto start = Clock::now();
  const int K = body.numBetas();
  if (betas_in.size() > K || !betas_in.allFinite())
    throw InputError("betas: expected at most " + std::to_string(K) +
                     " finite values, got " + std::to_string(betas_in.size()));
  VecX betas = VecX::Zero(K);
  betas.head(betas_in.size()) = betas_in;

  std::unique_ptr<AvatarCache> cache;
  if (settings.use_cache) cache = std::make_unique<AvatarCache>(settings.cache_dir);

  VolumetricData d;
  d.material_model = settings.material_file.empty()
                         ? MaterialModel::defaults(K)
                         : MaterialModel::load(settings.material_file, K);
  d.templ = buildVolumetricTemplate(body, settings.tet_mesh, cache.get(), &r);
  const TetMesh& mesh = d.templ->mesh;
  const long N = mesh.numNodes();
  d.key = dataKey(d.templ->key, betas, d.material_model);
  d.rest_nodes = shapedNodes(mesh, d.templ->fields, betas);
  d.rest_joints = body.J_regressor * d.rest_nodes.topRows(body.numVertices());

  bool loaded = false;
  if (cache) {
    const auto t0 = Clock::now();
    std::string problem;
    if (auto f = cache->load(d.key, &problem)) {
      try {
        const long T = mesh.numTets();
        const std::vector<int64_t> bones = f->integers("bone_of_node", {N});
        d.bone_of_node.resize(N);
        for (long i = 0; i < N; ++i) d.bone_of_node(i) = int(bones[size_t(i)]);
        d.tissue_thickness = f->vector("tissue_thickness", body.numVertices());
        TetMaterials& m = d.materials;
        m.density = f->vector("density", T);
        m.young = f->matrix("young", T, 3);
        m.poisson = f->matrix("poisson", T, 3);
        m.shear = f->matrix("shear", T, 3);
        m.fung = f->vector("fung", T);
        m.skin_fraction = f->vector("skin_fraction", T);
        const RowMatX frames = f->matrix("frame", T, 9);
        m.frame.resize(size_t(T));
        for (long t = 0; t < T; ++t)
          m.frame[size_t(t)] = Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(
              frames.row(t).data());
        const std::vector<int64_t> layer = f->integers("layer", {T});
        m.layer.resize(T);
        for (long t = 0; t < T; ++t) m.layer(t) = int(layer[size_t(t)]);
        loaded = true;
        r.data_from_cache = true;
      } catch (const Error& e) {
        problem = std::string("avatar cache file ") + cache->pathFor(d.key) +
                  " does not hold volumetric data (" + e.what() + "); rebuilding it";
      }
    }
    if (!problem.empty()) r.warnings += problem + "\n";
    r.seconds_cache_load += secondsSince(t0);
  }

  if (!loaded) {
    auto t0 = Clock::now();
    const MatX surface_weights = d.templ->fields.weights.topRows(body.numVertices());
    d.tissue_thickness =
        surfaceTissueThickness(d.rest_nodes.topRows(body.numVertices()), surface_weights,
                               d.rest_joints, body.parents, d.material_model, betas);
    d.bone_of_node = selectBoneNodes(mesh, d.rest_nodes, d.templ->fields.weights, d.rest_joints,
                                     body.parents, d.tissue_thickness);
    r.seconds_bone_nodes = secondsSince(t0);
    t0 = Clock::now();
    d.materials = computeTetMaterials(mesh, d.rest_nodes, d.templ->fields.weights,
                                      d.rest_joints, body.parents, d.material_model, betas);
    r.seconds_materials = secondsSince(t0);
    if (cache) {
      t0 = Clock::now();
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
      cache->store(d.key, w);
      r.seconds_cache_store += secondsSince(t0);
    }
  }
  r.seconds_total = secondsSince(start);
  return d;
}

}  // namespace flsh
