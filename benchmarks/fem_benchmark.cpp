// FEM soft skeleton at the default resolution (synthetic SMPL-size body: 6890 surface vertices,
// ~10 000 nodes, ~39 000 tets) tracking the built-in walk on a ground plane at h = 1/30 s, the
// way `flsh simulate` runs it (Scene with SceneOptions::soft_tissue_newton).
// Goal on the 2-core machine (issue 29): ≥ 5 converged steps/s on every motion (walk, jumping
// jacks, jump, ball), with the distance to a 1e-8 solve (--reference 1e-8) reported beside.
//
// Usage: fem_benchmark [STEPS=30] [--resolution R] [--tolerance T] [--no-lag] [--threads N]
//                      [--reference T_REF] [--cg ETA REFACTOR_AFTER MAX_CG] [--motion NAME]
//                      [--no-ground] [--contact-stiffness K] [--psd-hessian]
//                      [--exact-preconditioner] [--inertia-floor I] [--materials FILE]
//                      [--hessian-parts N] [--reuse-below X] [--no-coarse] [--presolve N]
//                      [--presolve-tolerance X]
//   --tolerance: Newton's relative gradient tolerance (default: the scene default);
//   --no-lag:    factor every Newton iteration (plain Newton on CHOLMOD) for comparison;
//   --psd-hessian: the PSD Hessian form only (exact_hessian = false), for comparison;
//   --exact-preconditioner: PCG applies the lagged factor with CHOLMOD's double-precision solve
//                (lagged.fast_preconditioner = false), for comparison;
//   --reference: also run a second scene at tolerance T_REF in lockstep (untimed) and print
//                the largest difference of the nodes' positions from it (the cost of the
//                tolerance in accuracy);
//   --cg:        the lagged-factor settings (NewtonOptions::lagged): CG forcing term, refactor
//                after this many CG iterations, CG iteration limit;
//   --motion:    a built-in motion instead of "walk" (e.g. jumping_jacks, jump), or "ball": a
//                standing body whose belly a ball presses (belly_ball.h, as rom_benchmark's).
//   --reuse-below X: lagged.reuse_hessian_below (chord steps near convergence; default 1e-4);
//   --presolve N: coarse_presolve.max_iterations (Newton iterations on the bones alone, the
//                soft tissue held, before those on every DoF; 0 = off), for comparison;
//   --presolve-tolerance X: coarse_presolve.relative_tolerance;
//   --no-coarse: PCG on the lagged factor alone (lagged.coarse_correction = false), for
//                comparison;
//   --inertia-floor: SimulableOptions::tracking_inertia_floor (kg·m²; 0 = the former model).
//   --materials: a material file (docs/materials.md) instead of the built-in defaults, e.g. a
//                version-1 file for the body without regions (issue 29).
//   --hessian-parts N: after the timed steps, at the last state, time N exact Hessians (the
//                scene's, as Newton asks for it) and their parts: the dynamic part's blocks and
//                triplets (inertia), the potential part's (gravity, elasticity, springs,
//                contact) and the scene's assembly of both into the sparse matrix (a separate
//                HessianAssembler on the same lists); the median and fastest milliseconds per
//                call (issue 29).
// Prints steps/s over the timed steps (after 3 warm-up steps) and the per-step breakdown:
// Newton iterations, seconds in energy / gradient / Hessian assembly / factorization / solves,
// factorizations and PCG iterations per step, and the largest soft-tissue displacement.
// FLSH_BENCH_VERBOSE=1 prints every timed step (iterations, halvings, factorizations, CG).
#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>

#include "belly_ball.h"
#include "flsh/body/motion.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/solve/hessian_assembler.h"
#include "flsh/solve/scene.h"

namespace {

using namespace flsh;
using Clock = std::chrono::steady_clock;

double seconds(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

// Milliseconds per call of f: the median and the fastest of `repeats` timed calls (one untimed
// call first). On a shared machine the fastest is the least disturbed.
struct CallTimes {
  double median = 0.0, fastest = 0.0;
};
template <class F>
CallTimes millisecondsPerCall(int repeats, F&& f) {
  f();
  std::vector<double> ms;
  for (int k = 0; k < repeats; ++k) {
    const auto t0 = Clock::now();
    f();
    ms.push_back(1000.0 * seconds(t0, Clock::now()));
  }
  std::sort(ms.begin(), ms.end());
  return {ms[ms.size() / 2], ms.front()};
}

// --hessian-parts: the exact Hessian at the scene's current state and its parts (see above).
void printHessianParts(Scene& scene, const Simulable& sim, int repeats) {
  SpMat H;
  std::vector<Triplet> triplets;
  std::vector<FixedHessianBlocks> blocks;
  const CallTimes whole = millisecondsPerCall(repeats, [&] { scene.hessian(H, false); });
  const CallTimes dynamic = millisecondsPerCall(repeats, [&] {
    triplets.clear();
    blocks.clear();
    sim.getDynamicHessianTripletVector(triplets, blocks, 0, false);
  });
  const CallTimes potential = millisecondsPerCall(repeats, [&] {
    triplets.clear();
    blocks.clear();
    sim.getPotentialHessianTripletVector(triplets, blocks, 0, false);
  });
  // The scene's lists (both parts, as Scene::hessian collects them) on an assembler grouped as
  // the scene's (6 DoFs per bone, 3 per node).
  triplets.clear();
  blocks.clear();
  const size_t potential_start = sim.getHessianTripletVector(triplets, blocks, 0, false);
  std::vector<int> groups;
  for (int d = 0; d < sim.numBoneDofs(); d += 6) groups.push_back(d);
  for (int d = sim.numBoneDofs(); d <= sim.numDofs(); d += 3) groups.push_back(d);
  HessianAssembler assembler;
  assembler.setGroups(groups);
  SpMat A;
  const std::vector<size_t> ends{potential_start, triplets.size()};
  const CallTimes assembly = millisecondsPerCall(
      repeats, [&] { assembler.assemble(triplets, ends, blocks, sim.numDofs(), A); });
  size_t fixed = 0;
  for (const FixedHessianBlocks& list : blocks) fixed += list.empty() ? 0 : list.positions->size();
  std::printf(
      "exact Hessian at the last state, %zu triplets, %zu fixed blocks, %lld stored "
      "entries; ms per call, median (fastest) of %d calls: whole %.1f (%.1f), dynamic "
      "part %.1f (%.1f), potential part %.1f (%.1f), assembly %.1f (%.1f)\n",
      triplets.size(), fixed, (long long)A.nonZeros(), repeats, whole.median, whole.fastest,
      dynamic.median, dynamic.fastest, potential.median, potential.fastest, assembly.median,
      assembly.fastest);
}

}  // namespace

int main(int argc, char** argv) {
  int steps = 30;
  double resolution = 1.0, tolerance = -1.0;
  bool lag = true, ground = true, psd_only = false, exact_preconditioner = false;
  double contact_stiffness = -1.0;
  double inertia_floor = -1.0;
  std::string motion_name = "walk";
  double reuse_below = -1.0;
  bool coarse = true;
  int presolve = -1;
  double presolve_tolerance = -1.0;
  std::string materials;
  double reference = -1.0;
  double cg_tolerance = -1.0;
  int refactor_after = 0, max_cg = 0;
  int hessian_parts = 0;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--resolution" && i + 1 < argc)
      resolution = std::atof(argv[++i]);
    else if (a == "--tolerance" && i + 1 < argc)
      tolerance = std::atof(argv[++i]);
    else if (a == "--no-lag")
      lag = false;
    else if (a == "--no-ground")
      ground = false;
    else if (a == "--psd-hessian")
      psd_only = true;
    else if (a == "--exact-preconditioner")
      exact_preconditioner = true;
    else if (a == "--contact-stiffness" && i + 1 < argc)
      contact_stiffness = std::atof(argv[++i]);
    else if (a == "--reuse-below" && i + 1 < argc)
      reuse_below = std::atof(argv[++i]);
    else if (a == "--no-coarse")
      coarse = false;
    else if (a == "--presolve" && i + 1 < argc)
      presolve = std::atoi(argv[++i]);
    else if (a == "--presolve-tolerance" && i + 1 < argc)
      presolve_tolerance = std::atof(argv[++i]);
    else if (a == "--motion" && i + 1 < argc)
      motion_name = argv[++i];
    else if (a == "--inertia-floor" && i + 1 < argc)
      inertia_floor = std::atof(argv[++i]);
    else if (a == "--materials" && i + 1 < argc)
      materials = argv[++i];
    else if (a == "--cg" && i + 3 < argc) {  // forcing term, refactor-after, max CG iterations
      cg_tolerance = std::atof(argv[++i]);
      refactor_after = std::atoi(argv[++i]);
      max_cg = std::atoi(argv[++i]);
    } else if (a == "--reference" && i + 1 < argc)
      reference = std::atof(argv[++i]);
    else if (a == "--hessian-parts" && i + 1 < argc)
      hessian_parts = std::atoi(argv[++i]);
    else if (a == "--threads" && i + 1 < argc)
      omp_set_num_threads(std::atoi(argv[++i]));
    else if (!a.empty() && a[0] != '-')
      steps = std::max(1, std::atoi(a.c_str()));
    else {
      std::fprintf(
          stderr,
          "usage: fem_benchmark [STEPS] [--resolution R] [--tolerance T] [--no-lag] "
          "[--threads N] [--reference T_REF] [--cg ETA REFACTOR_AFTER MAX_CG] [--motion NAME] "
          "[--no-ground] [--contact-stiffness K] [--psd-hessian] [--inertia-floor I] "
          "[--exact-preconditioner] [--materials FILE] [--hessian-parts N] [--reuse-below X] "
          "[--no-coarse] [--presolve N] [--presolve-tolerance X]\n");
      return 2;
    }
  }
  try {
    const auto t0 = Clock::now();
    auto body = std::make_shared<BodyModel>(makeSyntheticBody({}));
    SoftAvatarSettings settings;
    settings.volumetric.tet_mesh.resolution = resolution;
    settings.volumetric.material_file = materials;
    auto avatar = std::make_shared<SoftAvatar>(body, VecX(), settings);
    avatar->enableSoftTissue();
    avatar->initVolumetricData();
    const auto t1 = Clock::now();
    const VolumetricData& data = avatar->volumetricData();
    std::printf("avatar: %d nodes (%d bone nodes), %d tets, built/loaded in %.2f s\n",
                data.numNodes(), data.numBoneNodes(), data.numTets(), seconds(t0, t1));

    const double h = 1.0 / 30.0;
    const bool ball = motion_name == "ball";
    auto walk =
        std::make_shared<Motion>(makeBuiltinMotion(ball ? "stand" : motion_name, 20.0, 30.0));
    SimulableOptions options;
    options.time_step = h;
    if (contact_stiffness > 0) options.contact.stiffness = contact_stiffness;
    if (inertia_floor >= 0) options.tracking_inertia_floor = inertia_floor;
    auto sim = std::make_shared<Simulable>(avatar, walk, options);
    SceneOptions scene_options;
    if (tolerance > 0) scene_options.soft_tissue_newton.gradient_tolerance = tolerance;
    if (!lag) scene_options.soft_tissue_newton.lagged.enabled = false;
    if (psd_only) scene_options.soft_tissue_newton.exact_hessian = false;
    if (reuse_below >= 0) scene_options.soft_tissue_newton.lagged.reuse_hessian_below = reuse_below;
    scene_options.soft_tissue_newton.lagged.coarse_correction = coarse;
    if (presolve >= 0) scene_options.soft_tissue_newton.coarse_presolve.max_iterations = presolve;
    if (presolve_tolerance > 0)
      scene_options.soft_tissue_newton.coarse_presolve.relative_tolerance = presolve_tolerance;
    if (exact_preconditioner) scene_options.soft_tissue_newton.lagged.fast_preconditioner = false;
    if (cg_tolerance > 0) {
      scene_options.soft_tissue_newton.lagged.cg_relative_tolerance = cg_tolerance;
      scene_options.soft_tissue_newton.lagged.refactor_after_cg_iterations = refactor_after;
      scene_options.soft_tissue_newton.lagged.max_cg_iterations = max_cg;
    }
    Scene scene(scene_options);
    scene.addSimulable(sim);
    scene.initialize();
    if (ground)
      scene.addCollider(
          Collider::plane(Vec3(0, sim->getNodes().col(1).minCoeff() - 0.002, 0), Vec3::UnitY()));
    if (ball) scene.addCollider(bench::bellyBall());
    std::printf(
        "state: %d DoFs (%d soft-tissue nodes); Newton tolerance %.1e (relative), "
        "lagged factor %s\n",
        sim->numDofs(), int(sim->softNodes().size()),
        scene_options.soft_tissue_newton.gradient_tolerance, lag ? "on" : "off");

    // The reference: the same scene solved to `reference`, stepped after each timed step.
    std::unique_ptr<Scene> ref_scene;
    std::shared_ptr<Simulable> ref_sim;
    if (reference > 0) {
      SceneOptions ref_options = scene_options;
      ref_options.soft_tissue_newton.gradient_tolerance = reference;
      ref_options.soft_tissue_newton.max_iterations = 200;
      ref_sim = std::make_shared<Simulable>(avatar, walk, options);
      ref_scene = std::make_unique<Scene>(ref_options);
      ref_scene->addSimulable(ref_sim);
      ref_scene->initialize();
      for (const Collider& c : scene.colliders()) ref_scene->addCollider(c);
      for (int k = 0; k < 3; ++k) ref_scene->step();
    }
    double largest_difference = 0.0;
    auto untimed = std::chrono::duration<double>::zero();

    for (int k = 0; k < 3; ++k) scene.step();  // warm-up: symbolic analysis, first factor
    NewtonResult sum;
    int unconverged = 0;
    double largest_u = 0.0;
    const auto start = Clock::now();
    for (int k = 0; k < steps; ++k) {
      const StepStats s = scene.step();
      const NewtonResult& r = s.newton;
      if (std::getenv("FLSH_BENCH_VERBOSE"))
        std::printf(
            "  step %d: %d iterations, %d line-search halvings, %d factorizations, %d CG, "
            "|g| %.2e, %s\n",
            k, r.iterations, r.line_search_steps, r.factorizations, r.cg_iterations,
            r.gradient_norm, r.message.c_str());
      unconverged += r.converged ? 0 : 1;
      sum.addCounts(r);
      const auto pause = Clock::now();
      largest_u =
          std::max(largest_u, sim->getSoftTissueDisplacements().rowwise().norm().maxCoeff());
      if (ref_scene) {
        ref_scene->step();
        largest_difference = std::max(
            largest_difference,
            (sim->getVolumeNodes() - ref_sim->getVolumeNodes()).rowwise().norm().maxCoeff());
      }
      untimed += Clock::now() - pause;
    }
    const double total = seconds(start, Clock::now()) - untimed.count();
    const double n = steps;
    std::printf("steps: %d in %.2f s -> %.2f steps/s (%d not converged)\n", steps, total,
                steps / total, unconverged);
    std::printf(
        "per step: %.2f Newton iterations (and %.2f on the bones alone), %.2f Hessian assemblies "
        "(%.2f reused; %.2f "
        "iterations fell back to the PSD form), %.2f factorizations, %.1f PCG "
        "iterations\n",
        sum.iterations / n, sum.coarse_iterations / n, sum.hessian_evaluations / n,
        sum.hessian_reuses / n, sum.psd_fallbacks / n, sum.factorizations / n,
        sum.cg_iterations / n);
    std::printf(
        "per step seconds: energy %.3f, gradient %.3f, Hessian %.3f, factorization "
        "%.3f, solves %.3f, other %.3f\n",
        sum.seconds_energy / n, sum.seconds_gradient / n, sum.seconds_hessian / n,
        sum.seconds_factorization / n, sum.seconds_solve / n,
        (total - sum.seconds_energy - sum.seconds_gradient - sum.seconds_hessian -
         sum.seconds_factorization - sum.seconds_solve) /
            n);
    std::printf("largest soft-tissue displacement: %.1f mm\n", 1000.0 * largest_u);
    if (ref_scene)
      std::printf("largest node distance from the run at tolerance %.0e: %.4f mm\n", reference,
                  1000.0 * largest_difference);
    if (hessian_parts > 0) printHessianParts(scene, *sim, hessian_parts);
    return unconverged == 0 ? 0 : 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "fem_benchmark: %s\n", e.what());
    return 1;
  }
}
