// The `flsh` command-line program.
//
//   flsh synth-body --out BODY.npz [--vertices N] [--height M]
//   flsh motion --name walk --out MOTION.npz [--seconds S] [--fps F]
//   flsh pose --model BODY.npz --motion MOTION.npz --out OUT.npz [--betas b0,b1,…]
//   flsh demo [--out DIR] [--vertices N] [--motion NAME]
//   flsh simulate [SCENE.json] [--out DIR] [--duration S] [--time-step H] [--cache DIR]
//                 [--no-cache]
//   flsh avatar --model BODY.npz [--betas b0,b1,…] [--soft fem|rom] [--cache DIR]
//               [--resolution R] [--materials FILE] [--no-cache]
//               [--handles H] [--elastic-cubature N] [--inertial-cubature N]
//
// Every command prints a one-line summary on success, and on bad input exits non-zero with a
// message naming the input, leaving no partial output file (all writes are atomic).
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <map>
#include <memory>
#include <sstream>

#include "flsh/body/body_forward.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "flsh/io/atomic_file.h"
#include "flsh/io/gltf.h"
#include "flsh/io/mesh_io.h"
#include "flsh/io/motion.h"
#include "flsh/io/npz.h"
#include "flsh/io/scene_file.h"
#include "flsh/render/render.h"
#include "flsh/sim/simulable.h"
#include "flsh/solve/scene.h"
#include "flsh/volume/soft_avatar.h"

namespace {

using namespace flsh;
using Clock = std::chrono::steady_clock;

double secondsSince(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

/// Writes frames[k] as DIR/frame_%04d.ply and removes higher-numbered frames left by an
/// earlier, longer run in the same folder (they would mix with this one).
void writeFrameMeshes(const std::filesystem::path& dir, const std::vector<MatX3>& frames,
                      const MatX3i& faces) {
  namespace fs = std::filesystem;
  io::ensureDirectory(dir.string());
  auto name = [](size_t k) {
    char buffer[64];
    std::snprintf(buffer, sizeof(buffer), "frame_%04zu.ply", k);
    return std::string(buffer);
  };
  for (size_t k = 0; k < frames.size(); ++k) io::writePly((dir / name(k)).string(), frames[k], faces);
  for (size_t k = frames.size();; ++k) {
    std::error_code ec;
    if (!fs::remove(dir / name(k), ec)) break;
  }
}

/// Parses "b0,b1,…" into a vector; throws InputError naming the option.
VecX parseBetas(const std::string& text) {
  std::vector<double> values;
  std::stringstream in(text);
  std::string item;
  while (std::getline(in, item, ',')) {
    try {
      size_t used = 0;
      values.push_back(std::stod(item, &used));
      if (used != item.size()) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      throw InputError("--betas: '" + item + "' is not a number (expected b0,b1,… )");
    }
  }
  if (values.empty()) throw InputError("--betas: expected comma-separated numbers, got '" + text + "'");
  return Eigen::Map<VecX>(values.data(), long(values.size()));
}

/// Fits `betas` to the model's K shape components: shorter is zero padded by the forward pass;
/// longer is cut to K, with a warning if a dropped coefficient is nonzero.
VecX fitBetas(const VecX& betas, const BodyModel& model, const std::string& origin) {
  const long K = model.numBetas();
  if (betas.size() <= K) return betas;
  if (betas.tail(betas.size() - K).cwiseAbs().maxCoeff() > 0.0)
    std::cerr << "flsh: warning: " << origin << " has " << betas.size()
              << " shape coefficients, the model " << K << "; using the first " << K << "\n";
  return betas.head(K);
}

/// Vertices (T × 3V) and joints (T × 72) written as float64 arrays (T, V, 3) and (T, 24, 3).
void writePosedNpz(const std::string& path, const PosedBatch& batch, int V, const VecX& betas,
                   double fps) {
  io::NpzWriter out;
  const long T = batch.vertices.rows();
  out.add("vertices", batch.vertices.data(), {T, V, 3});
  out.add("joints", batch.joints.data(), {T, kNumJoints, 3});
  out.add("betas", Eigen::Ref<const VecX>(betas));
  out.addScalar("fps", fps);
  out.save(path);
}

int cmdSynthBody(const std::string& out, int vertices, double height) {
  const auto t0 = Clock::now();
  SyntheticBodyOptions options;
  options.vertices = vertices;
  options.height = height;
  const BodyModel body = makeSyntheticBody(options);
  saveBodyModel(body, out);
  std::printf("synth-body: wrote %s (%d vertices, %d faces, %d joints, %d shape directions) in %.2f s\n",
              out.c_str(), body.numVertices(), body.numFaces(), body.numJoints(), body.numBetas(),
              secondsSince(t0));
  return 0;
}

int cmdMotion(const std::string& name, const std::string& out, double seconds, double fps) {
  const Motion motion = makeBuiltinMotion(name, seconds, fps);
  saveMotion(motion, out);
  std::printf("motion: wrote %s (%s, %d frames at %g fps)\n", out.c_str(), name.c_str(),
              motion.numFrames(), motion.fps);
  return 0;
}

int cmdPose(const std::string& model_path, const std::string& motion_spec, const std::string& out,
            const std::string& betas_text) {
  const auto t0 = Clock::now();
  const BodyModel model = loadBodyModel(model_path);
  const Motion motion = loadOrMakeMotion(motion_spec);
  const VecX betas = betas_text.empty() ? fitBetas(motion.betas, model, motion.source)
                                        : fitBetas(parseBetas(betas_text), model, "--betas");
  if (betas.size() > 0 && !betas.allFinite()) throw InputError(motion.source + ": betas contain NaN or Inf");
  const PosedBatch batch = poseBodyBatch(model, betas, motion.poses, motion.trans);
  writePosedNpz(out, batch, model.numVertices(), betas, motion.fps);
  std::printf("pose: wrote %s (%d frames × %d vertices, %.1f fps motion) in %.2f s\n", out.c_str(),
              motion.numFrames(), model.numVertices(), motion.fps, secondsSince(t0));
  return 0;
}

struct AvatarArgs {
  std::string model, betas, soft = "none", cache, materials;
  double resolution = 1.0;
  bool no_cache = false;
  // --soft rom only (as the scene keys handles / elastic_cubature / inertial_cubature):
  int handles = ReducedSettings().num_handles;
  int elastic_cubature = ReducedSettings().elastic_cubature_points;   ///< 0 = off
  int inertial_cubature = ReducedSettings().inertial_cubature_points; ///< 0 = off
  bool partition_of_unity = false;  ///< ReducedSettings::surface_partition_of_unity
  bool reduced_options_given = false;
};

// The ROM's settings as the scene keys handles / elastic_cubature / inertial_cubature /
// surface_partition_of_unity and the `flsh avatar` flags give them: 0 sample tets switches that
// cubature off (exact integration), and its count then keeps the (unused) default.
void setReducedSettings(ReducedSettings& reduced, int handles, int elastic, int inertial,
                        bool partition_of_unity) {
  reduced.num_handles = handles;
  if (elastic > 0) reduced.elastic_cubature_points = elastic;
  if (inertial > 0) reduced.inertial_cubature_points = inertial;
  reduced.surface_partition_of_unity = partition_of_unity;
}

// Soft tissue, the reduced model and the cubatures that are on (as setReducedSettings).
void enableReducedModel(SoftAvatar& avatar, int elastic, int inertial) {
  avatar.enableSoftTissue();
  avatar.enableReducedModel();
  avatar.enableElasticCubature(elastic > 0);
  avatar.enableInertialCubature(inertial > 0);
}

// Builds (or loads) an avatar and prints its statistics as JSON on stdout.
int cmdAvatar(const AvatarArgs& args) {
  const auto t0 = Clock::now();
  std::shared_ptr<const BodyModel> body;
  if (args.model.rfind("synthetic", 0) == 0) {
    // "synthetic" or "synthetic:N": the built-in synthetic body (N vertices, default 6890).
    SyntheticBodyOptions options;
    if (args.model.size() > 9) {
      if (args.model[9] != ':')
        throw InputError("--model: expected a .npz path, 'synthetic' or 'synthetic:N', got '" +
                         args.model + "'");
      try {
        options.vertices = std::stoi(args.model.substr(10));
      } catch (const std::exception&) {
        throw InputError("--model: '" + args.model.substr(10) +
                         "' is not a vertex count (synthetic:N)");
      }
    }
    body = std::make_shared<const BodyModel>(makeSyntheticBody(options));
  } else {
    body = std::make_shared<const BodyModel>(loadBodyModel(args.model));
  }
  const double load_seconds = secondsSince(t0);
  const VecX betas = args.betas.empty() ? VecX::Zero(body->numBetas())
                                        : fitBetas(parseBetas(args.betas), *body, "--betas");
  if (args.soft != "none" && args.soft != "fem" && args.soft != "rom")
    throw InputError("--soft: expected fem or rom (or none: the skeleton), got '" + args.soft + "'");
  if (!(args.resolution > 0) || !std::isfinite(args.resolution))
    throw InputError("--resolution: expected a number > 0, got " + std::to_string(args.resolution));
  if (args.reduced_options_given && args.soft != "rom")
    throw InputError("--handles, --elastic-cubature, --inertial-cubature and "
                     "--partition-of-unity are only for --soft rom, got --soft " + args.soft);
  if (args.handles < 1)
    throw InputError("--handles: expected an integer >= 1, got " + std::to_string(args.handles));
  if (args.elastic_cubature < 0)
    throw InputError("--elastic-cubature: expected a number of sample tets >= 0 (0 = off), got " +
                     std::to_string(args.elastic_cubature));
  if (args.inertial_cubature < 0)
    throw InputError("--inertial-cubature: expected a number of sample tets >= 0 (0 = off), got " +
                     std::to_string(args.inertial_cubature));

  SoftAvatarSettings settings;
  settings.volumetric.tet_mesh.resolution = args.resolution;
  settings.volumetric.material_file = args.materials;
  settings.volumetric.cache_dir = args.cache;
  settings.volumetric.use_cache = !args.no_cache;
  setReducedSettings(settings.reduced, args.handles, args.elastic_cubature,
                     args.inertial_cubature, args.partition_of_unity);
  SoftAvatar avatar(body, betas, settings);
  avatar.enableSoftTissue(args.soft != "none");
  if (args.soft == "rom") enableReducedModel(avatar, args.elastic_cubature, args.inertial_cubature);
  const auto build_start = Clock::now();
  avatar.initVolumetricData();
  const double build_seconds = secondsSince(build_start);

  const VolumetricBuildReport& r = avatar.volumetricBuildReport();
  if (!r.warnings.empty()) std::cerr << "flsh avatar: warning: " << r.warnings;
  const ReducedBuildReport& rr = avatar.reducedBuildReport();
  if (!rr.warnings.empty()) std::cerr << "flsh avatar: warning: " << rr.warnings;
  nlohmann::ordered_json out;
  out["model"] = body->source.empty() ? args.model : body->source;
  out["soft"] = args.soft;
  out["vertices"] = body->numVertices();
  out["betas"] = std::vector<double>(avatar.betas().data(),
                                     avatar.betas().data() + avatar.betas().size());
  out["total_mass_kg"] = avatar.totalMass();
  out["volume_m3"] = avatar.volume();
  nlohmann::ordered_json seconds;
  seconds["model_load"] = load_seconds;
  seconds["skeleton"] = avatar.skeletonSeconds();
  if (avatar.hasVolumetricData()) {
    const VolumetricData& d = avatar.volumetricData();
    const TetMeshQuality& q = d.templ->quality;
    out["nodes"] = d.numNodes();
    out["surface_nodes"] = d.templ->mesh.num_surface_nodes;
    out["tets"] = d.numTets();
    out["bone_nodes"] = d.numBoneNodes();
    out["soft_tissue_nodes"] = d.numNodes() - d.numBoneNodes();
    out["soft_body_mass_kg"] = d.totalMass();
    out["quality"] = {{"min_dihedral_deg", q.min_dihedral_deg},
                      {"max_dihedral_deg", q.max_dihedral_deg},
                      {"max_radius_edge_ratio", q.max_radius_edge_ratio},
                      {"mean_radius_edge_ratio", q.mean_radius_edge_ratio},
                      {"min_volume_m3", q.min_volume}};
    seconds["meshing"] = r.seconds_meshing;
    seconds["harmonic_fields"] = r.seconds_harmonic;
    seconds["mesh_quality"] = r.seconds_quality;
    seconds["bone_nodes"] = r.seconds_bone_nodes;
    seconds["materials"] = r.seconds_materials;
    seconds["cache_load"] = r.seconds_cache_load;
    seconds["cache_store"] = r.seconds_cache_store;
    const bool used = settings.volumetric.use_cache;
    out["cache"] = {
        {"directory", used ? AvatarCache(args.cache).directory() : std::string()},
        {"template", !used ? "off" : r.template_from_cache ? "hit" : "miss"},
        {"shape", !used ? "off" : r.data_from_cache ? "hit" : "miss"},
        {"warnings", r.warnings}};
  }
  if (avatar.hasReducedData()) {
    const ReducedData& d = avatar.reducedData();
    auto cubature = [](const Cubature& c, double test_error, bool on) {
      nlohmann::ordered_json j;
      j["enabled"] = on;
      j["tets"] = on ? int(c.elements.size()) : 0;
      j["weight_sum"] = on ? c.weights.sum() : 0.0;
      j["training_error"] = on ? c.training_error : 0.0;
      j["held_out_error"] = on ? test_error : 0.0;
      return j;
    };
    nlohmann::ordered_json reduced;
    reduced["handles"] = d.numHandles();
    reduced["dofs"] = 6 * kNumJoints + 3 * d.numHandles();
    reduced["basis_nonzeros"] = long(d.basis.nonZeros());
    reduced["surface_partition_of_unity"] = settings.reduced.surface_partition_of_unity;
    reduced["basis_max_bound_violation"] = d.basis_max_bound_violation;
    reduced["basis_max_constraint_error"] = d.basis_max_constraint_error;
    reduced["basis_converged"] = d.basis_converged;
    reduced["elastic_cubature"] =
        cubature(d.elastic, d.elastic_test_error, avatar.elasticCubatureEnabled());
    reduced["inertial_cubature"] =
        cubature(d.inertial, d.inertial_test_error, avatar.inertialCubatureEnabled());
    reduced["inertial_cubature"]["rigid_motion_error"] =
        avatar.inertialCubatureEnabled() ? d.inertial_rigid_error : 0.0;
    out["reduced"] = reduced;
    out["cache"]["reduced"] = !settings.volumetric.use_cache ? "off"
                              : rr.from_cache                ? "hit"
                                                             : "miss";
    out["cache"]["reduced_warnings"] = rr.warnings;
    seconds["handles"] = rr.seconds_handles;
    seconds["basis"] = rr.seconds_basis;
    seconds["cubature_training"] = rr.seconds_training;
    seconds["cubature"] = rr.seconds_cubature;
    seconds["reduced_cache_load"] = rr.seconds_cache_load;
    seconds["reduced_cache_store"] = rr.seconds_cache_store;
    seconds["reduced_total"] = rr.seconds_total;
  }
  seconds["avatar_total"] = build_seconds;
  out["seconds"] = seconds;
  std::printf("%s\n", out.dump(2).c_str());
  return 0;
}

int cmdDemo(const std::string& out_dir, int vertices, const std::string& motion_name,
            double seconds) {
  const auto t0 = Clock::now();
  namespace fs = std::filesystem;
  io::ensureDirectory(out_dir);
  SyntheticBodyOptions options;
  options.vertices = vertices;
  std::printf("demo: generating the synthetic body (%d vertices)...\n", vertices);
  std::fflush(stdout);
  const BodyModel body = makeSyntheticBody(options);
  saveBodyModel(body, (fs::path(out_dir) / "body.npz").string());
  const Motion motion = makeBuiltinMotion(motion_name, seconds, 30.0);
  saveMotion(motion, (fs::path(out_dir) / "motion.npz").string());
  const VecX betas = VecX::Zero(body.numBetas());
  const PosedBatch batch = poseBodyBatch(body, betas, motion.poses, motion.trans);
  writePosedNpz((fs::path(out_dir) / "posed.npz").string(), batch, body.numVertices(), betas,
                motion.fps);
  const fs::path mesh_dir = fs::path(out_dir) / "meshes";
  const int T = motion.numFrames(), V = body.numVertices();
  std::vector<MatX3> frames(T);
  for (int t = 0; t < T; ++t) frames[t] = Eigen::Map<const MatX3>(batch.vertices.row(t).data(), V, 3);
  writeFrameMeshes(mesh_dir, frames, body.faces);
  // A sheet of five evenly spaced frames.
  const int shown = std::min(5, T);
  std::vector<MatX3> picked;
  for (int k = 0; k < shown; ++k) picked.push_back(frames[shown > 1 ? k * (T - 1) / (shown - 1) : 0]);
  render::RenderOptions view;
  view.width = 320;
  view.height = 480;
  const std::string png = (fs::path(out_dir) / "sheet.png").string();
  render::writePng(png, render::renderSheet(picked, body.faces, view));
  std::printf("demo: posed the synthetic body through '%s' (%d frames): %s/{body,motion,posed}.npz, "
              "%d meshes in %s, picture %s; %.2f s\n",
              motion_name.c_str(), T, out_dir.c_str(), T, mesh_dir.string().c_str(), png.c_str(),
              secondsSince(t0));
  return 0;
}

// ---------------------------------------------------------------------------------------------
// flsh simulate

/// A closed UV sphere of radius r about the origin, axis +z, with no vertex ring on the equator
/// (so that stretching the halves apart along z turns it into a capsule). #V × 3, #F × 3.
void makeUvSphere(double r, int rings, int segments, MatX3& V, MatX3i& F) {
  const double pi = 3.14159265358979323846;
  V.resize(2 + rings * segments, 3);
  V.row(0) << 0, 0, r;
  for (int k = 0; k < rings; ++k) {
    const double polar = pi * (k + 0.5) / rings;
    for (int s = 0; s < segments; ++s) {
      const double azimuth = 2 * pi * s / segments;
      V.row(1 + k * segments + s) << r * std::sin(polar) * std::cos(azimuth),
          r * std::sin(polar) * std::sin(azimuth), r * std::cos(polar);
    }
  }
  V.row(1 + rings * segments) << 0, 0, -r;
  const int bottom = 1 + rings * segments;
  auto ring = [&](int k, int s) { return 1 + k * segments + (s % segments); };
  std::vector<Eigen::Vector3i> faces;
  for (int s = 0; s < segments; ++s) {
    faces.emplace_back(0, ring(0, s), ring(0, s + 1));
    for (int k = 0; k + 1 < rings; ++k) {
      faces.emplace_back(ring(k, s), ring(k + 1, s), ring(k + 1, s + 1));
      faces.emplace_back(ring(k, s), ring(k + 1, s + 1), ring(k, s + 1));
    }
    faces.emplace_back(bottom, ring(rings - 1, s + 1), ring(rings - 1, s));
  }
  F.resize(long(faces.size()), 3);
  for (size_t f = 0; f < faces.size(); ++f) F.row(long(f)) = faces[f].transpose();
}

/// Triangle mesh of a sphere or capsule collider at zero path offset (planes have none).
bool colliderMesh(const Collider& collider, MatX3& V, MatX3i& F) {
  if (collider.shape() == ColliderShape::Plane) return false;
  makeUvSphere(collider.radius(), 12, 24, V, F);  // 12 rings: none on the equator
  if (collider.shape() == ColliderShape::Sphere) {
    V.rowwise() += collider.p0().transpose();
    return true;
  }
  const Vec3 a = collider.p0(), b = collider.p1();
  const double half = 0.5 * (b - a).norm();
  for (Eigen::Index i = 0; i < V.rows(); ++i) V(i, 2) += V(i, 2) > 0 ? half : -half;
  const Mat3 R = Eigen::Quaterniond::FromTwoVectors(Vec3::UnitZ(), half > 0 ? Vec3(b - a) : Vec3::UnitZ())
                     .toRotationMatrix();
  V = (V * R.transpose()).rowwise() + (0.5 * (a + b)).transpose();
  return true;
}

/// A square of `half` m half-size on a plane collider, centred at the point of the plane
/// nearest to `center` (a ground for glTF viewers).
void planeQuad(const Collider& plane, const Vec3& center, double half, MatX3& V, MatX3i& F) {
  const Vec3 n = plane.p1();
  const Vec3 c = center - (center - plane.p0()).dot(n) * n;
  const Vec3 u = n.unitOrthogonal(), w = n.cross(u);
  V.resize(4, 3);
  V.row(0) = (c - half * u - half * w).transpose();
  V.row(1) = (c + half * u - half * w).transpose();
  V.row(2) = (c + half * u + half * w).transpose();
  V.row(3) = (c - half * u + half * w).transpose();
  F.resize(2, 3);
  F << 0, 1, 2, 0, 2, 3;  // counter-clockwise seen from the normal side
}

/// One line on stderr that updates in place on a terminal; a line per 10 % otherwise.
class ProgressBar {
 public:
  explicit ProgressBar(int total) : total_(std::max(1, total)), tty_(isatty(fileno(stderr)) != 0) {}
  void update(int done, double sim_time) {
    const double elapsed = secondsSince(start_);
    const int percent = int(100.0 * done / total_);
    if (tty_) {
      if (done < total_ && secondsSince(last_) < 0.1) return;
      last_ = Clock::now();
    } else {
      if (percent / 10 == last_decile_ && done < total_) return;
      last_decile_ = percent / 10;
    }
    const double rate = elapsed > 0 ? done / elapsed : 0.0;
    const double eta = rate > 0 ? (total_ - done) / rate : 0.0;
    const int width = 24, filled = width * done / total_;
    std::fprintf(stderr, "%s[%s%s] %3d%%  step %d/%d  t = %.3f s  %.0f steps/s  ETA %.1f s%s",
                 tty_ ? "\r" : "", std::string(filled, '#').c_str(),
                 std::string(width - filled, '.').c_str(), percent, done, total_, sim_time, rate,
                 eta, tty_ ? "\033[K" : "\n");
    std::fflush(stderr);
  }
  void finish() {
    if (tty_) std::fputc('\n', stderr);
  }

 private:
  int total_;
  bool tty_;
  int last_decile_ = 0;  // the first line comes at 10 %
  Clock::time_point start_ = Clock::now(), last_ = Clock::time_point();
};

/// One avatar of the scene while it is simulated, and what is recorded of it.
struct AvatarRun {
  const AvatarSpec* spec = nullptr;
  std::string where;  ///< "SCENE: avatars[i]" for messages
  std::shared_ptr<const BodyModel> body;
  std::shared_ptr<SoftAvatar> avatar;
  std::shared_ptr<const Motion> motion;
  std::shared_ptr<Simulable> simulable;
  bool soft = false;  ///< "simulation": "fem" or "rom" (soft-tissue displacements)
  bool rom = false;   ///< "simulation": "rom"
  // Per saved frame:
  std::vector<VecX> states, poses;
  std::vector<VecX> displacement_norms;  ///< soft only: ‖u_i‖ of the surface vertices, #V, m
  std::vector<Vec3> trans;
  std::vector<MatX3> vertices, joints;
  std::vector<std::vector<Mat3>> rotations;
};

/// The avatar's motion with its yaw (about +y through the root's rest position) and offset:
/// every frame is rigidly moved, trans' = R_y trans + offset and R_root' = R_y R_root.
std::shared_ptr<Motion> placedMotion(Motion motion, const AvatarSpec& spec) {
  const Mat3 Ry = Eigen::AngleAxisd(spec.yaw, Vec3::UnitY()).toRotationMatrix();
  for (int k = 0; k < motion.numFrames(); ++k) {
    const Vec3 trans = motion.trans.row(k).transpose();
    motion.trans.row(k) = (Ry * trans + spec.offset).transpose();
    const Vec3 root = motion.poses.row(k).head<3>().transpose();
    motion.poses.row(k).head<3>() = logSO3(Ry * rodrigues(root)).transpose();
  }
  return std::make_shared<Motion>(std::move(motion));
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

/// One stderr line about a ROM avatar's reduced data: basis, cubatures, cache and build time.
void printReducedReport(const std::string& name, const SoftAvatar& avatar, bool use_cache) {
  const ReducedData& data = avatar.reducedData();
  const ReducedBuildReport& report = avatar.reducedBuildReport();
  if (!report.warnings.empty())
    std::fprintf(stderr, "simulate: warning: avatar '%s': %s", name.c_str(),
                 report.warnings.c_str());
  if (!data.basis_converged)
    std::fprintf(stderr,
                 "simulate: warning: avatar '%s': the bounded biharmonic solve of some handle "
                 "did not converge (max bound violation %.2g)\n",
                 name.c_str(), data.basis_max_bound_violation);
  char cache[64];
  if (!use_cache)
    std::snprintf(cache, sizeof(cache), "off, built in %.1f s", report.seconds_total);
  else if (report.from_cache)
    std::snprintf(cache, sizeof(cache), "hit (%.2f s)", report.seconds_total);
  else
    std::snprintf(cache, sizeof(cache), "miss (built and stored in %.1f s)", report.seconds_total);
  std::fprintf(stderr,
               "simulate: avatar '%s' (rom): %d handles, basis %ld nonzeros; elastic cubature "
               "%s; inertial cubature %s; reduced data cache: %s\n",
               name.c_str(), data.numHandles(), long(data.basis.nonZeros()),
               cubatureSummary(data.elastic, data.elastic_test_error,
                               avatar.elasticCubatureEnabled())
                   .c_str(),
               cubatureSummary(data.inertial, data.inertial_test_error,
                               avatar.inertialCubatureEnabled(), data.inertial_rigid_error)
                   .c_str(),
               cache);
}

/// Loads every body model, motion and avatar of the scene (nothing is written).
std::vector<AvatarRun> buildAvatars(const SceneSpec& scene) {
  std::map<std::string, std::shared_ptr<const BodyModel>> bodies;  // shared per model
  std::vector<AvatarRun> runs(scene.avatars.size());
  for (size_t i = 0; i < scene.avatars.size(); ++i) {
    const AvatarSpec& spec = scene.avatars[i];
    AvatarRun& run = runs[i];
    run.spec = &spec;
    run.where = scene.source + ": avatars[" + std::to_string(i) + "]";
    const std::string key = spec.model == "synthetic"
                                ? "synthetic:" + std::to_string(spec.synthetic_vertices)
                                : spec.model;
    auto& body = bodies[key];
    if (!body) {
      if (spec.model == "synthetic") {
        std::fprintf(stderr, "simulate: generating the synthetic body (%d vertices)...\n",
                     spec.synthetic_vertices);
        SyntheticBodyOptions options;
        options.vertices = spec.synthetic_vertices;
        body = std::make_shared<const BodyModel>(makeSyntheticBody(options));
      } else {
        body = std::make_shared<const BodyModel>(loadBodyModel(spec.model));
      }
      if (body->numJoints() != kNumJoints)
        throw InputError(run.where + ".model: " + spec.model + " has " +
                         std::to_string(body->numJoints()) + " joints, expected 24 (SMPL)");
    }
    run.body = body;

    std::shared_ptr<Motion> motion;
    if (!spec.motion.empty()) {
      const std::string prefix = "builtin:";
      Motion raw = spec.motion.rfind(prefix, 0) == 0
                       ? makeBuiltinMotion(spec.motion.substr(prefix.size()),
                                           spec.motion_seconds > 0 ? spec.motion_seconds
                                                                   : scene.duration)
                       : loadMotion(spec.motion);
      motion = placedMotion(std::move(raw), spec);
    }
    run.motion = motion;

    VecX betas = spec.betas;
    if (betas.size() > body->numBetas())
      throw InputError(run.where + ".betas: " + std::to_string(betas.size()) +
                       " values, but the model has " + std::to_string(body->numBetas()) +
                       " shape components");
    if (betas.size() == 0 && motion && motion->betas.size() > 0)
      betas = fitBetas(motion->betas, *body, motion->source);
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
                         spec.inertial_cubature, spec.surface_partition_of_unity);
    run.avatar = std::make_shared<SoftAvatar>(body, betas, settings);
    if (run.soft) {
      std::fprintf(stderr, "simulate: building the volumetric body%s of avatar '%s'...\n",
                   run.rom ? " and the reduced basis" : "", spec.name.c_str());
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
        std::fprintf(stderr, "simulate: warning: avatar '%s': %s", spec.name.c_str(),
                     report.warnings.c_str());
      std::fprintf(stderr,
                   "simulate: avatar '%s': %d nodes (%d soft tissue), %d tets; cache: %s\n",
                   spec.name.c_str(), data.numNodes(), data.numNodes() - data.numBoneNodes(),
                   data.numTets(),
                   !scene.use_cache                ? "off"
                   : report.data_from_cache        ? "hit"
                   : report.template_from_cache    ? "template hit, shape built"
                                                   : "miss (built and stored)");
    }
    if (run.rom) printReducedReport(spec.name, *run.avatar, scene.use_cache);
    SimulableOptions options = spec.options;
    options.time_step = scene.time_step;
    run.simulable = std::make_shared<Simulable>(run.avatar, run.motion, options);
  }
  return runs;
}

void recordFrame(AvatarRun& run) {
  const Simulable& sim = *run.simulable;
  run.states.push_back(sim.getState());
  run.poses.push_back(sim.getPose());
  run.trans.push_back(sim.getTrans());
  run.vertices.push_back(sim.getVertices());
  run.joints.push_back(sim.bonePositions());
  run.rotations.push_back(sim.boneRotations());
  if (run.soft) run.displacement_norms.push_back(sim.getSoftTissueDisplacements().rowwise().norm());
}

/// Largest ‖u_i‖ of a saved frame, mm (0 for an empty frame).
double maxDisplacementMm(const VecX& norms) {
  return norms.size() > 0 ? 1000.0 * norms.maxCoeff() : 0.0;
}

/// (T, …) float64 array of per-frame matrices stacked in C order.
template <class M>
void addStacked(io::NpzWriter& npz, const std::string& key, const std::vector<M>& frames,
                std::vector<long> frame_shape) {
  size_t per_frame = 1;
  for (long n : frame_shape) per_frame *= size_t(n);
  std::vector<double> data(frames.size() * per_frame);
  for (size_t k = 0; k < frames.size(); ++k) {
    // Row-major copy (MatX3 is row-major; vectors are 1-D).
    const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> rows = frames[k];
    if (size_t(rows.size()) != per_frame)
      throw Error("simulate: internal shape mismatch in " + key);
    std::copy(rows.data(), rows.data() + per_frame, data.begin() + long(k * per_frame));
  }
  frame_shape.insert(frame_shape.begin(), long(frames.size()));
  npz.add(key, data.data(), frame_shape);
}

const Vec3 kAvatarColors[] = {Vec3(0.80, 0.62, 0.52), Vec3(0.55, 0.66, 0.80),
                              Vec3(0.62, 0.78, 0.55), Vec3(0.82, 0.72, 0.45)};
const Vec3 kColliderColor(0.90, 0.25, 0.20);

int cmdSimulate(const std::string& scene_path, const SceneOverrides& overrides) {
  namespace fs = std::filesystem;
  const auto t_setup = Clock::now();
  // Everything is read and checked before anything is written.
  const SceneSpec scene = scene_path.empty() ? defaultScene(overrides)
                                             : loadSceneFile(scene_path, overrides);
  std::vector<AvatarRun> runs = buildAvatars(scene);

  SceneOptions scene_options;
  scene_options.newton = scene.newton;
  // Soft-tissue scenes keep their own solver choices (SceneOptions::soft_tissue_newton with an
  // FEM avatar, else reduced_newton for ROM avatars: Hessian form, linear solver, lagged factor,
  // tolerance) and take the scene's iteration limit and step tolerance; their gradient
  // tolerance comes from the scene file's "soft_tissue_gradient_tolerance" (FEM).
  scene_options.soft_tissue_newton.max_iterations = scene.newton.max_iterations;
  scene_options.soft_tissue_newton.step_tolerance = scene.newton.step_tolerance;
  if (scene.soft_tissue_gradient_tolerance > 0)
    scene_options.soft_tissue_newton.gradient_tolerance = scene.soft_tissue_gradient_tolerance;
  // Scenes whose soft avatars are all "rom": the same, with "reduced_gradient_tolerance".
  scene_options.reduced_newton.max_iterations = scene.newton.max_iterations;
  scene_options.reduced_newton.step_tolerance = scene.newton.step_tolerance;
  if (scene.reduced_gradient_tolerance > 0)
    scene_options.reduced_newton.gradient_tolerance = scene.reduced_gradient_tolerance;
  // Their lagged-factor settings ("soft_tissue_lagged" / "reduced_lagged"; the solvers'
  // defaults unless the file sets them).
  scene_options.soft_tissue_newton.lagged = scene.soft_tissue_lagged;
  scene_options.reduced_newton.lagged = scene.reduced_lagged;
  scene_options.avatar_contact = scene.avatar_contact;
  Scene sim_scene(scene_options);
  for (auto& run : runs) sim_scene.addSimulable(run.simulable);
  for (const auto& collider : scene.colliders) sim_scene.addCollider(collider);
  sim_scene.initialize();
  // An avatar starting deep inside the ground is usually a wrong plane height: say so.
  for (const auto& run : runs) {
    const MatX3 nodes = run.simulable->getNodes();
    for (const auto& collider : scene.colliders) {
      if (collider.shape() != ColliderShape::Plane) continue;
      double deepest = 0.0;
      for (Eigen::Index i = 0; i < nodes.rows(); ++i)
        deepest = std::min(deepest, collider.signedDistance(nodes.row(i).transpose(), 0.0));
      if (deepest < -0.02)
        std::fprintf(stderr, "simulate: warning: avatar '%s' starts %.3f m deep in plane '%s'\n",
                     run.spec->name.c_str(), -deepest, collider.name.c_str());
    }
  }
  const double setup_seconds = secondsSince(t_setup);

  // ---- simulation: record frames in memory, write nothing yet ----
  const double h = scene.time_step;
  const int steps = std::max(1, int(std::lround(scene.duration / h)));
  const int every = scene.outputs.every;
  std::vector<double> times;
  std::vector<std::vector<Vec3>> collider_offsets(scene.colliders.size());
  auto record = [&](double t) {
    times.push_back(t);
    for (auto& run : runs) recordFrame(run);
    for (size_t c = 0; c < scene.colliders.size(); ++c)
      collider_offsets[c].push_back(scene.colliders[c].path.offsetAt(t));
  };
  record(0.0);
  const auto t_sim = Clock::now();
  ProgressBar progress(steps);
  long newton_iterations = 0, factorizations = 0, cg_iterations = 0;
  int unconverged = 0, max_contacts = 0;
  std::string first_unconverged;
  for (int s = 1; s <= steps; ++s) {
    const StepStats stats = sim_scene.step();
    newton_iterations += stats.newton.iterations;
    factorizations += stats.newton.factorizations;
    cg_iterations += stats.newton.cg_iterations;
    max_contacts = std::max(max_contacts, stats.active_contacts);
    if (!stats.newton.converged && unconverged++ == 0)
      first_unconverged = "step " + std::to_string(s) + ": " + stats.newton.message;
    for (const auto& run : runs)
      if (!run.simulable->getState().allFinite())
        throw Error("simulation diverged: avatar '" + run.spec->name +
                    "' has a non-finite state after step " + std::to_string(s) + " (t = " +
                    std::to_string(s * h) + " s); nothing was written");
    if (s % every == 0) record(s * h);
    progress.update(s, s * h);
  }
  progress.finish();
  const double sim_seconds = secondsSince(t_sim);

  // ---- outputs, each file atomic ----
  const auto t_out = Clock::now();
  const fs::path dir(scene.outputs.dir);
  const OutputSpec& wanted = scene.outputs;
  if (wanted.ply || wanted.npz || wanted.gltf || wanted.png) io::ensureDirectory(dir.string());
  const int T = int(times.size());
  std::vector<std::string> written;

  if (scene.outputs.ply) {
    for (const auto& run : runs) {
      writeFrameMeshes(dir / "meshes" / run.spec->name, run.vertices, run.body->faces);
    }
    written.push_back("meshes/<avatar>/frame_*.ply");
  }

  if (scene.outputs.npz) {
    io::NpzWriter npz;
    npz.add("times", Eigen::Map<const VecX>(times.data(), T));
    npz.addScalar("time_step", h);
    for (const auto& run : runs) {
      const std::string& name = run.spec->name;
      const long V = run.body->numVertices(), F = run.body->numFaces();
      addStacked(npz, name + "_states", run.states, {long(run.states[0].size())});
      addStacked(npz, name + "_poses", run.poses, {kSmplPoseSize});
      addStacked(npz, name + "_trans", run.trans, {3});
      addStacked(npz, name + "_vertices", run.vertices, {V, 3});
      addStacked(npz, name + "_joints", run.joints, {kNumJoints, 3});
      std::vector<int64_t> faces(size_t(F) * 3);
      for (long f = 0; f < F; ++f)
        for (int c = 0; c < 3; ++c) faces[3 * f + c] = run.body->faces(f, c);
      npz.add(name + "_faces", faces.data(), {F, 3});
      npz.add(name + "_betas", Eigen::Ref<const VecX>(run.avatar->betas()));
      if (run.soft) {
        VecX max_mm(T);
        for (int k = 0; k < T; ++k) max_mm[k] = maxDisplacementMm(run.displacement_norms[k]);
        npz.add(name + "_max_displacement_mm", Eigen::Ref<const VecX>(max_mm));
      }
    }
    for (size_t c = 0; c < scene.colliders.size(); ++c)
      addStacked(npz, scene.colliders[c].name + "_offset", collider_offsets[c], {3});
    npz.save((dir / "states.npz").string());
    written.push_back("states.npz");
  }

  if (scene.outputs.gltf) {
    std::vector<io::GltfSkinnedAvatar> avatars;
    Vec3 center = Vec3::Zero();
    for (size_t i = 0; i < runs.size(); ++i) {
      const AvatarRun& run = runs[i];
      io::GltfSkinnedAvatar a;
      a.name = run.spec->name;
      a.rest_vertices = run.avatar->restVertices();
      a.faces = run.body->faces;
      a.weights = run.body->weights;
      a.parents = run.body->parents;
      a.rest_joints = run.avatar->restJoints();
      a.bone_names.assign(kSmplJointNames.begin(), kSmplJointNames.end());
      a.rotations = run.rotations;
      a.positions = run.joints;
      a.color = kAvatarColors[i % 4];
      center += run.joints[0].row(0).transpose() / double(runs.size());
      avatars.push_back(std::move(a));
    }
    std::vector<io::GltfRigidMesh> rigid;
    for (size_t c = 0; c < scene.colliders.size(); ++c) {
      const Collider& collider = scene.colliders[c];
      io::GltfRigidMesh m;
      m.name = collider.name;
      if (colliderMesh(collider, m.vertices, m.faces)) {
        m.translations = collider_offsets[c];
        m.color = kColliderColor;
      } else {
        planeQuad(collider, center, 5.0, m.vertices, m.faces);
        m.color = Vec3(0.7, 0.7, 0.7);
      }
      rigid.push_back(std::move(m));
    }
    io::writeGlb((dir / "animation.glb").string(), times, avatars, rigid);
    written.push_back("animation.glb");
  }

  double sheet_max_mm = 0.0;  // colour scale of the soft avatars in sheet.png
  if (scene.outputs.png) {
    // All avatars and the sphere/capsule colliders in one mesh per shown frame, framed on the
    // avatars (a collider far away is cut off rather than shrinking the bodies).
    const int shown = std::min(scene.outputs.png_frames, T);
    auto shownFrame = [&](int j) { return shown > 1 ? j * (T - 1) / (shown - 1) : 0; };
    // Soft avatars are coloured by ‖u_i‖ with one scale over the whole sheet.
    for (int j = 0; j < shown; ++j)
      for (const auto& run : runs)
        if (run.soft)
          sheet_max_mm = std::max(sheet_max_mm,
                                  maxDisplacementMm(run.displacement_norms[shownFrame(j)]));
    MatX3i faces;
    std::vector<MatX3> frames, colors;
    Eigen::AlignedBox3d box;
    for (int j = 0; j < shown; ++j) {
      const int k = shownFrame(j);
      std::vector<std::pair<MatX3, MatX3i>> parts;
      std::vector<MatX3> part_colors;  // #part vertices × 3 each
      auto uniform = [](long rows, const Vec3& color) {
        MatX3 C(rows, 3);
        C.rowwise() = color.transpose();
        return C;
      };
      for (size_t i = 0; i < runs.size(); ++i) {
        parts.emplace_back(runs[i].vertices[k], runs[i].body->faces);
        const AvatarRun& run = runs[i];
        part_colors.push_back(
            run.soft ? render::displacementColors(1000.0 * run.displacement_norms[k], sheet_max_mm)
                     : uniform(run.vertices[k].rows(), kAvatarColors[i % 4]));
        for (Eigen::Index v = 0; v < runs[i].vertices[k].rows(); ++v)
          box.extend(runs[i].vertices[k].row(v).transpose());
      }
      for (size_t c = 0; c < scene.colliders.size(); ++c) {
        MatX3 V;
        MatX3i F;
        if (!colliderMesh(scene.colliders[c], V, F)) continue;
        V.rowwise() += collider_offsets[c][k].transpose();
        parts.emplace_back(V, F);
        part_colors.push_back(uniform(V.rows(), kColliderColor));
      }
      long nv = 0, nf = 0;
      for (const auto& p : parts) nv += p.first.rows(), nf += p.second.rows();
      MatX3 V(nv, 3), C(nv, 3);
      MatX3i F(nf, 3);
      long v0 = 0, f0 = 0;
      for (size_t p = 0; p < parts.size(); ++p) {
        V.middleRows(v0, parts[p].first.rows()) = parts[p].first;
        C.middleRows(v0, parts[p].first.rows()) = part_colors[p];
        F.middleRows(f0, parts[p].second.rows()) = parts[p].second.array() + int(v0);
        v0 += parts[p].first.rows();
        f0 += parts[p].second.rows();
      }
      faces = F;
      frames.push_back(std::move(V));
      colors.push_back(std::move(C));
    }
    render::RenderOptions view;
    view.width = 320;
    view.height = 480;
    // Padded except below: the renderer puts its floor at the bottom of the box (the soles).
    view.frame = Eigen::AlignedBox3d(box.min() - Vec3(0.15, 0.0, 0.15), box.max() + Vec3::Constant(0.15));
    render::writePng((dir / "sheet.png").string(),
                     render::renderSheet(frames, faces, view, 0, colors));
    written.push_back("sheet.png");
  }
  const double out_seconds = secondsSince(t_out);

  std::string outputs;
  for (const auto& w : written) outputs += (outputs.empty() ? "" : ", ") + w;
  for (const auto& run : runs) {
    if (!run.soft) continue;
    double run_max_mm = 0.0;
    for (const VecX& norms : run.displacement_norms)
      run_max_mm = std::max(run_max_mm, maxDisplacementMm(norms));
    std::printf("simulate: avatar '%s' (%s): max soft-tissue displacement |u| %.3f mm over the "
                "saved frames\n",
                run.spec->name.c_str(), run.spec->simulation.c_str(), run_max_mm);
  }
  const bool any_soft =
      std::any_of(runs.begin(), runs.end(), [](const AvatarRun& r) { return r.soft; });
  if (scene.outputs.png && any_soft)
    std::printf("simulate: sheet.png colours soft avatars by |u| (viridis): 0 mm dark purple to "
                "%.3f mm yellow\n",
                sheet_max_mm);
  if (unconverged > 0)
    std::fprintf(stderr, "simulate: warning: %d of %d steps did not converge (first: %s)\n",
                 unconverged, steps, first_unconverged.c_str());
  std::printf("simulate: %s: %zu avatar(s), %zu collider(s), %d steps of %.4g s (%.3g s), "
              "%d frames; %.0f steps/s, %.2f Newton iterations/step (%.2f factorizations, "
              "%.1f PCG iterations), %d unconverged, "
              "max %d contacts; wall time: set-up %.2f s, simulation %.2f s, output %.2f s; "
              "wrote %s in %s\n",
              scene.source.c_str(), runs.size(), scene.colliders.size(), steps, h, steps * h, T,
              steps / std::max(sim_seconds, 1e-9), double(newton_iterations) / steps,
              double(factorizations) / steps, double(cg_iterations) / steps, unconverged,
              max_contacts, setup_seconds, sim_seconds, out_seconds,
              outputs.empty() ? "nothing" : outputs.c_str(), dir.string().c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"flsh: differentiable physics of SMPL human bodies"};
  app.require_subcommand(1);

  std::string out, model, motion_spec, betas, name = "walk", demo_out = "out/demo";
  int vertices = 6890;
  double height = 1.70, seconds = 2.0, fps = 30.0;

  auto* synth = app.add_subcommand("synth-body", "Write a synthetic SMPL-format body (.npz)");
  synth->add_option("--out", out, "output .npz file")->required();
  synth->add_option("--vertices", vertices, "number of surface vertices")->capture_default_str();
  synth->add_option("--height", height, "standing height in T-pose, m")->capture_default_str();

  auto* motion = app.add_subcommand("motion", "Write a built-in motion as an AMASS-style .npz");
  motion->add_option("--name", name, "built-in motion: " + [] {
    std::string s;
    for (const auto& n : builtinMotionNames()) s += (s.empty() ? "" : ", ") + n;
    return s;
  }())->capture_default_str();
  motion->add_option("--out", out, "output .npz file")->required();
  motion->add_option("--seconds", seconds, "duration, s")->capture_default_str();
  motion->add_option("--fps", fps, "frames per second")->capture_default_str();

  auto* pose = app.add_subcommand("pose", "Pose a body through a motion: vertices and joints per frame");
  pose->add_option("--model", model, "SMPL-format body model (.npz)")->required();
  pose->add_option("--motion", motion_spec, "AMASS-style .npz, or builtin:NAME")->required();
  pose->add_option("--out", out, "output .npz with vertices (T,V,3) and joints (T,24,3)")->required();
  pose->add_option("--betas", betas, "shape coefficients b0,b1,… (default: the motion's betas)");

  auto* demo = app.add_subcommand("demo", "Default job: synthetic body through a built-in motion, meshes and a picture");
  demo->add_option("--out", demo_out, "output directory")->capture_default_str();
  demo->add_option("--vertices", vertices, "vertices of the synthetic body")->capture_default_str();
  demo->add_option("--motion", name, "built-in motion")->capture_default_str();
  demo->add_option("--seconds", seconds, "duration, s")->capture_default_str();

  std::string scene_path, sim_out;
  double duration = 0.0, time_step = 0.0;
  auto* simulate = app.add_subcommand(
      "simulate", "Main job: simulate a scene (default: a synthetic walker hit by a ball); "
                  "writes PLY meshes, states.npz, animation.glb and sheet.png");
  simulate->add_option("scene", scene_path, "scene file (.json, see docs/scene_format.md); "
                                            "none = the built-in default scene");
  simulate->add_option("--out", sim_out, "output directory (overrides outputs.dir)");
  simulate->add_option("--duration", duration, "simulated time, s (overrides duration)");
  simulate->add_option("--time-step", time_step, "time step, s (overrides time_step)");
  std::string sim_cache;
  bool sim_no_cache = false;
  auto* sim_cache_option = simulate->add_option(
      "--cache", sim_cache,
      "avatar cache directory of \"fem\" and \"rom\" avatars (overrides cache_dir; default: "
      "$FLSH_CACHE_DIR, else ~/.cache/flsh)");
  simulate->add_flag("--no-cache", sim_no_cache, "neither read nor write the avatar cache")
      ->excludes(sim_cache_option);

  AvatarArgs avatar_args;
  auto* avatar = app.add_subcommand(
      "avatar", "Build (or load from the cache) an avatar and print its statistics as JSON");
  avatar->add_option("--model", avatar_args.model,
                     "SMPL-format body (.npz), or synthetic[:VERTICES] for the built-in body")
      ->required();
  avatar->add_option("--betas", avatar_args.betas, "shape coefficients b0,b1,… (default: zeros)");
  avatar->add_option("--soft", avatar_args.soft,
                     "soft-tissue model: fem, rom, or none (the articulated skeleton)")
      ->capture_default_str();
  avatar->add_option("--cache", avatar_args.cache,
                     "cache directory (default: $FLSH_CACHE_DIR, else ~/.cache/flsh)");
  avatar->add_flag("--no-cache", avatar_args.no_cache, "neither read nor write the cache");
  avatar->add_option("--resolution", avatar_args.resolution,
                     "interior node density of the tet mesh relative to the default")
      ->capture_default_str();
  avatar->add_option("--materials", avatar_args.materials,
                     "material file (JSON, docs/materials.md; default: built-in coefficients)");
  auto* handles_option = avatar->add_option("--handles", avatar_args.handles,
                                            "--soft rom: point handles of the reduced basis")
                             ->capture_default_str();
  auto* elastic_option =
      avatar->add_option("--elastic-cubature", avatar_args.elastic_cubature,
                         "--soft rom: sample tets of the elastic cubature (0 = off, exact)")
          ->capture_default_str();
  auto* inertial_option =
      avatar->add_option("--inertial-cubature", avatar_args.inertial_cubature,
                         "--soft rom: sample tets of the inertial cubature (0 = off, exact)")
          ->capture_default_str();
  auto* pou_option = avatar->add_flag(
      "--partition-of-unity", avatar_args.partition_of_unity,
      "--soft rom: basis rescaled to sum to 1 on the soft surface (docs/rom.md)");

  CLI11_PARSE(app, argc, argv);
  const std::string command = app.get_subcommands().front()->get_name();
  try {
    if (command == "synth-body") return cmdSynthBody(out, vertices, height);
    if (command == "motion") return cmdMotion(name, out, seconds, fps);
    if (command == "pose") return cmdPose(model, motion_spec, out, betas);
    if (command == "demo") return cmdDemo(demo_out, vertices, name, seconds);
    if (command == "avatar") {
      avatar_args.reduced_options_given =
          handles_option->count() + elastic_option->count() + inertial_option->count() +
              pou_option->count() > 0;
      return cmdAvatar(avatar_args);
    }
    if (command == "simulate") {
      SceneOverrides overrides;
      overrides.duration = duration;
      overrides.time_step = time_step;
      overrides.output_dir = sim_out;
      overrides.cache_dir = sim_cache;
      overrides.no_cache = sim_no_cache;
      if (simulate->count("--cache") && sim_cache.empty())
        throw InputError("--cache: expected a directory, got an empty string");
      if (simulate->count("--duration") && duration == 0.0)
        throw InputError("--duration: expected a time > 0 s, got 0");
      if (simulate->count("--time-step") && time_step == 0.0)
        throw InputError("--time-step: expected a time step > 0 s, got 0");
      if (simulate->count("--out") && sim_out.empty())
        throw InputError("--out: expected a directory, got an empty string");
      return cmdSimulate(scene_path, overrides);
    }
  } catch (const flsh::Error& e) {
    std::fprintf(stderr, "flsh %s: error: %s\n", command.c_str(), e.what());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "flsh %s: internal error: %s\n", command.c_str(), e.what());
    return 3;
  }
  return 1;
}
