// Two-level build of the volumetric body with the on-disk cache (volumetric_data.h).
#include "flsh/volume/volumetric_data.h"

#include <Eigen/Geometry>
#include <chrono>

#include "core/seconds_since.h"
#include "flsh/body/body_forward.h"
#include "flsh/core/error.h"
#include "flsh/core/sha256.h"
#include "volumetric_cache.h"

namespace flsh {

namespace {

using Clock = std::chrono::steady_clock;
using detail::secondsSince;

void hashBody(Sha256& h, const BodyModel& body) {
  h.updateMatrix("v_template", body.v_template);
  h.updateMatrix("shapedirs", body.shapedirs);
  h.updateMatrix("posedirs", body.posedirs);
  h.updateMatrix("J_regressor", MatX(body.J_regressor));
  h.updateMatrix("weights", body.weights);
  h.updateMatrix("faces", body.faces);
  h.updateField("parents", body.parents.data(), body.parents.size() * sizeof(int));
}

/// The tet mesh follows the shape through the harmonically extended shape directions; a shape
/// far out (e.g. β_belly = −5 on the synthetic body) can fold a tet over: refused here, naming β,
/// rather than later by the element that meets it.
void checkShapedTets(const TetMesh& mesh, const MatX3& nodes, const VecX& betas) {
  int inverted = 0, first = -1;
  for (int e = 0; e < mesh.tets.rows(); ++e) {
    const Vec3 x0 = nodes.row(mesh.tets(e, 0)).transpose();
    const Vec3 a = nodes.row(mesh.tets(e, 1)).transpose() - x0;
    const Vec3 b = nodes.row(mesh.tets(e, 2)).transpose() - x0;
    const Vec3 c = nodes.row(mesh.tets(e, 3)).transpose() - x0;
    if (!(a.cross(b).dot(c) > 0.0)) {
      if (first < 0) first = e;
      ++inverted;
    }
  }
  if (inverted == 0) return;
  std::string beta_text;
  for (Eigen::Index k = 0; k < betas.size(); ++k)
    if (betas[k] != 0.0)
      beta_text += (beta_text.empty() ? "" : ", ") + std::string("β") + std::to_string(k) + " = " +
                   std::to_string(betas[k]);
  throw InputError("betas: the shape (" + (beta_text.empty() ? "all zero" : beta_text) +
                   ") folds " + std::to_string(inverted) + " of the tet mesh's " +
                   std::to_string(mesh.tets.rows()) + " tets inside out (first: tet " +
                   std::to_string(first) +
                   "): the soft-tissue models cannot use it; use a shape closer to the mean "
                   "(smaller |β|)");
}

std::string dataKey(const std::string& template_key, const VecX& betas,
                    const MaterialModel& materials) {
  Sha256 h;
  h.update("flsh volumetric data");
  const int version = AvatarCache::kFormatVersion;
  h.updateField("version", &version, sizeof(version));
  // Revision of the shape-level rules (2: bones with too few deep nodes get anchor nodes; 3:
  // tissue thickness and soft-tissue stiffness depend on the body region), so that data cached
  // under an older rule is rebuilt rather than reused.
  const int rules = 3;
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

  if (cache) {
    const auto t0 = Clock::now();
    std::string problem;
    if (auto f = cache->load(out->key, &problem)) {
      try {
        readTemplateCacheArrays(*f, body, *out);
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
    cache->store(out->key, templateCacheArrays(*out));
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
    throw InputError("betas: expected at most " + std::to_string(K) + " finite values, got " +
                     std::to_string(betas_in.size()));
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
  d.key = dataKey(d.templ->key, betas, d.material_model);
  d.rest_nodes = shapedNodes(mesh, d.templ->fields, betas);
  checkShapedTets(mesh, d.rest_nodes, betas);
  d.rest_joints = body.J_regressor * d.rest_nodes.topRows(body.numVertices());

  bool loaded = false;
  if (cache) {
    const auto t0 = Clock::now();
    std::string problem;
    if (auto f = cache->load(d.key, &problem)) {
      try {
        readDataCacheArrays(*f, betas, d);
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
    d.materials = computeTetMaterials(mesh, d.rest_nodes, d.templ->fields.weights, d.rest_joints,
                                      body.parents, d.material_model, betas);
    r.seconds_materials = secondsSince(t0);
    if (cache) {
      t0 = Clock::now();
      cache->store(d.key, dataCacheArrays(d));
      r.seconds_cache_store += secondsSince(t0);
    }
  }
  r.seconds_total = secondsSince(start);
  return d;
}

}  // namespace flsh
