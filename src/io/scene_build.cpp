#include "flsh/io/scene_build.h"

#include <Eigen/Geometry>
#include <cctype>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <map>

#include "flsh/body/body_forward.h"
#include "flsh/body/motion_frame.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"

namespace flsh::io {

namespace {

/// What flsh made of a model file of another SMPL family (docs/formats.md).
std::string familyNote(const BodyModel& body) {
  return body.family == "SMPL-H" ? "its finger joints merged into SMPL's hand joints (hands held "
                                   "in the model's rest pose)"
                                 : "read as SMPL";
}

/// The avatar's surface at t = 0 (the motion's first frame, else the rest pose), as
/// Simulable::initialize() places it.
MatX3 startVertices(const SceneAvatar& run) {
  const VecX& betas = run.avatar->betas();
  if (!run.motion) return poseBody(*run.body, betas, VecX::Zero(kSmplPoseSize)).vertices;
  return poseBody(*run.body, betas, run.motion->poses.row(0).transpose(),
                  run.motion->trans.row(0).transpose())
      .vertices;
}

std::string format(const char* pattern, double value) {
  char text[64];
  std::snprintf(text, sizeof(text), pattern, value);
  return text;
}

/// A report's warnings (lines ending in newlines) without the last newline.
std::string trimmed(std::string text) {
  while (!text.empty() && text.back() == '\n') text.pop_back();
  return text;
}

/// The model file of an avatar: its "model" path with kGenderPlaceholder filled in by the
/// motion's gender ("neutral" without one), checked to be a file.
std::string modelPathFor(const AvatarSpec& spec, const Motion* motion, const std::string& where) {
  const size_t at = spec.model.find(kGenderPlaceholder);
  if (at == std::string::npos) return spec.model;
  std::string gender = motion ? motion->gender : "";
  for (char& c : gender) c = char(std::tolower(static_cast<unsigned char>(c)));
  if (gender.empty()) gender = "neutral";
  const std::string origin =
      motion && !motion->gender.empty() ? "the gender of " + motion->source : "no gender given";
  if (gender != "female" && gender != "male" && gender != "neutral")
    throw InputError(where + ".model: " + spec.model + ": " + origin + " is \"" + gender +
                     "\", expected \"female\", \"male\" or \"neutral\"");
  std::string path = spec.model;
  path.replace(at, std::string(kGenderPlaceholder).size(), gender);
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec))
    throw FileError(where + ".model: body model file not found: " + path + " (" + origin + ": \"" +
                    gender + "\")");
  return path;
}

/// "500 tets, held-out error 0.84 %" or "off (exact)" for one cubature of the reduced data;
/// with `rigid_error` ≥ 0 (the inertial one's) also ", rigid motions within 1 %".
std::string cubatureSummary(const Cubature& cubature, double test_error, bool enabled,
                            double rigid_error = -1.0) {
  if (!enabled) return "off (exact)";
  char text[128];
  int length = std::snprintf(text, sizeof(text), "%d tets, held-out error %.2f %%",
                             int(cubature.elements.size()), 100.0 * test_error);
  if (rigid_error >= 0)
    std::snprintf(text + length, sizeof(text) - size_t(length), ", rigid motions within %d %%",
                  int(std::ceil(100.0 * rigid_error)));
  return text;
}

/// A ROM avatar's reduced data in one line (basis, cubatures, cache and build time), after its
/// warnings.
void reportReducedData(const std::string& name, const SoftAvatar& avatar, bool use_cache,
                       const SceneBuildLog& log) {
  const ReducedData& data = avatar.reducedData();
  const ReducedBuildReport& report = avatar.reducedBuildReport();
  if (!report.warnings.empty()) log("warning: avatar '" + name + "': " + trimmed(report.warnings));
  if (!data.basis_converged)
    log("warning: avatar '" + name +
        "': the bounded biharmonic solve of some handle did not "
        "converge (max bound violation " +
        format("%.2g", data.basis_max_bound_violation) + ")");
  const std::string cache = !use_cache ? format("off, built in %.1f s", report.seconds_total)
                            : report.from_cache
                                ? format("hit (%.2f s)", report.seconds_total)
                                : format("miss (built and stored in %.1f s)", report.seconds_total);
  // "72 modes", "87 handles, basis N nonzeros" or both, by the basis kind.
  std::string basis;
  if (data.numModes() > 0) basis = std::to_string(data.numModes()) + " modes";
  if (data.basis_kind != ReducedBasisKind::Modes)
    basis += (basis.empty() ? "" : ", ") + std::to_string(data.numHandles()) + " handles, basis " +
             std::to_string(long(data.basis.nonZeros())) + " nonzeros";
  log("avatar '" + name + "' (rom): " + basis + "; elastic cubature " +
      cubatureSummary(data.elastic, data.elastic_test_error, avatar.elasticCubatureEnabled()) +
      "; inertial cubature " +
      cubatureSummary(data.inertial, data.inertial_test_error, avatar.inertialCubatureEnabled(),
                      data.inertial_rigid_error) +
      "; reduced data cache: " + cache);
}

}  // namespace

std::vector<SceneAvatar> buildSceneAvatars(const SceneSpec& scene, const SceneBuildLog& log_line) {
  const SceneBuildLog log = log_line ? log_line : [](const std::string&) {};
  std::map<std::string, std::shared_ptr<const BodyModel>> bodies;  // shared per model
  std::vector<SceneAvatar> runs(scene.avatars.size());
  for (size_t i = 0; i < scene.avatars.size(); ++i) {
    const AvatarSpec& spec = scene.avatars[i];
    SceneAvatar& run = runs[i];
    run.spec = &spec;
    run.where = scene.source + ": avatars[" + std::to_string(i) + "]";

    std::shared_ptr<Motion> motion;
    if (!spec.motion.empty()) {
      const std::string prefix = "builtin:";
      Motion raw =
          spec.motion.rfind(prefix, 0) == 0
              ? makeBuiltinMotion(spec.motion.substr(prefix.size()),
                                  spec.motion_seconds > 0 ? spec.motion_seconds : scene.duration)
              : loadMotion(spec.motion, spec.up);
      checkMotionValues(raw,
                        run.where + ".motion: " + (raw.source.empty() ? spec.motion : raw.source));
      motion = std::make_shared<Motion>(placedMotion(std::move(raw), spec.yaw, spec.offset));
      checkMotionValues(*motion,
                        run.where + ".offset: the motion placed by offset and yaw_degrees");
    }
    run.motion = motion;

    const std::string model = modelPathFor(spec, motion.get(), run.where);
    const std::string key =
        model == "synthetic" ? "synthetic:" + std::to_string(spec.synthetic_vertices) : model;
    auto& body = bodies[key];
    if (!body) {
      if (model == "synthetic") {
        log("generating the synthetic body (" + std::to_string(spec.synthetic_vertices) +
            " vertices)...");
        SyntheticBodyOptions options;
        options.vertices = spec.synthetic_vertices;
        body = sharedSyntheticBody(options);
      } else {
        body = std::make_shared<const BodyModel>(loadBodyModel(model));
        if (body->family != "SMPL")
          log("avatar '" + spec.name + "': " + model + ": " + body->family + " body model, " +
              familyNote(*body));
      }
      if (body->numJoints() != kNumJoints)
        throw InputError(run.where + ".model: " + model + " has " +
                         std::to_string(body->numJoints()) + " joints, expected 24 (SMPL)");
    }
    run.body = body;

    VecX betas = spec.betas;
    if (betas.size() > body->numBetas())
      throw InputError(run.where + ".betas: " + std::to_string(betas.size()) +
                       " values, but the model has " + std::to_string(body->numBetas()) +
                       " shape components");
    checkShapeCoefficients(betas, run.where + ".betas");
    if (betas.size() == 0 && motion && motion->betas.size() > 0) {
      std::string warning;
      betas = fitBetas(motion->betas, *body, motion->source, &warning);
      if (!warning.empty()) log("warning: " + warning);
      checkShapeCoefficients(betas, run.where + ".motion: " + motion->source + ": betas");
    }
    if (betas.size() == 0) betas = VecX::Zero(body->numBetas());
    SoftAvatarSettings settings;
    run.rom = spec.simulation == "rom";
    run.soft = spec.simulation == "fem" || run.rom;
    if (run.soft) {
      settings.volumetric.tet_mesh.resolution = spec.resolution;
      settings.volumetric.material_file = spec.material_file;
      settings.volumetric.cache_dir = scene.cache_dir;
      settings.volumetric.use_cache = scene.use_cache;
    }
    if (run.rom)
      setReducedSettings(settings.reduced, spec.handles, spec.elastic_cubature,
                         spec.inertial_cubature, spec.surface_partition_of_unity, spec.basis,
                         spec.vibration_modes, spec.modal_columns);
    run.avatar = std::make_shared<SoftAvatar>(body, betas, settings);
    if (run.soft) {
      log(std::string("building the volumetric body") + (run.rom ? " and the reduced basis" : "") +
          " of avatar '" + spec.name + "'...");
      run.avatar->enableSoftTissue();
    }
    if (run.rom) enableReducedModel(*run.avatar, spec.elastic_cubature, spec.inertial_cubature);
    try {
      run.avatar->initVolumetricData();
    } catch (const InputError& e) {
      // E.g. more handles than the body has soft-tissue surface nodes: name the avatar.
      throw InputError(run.where + " ('" + spec.name + "', \"" + spec.simulation +
                       "\"): " + e.what());
    }
    if (run.soft) {
      const VolumetricBuildReport& report = run.avatar->volumetricBuildReport();
      const VolumetricData& data = run.avatar->volumetricData();
      if (!report.warnings.empty())
        log("warning: avatar '" + spec.name + "': " + trimmed(report.warnings));
      log("avatar '" + spec.name + "': " + std::to_string(data.numNodes()) + " nodes (" +
          std::to_string(data.numNodes() - data.numBoneNodes()) + " soft tissue), " +
          std::to_string(data.numTets()) + " tets; cache: " +
          (!scene.use_cache             ? "off"
           : report.data_from_cache     ? "hit"
           : report.template_from_cache ? "template hit, shape built"
                                        : "miss (built and stored)"));
    }
    if (run.rom) reportReducedData(spec.name, *run.avatar, scene.use_cache, log);
    SimulableOptions options = spec.options;
    options.time_step = scene.time_step;
    run.simulable = std::make_shared<Simulable>(run.avatar, run.motion, options);
  }
  return runs;
}

SceneOptions sceneOptionsOf(const SceneSpec& scene) {
  SceneOptions options;
  options.newton = scene.newton;
  options.soft_tissue_newton.max_iterations = scene.newton.max_iterations;
  options.soft_tissue_newton.step_tolerance = scene.newton.step_tolerance;
  if (scene.soft_tissue_gradient_tolerance > 0)
    options.soft_tissue_newton.gradient_tolerance = scene.soft_tissue_gradient_tolerance;
  options.reduced_newton.max_iterations = scene.reduced_iteration_budget > 0
                                              ? scene.reduced_iteration_budget
                                              : scene.newton.max_iterations;
  options.reduced_newton.step_tolerance = scene.newton.step_tolerance;
  if (scene.reduced_gradient_tolerance > 0)
    options.reduced_newton.gradient_tolerance = scene.reduced_gradient_tolerance;
  options.soft_tissue_newton.lagged = scene.soft_tissue_lagged;
  options.reduced_newton.lagged = scene.reduced_lagged;
  options.soft_tissue_newton.coarse_presolve = scene.soft_tissue_presolve;
  options.reduced_newton.coarse_presolve = scene.reduced_presolve;
  options.avatar_contact = scene.avatar_contact;
  return options;
}

void setReducedSettings(ReducedSettings& reduced, int handles, int elastic, int inertial,
                        bool partition_of_unity, ReducedBasisKind basis, int vibration_modes,
                        int modal_columns) {
  reduced.num_handles = handles;
  reduced.basis_kind = basis;
  reduced.modes.vibration_modes = vibration_modes;
  reduced.modes.columns = modal_columns;
  if (elastic > 0) reduced.elastic_cubature_points = elastic;
  if (inertial > 0) reduced.inertial_cubature_points = inertial;
  reduced.surface_partition_of_unity = partition_of_unity;
}

void enableReducedModel(SoftAvatar& avatar, int elastic, int inertial) {
  avatar.enableSoftTissue();
  avatar.enableReducedModel();
  avatar.enableElasticCubature(elastic > 0);
  avatar.enableInertialCubature(inertial > 0);
}

VecX fitBetas(const VecX& betas, const BodyModel& model, const std::string& origin,
              std::string* warning) {
  const long K = model.numBetas();
  if (betas.size() <= K) return betas;
  if (warning && betas.tail(betas.size() - K).cwiseAbs().maxCoeff() > 0.0)
    *warning = origin + " has " + std::to_string(betas.size()) + " shape coefficients, the model " +
               std::to_string(K) + "; using the first " + std::to_string(K);
  return betas.head(K);
}

std::vector<Collider> sceneColliders(const SceneSpec& scene,
                                     const std::vector<SceneAvatar>& avatars,
                                     const SceneBuildLog& log) {
  std::vector<Collider> colliders = scene.colliders;
  const GroundSpec& ground = scene.ground;
  if (!ground.enabled) return colliders;
  double height = ground.height;
  if (ground.automatic) {
    height = std::numeric_limits<double>::infinity();
    std::string lowest;
    for (const SceneAvatar& run : avatars) {
      const double y = run.motion ? lowestPointHeight(*run.body, run.avatar->betas(), *run.motion,
                                                      ground.over_seconds)
                                  : startVertices(run).col(1).minCoeff();
      if (y < height) {
        height = y;
        lowest = run.spec->name;
      }
    }
    if (log)
      log("ground: auto, plane at y = " + format("%.4g", height) +
          " m, under the lowest point of avatar '" + lowest + "' over its first " +
          format("%g", ground.over_seconds) + " s");
  }
  Collider plane = Collider::plane(Vec3(0.0, height, 0.0), Vec3::UnitY());
  plane.name = "ground";
  colliders.push_back(plane);
  return colliders;
}

std::vector<std::string> startWarnings(const std::vector<SceneAvatar>& avatars,
                                       const std::vector<Collider>& colliders) {
  std::vector<std::string> warnings;
  for (const SceneAvatar& run : avatars) {
    const MatX3 nodes = startVertices(run);
    double nearest = std::numeric_limits<double>::infinity();  // floors only
    std::string nearest_name;
    for (const Collider& collider : colliders) {
      if (collider.shape() != ColliderShape::Plane) continue;
      double lowest = std::numeric_limits<double>::infinity();
      for (Eigen::Index i = 0; i < nodes.rows(); ++i)
        lowest = std::min(lowest, collider.signedDistance(nodes.row(i).transpose(), 0.0));
      if (lowest < -kStartDepthWarning)
        warnings.push_back("avatar '" + run.spec->name + "' starts " + format("%.3f", -lowest) +
                           " m deep in plane '" + collider.name + "'");
      if (collider.p1().y() > 0.7 && std::abs(lowest) < std::abs(nearest)) {
        nearest = lowest;
        nearest_name = collider.name;
      }
    }
    if (std::isfinite(nearest) && nearest > kStartHeightWarning)
      warnings.push_back("avatar '" + run.spec->name + "' starts " + format("%.3f", nearest) +
                         " m above the nearest floor ('" + nearest_name +
                         "'), the lowest point of its body at t = 0; \"ground\": \"auto\" puts "
                         "the ground under it" +
                         (run.motion && run.motion->up == "y" && run.spec->up.empty()
                              ? ""
                              : ", and \"up\" says which way the clip was recorded"));
  }
  return warnings;
}

void checkMotionValues(const Motion& motion, const std::string& what) {
  for (Eigen::Index t = 0; t < motion.poses.rows(); ++t)
    checkPoseAngles(motion.poses.row(t).transpose(), what + ": poses: frame " + std::to_string(t));
  for (Eigen::Index t = 0; t < motion.trans.rows(); ++t)
    for (int c = 0; c < motion.trans.cols(); ++c)
      if (!(std::abs(motion.trans(t, c)) <= kMaxStatePosition))
        throw InputError(
            what + ": trans: frame " + std::to_string(t) + " has " +
            format("%.6g", motion.trans(t, c)) + " m, expected a finite value within [-" +
            format("%.6g", kMaxStatePosition) + ", " + format("%.6g", kMaxStatePosition) + "] m");
}

}  // namespace flsh::io
