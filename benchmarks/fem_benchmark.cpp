// FEM soft skeleton at the default resolution (synthetic SMPL-size body: 6890 surface vertices,
// ~10 000 nodes, ~39 000 tets) tracking the built-in walk on a ground plane at h = 1/30 s, the
// way `flsh simulate` runs it (Scene with SceneOptions::soft_tissue_newton).
// Goal on the 2-core machine (issue "FEM soft skeleton"): ≥ 2 converged steps/s (at least ≥ 1).
//
// Usage: fem_benchmark [STEPS=30] [--resolution R] [--tolerance T] [--no-lag] [--threads N]
//   --tolerance: Newton's relative gradient tolerance (default: the scene default);
//   --no-lag:    factor every Newton iteration (plain Newton on CHOLMOD) for comparison.
// Prints steps/s over the timed steps (after 3 warm-up steps) and the per-step breakdown:
// Newton iterations, seconds in energy / gradient / Hessian assembly / factorization / solves,
// factorizations and PCG iterations per step, and the largest soft-tissue displacement.
#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>

#include "flsh/body/synthetic_body.h"
#include "flsh/io/motion.h"
#include "flsh/solve/scene.h"

namespace {

using namespace flsh;
using Clock = std::chrono::steady_clock;

double seconds(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

}  // namespace

int main(int argc, char** argv) {
  int steps = 30;
  double resolution = 1.0, tolerance = -1.0;
  bool lag = true;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--resolution" && i + 1 < argc) resolution = std::atof(argv[++i]);
    else if (a == "--tolerance" && i + 1 < argc) tolerance = std::atof(argv[++i]);
    else if (a == "--no-lag") lag = false;
    else if (a == "--threads" && i + 1 < argc) omp_set_num_threads(std::atoi(argv[++i]));
    else if (!a.empty() && a[0] != '-') steps = std::max(1, std::atoi(a.c_str()));
    else {
      std::fprintf(stderr,
                   "usage: fem_benchmark [STEPS] [--resolution R] [--tolerance T] [--no-lag] "
                   "[--threads N]\n");
      return 2;
    }
  }
  try {
    const auto t0 = Clock::now();
    auto body = std::make_shared<BodyModel>(makeSyntheticBody({}));
    SoftAvatarSettings settings;
    settings.volumetric.tet_mesh.resolution = resolution;
    auto avatar = std::make_shared<SoftAvatar>(body, VecX(), settings);
    avatar->enableSoftTissue();
    avatar->initVolumetricData();
    const auto t1 = Clock::now();
    const VolumetricData& data = avatar->volumetricData();
    std::printf("avatar: %d nodes (%d bone nodes), %d tets, built/loaded in %.2f s\n",
                data.numNodes(), data.numBoneNodes(), data.numTets(), seconds(t0, t1));

    const double h = 1.0 / 30.0;
    auto walk = std::make_shared<Motion>(makeBuiltinMotion("walk", 20.0, 30.0));
    SimulableOptions options;
    options.time_step = h;
    auto sim = std::make_shared<Simulable>(avatar, walk, options);
    SceneOptions scene_options;
    if (tolerance > 0) scene_options.soft_tissue_newton.gradient_tolerance = tolerance;
    if (!lag) scene_options.soft_tissue_newton.lagged.enabled = false;
    Scene scene(scene_options);
    scene.addSimulable(sim);
    scene.initialize();
    scene.addCollider(
        Collider::plane(Vec3(0, sim->getNodes().col(1).minCoeff() - 0.002, 0), Vec3::UnitY()));
    std::printf("state: %d DoFs (%d soft-tissue nodes); Newton tolerance %.1e (relative), "
                "lagged factor %s\n",
                sim->numDofs(), int(sim->softNodes().size()),
                scene_options.soft_tissue_newton.gradient_tolerance, lag ? "on" : "off");

    for (int k = 0; k < 3; ++k) scene.step();  // warm-up: symbolic analysis, first factor
    NewtonResult sum;
    int unconverged = 0;
    double largest_u = 0.0;
    const auto start = Clock::now();
    for (int k = 0; k < steps; ++k) {
      const StepStats s = scene.step();
      const NewtonResult& r = s.newton;
      unconverged += r.converged ? 0 : 1;
      sum.iterations += r.iterations;
      sum.factorizations += r.factorizations;
      sum.cg_iterations += r.cg_iterations;
      sum.seconds_energy += r.seconds_energy;
      sum.seconds_gradient += r.seconds_gradient;
      sum.seconds_hessian += r.seconds_hessian;
      sum.seconds_factorization += r.seconds_factorization;
      sum.seconds_solve += r.seconds_solve;
      largest_u = std::max(largest_u, sim->getSoftTissueDisplacements().rowwise().norm().maxCoeff());
    }
    const double total = seconds(start, Clock::now());
    const double n = steps;
    std::printf("steps: %d in %.2f s -> %.2f steps/s (%d not converged)\n", steps, total,
                steps / total, unconverged);
    std::printf("per step: %.2f Newton iterations, %.2f factorizations, %.1f PCG iterations\n",
                sum.iterations / n, sum.factorizations / n, sum.cg_iterations / n);
    std::printf("per step seconds: energy %.3f, gradient %.3f, Hessian %.3f, factorization "
                "%.3f, solves %.3f, other %.3f\n",
                sum.seconds_energy / n, sum.seconds_gradient / n, sum.seconds_hessian / n,
                sum.seconds_factorization / n, sum.seconds_solve / n,
                (total - sum.seconds_energy - sum.seconds_gradient - sum.seconds_hessian -
                 sum.seconds_factorization - sum.seconds_solve) / n);
    std::printf("largest soft-tissue displacement: %.1f mm\n", 1000.0 * largest_u);
    return unconverged == 0 ? 0 : 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "fem_benchmark: %s\n", e.what());
    return 1;
  }
}
