// Stability sweep of the three models (issue 23, part 4): the articulated skeleton, the FEM soft
// skeleton and the ROM soft skeleton, each run over families of cases varied from one base case,
// with a table of what stayed finite, bounded and converged.
//
// Base case: the synthetic body with 1000 surface vertices (soft models: tet-mesh resolution 0.5,
// the ROM with 16 handles and 60 + 60 cubature tets trained on 80 samples, the small soft avatar
// of tests/support), tracking the built-in walk, a ground plane 2 mm under the lowest vertex,
// h = 1/30 s, the scene's default Newton settings for the model. Families (each case changes one
// thing of the base case):
//   h          time step 1e-4, 1e-3, 1/60, 1/30, 0.1 s;
//   stiffness  joint, tracking and root springs scaled together by 1e-3 … 1e3; for the soft models
//              also the tissue's elastic moduli (E1–E3 and G12–G23 of skin and soft tissue, in a
//              material file written from MaterialModel::defaults; Poisson ratios, density and
//              Fung exponent unchanged);
//   beta       each shape component at −5 and at +5 (the others 0);
//   ball       a sphere (r = 12 cm) hitting the belly at 1, 5, 20 m/s relative to the walking body:
//              it starts 2 cm in front of the belly, goes 8 cm past the belly's surface, stays
//              there 0.1 s and goes back at the same speed (it follows the walk's translation);
//              the same three speeds again at h = 1e-3 s ("20@1e-3"): the ball is a kinematic
//              collider and contact is evaluated at the steps' ends, so at h = 1/30 s the 5 and
//              20 m/s balls are at the same places at every step (both at full depth by the
//              first step's end);
//   ground     the ground plane 0.3 m above the lowest vertex (the feet start 0.3 m inside it);
//   pi         a few joints (elbows, knees, shoulders, neck, or all of these) turned from 0 to
//              π − 0.01 ("pi-0.01") or to π + 0.3 ("through", passing π at 0.28 s) over 0.3 s and
//              held, on top of the walk;
//   fast       walk and jumping_jacks played 5× fast (Motion::fps × 5).
// Every run simulates 0.5 s (--duration), capped to 40 steps (--steps): so h = 1e-4 and 1e-3 run
// 40 steps (4 ms and 40 ms), 1/60 30 steps, 1/30 15 and 0.1 5.
//
// Per run, after every step: finite = the state, every node (getVolumeNodes: every tet node of
// the soft models, the surface vertices of the skeleton) and every output vertex (getVertices)
// finite; bounded = every node within kMaxDistance (10 m) of the root's mocap target and no node
// faster than kMaxSpeed (100 m/s: 5× the fastest ball and about 5× the fastest node of the runs
// that stay well behaved, 21 m/s in the 5× walk) over the step. A step converged when Newton says
// so (NewtonResult::converged) and its final ‖g‖∞ is at most kMaxConvergedResidual (10 N or N·m;
// converged steps of the base case end below 1e-2): Newton's tolerance is relative to the
// gradient at the step's initial guess, so a step that starts where that gradient is huge can be
// reported converged with forces of 1e20 N left ("falsely converged" below). A step "needed a
// fallback" when it did not converge (either way), Newton shifted the Hessian's diagonal
// (NewtonResult::regularizations) or halved the line search more than kMaxHalvings (5) times in
// the step. PSD-form iterations (NewtonResult::psd_fallbacks) are listed apart: the skeleton's
// come from an exact Hessian that is not positive definite, while the soft models' lagged factor
// is always of the PSD form, so every factor refresh counts there. An exception is "non-finite"
// when it reports a NaN / non-finite value (or is not a flsh::Error), else "refused" (a clear
// flsh::Error for an input the library does not take, e.g. a shape whose tet mesh inverts); a
// refused run is left out of the percentages.
//
// Usage: stability_benchmark [--models skeleton,fem,rom] [--families h,stiffness,...]
//                            [--steps N] [--duration S] [--model M --family F --value V]
//                            [--cache-dir DIR] [--threads N] [--no-tissue-scale] [--verbose]
//                            [--list]
//   --model/--family/--value: run the matching cases only (e.g. --model fem --family h
//       --value 0.1; --value is the case's label, compared per ':'-separated part as text or as a
//       number, so 1e-4 = 0.0001 and 1/60 = 0.016667; beta labels are "K:±5", pi labels
//       "GROUP:pi-0.01" or "GROUP:through"); --verbose prints every step;
//   --threads: OpenMP threads (default 1: on this shared 2-core machine, with other jobs running,
//       2 threads made the FEM's base case 7x and the ROM's 17x slower than 1 thread);
//   --cache-dir: the avatar cache (tet meshes, ROM data, scaled material files); default
//       /tmp/flsh_stability_cache;
//   --no-tissue-scale: the stiffness family scales only the springs;
//   --list: print the cases and exit.
// Prints one line per run, the table (rows model × family) in Markdown, the runs to look at with
// the command that reproduces each, the command line and the wall time. Exit status 1 when a run
// went non-finite or unbounded.
#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "flsh/body/motion.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/core/error.h"
#include "flsh/solve/scene.h"
#include "flsh/volume/materials.h"

namespace {

using namespace flsh;
using Clock = std::chrono::steady_clock;

constexpr double kPi = 3.14159265358979323846;
constexpr double kMaxDistance = 10.0;  // m from the root's target
constexpr double kMaxSpeed = 100.0;    // m/s, any node
constexpr int kMaxHalvings = 5;        // line-search halvings per step before it counts
// ‖g‖∞ (N or N·m) above which a step Newton calls converged is counted as falsely converged.
constexpr double kMaxConvergedResidual = 10.0;
constexpr int kBodyVertices = 1000;

double seconds(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

std::string format(const char* fmt, double a) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), fmt, a);
  return buf;
}

enum class Model { Skeleton, Fem, Rom };
const char* modelName(Model m) {
  return m == Model::Skeleton ? "skeleton" : m == Model::Fem ? "fem" : "rom";
}

const std::vector<std::string> kFamilies = {"h",      "stiffness", "beta", "ball",
                                            "ground", "pi",        "fast"};

// ---- cases -----------------------------------------------------------------------------------

struct Case {
  std::string family, value;  // value: the label --value matches
  double h = 1.0 / 30.0;
  double stiffness_scale = 1.0;
  int beta_index = -1;  // −1: β = 0
  double beta_value = 0.0;
  double ball_speed = 0.0;       // m/s relative to the body; 0: no ball
  double ground_raise = -0.002;  // plane height above the lowest vertex, m
  std::string motion = "walk";
  double fps_scale = 1.0;
  std::string pi_group;  // "": none
  double pi_angle = 0.0;
  std::string describe() const;
};

std::string Case::describe() const {
  if (family == "h") return "h = " + value + " s";
  if (family == "stiffness") return "springs (and tissue) x" + value;
  if (family == "beta")
    return "beta[" + std::to_string(beta_index) + "] (" + kSyntheticShapeNames[size_t(beta_index)] +
           ") = " + format("%+g", beta_value);
  if (family == "ball")
    return "ball at " + format("%g", ball_speed) + " m/s into the belly" +
           (h == 1e-3 ? " (h = 1e-3 s)" : "");
  if (family == "ground") return "feet 0.3 m inside the ground";
  if (family == "pi") return value + " (rad; joints near pi)";
  if (family == "fast") return motion + " at 5x speed";
  return family + " " + value;
}

// The π family's joint groups: SMPL joints and the axis each turns about (flexion).
struct PiJoint {
  const char* name;
  Vec3 axis;
};
std::vector<PiJoint> piJoints(const std::string& group) {
  std::vector<PiJoint> j;
  if (group == "elbows" || group == "all") {
    j.push_back({"left_elbow", Vec3(0, -1, 0)});
    j.push_back({"right_elbow", Vec3(0, 1, 0)});
  }
  if (group == "knees" || group == "all") {
    j.push_back({"left_knee", Vec3(1, 0, 0)});
    j.push_back({"right_knee", Vec3(1, 0, 0)});
  }
  if (group == "shoulders" || group == "all") {
    j.push_back({"left_shoulder", Vec3(0, 0, 1)});
    j.push_back({"right_shoulder", Vec3(0, 0, -1)});
  }
  if (group == "neck" || group == "all") j.push_back({"neck", Vec3(1, 0, 0)});
  return j;
}

std::vector<Case> allCases(int num_betas) {
  std::vector<Case> cases;
  const Case base;
  for (const auto& [label, h] : std::vector<std::pair<std::string, double>>{
           {"1e-4", 1e-4}, {"1e-3", 1e-3}, {"1/60", 1.0 / 60}, {"1/30", 1.0 / 30}, {"0.1", 0.1}}) {
    Case c = base;
    c.family = "h";
    c.value = label;
    c.h = h;
    cases.push_back(c);
  }
  for (const auto& [label, s] : std::vector<std::pair<std::string, double>>{{"1e-3", 1e-3},
                                                                            {"1e-2", 1e-2},
                                                                            {"0.1", 0.1},
                                                                            {"1", 1.0},
                                                                            {"10", 10.0},
                                                                            {"1e2", 1e2},
                                                                            {"1e3", 1e3}}) {
    Case c = base;
    c.family = "stiffness";
    c.value = label;
    c.stiffness_scale = s;
    cases.push_back(c);
  }
  for (int k = 0; k < num_betas; ++k)
    for (double b : {-5.0, 5.0}) {
      Case c = base;
      c.family = "beta";
      c.value = std::to_string(k) + (b < 0 ? ":-5" : ":+5");
      c.beta_index = k;
      c.beta_value = b;
      cases.push_back(c);
    }
  // At h = 1/30 s the 5 and 20 m/s balls are at the same places at every step's end (both reach
  // their full depth within the first step): the same speeds again at h = 1e-3 s.
  for (double h : {1.0 / 30, 1e-3})
    for (double v : {1.0, 5.0, 20.0}) {
      Case c = base;
      c.family = "ball";
      c.value = format("%g", v) + (h == 1e-3 ? "@1e-3" : "");
      c.ball_speed = v;
      c.h = h;
      cases.push_back(c);
    }
  {
    Case c = base;
    c.family = "ground";
    c.value = "0.3";
    c.ground_raise = 0.3;
    cases.push_back(c);
  }
  for (const char* group : {"elbows", "knees", "shoulders", "neck", "all"})
    for (bool through : {false, true}) {
      Case c = base;
      c.family = "pi";
      c.pi_group = group;
      c.value = std::string(group) + (through ? ":through" : ":pi-0.01");
      c.pi_angle = through ? kPi + 0.3 : kPi - 0.01;
      cases.push_back(c);
    }
  for (const char* m : {"walk", "jumping_jacks"}) {
    Case c = base;
    c.family = "fast";
    c.value = m;
    c.motion = m;
    c.fps_scale = 5.0;
    cases.push_back(c);
  }
  return cases;
}

// "1/60" → 0.01667, "1e-4" → 1e-4; false when `text` is not a number.
bool parseNumber(const std::string& text, double& x) {
  const size_t slash = text.find('/');
  char* end = nullptr;
  if (slash != std::string::npos) {
    double a = 0, b = 0;
    if (!parseNumber(text.substr(0, slash), a) || !parseNumber(text.substr(slash + 1), b) || b == 0)
      return false;
    x = a / b;
    return true;
  }
  if (text.empty()) return false;
  x = std::strtod(text.c_str(), &end);
  return end && *end == '\0';
}

std::vector<std::string> split(const std::string& text, char sep) {
  std::vector<std::string> parts;
  size_t start = 0;
  for (size_t at; (at = text.find(sep, start)) != std::string::npos; start = at + 1)
    parts.push_back(text.substr(start, at - start));
  parts.push_back(text.substr(start));
  return parts;
}

bool valueMatches(const std::string& label, const std::string& wanted) {
  const auto a = split(label, ':'), b = split(wanted, ':');
  if (a.size() != b.size()) return false;
  for (size_t k = 0; k < a.size(); ++k) {
    double x = 0, y = 0;
    if (a[k] == b[k]) continue;
    if (parseNumber(a[k], x) && parseNumber(b[k], y) &&
        std::abs(x - y) <= 1e-9 * std::max(std::abs(x), std::abs(y)))
      continue;
    return false;
  }
  return true;
}

// ---- avatars (built once per model, β and tissue scale) -------------------------------------

struct Avatars {
  std::shared_ptr<const BodyModel> body;
  std::string cache_dir;
  bool tissue_scale = true;
  std::map<std::string, std::shared_ptr<const SoftAvatar>> built;
  std::map<std::string, double> build_seconds;

  // A material file with every elastic modulus of both layers scaled (empty for scale 1).
  std::string materialFile(double scale) {
    if (scale == 1.0) return "";
    MaterialModel m = MaterialModel::defaults(body->numBetas());
    for (int layer : {MaterialModel::kSkin, MaterialModel::kSoftTissue})
      for (const char* q : {"E1", "E2", "E3", "G12", "G13", "G23"})
        m.setCoefficient(q, layer, scale * m.baseValue(q, layer), m.logSlopes(q, layer));
    std::filesystem::create_directories(cache_dir);
    const std::string path = cache_dir + "/materials_x" + format("%g", scale) + ".json";
    m.save(path);
    return path;
  }

  std::shared_ptr<const SoftAvatar> get(Model model, const Case& c) {
    VecX betas = VecX::Zero(body->numBetas());
    if (c.beta_index >= 0) betas[c.beta_index] = c.beta_value;
    const double tissue = model != Model::Skeleton && tissue_scale ? c.stiffness_scale : 1.0;
    const std::string key = std::string(modelName(model)) + " beta " +
                            std::to_string(c.beta_index) + format(" %g", c.beta_value) +
                            " tissue " + format("%g", tissue);
    auto it = built.find(key);
    if (it != built.end()) return it->second;
    const auto t0 = Clock::now();
    SoftAvatarSettings settings;
    settings.voxel_size = 0.02;
    settings.volumetric.cache_dir = cache_dir;
    settings.volumetric.tet_mesh.resolution = 0.5;
    settings.volumetric.material_file = materialFile(tissue);
    settings.reduced.basis_kind = ReducedBasisKind::Handles;
    settings.reduced.num_handles = 16;
    settings.reduced.elastic_cubature_points = 60;
    settings.reduced.inertial_cubature_points = 60;
    settings.reduced.training_samples = 80;
    auto avatar = std::make_shared<SoftAvatar>(body, betas, settings);
    if (model != Model::Skeleton) avatar->enableSoftTissue();
    if (model == Model::Rom) {
      avatar->enableReducedModel();
      avatar->enableElasticCubature();
      avatar->enableInertialCubature();
    }
    avatar->initVolumetricData();
    build_seconds[key] = seconds(t0, Clock::now());
    built[key] = avatar;
    return avatar;
  }
};

// ---- motions and colliders --------------------------------------------------------------------

std::shared_ptr<const Motion> makeMotion(const Case& c, double duration) {
  // Longer than the run, played fps_scale times faster.
  const double length = std::max(4.0, (duration + 1.0) * c.fps_scale);
  auto m = std::make_shared<Motion>(makeBuiltinMotion(c.motion, length, 30.0));
  m->fps *= c.fps_scale;
  if (!c.pi_group.empty()) {
    // θ(t) = θ_max · min(1, t / 0.3 s) about each joint's flexion axis, replacing the walk's.
    for (int f = 0; f < m->numFrames(); ++f) {
      const double theta = c.pi_angle * std::min(1.0, (f / m->fps) / 0.3);
      for (const PiJoint& j : piJoints(c.pi_group))
        m->poses.row(f).segment<3>(3 * smplJointIndex(j.name)) = theta * j.axis.transpose();
    }
  }
  return m;
}

// The mocap's root translation at time t (linear, held outside the clip, as the simulable does).
Vec3 transAt(const Motion& m, double t) {
  const int last = m.numFrames() - 1;
  const double frame = std::clamp(t * m.fps, 0.0, double(last));
  const int f0 = std::min(int(std::floor(frame)), last), f1 = std::min(f0 + 1, last);
  const double a = frame - f0;
  return ((1 - a) * m.trans.row(f0) + a * m.trans.row(f1)).transpose();
}

// The ball of the "ball" family (see the top of the file), placed from the initial state.
Collider makeBall(const Simulable& sim, const Motion& motion, double speed) {
  const MatX3 nodes = sim.getNodes();
  const MatX3& joints = sim.bonePositions();
  const double y0 = joints(0, 1), y1 = joints(smplJointIndex("spine2"), 1);
  int belly = -1;
  for (int i = 0; i < nodes.rows(); ++i)
    if (std::abs(nodes(i, 0) - joints(0, 0)) < 0.06 && nodes(i, 1) >= y0 && nodes(i, 1) <= y1 &&
        (belly < 0 || nodes(i, 2) > nodes(belly, 2)))
      belly = i;
  if (belly < 0) throw Error("stability_benchmark: no belly vertex found for the ball");
  const double radius = 0.12, gap = 0.02, depth = 0.08, hold = 0.1;
  const Vec3 start = nodes.row(belly).transpose() + Vec3(0, 0, radius + gap);
  const double t1 = (gap + depth) / speed, t2 = t1 + hold, t3 = t2 + t1;
  Collider ball = Collider::sphere(start, radius);
  ball.name = "ball";
  std::vector<double> times;
  for (double t = 0; t < 1.0; t += 1.0 / 120) times.push_back(t);
  for (double t : {t1, t2, t3}) times.push_back(t);
  std::sort(times.begin(), times.end());
  times.erase(std::unique(times.begin(), times.end(),
                          [](double a, double b) { return std::abs(a - b) < 1e-9; }),
              times.end());
  const Vec3 trans0 = transAt(motion, 0.0);
  for (double t : times) {
    double in = 0.0;  // how far the ball went towards the body, m
    if (t <= t1)
      in = speed * t;
    else if (t <= t2)
      in = gap + depth;
    else
      in = std::max(0.0, gap + depth - speed * (t - t2));
    ball.path.times.push_back(t);
    ball.path.offsets.push_back(transAt(motion, t) - trans0 - Vec3(0, 0, in));
  }
  return ball;
}

// ---- one run -----------------------------------------------------------------------------------

struct RunResult {
  Model model = Model::Skeleton;
  Case c;
  int steps_planned = 0, steps_done = 0;
  bool finite = true, bounded = true, refused = false, nan_exception = false;
  int unconverged = 0, false_converged = 0, fallback_steps = 0;
  double max_residual = 0.0;  // largest final ‖g‖∞ of a step
  long iterations = 0, psd_iterations = 0, regularizations = 0, halvings = 0;
  int max_iterations = 0;
  double max_speed = 0.0, max_distance = 0.0, seconds = 0.0;
  std::string exception, problem, last_message;
  bool failed() const { return !finite || !bounded; }
  bool converged() const { return unconverged == 0 && false_converged == 0; }
  bool clean() const { return !failed() && !refused && converged(); }
  // Larger is worse: non-finite, unbounded, not converged, refused, fallbacks, iterations.
  double badness() const {
    return (!finite) * 1e12 + (!bounded) * 1e11 + (unconverged + false_converged) * 1e8 +
           refused * 1e7 + fallback_steps * 1e4 + max_iterations;
  }
};

bool isNanMessage(const std::string& m) {
  for (const char* w : {"non-finite", "not finite", "NaN", "Inf"})
    if (m.find(w) != std::string::npos) return true;
  return false;
}

RunResult run(Avatars& avatars, Model model, const Case& c, int max_steps, double duration,
              bool verbose) {
  RunResult r;
  r.model = model;
  r.c = c;
  r.steps_planned = std::max(1, std::min(max_steps, int(std::lround(duration / c.h))));
  const auto t0 = Clock::now();
  int step = -1;
  try {
    auto avatar = avatars.get(model, c);
    auto motion = makeMotion(c, duration);
    SimulableOptions options;
    options.time_step = c.h;
    options.joint_stiffness *= c.stiffness_scale;
    options.tracking_stiffness *= c.stiffness_scale;
    options.root_stiffness *= c.stiffness_scale;
    auto sim = std::make_shared<Simulable>(avatar, motion, options);
    Scene scene;
    scene.addSimulable(sim);
    scene.initialize();
    const double lowest = sim->getNodes().col(1).minCoeff();
    scene.addCollider(Collider::plane(Vec3(0, lowest + c.ground_raise, 0), Vec3::UnitY()));
    if (c.ball_speed > 0) scene.addCollider(makeBall(*sim, *motion, c.ball_speed));
    const Vec3 root_rest = avatar->restJoints().row(0).transpose();
    MatX3 previous = sim->getVolumeNodes();
    for (step = 0; step < r.steps_planned; ++step) {
      const StepStats s = scene.step();
      const NewtonResult& n = s.newton;
      r.steps_done = step + 1;
      r.last_message = n.message;
      r.iterations += n.iterations;
      r.max_iterations = std::max(r.max_iterations, n.iterations);
      r.psd_iterations += n.psd_fallbacks;
      r.regularizations += n.regularizations;
      r.halvings += n.line_search_steps;
      r.unconverged += n.converged ? 0 : 1;
      r.max_residual = std::max(r.max_residual, n.gradient_norm);
      const bool false_converged = n.converged && !(n.gradient_norm <= kMaxConvergedResidual);
      r.false_converged += false_converged ? 1 : 0;
      const bool fallback = !n.converged || false_converged || n.regularizations > 0 ||
                            n.line_search_steps > kMaxHalvings;
      r.fallback_steps += fallback ? 1 : 0;
      const MatX3 nodes = sim->getVolumeNodes();
      const bool finite =
          sim->getState().allFinite() && nodes.allFinite() && sim->getVertices().allFinite();
      if (!finite) {
        r.finite = false;
        r.problem = "non-finite state or nodes after step " + std::to_string(step);
      } else {
        const Vec3 target = root_rest + transAt(*motion, sim->time());
        const double distance = (nodes.rowwise() - target.transpose()).rowwise().norm().maxCoeff();
        const double speed = (nodes - previous).rowwise().norm().maxCoeff() / c.h;
        r.max_distance = std::max(r.max_distance, distance);
        r.max_speed = std::max(r.max_speed, speed);
        if (r.bounded && (distance > kMaxDistance || speed > kMaxSpeed)) {
          r.bounded = false;
          r.problem = "unbounded at step " + std::to_string(step) +
                      format(": node %.3g m", distance) + " from the root target" +
                      format(", %.3g m/s", speed);
        }
      }
      if (verbose)
        std::printf(
            "    step %2d t=%.4f: %s, %d iterations, %d halvings, %d PSD-form, %d shifts, "
            "%d contacts, max node speed %.3g m/s, %s\n",
            step, sim->time(), n.converged ? "converged" : "NOT converged", n.iterations,
            n.line_search_steps, n.psd_fallbacks, n.regularizations, s.active_contacts,
            (nodes - previous).rowwise().norm().maxCoeff() / c.h, n.message.c_str());
      if ((!n.converged || false_converged) && r.problem.empty())
        r.problem = "step " + std::to_string(step) + (n.converged ? " falsely" : " not") +
                    " converged: " + n.message;
      if (!finite) break;
      previous = nodes;
    }
  } catch (const Error& e) {
    r.exception = e.what();
  } catch (const std::exception& e) {
    r.exception = std::string("(not a flsh::Error) ") + e.what();
    r.nan_exception = true;
  }
  if (!r.exception.empty()) {
    if (r.nan_exception || isNanMessage(r.exception)) {
      r.nan_exception = true;
      r.finite = false;
    } else {
      r.refused = true;
    }
    r.problem = (step < 0 ? "exception while setting up: "
                          : "exception at step " + std::to_string(step) + ": ") +
                r.exception;
  }
  r.seconds = seconds(t0, Clock::now());
  return r;
}

std::string command(const RunResult& r, int max_steps, double duration, const std::string& cache,
                    bool tissue_scale) {
  std::string s = "stability_benchmark --model " + std::string(modelName(r.model)) + " --family " +
                  r.c.family + " --value " + r.c.value + " --verbose";
  if (max_steps != 40) s += " --steps " + std::to_string(max_steps);
  if (duration != 0.5) s += " --duration " + format("%g", duration);
  if (cache != "/tmp/flsh_stability_cache") s += " --cache-dir " + cache;
  if (!tissue_scale) s += " --no-tissue-scale";
  return s;
}

std::string outcome(const RunResult& r) {
  std::string s = std::to_string(r.steps_done) + "/" + std::to_string(r.steps_planned) + " steps";
  if (!r.finite)
    s += ", NON-FINITE";
  else if (!r.bounded)
    s += ", UNBOUNDED";
  if (r.refused) s += ", refused";
  if (r.unconverged) s += ", " + std::to_string(r.unconverged) + " not converged";
  if (r.false_converged) s += ", " + std::to_string(r.false_converged) + " falsely converged";
  if (r.fallback_steps) s += ", " + std::to_string(r.fallback_steps) + " with a fallback";
  return s;
}

}  // namespace

int main(int argc, char** argv) {
  std::string models_option = "skeleton,fem,rom", families_option, value_option;
  std::string cache_dir = "/tmp/flsh_stability_cache";
  int max_steps = 40;
  double duration = 0.5;
  bool verbose = false, list = false, tissue_scale = true;
  int threads = 1;
  std::string cmdline;
  for (int i = 0; i < argc; ++i) cmdline += (i ? " " : "") + std::string(argv[i]);
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const bool more = i + 1 < argc;
    if ((a == "--models" || a == "--model") && more)
      models_option = argv[++i];
    else if ((a == "--families" || a == "--family") && more)
      families_option = argv[++i];
    else if (a == "--value" && more)
      value_option = argv[++i];
    else if (a == "--steps" && more)
      max_steps = std::max(1, std::atoi(argv[++i]));
    else if (a == "--duration" && more)
      duration = std::atof(argv[++i]);
    else if (a == "--cache-dir" && more)
      cache_dir = argv[++i];
    else if (a == "--threads" && more)
      threads = std::max(1, std::atoi(argv[++i]));
    else if (a == "--no-tissue-scale")
      tissue_scale = false;
    else if (a == "--verbose")
      verbose = true;
    else if (a == "--list")
      list = true;
    else {
      std::fprintf(stderr,
                   "usage: stability_benchmark [--models skeleton,fem,rom] [--families "
                   "h,stiffness,beta,ball,ground,pi,fast] [--steps N] [--duration S]\n"
                   "                           [--model M --family F --value V] [--cache-dir DIR] "
                   "[--threads N] [--no-tissue-scale] [--verbose] [--list]\n");
      return 2;
    }
  }
  omp_set_num_threads(threads);
  try {
    std::vector<Model> models;
    for (const std::string& m : split(models_option, ',')) {
      if (m == "skeleton")
        models.push_back(Model::Skeleton);
      else if (m == "fem")
        models.push_back(Model::Fem);
      else if (m == "rom")
        models.push_back(Model::Rom);
      else
        throw InputError("--models: '" + m + "' is not skeleton, fem or rom");
    }
    std::vector<std::string> families = kFamilies;
    if (!families_option.empty()) {
      families = split(families_option, ',');
      for (const std::string& f : families)
        if (std::find(kFamilies.begin(), kFamilies.end(), f) == kFamilies.end())
          throw InputError("--families: '" + f +
                           "' is not one of h, stiffness, beta, ball, "
                           "ground, pi, fast");
    }
    if (!(duration > 0)) throw InputError("--duration must be > 0");
    const auto start = Clock::now();
    Avatars avatars;
    avatars.body = std::make_shared<BodyModel>(makeSyntheticBody({kBodyVertices, 1.70}));
    avatars.cache_dir = cache_dir;
    avatars.tissue_scale = tissue_scale;
    std::vector<Case> cases;
    for (const Case& c : allCases(avatars.body->numBetas()))
      if (std::find(families.begin(), families.end(), c.family) != families.end() &&
          (value_option.empty() || valueMatches(c.value, value_option)))
        cases.push_back(c);
    if (cases.empty()) throw InputError("no case matches --families / --value (try --list)");
    if (list) {
      for (const Case& c : cases)
        std::printf("%-10s %-18s %s\n", c.family.c_str(), c.value.c_str(), c.describe().c_str());
      return 0;
    }
    std::printf(
        "stability sweep: synthetic body (%d vertices), walk, ground, h = 1/30 s base; "
        "%.2f s per run capped to %d steps; %zu cases x %zu models; cache %s\n",
        kBodyVertices, duration, max_steps, cases.size(), models.size(), cache_dir.c_str());
    std::vector<RunResult> results;
    for (Model model : models) {
      for (const Case& c : cases) {
        RunResult r = run(avatars, model, c, max_steps, duration, verbose);
        std::printf(
            "%-8s %-9s %-18s %-48s %5.1f s  its %3ld (max %2d), PSD-form %3ld, halvings "
            "%3ld, shifts %ld, |g|inf <= %8.2g, |v| %6.2f m/s, dist %5.2f m%s%s\n",
            modelName(model), c.family.c_str(), c.value.c_str(), outcome(r).c_str(), r.seconds,
            r.iterations, r.max_iterations, r.psd_iterations, r.halvings, r.regularizations,
            r.max_residual, r.max_speed, r.max_distance, r.problem.empty() ? "" : ": ",
            r.problem.c_str());
        std::fflush(stdout);
        results.push_back(std::move(r));
      }
    }

    // Avatars built.
    std::printf("\navatars (built or loaded from the cache):\n");
    for (const auto& [key, avatar] : avatars.built) {
      std::string what;
      if (avatar->hasVolumetricData())
        what = std::to_string(avatar->volumetricData().numNodes()) + " nodes, " +
               std::to_string(avatar->volumetricData().numTets()) + " tets";
      if (avatar->hasReducedData())
        what += ", " + std::to_string(avatar->reducedData().numHandles()) + " handles";
      std::printf("  %-36s %6.2f s %s\n", key.c_str(), avatars.build_seconds[key], what.c_str());
    }

    // The table.
    std::printf(
        "\n| model | family | runs | finite & bounded | all steps converged | steps with a "
        "fallback / steps | PSD-form / Newton iterations | refused | worst case |\n"
        "|---|---|---|---|---|---|---|---|---|\n");
    bool any_failed = false;
    for (Model model : models)
      for (const std::string& family : families) {
        int runs = 0, refused = 0, ok = 0, converged = 0, fallback = 0, steps = 0;
        long psd = 0, its = 0;
        const RunResult* worst = nullptr;
        for (const RunResult& r : results) {
          if (r.model != model || r.c.family != family) continue;
          ++runs;
          steps += r.steps_done;
          fallback += r.fallback_steps;
          psd += r.psd_iterations;
          its += r.iterations;
          if (r.refused)
            ++refused;
          else {
            ok += r.failed() ? 0 : 1;
            converged += r.converged() && !r.failed() ? 1 : 0;
          }
          any_failed = any_failed || r.failed();
          if (!worst || r.badness() > worst->badness()) worst = &r;
        }
        if (!runs) continue;
        const int counted = runs - refused;
        const auto pct = [&](int k) {
          return counted ? format("%.0f %%", 100.0 * k / counted) : std::string("—");
        };
        std::string worst_text = "—";
        if (worst && worst->refused && worst->converged() && !worst->failed())
          worst_text = worst->c.describe() + ": refused (" + worst->exception.substr(0, 60) +
                       (worst->exception.size() > 60 ? "…)" : ")");
        else if (worst && worst->badness() > 0)
          worst_text = worst->c.describe() + ": " + outcome(*worst) +
                       format(", ≤ %g Newton iterations", worst->max_iterations) +
                       format(", final ‖g‖∞ ≤ %.2g", worst->max_residual) +
                       format(", node speed ≤ %.3g m/s", worst->max_speed);
        std::printf("| %s | %s | %d | %s | %s | %d / %d | %ld / %ld | %d | %s |\n",
                    modelName(model), family.c_str(), runs, pct(ok).c_str(), pct(converged).c_str(),
                    fallback, steps, psd, its, refused, worst_text.c_str());
      }

    // The runs to look at.
    std::printf("\nruns to look at (non-finite, unbounded, refused or not converged):\n");
    int listed = 0;
    for (const RunResult& r : results) {
      if (r.clean()) continue;
      ++listed;
      std::printf("  %s %s = %s (%s): %s\n    %s\n    reproduce: %s\n", modelName(r.model),
                  r.c.family.c_str(), r.c.value.c_str(), r.c.describe().c_str(), outcome(r).c_str(),
                  r.problem.c_str(),
                  command(r, max_steps, duration, cache_dir, tissue_scale).c_str());
    }
    if (!listed) std::printf("  none\n");
    std::printf("\ncommand: %s\nwall time: %.1f s (%d threads)\n", cmdline.c_str(),
                seconds(start, Clock::now()), omp_get_max_threads());
    return any_failed ? 1 : 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stability_benchmark: %s\n", e.what());
    return 2;
  }
}
