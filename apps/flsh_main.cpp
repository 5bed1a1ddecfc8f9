// The `flsh` command-line program.
//
//   flsh synth-body --out BODY.npz [--vertices N] [--height M]
//   flsh motion --name walk --out MOTION.npz [--seconds S] [--fps F]
//   flsh pose --model BODY.npz --motion MOTION.npz --out OUT.npz [--betas b0,b1,…]
//   flsh demo [--out DIR] [--vertices N] [--motion NAME]
//
// Every command prints a one-line summary on success, and on bad input exits non-zero with a
// message naming the input, leaving no partial output file (all writes are atomic).
#include <CLI/CLI.hpp>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <sstream>

#include "flsh/body/body_forward.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/core/error.h"
#include "flsh/io/atomic_file.h"
#include "flsh/io/mesh_io.h"
#include "flsh/io/motion.h"
#include "flsh/io/npz.h"
#include "flsh/render/render.h"

namespace {

using namespace flsh;
using Clock = std::chrono::steady_clock;

double secondsSince(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
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
  io::ensureDirectory(mesh_dir.string());
  const int T = motion.numFrames(), V = body.numVertices();
  std::vector<MatX3> frames(T);
  for (int t = 0; t < T; ++t) {
    frames[t] = Eigen::Map<const MatX3>(batch.vertices.row(t).data(), V, 3);
    char name[64];
    std::snprintf(name, sizeof(name), "frame_%04d.ply", t);
    io::writePly((mesh_dir / name).string(), frames[t], body.faces);
  }
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

  CLI11_PARSE(app, argc, argv);
  const std::string command = app.get_subcommands().front()->get_name();
  try {
    if (command == "synth-body") return cmdSynthBody(out, vertices, height);
    if (command == "motion") return cmdMotion(name, out, seconds, fps);
    if (command == "pose") return cmdPose(model, motion_spec, out, betas);
    if (command == "demo") return cmdDemo(demo_out, vertices, name, seconds);
  } catch (const flsh::Error& e) {
    std::fprintf(stderr, "flsh %s: error: %s\n", command.c_str(), e.what());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "flsh %s: internal error: %s\n", command.c_str(), e.what());
    return 3;
  }
  return 1;
}
