// The `flsh` command-line program.
//
//   flsh synth-body --out BODY.npz [--vertices N] [--height M]
//   flsh motion --name walk --out MOTION.npz [--seconds S] [--fps F] [--up y|z]
//   flsh pose --model BODY.npz --motion MOTION.npz --out OUT.npz [--betas b0,b1,…] [--up y|z]
//   flsh demo [--out DIR] [--vertices N] [--motion NAME] [--seconds S]
//   flsh simulate [SCENE.json] [--out DIR] [--duration S] [--time-step H] [--cache DIR]
//                 [--no-cache]
//   flsh avatar --model BODY.npz [--betas b0,b1,…] [--soft fem|rom] [--cache DIR]
//               [--resolution R] [--materials FILE] [--no-cache]
//               [--preset realtime] [--basis modes|handles|modes+handles] [--vibration-modes M]
//               [--modal-columns C] [--handles H] [--elastic-cubature N]
//               [--inertial-cubature N] [--partition-of-unity]
//
// Every command prints a one-line summary on success. Every failure (a bad option, file or
// value, an impossible size, a failed simulation) exits with status 2 and a message naming the
// input and what is allowed, checked before any work where it can be; 3 is left for internal
// errors. Output files are written atomically, and output folders (simulate, demo) as a whole
// through a staging folder beside them (flsh/io/output_dir.h, docs/scene_format.md).
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <new>
#include <nlohmann/json.hpp>
#include <sstream>

#include "flsh/body/body_forward.h"
#include "flsh/body/motion.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/core/error.h"
#include "flsh/core/memory_check.h"
#include "flsh/format/atomic_file.h"
#include "flsh/format/mesh_io.h"
#include "flsh/format/npz.h"
#include "flsh/io/output_dir.h"
#include "flsh/io/presets.h"
#include "flsh/io/scene_build.h"
#include "flsh/io/scene_file.h"
#include "flsh/io/scene_outputs.h"
#include "flsh/io/scene_run.h"
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

/// Most frames `flsh motion` and `flsh demo` generate.
constexpr double kMaxMotionFrames = 1e6;

/// A number as %g with 6 digits, for messages.
std::string number(double value) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.6g", value);
  return text;
}

/// Parses "b0,b1,…" into a vector; throws InputError naming the option and the value unless
/// every value is a finite number within ±kMaxShapeCoefficient.
VecX parseBetas(const std::string& text) {
  std::vector<double> values;
  std::stringstream in(text);
  std::string item;
  const std::string range = "expected comma-separated numbers within [-" +
                            number(kMaxShapeCoefficient) + ", " + number(kMaxShapeCoefficient) +
                            "]";
  while (std::getline(in, item, ',')) {
    const std::string which =
        "--betas: value b" + std::to_string(values.size()) + " = '" + item + "'";
    double value = 0.0;
    try {
      size_t used = 0;
      value = std::stod(item, &used);
      if (used != item.size()) throw std::invalid_argument(item);
    } catch (const std::out_of_range&) {
      throw InputError(which + " is out of range (" + range + ")");
    } catch (const std::exception&) {
      throw InputError(which + " is not a number (" + range + ")");
    }
    if (!std::isfinite(value)) throw InputError(which + " is not finite (" + range + ")");
    if (std::abs(value) > kMaxShapeCoefficient)
      throw InputError(which + " is out of range (" + range + ")");
    values.push_back(value);
  }
  if (values.empty()) throw InputError("--betas: " + range + ", got '" + text + "'");
  return Eigen::Map<VecX>(values.data(), long(values.size()));
}

/// Throws InputError naming `what` unless `value` is a finite number in [lo, hi] (open at lo
/// when `open_lo`), with `unit` in the message.
void checkRange(const std::string& what, double value, double lo, double hi, bool open_lo,
                const std::string& unit) {
  const bool ok = std::isfinite(value) && (open_lo ? value > lo : value >= lo) && value <= hi;
  if (!ok)
    throw InputError(what + ": expected " + number(lo) + (open_lo ? " < " : " <= ") +
                     "value <= " + number(hi) + (unit.empty() ? "" : " (" + unit + ")") + ", got " +
                     number(value));
}

/// Throws InputError unless a built-in motion of `seconds` at `fps` has at most
/// kMaxMotionFrames frames; `what` names the options.
void checkMotionLength(const std::string& what, double seconds, double fps) {
  const double frames = std::round(seconds * fps) + 1;
  if (!(frames <= kMaxMotionFrames))
    throw InputError(what + ": " + number(seconds) + " s at " + number(fps) + " fps is " +
                     number(frames) + " frames, expected at most " + number(kMaxMotionFrames) +
                     " (seconds x fps <= " + number(kMaxMotionFrames - 1) + ")");
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
  checkRange("--vertices", vertices, kMinSyntheticVertices, kMaxSyntheticVertices, false, "");
  checkRange("--height", height, kMinSyntheticHeight, kMaxSyntheticHeight, false, "m");
  io::checkOutputFile(out, "--out");
  SyntheticBodyOptions options;
  options.vertices = vertices;
  options.height = height;
  const BodyModel body = makeSyntheticBody(options);
  saveBodyModel(body, out);
  std::printf(
      "synth-body: wrote %s (%d vertices, %d faces, %d joints, %d shape directions) in %.2f s\n",
      out.c_str(), body.numVertices(), body.numFaces(), body.numJoints(), body.numBetas(),
      secondsSince(t0));
  return 0;
}

int cmdMotion(const std::string& name, const std::string& out, double seconds, double fps,
              const std::string& up) {
  checkRange("--seconds", seconds, 0.0, kMaxMotionFrames, false, "s");
  checkRange("--fps", fps, 0.0, 1000.0, true, "frames per second");
  checkMotionLength("--seconds, --fps", seconds, fps);
  io::checkOutputFile(out, "--out");
  const Motion motion = makeBuiltinMotion(name, seconds, fps);
  saveMotion(motion, out, up.empty() ? "y" : up);
  std::printf("motion: wrote %s (%s, %d frames at %g fps, %s up)\n", out.c_str(), name.c_str(),
              motion.numFrames(), motion.fps, up.empty() ? "y" : up.c_str());
  return 0;
}

int cmdPose(const std::string& model_path, const std::string& motion_spec, const std::string& out,
            const std::string& betas_text, const std::string& up) {
  const auto t0 = Clock::now();
  const VecX given_betas = betas_text.empty() ? VecX() : parseBetas(betas_text);
  io::checkOutputFile(out, "--out");
  const BodyModel model = loadBodyModel(model_path);
  const Motion motion = loadOrMakeMotion(motion_spec, 2.0, 30.0, up);
  const std::string motion_name = motion.source.empty() ? "--motion " + motion_spec : motion.source;
  io::checkMotionValues(motion, motion_name);
  // Each input is checked where it enters: the motion's own betas name the motion file.
  std::string warning;
  const VecX betas = io::fitBetas(betas_text.empty() ? motion.betas : given_betas, model,
                                  betas_text.empty() ? motion_name : "--betas", &warning);
  if (!warning.empty()) std::fprintf(stderr, "flsh: warning: %s\n", warning.c_str());
  if (betas_text.empty()) checkShapeCoefficients(betas, motion_name + ": betas");
  checkMemory(motion_name, double(motion.numFrames()) * model.numVertices() * 3 * 8 * 2.0,
              "pose a shorter motion (vertices of every frame are kept, then written)");
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
  int elastic_cubature = ReducedSettings().elastic_cubature_points;    ///< 0 = off
  int inertial_cubature = ReducedSettings().inertial_cubature_points;  ///< 0 = off
  bool partition_of_unity = false;  ///< ReducedSettings::surface_partition_of_unity
  std::string basis = reducedBasisKindName(ReducedSettings().basis_kind);
  int vibration_modes = ReducedSettings().modes.vibration_modes;
  int modal_columns = ReducedSettings().modes.columns;  ///< 0 = every column
  bool reduced_options_given = false;
  bool basis_given = false, handles_given = false, modal_options_given = false;
};

// Builds (or loads) an avatar and prints its statistics as JSON on stdout.
int cmdAvatar(const AvatarArgs& args) {
  const auto t0 = Clock::now();
  // Options first (as the scene keys resolution, handles, elastic_cubature, inertial_cubature).
  if (!args.betas.empty()) parseBetas(args.betas);
  if (args.soft != "none" && args.soft != "fem" && args.soft != "rom")
    throw InputError("--soft: expected fem or rom (or none: the skeleton), got '" + args.soft +
                     "'");
  checkRange("--resolution", args.resolution, 0.01, 100.0, false,
             "interior node density relative to the default");
  if (args.reduced_options_given && args.soft != "rom")
    throw InputError(
        "--preset, --handles, --elastic-cubature, --inertial-cubature, --partition-of-unity, "
        "--basis, --vibration-modes and --modal-columns are only for --soft rom, got --soft " +
        args.soft);
  // As in scene files: --handles without --basis chooses the handle basis (the modal basis,
  // the default, has no handles).
  const ReducedBasisKind basis = args.basis_given     ? parseReducedBasisKind(args.basis, "--basis")
                                 : args.handles_given ? ReducedBasisKind::Handles
                                                      : ReducedSettings().basis_kind;
  if (args.handles_given && basis == ReducedBasisKind::Modes)
    throw InputError(
        "--handles: not used by --basis modes (handles belong to --basis handles or "
        "modes+handles)");
  if (args.modal_options_given && basis == ReducedBasisKind::Handles)
    throw InputError(
        std::string("--vibration-modes and --modal-columns: only for --basis modes "
                    "or modes+handles") +
        (args.basis_given ? "" : " (--handles without --basis chooses the handle basis)"));
  checkRange("--vibration-modes", args.vibration_modes, 0, 100000, false, "an integer");
  checkRange("--modal-columns", args.modal_columns, 0, 100000, false, "an integer, 0 = all");
  checkRange("--handles", args.handles, 1, 100000, false, "an integer");
  checkRange("--elastic-cubature", args.elastic_cubature, 0, 1e7, false, "sample tets, 0 = off");
  checkRange("--inertial-cubature", args.inertial_cubature, 0, 1e7, false, "sample tets, 0 = off");
  if (!args.cache.empty() && std::filesystem::exists(args.cache) &&
      !std::filesystem::is_directory(args.cache))
    throw InputError("--cache: '" + args.cache + "' is a file, expected a folder");
  std::shared_ptr<const BodyModel> body;
  if (args.model.rfind("synthetic", 0) == 0) {
    // "synthetic" or "synthetic:N": the built-in synthetic body (N vertices, default 6890).
    SyntheticBodyOptions options;
    if (args.model.size() > 9) {
      if (args.model[9] != ':')
        throw InputError("--model: expected a .npz path, 'synthetic' or 'synthetic:N', got '" +
                         args.model + "'");
      const std::string count = args.model.substr(10);
      size_t used = 0;
      try {
        options.vertices = std::stoi(count, &used);
      } catch (const std::exception&) {
        used = 0;
      }
      if (used == 0 || used != count.size())
        throw InputError("--model: '" + count + "' is not a vertex count (synthetic:N, N in [" +
                         std::to_string(kMinSyntheticVertices) + ", " +
                         std::to_string(kMaxSyntheticVertices) + "])");
      checkRange("--model synthetic:N", options.vertices, kMinSyntheticVertices,
                 kMaxSyntheticVertices, false, "vertices");
    }
    body = std::make_shared<const BodyModel>(makeSyntheticBody(options));
  } else {
    body = std::make_shared<const BodyModel>(loadBodyModel(args.model));
  }
  const double load_seconds = secondsSince(t0);
  std::string warning;
  const VecX betas = args.betas.empty()
                         ? VecX::Zero(body->numBetas())
                         : io::fitBetas(parseBetas(args.betas), *body, "--betas", &warning);
  if (!warning.empty()) std::fprintf(stderr, "flsh: warning: %s\n", warning.c_str());

  SoftAvatarSettings settings;
  settings.volumetric.tet_mesh.resolution = args.resolution;
  settings.volumetric.material_file = args.materials;
  settings.volumetric.cache_dir = args.cache;
  settings.volumetric.use_cache = !args.no_cache;
  io::setReducedSettings(settings.reduced, args.handles, args.elastic_cubature,
                         args.inertial_cubature, args.partition_of_unity, basis,
                         args.vibration_modes, args.modal_columns);
  SoftAvatar avatar(body, betas, settings);
  avatar.enableSoftTissue(args.soft != "none");
  if (args.soft == "rom")
    io::enableReducedModel(avatar, args.elastic_cubature, args.inertial_cubature);
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
  out["betas"] =
      std::vector<double>(avatar.betas().data(), avatar.betas().data() + avatar.betas().size());
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
    out["cache"] = {{"directory", used ? AvatarCache(args.cache).directory() : std::string()},
                    {"template", !used                   ? "off"
                                 : r.template_from_cache ? "hit"
                                                         : "miss"},
                    {"shape", !used               ? "off"
                              : r.data_from_cache ? "hit"
                                                  : "miss"},
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
    reduced["basis"] = reducedBasisKindName(d.basis_kind);
    reduced["handles"] = d.numHandles();
    reduced["modes"] = d.numModes();
    reduced["dofs"] = 6 * kNumJoints + d.numSoftDofs();
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
  checkRange("--vertices", vertices, kMinSyntheticVertices, kMaxSyntheticVertices, false, "");
  checkRange("--seconds", seconds, 0.0, kMaxMotionFrames, false, "s");
  const double fps = 30.0;
  checkMotionLength("--seconds", seconds, fps);
  // The posed vertices, in memory and in posed.npz's buffer.
  checkMemory("--seconds, --vertices", (std::round(seconds * fps) + 1) * vertices * 3 * 8 * 2.0,
              "shorten --seconds or use fewer --vertices");
  const Motion motion = makeBuiltinMotion(motion_name, seconds, fps);
  // Everything goes to a staging folder beside --out, which replaces it at the end.
  io::StagedOutputDir out(
      out_dir,
      {io::OutputEntry::file("body.npz"), io::OutputEntry::file("motion.npz"),
       io::OutputEntry::file("posed.npz"), io::OutputEntry::folderOf("meshes", ".ply"),
       io::OutputEntry::file("sheet.png")},
      "--out");
  SyntheticBodyOptions options;
  options.vertices = vertices;
  std::printf("demo: generating the synthetic body (%d vertices)...\n", vertices);
  std::fflush(stdout);
  const BodyModel body = makeSyntheticBody(options);
  saveBodyModel(body, out.path("body.npz"));
  saveMotion(motion, out.path("motion.npz"));
  const VecX betas = VecX::Zero(body.numBetas());
  const PosedBatch batch = poseBodyBatch(body, betas, motion.poses, motion.trans);
  writePosedNpz(out.path("posed.npz"), batch, body.numVertices(), betas, motion.fps);
  const int T = motion.numFrames(), V = body.numVertices();
  auto frame = [&](int t) {
    return MatX3(Eigen::Map<const MatX3>(batch.vertices.row(t).data(), V, 3));
  };
  io::ensureDirectory(out.path("meshes"));
  for (int t = 0; t < T; ++t) {
    char name[64];
    std::snprintf(name, sizeof(name), "meshes/frame_%04d.ply", t);
    io::writePly(out.path(name), frame(t), body.faces);
  }
  // A sheet of five evenly spaced frames.
  const int shown = std::min(5, T);
  std::vector<MatX3> picked;
  for (int k = 0; k < shown; ++k)
    picked.push_back(frame(shown > 1 ? k * (T - 1) / (shown - 1) : 0));
  render::RenderOptions view;
  view.width = 320;
  view.height = 480;
  render::writePng(out.path("sheet.png"), render::renderSheet(picked, body.faces, view));
  out.commit();
  const fs::path dir(out_dir);
  std::printf(
      "demo: posed the synthetic body through '%s' (%d frames): %s/{body,motion,posed}.npz, "
      "%d meshes in %s, picture %s; %.2f s\n",
      motion_name.c_str(), T, out_dir.c_str(), T, (dir / "meshes").string().c_str(),
      (dir / "sheet.png").string().c_str(), secondsSince(t0));
  return 0;
}

// ---------------------------------------------------------------------------------------------
// flsh simulate

int cmdSimulate(const std::string& scene_path, const SceneOverrides& overrides) {
  // Everything is read and checked before anything is written (io::runScene).
  const SceneSpec scene =
      scene_path.empty() ? defaultScene(overrides) : loadSceneFile(scene_path, overrides);
  io::SceneRunOptions options;
  options.log = [](const std::string& line) {
    std::fprintf(stderr, "simulate: %s\n", line.c_str());
  };
  options.progress_bar = true;
  if (!overrides.output_dir.empty()) options.output_dir_origin = "--out";
  const io::SceneRunReport report = io::runScene(scene, options);
  const std::string warning = report.unconvergedWarning();
  if (!warning.empty()) std::fprintf(stderr, "simulate: warning: %s\n", warning.c_str());
  std::printf("%s", report.summary().c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"flsh: differentiable physics of SMPL human bodies"};
  app.require_subcommand(1);

  std::string out, model, motion_spec, betas, up, name = "walk", demo_out = "out/demo";
  int vertices = 6890;
  double height = 1.70, seconds = 2.0, fps = 30.0;

  auto* synth = app.add_subcommand("synth-body", "Write a synthetic SMPL-format body (.npz)");
  synth->add_option("--out", out, "output .npz file")->required();
  synth->add_option("--vertices", vertices, "number of surface vertices")->capture_default_str();
  synth->add_option("--height", height, "standing height in T-pose, m")->capture_default_str();

  auto* motion = app.add_subcommand("motion", "Write a built-in motion as an AMASS-style .npz");
  motion
      ->add_option(
          "--name", name,
          "built-in motion: " +
              [] {
                std::string s;
                for (const auto& n : builtinMotionNames()) s += (s.empty() ? "" : ", ") + n;
                return s;
              }())
      ->capture_default_str();
  motion->add_option("--out", out, "output .npz file")->required();
  motion->add_option("--seconds", seconds, "duration, s")->capture_default_str();
  motion->add_option("--fps", fps, "frames per second")->capture_default_str();
  motion
      ->add_option("--up", up,
                   "frame to write the motion in: y (flsh's world, default) or z (as AMASS stores "
                   "clips); the file's 'up' key says which")
      ->check(CLI::IsMember({"y", "z"}));

  auto* pose =
      app.add_subcommand("pose", "Pose a body through a motion: vertices and joints per frame");
  pose->add_option("--model", model, "SMPL-format body model (.npz)")->required();
  pose->add_option("--motion", motion_spec, "AMASS-style .npz, or builtin:NAME")->required();
  pose->add_option("--out", out, "output .npz with vertices (T,V,3) and joints (T,24,3)")
      ->required();
  pose->add_option("--betas", betas, "shape coefficients b0,b1,… (default: the motion's betas)");
  pose->add_option("--up", up,
                   "up axis the motion file was recorded in, y or z (default: the file's 'up' "
                   "key, else z as AMASS); the output is in flsh's y-up world")
      ->check(CLI::IsMember({"y", "z"}));

  auto* demo = app.add_subcommand(
      "demo", "Default job: synthetic body through a built-in motion, meshes and a picture");
  demo->add_option("--out", demo_out, "output directory")->capture_default_str();
  demo->add_option("--vertices", vertices, "vertices of the synthetic body")->capture_default_str();
  demo->add_option("--motion", name, "built-in motion")->capture_default_str();
  demo->add_option("--seconds", seconds, "duration, s")->capture_default_str();

  std::string scene_path, sim_out;
  double duration = 0.0, time_step = 0.0;
  auto* simulate =
      app.add_subcommand("simulate",
                         "Main job: simulate a scene (default: a synthetic walker hit by a ball); "
                         "writes PLY meshes, states.npz, animation.glb and sheet.png");
  simulate->add_option("scene", scene_path,
                       "scene file (.json, see docs/scene_format.md); "
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
  avatar
      ->add_option("--model", avatar_args.model,
                   "SMPL-format body (.npz), or synthetic[:VERTICES] for the built-in body")
      ->required();
  avatar->add_option("--betas", avatar_args.betas, "shape coefficients b0,b1,… (default: zeros)");
  avatar
      ->add_option("--soft", avatar_args.soft,
                   "soft-tissue model: fem, rom, or none (the articulated skeleton)")
      ->capture_default_str();
  avatar->add_option("--cache", avatar_args.cache,
                     "cache directory (default: $FLSH_CACHE_DIR, else ~/.cache/flsh)");
  avatar->add_flag("--no-cache", avatar_args.no_cache, "neither read nor write the cache");
  avatar
      ->add_option("--resolution", avatar_args.resolution,
                   "interior node density of the tet mesh relative to the default")
      ->capture_default_str();
  avatar->add_option("--materials", avatar_args.materials,
                     "material file (JSON, docs/materials.md; default: built-in coefficients)");
  auto* handles_option =
      avatar
          ->add_option("--handles", avatar_args.handles,
                       "--soft rom: point handles of the reduced basis (without --basis: "
                       "the handle basis)")
          ->capture_default_str();
  auto* elastic_option =
      avatar
          ->add_option("--elastic-cubature", avatar_args.elastic_cubature,
                       "--soft rom: sample tets of the elastic cubature (0 = off, exact)")
          ->capture_default_str();
  auto* inertial_option =
      avatar
          ->add_option("--inertial-cubature", avatar_args.inertial_cubature,
                       "--soft rom: sample tets of the inertial cubature (0 = off, exact)")
          ->capture_default_str();
  auto* pou_option =
      avatar->add_flag("--partition-of-unity", avatar_args.partition_of_unity,
                       "--soft rom: basis rescaled to sum to 1 on the soft surface (docs/rom.md)");
  std::string preset_name;
  auto* preset_option = avatar->add_option(
      "--preset", preset_name,
      "--soft rom: realtime (modes 12:24, 100-tet cubatures; flsh/io/presets.h); the options "
      "given beside it win");
  auto* basis_option = avatar
                           ->add_option("--basis", avatar_args.basis,
                                        "--soft rom: handles, modes or modes+handles (docs/rom.md)")
                           ->capture_default_str();
  auto* vibration_option =
      avatar
          ->add_option("--vibration-modes", avatar_args.vibration_modes,
                       "--soft rom with modes: fixed-interface vibration modes")
          ->capture_default_str();
  auto* columns_option =
      avatar
          ->add_option("--modal-columns", avatar_args.modal_columns,
                       "--soft rom with modes: columns kept by compression (0 = all)")
          ->capture_default_str();

  // CLI11's own exit codes (104, 106, 109, …) for a bad command line become 2, like every
  // other input error; --help exits 0.
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);  // prints the message (or the help)
    return code == 0 ? 0 : 2;
  }
  const std::string command = app.get_subcommands().front()->get_name();
  try {
    if (command == "synth-body") return cmdSynthBody(out, vertices, height);
    if (command == "motion") return cmdMotion(name, out, seconds, fps, up);
    if (command == "pose") return cmdPose(model, motion_spec, out, betas, up);
    if (command == "demo") return cmdDemo(demo_out, vertices, name, seconds);
    if (command == "avatar") {
      if (preset_option->count() > 0) {  // the preset's defaults under the options given
        const ReducedSettings r = presetReducedSettings(parsePreset(preset_name, "--preset"));
        if (basis_option->count() == 0 && handles_option->count() == 0)
          avatar_args.basis = reducedBasisKindName(r.basis_kind);
        if (vibration_option->count() == 0) avatar_args.vibration_modes = r.modes.vibration_modes;
        if (columns_option->count() == 0) avatar_args.modal_columns = r.modes.columns;
        if (elastic_option->count() == 0) avatar_args.elastic_cubature = r.elastic_cubature_points;
        if (inertial_option->count() == 0)
          avatar_args.inertial_cubature = r.inertial_cubature_points;
      }
      avatar_args.reduced_options_given = preset_option->count() + handles_option->count() +
                                              elastic_option->count() + inertial_option->count() +
                                              pou_option->count() + basis_option->count() +
                                              vibration_option->count() + columns_option->count() >
                                          0;
      avatar_args.basis_given =
          basis_option->count() > 0 || (preset_option->count() > 0 && handles_option->count() == 0);
      avatar_args.handles_given = handles_option->count() > 0;
      avatar_args.modal_options_given = vibration_option->count() + columns_option->count() > 0;
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
      if (!sim_cache.empty() && std::filesystem::exists(sim_cache) &&
          !std::filesystem::is_directory(sim_cache))
        throw InputError("--cache: '" + sim_cache + "' is a file, expected a folder");
      if (!sim_cache.empty() && std::filesystem::exists(sim_cache) &&
          !std::filesystem::is_directory(sim_cache))
        throw InputError("--cache: '" + sim_cache + "' is a file, expected a folder");
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
  } catch (const std::bad_alloc&) {
    std::fprintf(stderr,
                 "flsh %s: error: out of memory: the inputs need more memory than this "
                 "machine has (use a smaller body, a shorter motion or fewer saved frames)\n",
                 command.c_str());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "flsh %s: internal error: %s\n", command.c_str(), e.what());
    return 3;
  }
  return 1;
}
