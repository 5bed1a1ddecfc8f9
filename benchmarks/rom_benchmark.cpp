// (Past 800 lines on purpose: one file for the ROM's measurements — speed, --compare, --sag,
// --galerkin, --modal-fit — since they share the avatar builder, the scenarios and the runs.)
//
// ROM soft skeleton at the default resolution (synthetic SMPL-size body: 6890 surface vertices,
// ~10 000 nodes, ~39 000 tets; 87 handles, 500 + 500 cubature tets) tracking a built-in motion on
// a ground plane at h = 1/30 s, the way `flsh simulate` runs it (Scene with
// SceneOptions::reduced_newton). Goal on the 2-core machine (issue "ROM soft skeleton"):
// ≥ 500 steps/s; the FLSH paper reports 20 fps on 4 cores.
//
// Usage: rom_benchmark [STEPS=300] [--handles H] [--elastic N] [--inertial N] [--exact]
//                      [--tolerance T] [--exact-hessian | --psd-hessian] [--no-lag] [--motion NAME]
//                      [--no-ground] [--threads N] [--reference T_REF] [--inertia-floor I]
//                      [--basis-drop T] [--max-iterations N] [--materials PATH]
//                      [--training-samples N]
//        rom_benchmark --compare [--frames F] [--png PATH] [--csv PATH] [--materials PATH]
//                                [--models LIST] [--held-out]
//        rom_benchmark --plot-csv CSV [--png PATH]   (plots a --csv file of --compare again)
//        rom_benchmark --sag [--frames F]   (gravity's sag of a standing body: FEM and ROMs)
//        rom_benchmark --galerkin LIST      (linear static sag: Galerkin against best fit)
//        rom_benchmark --modal-fit LIST [--frames F]   (the FEM's u against modal bases' spans)
//   --held-out (--compare, --modal-fit): also arm swings and a jump, motions outside the
//              comparison (to check whether a choice carries over);
//   --handles / --elastic / --inertial: basis size and cubature tets (defaults 87, 500, 500);
//   --modes V[:C]: a basis with modes (static and V vibration modes, compressed to C columns),
//                  with the --handles appended (--handles 0: the modes alone);
//   --exact: no cubature (every tet and node integrated);
//   --surface-pou: ReducedSettings::surface_partition_of_unity (the partition-of-unity basis);
//   --training-samples: ReducedSettings::training_samples (random samples per cubature);
//   --basis-drop: ReducedSettings::basis_drop_below (basis weights below it dropped; 0: none);
//   --max-iterations: Newton iterations per step at most (a step that reaches it counts as not
//                     converged and keeps its last iterate): the real-time trade of a fixed
//                     budget, whose cost --reference measures;
//   --tolerance: Newton's gradient tolerance (default: the scene default);
//   --reference: also run the scene at tolerance T_REF in lockstep (untimed) and print the
//                largest surface vertex distance from it (the cost of the tolerance);
//   --no-lag: factor every Newton iteration (no lagged-factor PCG) for comparison;
//   --no-approximation: no directions from the constant soft–soft block (NewtonOptions::
//                       approximate_hessian off); --approximate-ratio R: its
//                       approximate_max_ratio; --no-reuse: approximate_reuse off;
//   --presolve N: coarse_presolve.max_iterations (Newton iterations on the bones alone first;
//                 0: none), for comparison;
//   --materials: the soft models' material file (docs/materials.md; default: the built-in one);
//   --inertia-floor: SimulableOptions::tracking_inertia_floor (kg·m²; 0 = the former model), for
//                    every model of the run (--compare too).
// Prints generation time, steps/s over the timed steps (after 3 warm-up steps) and the per-step
// breakdown (Newton iterations; seconds in energy / gradient / Hessian / factorization / solves).
//
// --compare: the speed–accuracy trade. The FEM soft skeleton is the reference; on each scenario
// (walk, jumping jacks: F frames each, tracking the motion on the ground; ball: a standing body
// whose belly a ball presses 4 cm in at 0.3 m/s and releases) the skeleton, ROMs of several handle
// and cubature counts and the FEM run the same frames. Per frame, a model's displacement error is
// the RMS over the surface vertices of ‖u_model − u_FEM‖ (soft-tissue displacements, unposed
// space) divided by the RMS of ‖u_FEM‖ (frames where that RMS is below 0.5 mm are skipped): 0 is
// the FEM, 1 is the skeleton (u = 0). Also printed: the RMS distance of the posed surfaces
// ‖x_model − x_FEM‖ (mm), which adds the differences of the bones' motion (each model's bones
// carry its own inertia). Prints a table (mean and largest error over frames, steps/s and
// speed-up over the FEM, per scenario) and plots the mean displacement error against steps/s
// into a PNG. For each ROM also the basis best fit: the least-squares fit of the FEM's u in the
// span of its basis (surface rows), relative to ‖u_FEM‖: what no dynamics in that basis can beat.
// --models LIST: the ROMs to run instead of the default set, comma-separated, each H (H handles,
// 500 + 500 cubature tets), H/E/I (0: that cubature off) or Hexact, optionally followed by "pou"
// (the partition-of-unity basis): e.g. --models 87pou,150pou,300pou or 87/500/0,87/0/500 (the
// skeleton and the FEM always run). A basis with modes (issue 26) is written mV[:C][+H] in place
// of H: the static modes and V vibration modes, compressed to C columns, with H handles appended
// (ReducedBasisKind::ModesAndHandles; without +H: Modes), e.g. m24:72/500/500 or m24+87exact;
// mV:CwX compresses with rotation weight X (ModalBasisSettings::rotation_weight), e.g. m24:72w1.
// A last sN trains both cubatures on N samples (default 600, ReducedSettings::training_samples;
// N samples cap a cubature at about N tets: the selection stops when more no longer lower the
// training error), e.g.
// m24:96/1000/1000s2000. A very last iN caps Newton at N iterations per step
// (NewtonOptions::max_iterations, the real-time trade; a step that reaches it keeps its last
// iterate), e.g. m12:24/150/100i3.
//
// --galerkin LIST: how far the Galerkin solution in a basis's span is from the FEM as handles are
// added, without dynamics or cubature: the linear static sag of a standing body (the FEM's
// soft-tissue Hessian K at rest and gravity's load f, u = K⁻¹f, bones held). For each handle
// count of LIST (comma-separated), with the prescribed and the partition-of-unity basis Φ:
// z = (ΦᵀKΦ)⁻¹Φᵀf against the FEM's u, and the least-squares best fit of u on the surface, as
// surface RMS errors relative to the FEM's. The entry "all" is the limit of ever more handles:
// every soft surface node free and the tissue inside the biharmonic extension of the surface
// (a constrained solve).
//
// --modal-fit LIST: what the nonlinear FEM (Fung stiffening, contact, pose-dependent coupling)
// leaves outside the span of the modal bases (docs/rom.md, "A basis from the physics"), on the
// scenarios of --compare: per frame the least-squares fit of the FEM's surface u, as --compare's
// basis best fit. Entries V (static modes + V vibration modes), V:C (compressed to C columns),
// V+H (with the columns of H handles appended), e.g. --modal-fit 0,24,24:72,24+87.
#include <omp.h>

#include <Eigen/Eigenvalues>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseLU>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "belly_ball.h"
#include "flsh/body/motion.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/core/error.h"
#include "flsh/render/plot.h"
#include "flsh/render/render.h"
#include "flsh/solve/scene.h"
#include "flsh/volume/modal_basis.h"
#include "flsh/volume/reduced_basis.h"
#include "flsh/volume/reduced_data.h"

namespace {

using namespace flsh;
using Clock = std::chrono::steady_clock;

double seconds(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

enum class Kind { Skeleton, Rom, Fem };

std::string g_material_file;  // --materials: every soft model's material file (empty: defaults)

std::string shortNumber(double x) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%g", x);
  return buf;
}

struct ModelSpec {
  Kind kind = Kind::Rom;
  int handles = 87, elastic = 500, inertial = 500;  // 0 cubature tets: exact integration
  bool pou = false;                                 // ReducedSettings::surface_partition_of_unity
  double basis_drop = -1.0;  // ReducedSettings::basis_drop_below (negative: its default)
  int training_samples = 0;  // ReducedSettings::training_samples (0: its default)
  // A basis with modes (ReducedBasisKind::Modes, or ModesAndHandles with handles > 0): the
  // static modes and this many vibration modes (−1: the handle basis), compressed to `columns`
  // (0: all).
  int vibration_modes = -1, columns = 0;
  double rotation_weight = 0.0;  // ModalBasisSettings::rotation_weight (0: its default)
  int max_iterations = 0;        // Newton iterations per step at most (0: the scene's default)
  std::string name() const {
    return avatarName() +
           (max_iterations > 0 ? " i" + std::to_string(max_iterations) : std::string());
  }
  /// The avatar's part of the name (models differing in the budget alone share an avatar).
  std::string avatarName() const {
    if (kind == Kind::Skeleton) return "skeleton";
    if (kind == Kind::Fem) return "FEM";
    std::string basis = std::to_string(handles);
    if (vibration_modes >= 0)
      basis = "m" + std::to_string(vibration_modes) +
              (columns > 0 ? ":" + std::to_string(columns) : std::string()) +
              (rotation_weight > 0 ? "w" + shortNumber(rotation_weight) : std::string()) +
              (handles > 0 ? "+" + std::to_string(handles) : std::string());
    char buf[64];
    if (elastic == 0 && inertial == 0)
      std::snprintf(buf, sizeof(buf), "ROM %s exact", basis.c_str());
    else
      std::snprintf(buf, sizeof(buf), "ROM %s/%d/%d", basis.c_str(), elastic, inertial);
    return std::string(buf) + (pou ? " PoU" : "") +
           (training_samples > 0 ? " s" + std::to_string(training_samples) : std::string());
  }
};

// One --models entry: H (87/500/500), H/E/I (0 tets: that cubature off, its energy integrated
// exactly), Hexact, with a trailing "pou" for the partition-of-unity basis: "150", "87/250/250",
// "87/500/0", "87exact", "300pou", "150/500/500pou"; a last "sN" sets the cubatures' training
// samples (ReducedSettings::training_samples), e.g. "m24:96/1000/1000s2000"; a very last "iN"
// caps Newton's iterations per step, e.g. "m12:24/100/100i3".
ModelSpec parseModel(const std::string& text) {
  std::string rest = text;
  ModelSpec m;
  // A trailing `tag` followed by digits N ≥ 1, removed from rest: N (0 when there is none).
  const auto trailingCount = [&](char tag, const char* what) {
    const size_t at = rest.find_last_of(tag);
    if (at == std::string::npos || at + 1 >= rest.size() ||
        rest.find_first_not_of("0123456789", at + 1) != std::string::npos)
      return 0;
    const int count = std::atoi(rest.c_str() + at + 1);
    if (count < 1)
      throw std::runtime_error("--models: '" + text + "': " + what + " " + tag + "N need N ≥ 1");
    rest.resize(at);
    return count;
  };
  m.max_iterations = trailingCount('i', "iteration budgets");
  if (rest.rfind("m", 0) == 0) {  // mV[:C][+H]…: a basis with modes
    int consumed = 0;
    if (std::sscanf(rest.c_str(), "m%d%n", &m.vibration_modes, &consumed) != 1 ||
        m.vibration_modes < 0)
      throw std::runtime_error("--models: '" + text + "': expected mV[:C][+H] with V ≥ 0");
    rest = rest.substr(size_t(consumed));
    if (!rest.empty() && rest[0] == ':') {
      m.columns = std::atoi(rest.c_str() + 1);
      rest = rest.substr(std::min(rest.find_first_not_of("0123456789", 1), rest.size()));
    }
    if (!rest.empty() && rest[0] == 'w') {  // wX: the compression's rotation weight
      m.rotation_weight = std::atof(rest.c_str() + 1);
      if (!(m.rotation_weight > 0))
        throw std::runtime_error("--models: '" + text + "': wX needs a weight > 0");
      rest = rest.substr(std::min(rest.find_first_not_of("0123456789.e-", 1), rest.size()));
    }
    if (!rest.empty() && rest[0] == '+')
      rest = rest.substr(1);
    else
      rest = "0" + rest;  // no handles: the H of the forms below is 0
  }
  const auto ends = [&](const std::string& tail) {
    if (rest.size() < tail.size() || rest.compare(rest.size() - tail.size(), tail.size(), tail))
      return false;
    rest.resize(rest.size() - tail.size());
    return true;
  };
  m.training_samples = trailingCount('s', "training samples");
  m.pou = ends("pou");
  const bool exact = ends("exact");
  int h = 0, e = 0, i = 0, consumed = 0;
  const int fields = std::sscanf(rest.c_str(), "%d/%d/%d%n", &h, &e, &i, &consumed);
  const bool whole = fields == 3 && consumed == int(rest.size());
  int consumed_h = 0;
  const bool handles_only =
      std::sscanf(rest.c_str(), "%d%n", &h, &consumed_h) == 1 && consumed_h == int(rest.size());
  if (!(whole && !exact) && !handles_only)
    throw std::runtime_error("--models: '" + text +
                             "' is not H, H/E/I or Hexact (each optionally followed by pou)");
  if (h < (m.vibration_modes >= 0 ? 0 : 1) || (whole && (e < 0 || i < 0)))
    throw std::runtime_error("--models: '" + text + "': handles must be ≥ 1, tets ≥ 0");
  m.handles = h;
  if (whole) {
    m.elastic = e;
    m.inertial = i;
  }
  if (exact) m.elastic = m.inertial = 0;
  return m;
}

std::shared_ptr<SoftAvatar> makeAvatar(std::shared_ptr<const BodyModel> body, const ModelSpec& m,
                                       double* build_seconds) {
  const auto t0 = Clock::now();
  SoftAvatarSettings settings;
  settings.volumetric.material_file = g_material_file;
  if (m.kind == Kind::Rom) {
    settings.reduced.num_handles = std::max(m.handles, 1);
    settings.reduced.basis_kind = ReducedBasisKind::Handles;  // hN: the handle basis
    if (m.vibration_modes >= 0) {
      settings.reduced.basis_kind =
          m.handles > 0 ? ReducedBasisKind::ModesAndHandles : ReducedBasisKind::Modes;
      settings.reduced.modes.vibration_modes = m.vibration_modes;
      settings.reduced.modes.columns = m.columns;
      if (m.rotation_weight > 0) settings.reduced.modes.rotation_weight = m.rotation_weight;
    }
    settings.reduced.surface_partition_of_unity = m.pou;
    if (m.basis_drop >= 0) settings.reduced.basis_drop_below = m.basis_drop;
    if (m.training_samples > 0) settings.reduced.training_samples = m.training_samples;
    if (m.elastic > 0) settings.reduced.elastic_cubature_points = m.elastic;
    if (m.inertial > 0) settings.reduced.inertial_cubature_points = m.inertial;
  }
  auto avatar = std::make_shared<SoftAvatar>(body, VecX(), settings);
  if (m.kind != Kind::Skeleton) avatar->enableSoftTissue();
  if (m.kind == Kind::Rom) {
    avatar->enableReducedModel();
    avatar->enableElasticCubature(m.elastic > 0);
    avatar->enableInertialCubature(m.inertial > 0);
  }
  avatar->initVolumetricData();
  if (build_seconds) *build_seconds = seconds(t0, Clock::now());
  return avatar;
}

// ---- one scenario
// ---------------------------------------------------------------------------------

struct Scenario {
  std::string name;
  std::shared_ptr<const Motion> motion;
  bool ball = false;
};

// A scene of one avatar following the scenario, ground 2 mm below the lowest vertex; with the
// ball (radius 12 cm) pressing the belly.
struct Run {
  std::shared_ptr<Simulable> sim;
  std::unique_ptr<Scene> scene;
};

// --inertia-floor (negative: the SimulableOptions default).
double inertia_floor_option = -1.0;
// --max-iterations (negative: the NewtonOptions default).
int max_iterations_option = -1;

Run makeRun(std::shared_ptr<SoftAvatar> avatar, const Scenario& sc, const SceneOptions& options,
            bool ground = true) {
  Run r;
  SimulableOptions sim_options;
  sim_options.time_step = 1.0 / 30.0;
  if (inertia_floor_option >= 0) sim_options.tracking_inertia_floor = inertia_floor_option;
  r.sim = std::make_shared<Simulable>(avatar, sc.motion, sim_options);
  r.scene = std::make_unique<Scene>(options);
  r.scene->addSimulable(r.sim);
  r.scene->initialize();
  if (ground)
    r.scene->addCollider(
        Collider::plane(Vec3(0, r.sim->getNodes().col(1).minCoeff() - 0.002, 0), Vec3::UnitY()));
  if (sc.ball) r.scene->addCollider(bench::bellyBall());  // belly_ball.h
  return r;
}

// --held-out: the comparison's scenarios followed by two more motions.
bool g_held_out = false;

// The comparison's scenarios: walk, jumping jacks, a ball pressing the belly of a standing body;
// with --held-out also arm swings and a jump (to check that a setting chosen on the first three
// carries over to other motions).
std::vector<Scenario> comparisonScenarios() {
  std::vector<Scenario> out = {
      {"walk", std::make_shared<Motion>(makeBuiltinMotion("walk", 20.0, 30.0)), false},
      {"jumping jacks", std::make_shared<Motion>(makeBuiltinMotion("jumping_jacks", 20.0, 30.0)),
       false},
      {"ball", std::make_shared<Motion>(makeBuiltinMotion("stand", 20.0, 30.0)), true}};
  if (g_held_out) {
    out.push_back({"arm swings",
                   std::make_shared<Motion>(makeBuiltinMotion("arm_swings", 20.0, 30.0)), false});
    out.push_back({"jump", std::make_shared<Motion>(makeBuiltinMotion("jump", 20.0, 30.0)), false});
  }
  return out;
}

struct Trajectory {
  std::vector<MatX3> surface;        // per frame, #V × 3 posed surface, m
  std::vector<MatX3> u;              // per frame, #V × 3 soft-tissue displacements, m
  std::vector<double> displacement;  // per frame, RMS ‖u‖ over the surface, m
  double steps_per_second = 0.0;
  int unconverged = 0;
};

Trajectory simulate(std::shared_ptr<SoftAvatar> avatar, const Scenario& sc, int frames,
                    int max_iterations = 0) {
  SceneOptions options;
  if (max_iterations > 0) options.reduced_newton.max_iterations = max_iterations;
  Run r = makeRun(avatar, sc, options);
  Trajectory t;
  double stepping = 0.0;
  for (int f = 0; f < frames; ++f) {
    const auto a = Clock::now();
    const StepStats s = r.scene->step();
    stepping += seconds(a, Clock::now());
    t.unconverged += s.newton.converged ? 0 : 1;
    t.surface.push_back(r.sim->getVertices());
    t.u.push_back(r.sim->getSoftTissueDisplacements());
    t.displacement.push_back(std::sqrt(t.u.back().rowwise().squaredNorm().mean()));
  }
  t.steps_per_second = frames / stepping;
  return t;
}

// The least-squares fit min_z ‖Φ_S z − u‖ of surface displacements u (#V × 3) in the span of the
// surface rows Φ_S of a basis: the RMS over the vertices of the residual's norm, m.
double bestFitResidualRms(const SpMat& basis, const MatX& u) {
  const SpMat surface = basis.topRows(u.rows());
  const Eigen::SimplicialLDLT<SpMat> normal(SpMat(surface.transpose() * surface));
  const MatX residual = surface * MatX(normal.solve(MatX(surface.transpose() * u))) - u;
  return std::sqrt(residual.rowwise().squaredNorm().mean());
}

// How well the basis can hold the FEM's displacements at all: per frame, the best fit's residual
// relative to ‖u_FEM‖, averaged over the frames the error counts (RMS ‖u_FEM‖ ≥ 0.5 mm).
// An orthonormal basis (3V × kept) of the span of the columns of P (dependent directions
// dropped).
MatX orthonormalSpan(const MatX& P) {
  const Eigen::SelfAdjointEigenSolver<MatX> gram(P.transpose() * P);
  const VecX& w = gram.eigenvalues();
  Eigen::Index kept = 0;
  while (kept < w.size() && w[w.size() - 1 - kept] > 1e-10 * w.maxCoeff()) ++kept;
  return P * gram.eigenvectors().rightCols(kept) *
         w.tail(kept).cwiseSqrt().cwiseInverse().asDiagonal();
}

// The RMS over the vertices of ‖u − Q Qᵀ u‖ for an orthonormal Q (3V × k; u #V × 3), m.
double projectionResidualRms(const MatX& Q, const MatX& u) {
  const RowMatX ur = u;
  const Eigen::Map<const VecX> flat(ur.data(), ur.size());
  const VecX residual = flat - Q * (Q.transpose() * flat);
  return std::sqrt(residual.squaredNorm() / double(u.rows()));
}

// The surface rows (3V × numSoftDofs) of a reduced basis with modes: each handle's φ ⊗ I₃, then
// the modes' rows.
MatX surfaceColumns(const ReducedData& rom, Eigen::Index V) {
  MatX P = MatX::Zero(3 * V, rom.numSoftDofs());
  for (int h = 0; h < rom.numHandles(); ++h)
    for (SpMat::InnerIterator it(rom.basis, h); it; ++it)
      if (it.row() < V)
        for (int a = 0; a < 3; ++a) P(3 * it.row() + a, 3 * h + a) = it.value();
  P.rightCols(rom.numModes()) = rom.modes.topRows(3 * V);
  return P;
}

double basisBestFit(const SoftAvatar& avatar, const Trajectory& fem) {
  const ReducedData& rom = avatar.reducedData();
  const MatX Q = rom.numModes() > 0 && !fem.u.empty()
                     ? orthonormalSpan(surfaceColumns(rom, fem.u[0].rows()))
                     : MatX();
  double sum = 0.0;
  int counted = 0;
  for (size_t f = 0; f < fem.u.size(); ++f) {
    if (fem.displacement[f] < 5e-4) continue;
    sum += (Q.size() > 0 ? projectionResidualRms(Q, fem.u[f])
                         : bestFitResidualRms(rom.basis, fem.u[f])) /
           fem.displacement[f];
    ++counted;
  }
  return counted ? sum / counted : 0.0;
}

// --modal-fit: the best fit of the FEM's u in the span of modal bases' surface rows (3V × r).
int modalFit(int frames, const std::string& list) {
  auto body = std::make_shared<BodyModel>(makeSyntheticBody({}));
  auto fem = makeAvatar(body, {Kind::Fem}, nullptr);
  const Eigen::Index V = body->numVertices();
  std::vector<std::pair<std::string, MatX>> bases;
  for (size_t start = 0; start < list.size();) {
    const size_t comma = std::min(list.find(',', start), list.size());
    const std::string entry = list.substr(start, comma - start);
    start = comma + 1;
    ModalBasisSettings s;
    s.vibration_modes = std::atoi(entry.c_str());
    const size_t colon = entry.find(':'), plus = entry.find('+');
    if (colon != std::string::npos) s.columns = std::atoi(entry.c_str() + colon + 1);
    const ModalBasis b = computeModalBasis(fem->volumetricData(), s);
    MatX P = b.basis.topRows(3 * V);
    std::string name = "static + " + std::to_string(s.vibration_modes) + " modes, " +
                       std::to_string(b.columns()) + " columns";
    if (plus != std::string::npos) {  // the handle basis' columns φ_h ⊗ e_a appended
      const int H = std::atoi(entry.c_str() + plus + 1);
      const auto handles = makeAvatar(body, {Kind::Rom, H, 0, 0}, nullptr);
      const SpMat& phi = handles->reducedData().basis;
      MatX both = MatX::Zero(3 * V, P.cols() + 3 * H);
      both.leftCols(P.cols()) = P;
      for (int h = 0; h < H; ++h)
        for (SpMat::InnerIterator it(phi, h); it; ++it)
          if (it.row() < V)
            for (int a = 0; a < 3; ++a) both(3 * it.row() + a, P.cols() + 3 * h + a) = it.value();
      P.swap(both);
      name += " + " + std::to_string(H) + " handles";
    }
    bases.emplace_back(name, orthonormalSpan(P));
  }
  const std::vector<Scenario> scenarios = comparisonScenarios();
  std::printf(
      "best fit of the FEM's surface u in each basis' span, relative to RMS ‖u_FEM‖, mean "
      "(max) over %d frames\n| basis |",
      frames);
  for (const Scenario& sc : scenarios) std::printf(" %s |", sc.name.c_str());
  std::printf("\n|---|");
  for (size_t k = 0; k < scenarios.size(); ++k) std::printf("---|");
  std::printf("\n");
  std::vector<std::vector<std::string>> cells(bases.size());
  for (const Scenario& sc : scenarios) {
    const Trajectory t = simulate(fem, sc, frames);
    for (size_t k = 0; k < bases.size(); ++k) {
      const MatX& Q = bases[k].second;
      double sum = 0.0, largest = 0.0;
      int counted = 0;
      for (size_t f = 0; f < t.u.size(); ++f) {
        if (t.displacement[f] < 5e-4) continue;
        const double e = projectionResidualRms(Q, t.u[f]) / t.displacement[f];
        sum += e;
        largest = std::max(largest, e);
        ++counted;
      }
      char cell[64];
      std::snprintf(cell, sizeof(cell), "%.1f %% (%.1f %%)", 100 * sum / std::max(1, counted),
                    100 * largest);
      cells[k].push_back(cell);
    }
  }
  for (size_t k = 0; k < bases.size(); ++k) {
    std::printf("| %s |", bases[k].first.c_str());
    for (const std::string& cell : cells[k]) std::printf(" %s |", cell.c_str());
    std::printf("\n");
  }
  return 0;
}

struct Row {
  std::string model, scenario;
  double mean_error = 0, max_error = 0, steps_per_second = 0, speedup = 0;
  double best_fit = -1;   // ROM: mean relative error of the FEM's u projected on the basis
  double surface_mm = 0;  // mean over frames of the RMS posed-surface distance, mm
  int unconverged = 0;
};

// Error against speed, one series per scenario (in the order they first appear); labels on
// the first scenario's points, except the cubature-count variants that sit on top of each other.
void plotRows(const std::vector<Row>& rows, const std::string& png) {
  std::vector<std::string> scenarios;
  for (const Row& r : rows)
    if (std::find(scenarios.begin(), scenarios.end(), r.scenario) == scenarios.end())
      scenarios.push_back(r.scenario);
  std::vector<render::PlotSeries> series;
  const Vec3 colors[] = {Vec3(0.12, 0.47, 0.71), Vec3(1.0, 0.5, 0.05), Vec3(0.17, 0.63, 0.17)};
  double fem_speed = 0.0;
  for (size_t s = 0; s < scenarios.size(); ++s) {
    render::PlotSeries ps;
    ps.label = scenarios[s];
    ps.color = colors[s % 3];
    for (const Row& r : rows)
      if (r.scenario == scenarios[s]) {
        ps.x.push_back(r.steps_per_second);
        ps.y.push_back(100 * r.mean_error);
        const bool variant =
            r.model.find("/250") != std::string::npos || r.model.find("/1000") != std::string::npos;
        ps.point_labels.push_back(s == 0 && !variant ? r.model : "");
        if (r.model == "FEM") fem_speed = std::max(fem_speed, r.steps_per_second);
      }
    series.push_back(ps);
  }
  render::PlotOptions options;
  options.title = "ROM, FEM, skeleton: displacement error vs speed";
  options.x_label = "steps per second (log), full body, h = 1/30 s";
  options.y_label = "RMS |u - u_FEM| / RMS |u_FEM|, %";
  options.log_x = true;
  options.h_lines.push_back({10.0, "goal: 10 %"});
  if (fem_speed > 0) options.v_lines.push_back({100 * fem_speed, "100x FEM"});
  render::writePng(png, render::renderPlot(series, options));
  std::printf("plot written to %s\n", png.c_str());
}

// The rows of a --csv file written by --compare (to plot them again).
std::vector<Row> readCsv(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw FileError("rom_benchmark: cannot read " + path);
  std::string line;
  std::getline(in, line);  // header
  std::vector<Row> rows;
  while (std::getline(in, line)) {
    std::vector<std::string> f;
    size_t start = 0;
    for (size_t comma; (comma = line.find(',', start)) != std::string::npos; start = comma + 1)
      f.push_back(line.substr(start, comma - start));
    f.push_back(line.substr(start));
    if (f.size() != 8)
      throw InputError(path + ": expected 8 comma-separated fields per row, got " +
                       std::to_string(f.size()) + " in \"" + line + "\"");
    Row r;
    r.model = f[0];
    r.scenario = f[1];
    r.mean_error = std::stod(f[2]);
    r.max_error = std::stod(f[3]);
    r.best_fit = std::stod(f[4]);
    r.surface_mm = std::stod(f[5]);
    r.steps_per_second = std::stod(f[6]);
    r.speedup = std::stod(f[7]);
    rows.push_back(r);
  }
  return rows;
}

int compare(int frames, const std::string& png, const std::string& csv,
            const std::vector<ModelSpec>& roms) {
  auto body = std::make_shared<BodyModel>(makeSyntheticBody({}));
  std::vector<ModelSpec> models = {{Kind::Skeleton}};
  if (roms.empty()) {
    for (int h : {43, 87, 150}) models.push_back({Kind::Rom, h, 500, 500});
    models.push_back({Kind::Rom, 87, 250, 250});
    models.push_back({Kind::Rom, 87, 1000, 1000});
    models.push_back({Kind::Rom, 87, 0, 0});
    for (int h : {87, 150}) models.push_back({Kind::Rom, h, 500, 500, true});
  } else {
    models.insert(models.end(), roms.begin(), roms.end());
  }
  models.push_back({Kind::Fem});
  const std::vector<Scenario> scenarios = comparisonScenarios();

  std::map<std::string, std::shared_ptr<SoftAvatar>> avatars;
  for (const ModelSpec& m : models) {
    double build = 0.0;
    if (avatars.count(m.avatarName())) continue;
    avatars[m.avatarName()] = makeAvatar(body, m, &build);
    std::printf("built %-18s in %6.2f s\n", m.avatarName().c_str(), build);
  }
  std::vector<Row> rows;
  for (const Scenario& sc : scenarios) {
    std::printf("scenario %s: FEM reference (%d frames)...\n", sc.name.c_str(), frames);
    std::fflush(stdout);
    const Trajectory fem = simulate(avatars["FEM"], sc, frames);
    for (const ModelSpec& m : models) {
      const Trajectory t = m.kind == Kind::Fem
                               ? fem
                               : simulate(avatars[m.avatarName()], sc, frames, m.max_iterations);
      Row row;
      row.model = m.name();
      row.scenario = sc.name;
      row.steps_per_second = t.steps_per_second;
      row.speedup = t.steps_per_second / fem.steps_per_second;
      row.unconverged = t.unconverged;
      int counted = 0;
      for (int f = 0; f < frames; ++f) {
        row.surface_mm +=
            1000.0 * std::sqrt((t.surface[f] - fem.surface[f]).rowwise().squaredNorm().mean()) /
            frames;
        if (fem.displacement[f] < 5e-4) continue;
        const double rms = std::sqrt((t.u[f] - fem.u[f]).rowwise().squaredNorm().mean());
        const double e = rms / fem.displacement[f];
        row.mean_error += e;
        row.max_error = std::max(row.max_error, e);
        ++counted;
      }
      row.mean_error = counted ? row.mean_error / counted : 0.0;
      if (m.kind == Kind::Rom) row.best_fit = basisBestFit(*avatars[m.avatarName()], fem);
      rows.push_back(row);
      char fit[48] = "";
      if (row.best_fit >= 0)
        std::snprintf(fit, sizeof(fit), " (basis best fit %5.1f %%)", 100 * row.best_fit);
      char unconverged[48] = "";
      if (row.unconverged > 0)
        std::snprintf(unconverged, sizeof(unconverged), " (%d steps not converged)",
                      row.unconverged);
      std::printf(
          "  %-18s displacement error mean %6.1f %% max %6.1f %%%s, surface %5.1f mm, "
          "%8.1f steps/s (%7.1f x FEM)%s\n",
          row.model.c_str(), 100 * row.mean_error, 100 * row.max_error, fit, row.surface_mm,
          row.steps_per_second, row.speedup, unconverged);
      std::fflush(stdout);
    }
  }

  std::printf(
      "\n| model | scenario | displacement error, mean (max) | basis best fit | posed "
      "surface, mm | steps/s | × FEM |\n");
  std::printf("|---|---|---|---|---|---|---|\n");
  for (const Row& r : rows) {
    char fit[32] = "—";
    if (r.best_fit >= 0) std::snprintf(fit, sizeof(fit), "%.1f %%", 100 * r.best_fit);
    std::printf("| %s | %s | %.1f %% (%.1f %%) | %s | %.1f | %.1f | %.1f |\n", r.model.c_str(),
                r.scenario.c_str(), 100 * r.mean_error, 100 * r.max_error, fit, r.surface_mm,
                r.steps_per_second, r.speedup);
  }
  if (!csv.empty()) {
    std::ofstream out(csv);
    out << "model,scenario,mean_error,max_error,basis_best_fit,surface_mm,steps_per_second,"
           "speedup\n";
    for (const Row& r : rows)
      out << r.model << "," << r.scenario << "," << r.mean_error << "," << r.max_error << ","
          << r.best_fit << "," << r.surface_mm << "," << r.steps_per_second << "," << r.speedup
          << "\n";
  }
  if (!png.empty()) plotRows(rows, png);
  return 0;
}

// --no-approximation and --approximate-ratio (for every run of the process).
bool g_no_approximation = false;
bool g_no_reuse = false;  // --no-reuse: NewtonOptions::approximate_reuse off
double g_approximate_ratio = 0.0;
int g_presolve = -1;  // --presolve: NewtonOptions::coarse_presolve.max_iterations

// ---- steps/s of one ROM
// --------------------------------------------------------------------------

int speed(int steps, const ModelSpec& m, double tolerance, const std::string& motion_name,
          bool ground, int hessian, bool lag, double reference) {
  auto body = std::make_shared<BodyModel>(makeSyntheticBody({}));
  double build = 0.0;
  auto avatar = makeAvatar(body, m, &build);
  const VolumetricData& data = avatar->volumetricData();
  const ReducedData& rom = avatar->reducedData();
  const ReducedBuildReport& rep = avatar->reducedBuildReport();
  std::printf(
      "avatar: %d nodes (%d bone nodes), %d tets; %d handles, cubature %d elastic / %d "
      "inertial tets (held-out errors %.2f %% / %.2f %%, rigid motions within %.2f %%); "
      "built/loaded in %.2f s (reduced level %s, %.2f s)\n",
      data.numNodes(), data.numBoneNodes(), data.numTets(), rom.numHandles(),
      int(rom.elastic.elements.size()), int(rom.inertial.elements.size()),
      100 * rom.elastic_test_error, 100 * rom.inertial_test_error, 100 * rom.inertial_rigid_error,
      build, rep.from_cache ? "from the cache" : "built", rep.seconds_total);

  SceneOptions scene_options;
  if (tolerance > 0) scene_options.reduced_newton.gradient_tolerance = tolerance;
  if (hessian >= 0) scene_options.reduced_newton.exact_hessian = hessian == 1;
  if (!lag) scene_options.reduced_newton.lagged.enabled = false;
  if (g_no_approximation) scene_options.reduced_newton.approximate_hessian = false;
  if (g_no_reuse) scene_options.reduced_newton.approximate_reuse = false;
  if (g_presolve >= 0) scene_options.reduced_newton.coarse_presolve.max_iterations = g_presolve;
  if (g_approximate_ratio > 0)
    scene_options.reduced_newton.approximate_max_ratio = g_approximate_ratio;
  if (max_iterations_option > 0)
    scene_options.reduced_newton.max_iterations = max_iterations_option;
  Scenario sc{motion_name, std::make_shared<Motion>(makeBuiltinMotion(motion_name, 60.0, 30.0)),
              false};
  Run r = makeRun(avatar, sc, scene_options, ground);
  std::printf("state: %d DoFs; Newton tolerance %.1e\n", r.sim->numDofs(),
              scene_options.reduced_newton.gradient_tolerance);
  // The reference: the same scene solved to `reference`, stepped after each timed step.
  std::unique_ptr<Run> ref;
  if (reference > 0) {
    SceneOptions ref_options = scene_options;
    ref_options.reduced_newton.gradient_tolerance = reference;
    ref_options.reduced_newton.max_iterations = 200;
    ref = std::make_unique<Run>(makeRun(avatar, sc, ref_options, ground));
    for (int k = 0; k < 3; ++k) ref->scene->step();
  }
  double largest_difference = 0.0;
  auto untimed = std::chrono::duration<double>::zero();
  for (int k = 0; k < 3; ++k) r.scene->step();
  NewtonResult sum;
  int unconverged = 0;
  double largest_u = 0.0;
  const auto start = Clock::now();
  for (int k = 0; k < steps; ++k) {
    const StepStats s = r.scene->step();
    const NewtonResult& n = s.newton;
    unconverged += n.converged ? 0 : 1;
    sum.addCounts(n);
    const auto pause = Clock::now();
    if (k % 10 == 0)
      largest_u =
          std::max(largest_u, r.sim->getSoftTissueDisplacements().rowwise().norm().maxCoeff());
    if (ref) {
      ref->scene->step();
      largest_difference =
          std::max(largest_difference,
                   (r.sim->getVertices() - ref->sim->getVertices()).rowwise().norm().maxCoeff());
    }
    untimed += Clock::now() - pause;
  }
  const double total = seconds(start, Clock::now()) - untimed.count();
  const double n = steps;
  std::printf("steps: %d in %.3f s -> %.1f steps/s (%d not converged)\n", steps, total,
              steps / total, unconverged);
  std::printf(
      "per step: %.2f Newton iterations (after %.2f on the bones alone), %.2f approximate "
      "directions (%.2f on a reused factor), %.2f Hessian assemblies (%.2f reused), %.2f "
      "factorizations, %.1f PCG iterations\n",
      sum.iterations / n, sum.coarse_iterations / n, sum.approximate_directions / n,
      sum.approximate_reuses / n, sum.hessian_evaluations / n, sum.hessian_reuses / n,
      sum.factorizations / n, sum.cg_iterations / n);
  std::printf(
      "per step ms: energy %.3f, gradient %.3f, Hessian %.3f, factorization %.3f, "
      "solves %.3f, other %.3f\n",
      1e3 * sum.seconds_energy / n, 1e3 * sum.seconds_gradient / n, 1e3 * sum.seconds_hessian / n,
      1e3 * sum.seconds_factorization / n, 1e3 * sum.seconds_solve / n,
      1e3 *
          (total - sum.seconds_energy - sum.seconds_gradient - sum.seconds_hessian -
           sum.seconds_factorization - sum.seconds_solve) /
          n);
  std::printf("largest soft-tissue displacement (every 10th step): %.1f mm\n", 1000.0 * largest_u);
  if (ref)
    std::printf("largest surface vertex distance from the run at tolerance %.0e: %.4f mm\n",
                reference, 1000.0 * largest_difference);
  return unconverged == 0 ? 0 : 1;
}

}  // namespace

// --sag: gravity's sag of a standing body (the built-in "stand" motion on the ground) after F
// steps, for the FEM and the ROM with 87 handles (both bases; exactly integrated and with the
// default cubatures): RMS ‖u‖ over the surface, and against the FEM's u the relative RMS
// distance and the cosine of the two fields. The sag is most of every scenario's displacement
// (docs/benchmarks.md).
int sag(int frames) {
  auto body = std::make_shared<BodyModel>(makeSyntheticBody({}));
  const Scenario stand{"stand", std::make_shared<Motion>(makeBuiltinMotion("stand", 20.0, 30.0)),
                       false};
  std::vector<ModelSpec> models = {{Kind::Fem}};
  for (bool pou : {false, true}) {
    models.push_back({Kind::Rom, 87, 0, 0, pou});
    models.push_back({Kind::Rom, 87, 500, 500, pou});
  }
  MatX3 fem_u;
  std::printf("gravity's sag of a standing body after %d steps (h = 1/30 s):\n", frames);
  for (const ModelSpec& m : models) {
    const Trajectory t = simulate(makeAvatar(body, m, nullptr), stand, frames);
    const MatX3& u = t.u.back();
    if (m.kind == Kind::Fem) fem_u = u;
    const double rms = std::sqrt(u.rowwise().squaredNorm().mean());
    const double fem_rms = std::sqrt(fem_u.rowwise().squaredNorm().mean());
    const double error = std::sqrt((u - fem_u).rowwise().squaredNorm().mean()) / fem_rms;
    const double cosine = (u.array() * fem_u.array()).sum() / (u.norm() * fem_u.norm());
    std::printf("  %-22s RMS sag %6.3f mm (%5.1f %% of the FEM's), error %5.1f %%, cosine %.3f\n",
                m.name().c_str(), 1e3 * rms, 100 * rms / fem_rms, 100 * error, cosine);
  }
  return 0;
}

// --galerkin (see the top of the file).
int galerkin(const std::string& list) {
  std::vector<std::string> entries;  // checked before anything is built
  for (size_t start = 0; start <= list.size();) {
    const size_t comma = std::min(list.find(',', start), list.size());
    entries.push_back(list.substr(start, comma - start));
    start = comma + 1;
  }
  for (const std::string& entry : entries) {
    int handles = 0, consumed = 0;
    if (entry != "all" && !(std::sscanf(entry.c_str(), "%d%n", &handles, &consumed) == 1 &&
                            consumed == int(entry.size()) && handles >= 1))
      throw std::runtime_error("--galerkin: '" + entry +
                               "' is neither a handle count (≥ 1) nor \"all\"");
  }
  auto body = std::make_shared<BodyModel>(makeSyntheticBody({}));
  auto avatar = makeAvatar(body, {Kind::Fem}, nullptr);
  const VolumetricData& data = avatar->volumetricData();
  SimulableOptions options;
  options.time_step = 1.0 / 30.0;
  auto sim = std::make_shared<Simulable>(
      avatar, std::make_shared<Motion>(makeBuiltinMotion("stand", 2.0, 30.0)), options);
  const int bone_dofs = 6 * kNumJoints, n = sim->numDofs(), ns = n - bone_dofs;
  std::vector<Triplet> triplets;
  sim->getPotentialHessianTripletVector(triplets, 0, false);
  SpMat H(n, n);
  H.setFromTriplets(triplets.begin(), triplets.end());
  const SpMat K = H.bottomRightCorner(ns, ns);
  VecX g = VecX::Zero(n);
  sim->getPotentialGradientVector(g);
  const VecX f = -g.tail(ns);  // elasticity is at rest: the soft rows are gravity's load
  const VecXi& soft = sim->softNodes();
  const int N = data.numNodes(), V = data.templ->mesh.num_surface_nodes;
  std::vector<int> dof(size_t(N), -1);
  for (int k = 0; k < soft.size(); ++k) dof[size_t(soft[k])] = k;
  const Eigen::SimplicialLDLT<SpMat> fem(K);
  if (fem.info() != Eigen::Success) throw std::runtime_error("--galerkin: K is not factorable");
  const VecX u_fem = fem.solve(f);
  auto surfaceField = [&](const VecX& u) {  // #V × 3, zero on bone nodes
    MatX x = MatX::Zero(V, 3);
    for (int i = 0; i < V; ++i)
      if (dof[size_t(i)] >= 0) x.row(i) = u.segment<3>(3 * dof[size_t(i)]).transpose();
    return x;
  };
  auto surfaceRms = [&](const VecX& u) {
    return std::sqrt(surfaceField(u).rowwise().squaredNorm().mean());
  };
  const double fem_rms = surfaceRms(u_fem);
  std::printf("linear static sag of a standing body: FEM %.3f mm RMS on the surface\n",
              1e3 * fem_rms);
  std::printf(
      "| handles | prescribed: Galerkin (sag) / best fit | partition of unity: Galerkin "
      "(sag) / best fit |\n|---|---|---|\n");
  for (const std::string& entry : entries) {
    if (entry == "all") {
      // Constraints Σ_j Q_ij u_j = 0 per interior soft node i (Q the biharmonic energy matrix,
      // bone nodes 0), solved with K as a KKT system.
      const SpMat Q = biharmonicEnergyMatrix(data.templ->mesh, data.rest_nodes);
      std::vector<Triplet> c;
      int rows = 0;
      for (int i = V; i < N; ++i) {
        if (dof[size_t(i)] < 0) continue;
        for (SpMat::InnerIterator it(Q, i); it; ++it)  // Q is symmetric: column i is row i
          if (dof[size_t(it.row())] >= 0)
            for (int k = 0; k < 3; ++k)
              c.emplace_back(rows + k, 3 * dof[size_t(it.row())] + k, it.value());
        rows += 3;
      }
      SpMat C(rows, ns);
      C.setFromTriplets(c.begin(), c.end());
      C *= K.diagonal().mean() / std::sqrt(SpMat(C * C.transpose()).diagonal().mean());
      std::vector<Triplet> kkt;
      for (int k = 0; k < K.outerSize(); ++k)
        for (SpMat::InnerIterator it(K, k); it; ++it)
          kkt.emplace_back(int(it.row()), int(it.col()), it.value());
      for (int k = 0; k < C.outerSize(); ++k)
        for (SpMat::InnerIterator it(C, k); it; ++it) {
          kkt.emplace_back(ns + int(it.row()), int(it.col()), it.value());
          kkt.emplace_back(int(it.col()), ns + int(it.row()), it.value());
        }
      SpMat A(ns + rows, ns + rows);
      A.setFromTriplets(kkt.begin(), kkt.end());
      A.makeCompressed();
      Eigen::SparseLU<SpMat> lu(A);
      if (lu.info() != Eigen::Success) throw std::runtime_error("--galerkin all: KKT solve failed");
      VecX rhs = VecX::Zero(ns + rows);
      rhs.head(ns) = f;
      const VecX u = VecX(lu.solve(rhs)).head(ns);
      std::printf("| all soft surface nodes, biharmonic inside | %.1f %% (%.1f %%) | |\n",
                  100 * surfaceRms(u - u_fem) / fem_rms, 100 * surfaceRms(u) / fem_rms);
      continue;
    }
    const int handles = std::atoi(entry.c_str());
    std::printf("| %d |", handles);
    for (bool pou : {false, true}) {
      ReducedSettings settings;
      settings.basis_kind = ReducedBasisKind::Handles;
      settings.num_handles = handles;
      settings.surface_partition_of_unity = pou;
      const ReducedData r = buildReducedData(data, *body, settings, false, false, nullptr);
      std::vector<Triplet> p;
      for (int h = 0; h < r.basis.outerSize(); ++h)
        for (SpMat::InnerIterator it(r.basis, h); it; ++it)
          if (dof[size_t(it.row())] >= 0)
            for (int k = 0; k < 3; ++k)
              p.emplace_back(3 * dof[size_t(it.row())] + k, 3 * h + k, it.value());
      SpMat P(ns, 3 * handles);
      P.setFromTriplets(p.begin(), p.end());
      const VecX u = P * VecX(MatX(P.transpose() * K * P).ldlt().solve(P.transpose() * f));
      std::printf(" %.1f %% (%.1f %%) / %.1f %% |", 100 * surfaceRms(u - u_fem) / fem_rms,
                  100 * surfaceRms(u) / fem_rms,
                  100 * bestFitResidualRms(r.basis, surfaceField(u_fem)) / fem_rms);
      std::fflush(stdout);
    }
    std::printf("\n");
  }
  return 0;
}

int main(int argc, char** argv) {
  int steps = 300, frames = 45;
  ModelSpec m;
  double tolerance = -1.0;
  bool ground = true, comparison = false, sag_only = false;
  int hessian = -1;  // −1: the scene default, 0: PSD, 1: exact
  bool lag = true;
  double reference = -1.0;
  std::string motion = "walk", png = "rom_tradeoff.png", csv, plot_csv, models_option,
              galerkin_list, modal_list;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--handles" && i + 1 < argc)
      m.handles = std::atoi(argv[++i]);
    else if (a == "--elastic" && i + 1 < argc)
      m.elastic = std::atoi(argv[++i]);
    else if (a == "--inertial" && i + 1 < argc)
      m.inertial = std::atoi(argv[++i]);
    else if (a == "--exact")
      m.elastic = m.inertial = 0;
    else if (a == "--surface-pou")
      m.pou = true;
    else if (a == "--modes" && i + 1 < argc) {  // V[:C]: a basis with modes (--handles 0: alone)
      const std::string v = argv[++i];
      m.vibration_modes = std::atoi(v.c_str());
      const size_t colon = v.find(':');
      if (colon != std::string::npos) m.columns = std::atoi(v.c_str() + colon + 1);
    } else if (a == "--basis-drop" && i + 1 < argc)
      m.basis_drop = std::atof(argv[++i]);
    else if (a == "--training-samples" && i + 1 < argc)
      m.training_samples = std::atoi(argv[++i]);
    else if (a == "--max-iterations" && i + 1 < argc)
      max_iterations_option = std::atoi(argv[++i]);
    else if (a == "--tolerance" && i + 1 < argc)
      tolerance = std::atof(argv[++i]);
    else if (a == "--motion" && i + 1 < argc)
      motion = argv[++i];
    else if (a == "--no-ground")
      ground = false;
    else if (a == "--exact-hessian")
      hessian = 1;
    else if (a == "--psd-hessian")
      hessian = 0;
    else if (a == "--no-lag")
      lag = false;
    else if (a == "--no-approximation")
      g_no_approximation = true;
    else if (a == "--no-reuse")
      g_no_reuse = true;
    else if (a == "--presolve" && i + 1 < argc)
      g_presolve = std::atoi(argv[++i]);
    else if (a == "--approximate-ratio" && i + 1 < argc)
      g_approximate_ratio = std::atof(argv[++i]);
    else if (a == "--reference" && i + 1 < argc)
      reference = std::atof(argv[++i]);
    else if (a == "--threads" && i + 1 < argc)
      omp_set_num_threads(std::atoi(argv[++i]));
    else if (a == "--compare")
      comparison = true;
    else if (a == "--held-out")
      g_held_out = true;
    else if (a == "--models" && i + 1 < argc)
      models_option = argv[++i];
    else if (a == "--sag")
      sag_only = true;
    else if (a == "--galerkin" && i + 1 < argc)
      galerkin_list = argv[++i];
    else if (a == "--modal-fit" && i + 1 < argc)
      modal_list = argv[++i];
    else if (a == "--materials" && i + 1 < argc)
      g_material_file = argv[++i];
    else if (a == "--inertia-floor" && i + 1 < argc)
      inertia_floor_option = std::atof(argv[++i]);
    else if (a == "--frames" && i + 1 < argc)
      frames = std::max(1, std::atoi(argv[++i]));
    else if (a == "--png" && i + 1 < argc)
      png = argv[++i];
    else if (a == "--csv" && i + 1 < argc)
      csv = argv[++i];
    else if (a == "--plot-csv" && i + 1 < argc)
      plot_csv = argv[++i];
    else if (!a.empty() && a[0] != '-')
      steps = std::max(1, std::atoi(a.c_str()));
    else {
      std::fprintf(stderr,
                   "usage: rom_benchmark [STEPS] [--handles H] [--elastic N] [--inertial N] "
                   "[--exact] [--surface-pou] [--tolerance T] [--exact-hessian | --psd-hessian] "
                   "[--no-lag] [--no-approximation] [--approximate-ratio R] [--motion NAME] "
                   "[--no-ground] [--threads N] [--reference T_REF] [--inertia-floor I] "
                   "[--basis-drop T] [--max-iterations N] [--presolve N]\n"
                   "       rom_benchmark --compare [--frames F] [--png PATH] [--csv PATH] "
                   "[--models LIST] [--held-out]\n"
                   "       rom_benchmark --sag [--frames F]\n"
                   "       rom_benchmark --galerkin LIST\n"
                   "       rom_benchmark --modal-fit LIST [--frames F] [--held-out]\n"
                   "       rom_benchmark --plot-csv CSV [--png PATH]\n");
      return 2;
    }
  }
  try {
    if (!plot_csv.empty()) {
      plotRows(readCsv(plot_csv), png);
      return 0;
    }
    if (!models_option.empty() && !comparison)
      throw std::runtime_error("--models chooses the ROMs of --compare; pass --compare too");
    if (comparison) {
      std::vector<ModelSpec> roms;
      for (size_t start = 0; start < models_option.size();) {
        const size_t comma = std::min(models_option.find(',', start), models_option.size());
        roms.push_back(parseModel(models_option.substr(start, comma - start)));
        start = comma + 1;
      }
      return compare(frames, png, csv, roms);
    }
    if (sag_only) return sag(frames);
    if (!galerkin_list.empty()) return galerkin(galerkin_list);
    if (!modal_list.empty()) return modalFit(frames, modal_list);
    return speed(steps, m, tolerance, motion, ground, hessian, lag, reference);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "rom_benchmark: %s\n", e.what());
    return 1;
  }
}
