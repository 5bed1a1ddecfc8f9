// The soft skeletons' adjoint (issue 25): the gradient of a whole-rollout loss with respect to
// every per-step pose and root target, the stiffnesses, the ground's offset, the initial state
// and velocity, the shape β (K) and the material vector (40 (1 + K) coefficients), by the reverse
// pass, against the
// forward pass it follows and the central differences it replaces. The full-size synthetic body
// (6890 vertices) tracking the built-in walk on a ground plane at h = 1/30 s: the FEM at the
// default resolution (30 steps by default) or the ROM with the default basis and both cubatures
// (100 steps).
//
// Loss: L = Σ_t ½‖J_t − Ĵ_t‖² + Σ_t ½‖V_t − V̂_t‖² over the 24 joints and the simulated surface of
// every step (targets: the base rollout's moved by a fixed random offset of up to 2 cm).
//
// Printed, each the median of `repeats` runs (wall clock; the machine is shared):
//  - forward without a tape (Scene::step, the scene's own Newton settings for the model);
//  - forward with the tape (Rollout::run at the same Newton settings: each step also factors its
//    exact Hessian for the reverse pass);
//  - the loss's cotangent (Rollout::trajectoryCotangent: the surface's Jacobians per step);
//  - backward: Rollout::backward (a solve with the step's exact Hessian and the parameter and
//    previous-state products per step), the same for every group but β and the material (what a
//    caller who does not ask for them pays: Rollout::backward's `groups`), and the first run's
//    alone (the first backward on an avatar builds what its simulables share: the ROM's table of
//    every tet in the subspace);
//  - the FEM (a tape of snapshots): how the backward solved (steps factored, PCG iterations per
//    step: TapeSolveOptions), and in the same repeats a backward that factors every step
//    (TapeSolveOptions::iterative = false) with the relative difference of its gradient;
//  - the process's peak resident memory after the runs, and the tape's share of it per step;
//  - central differences over the same parameters: 2 · #parameters forward passes without tape,
//    extrapolated from the timed one (not run).
// One directional derivative is compared with a central difference of two re-run rollouts, one
// along the material vector (every coefficient of the material file) with rollouts of
// SoftAvatar::withMaterial avatars and one along β with rollouts of SoftAvatar::withShape
// avatars.
//
// Usage: soft_adjoint_benchmark fem|rom [STEPS] [REPEATS=3] [--tolerance T]
//                               [--storage factors|snapshots] [--memory-only] [--modes V:C]
//   --tolerance: Newton's relative gradient tolerance of the rollouts (default: the rollout's
//                default, 1e-8);
//   --storage:   what the tape keeps (RolloutOptions::tape_storage; default Auto: snapshots for
//                the FEM, factors for the ROM).
//   --factor-every-step: TapeSolveOptions::iterative = false for every rollout (the backward
//                factors each step's exact Hessian instead of PCG with a nearby step's factor).
//   --memory-only: one forward with the tape and one backward of a random state cotangent, then
//                the peak resident memory against the memory before the rollout (for long
//                horizons: e.g. `fem 1000 --memory-only`; no plain forward, no checks).
//   --modes V:C: the ROM with the modal basis (ReducedBasisKind::Modes: the static modes and V
//                vibration modes, compressed to C columns; C = 0 keeps them all) instead of the
//                handle basis of 87 handles (this benchmark's default; the library's is modes).
#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "flsh/body/motion.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/diff/rollout.h"
#include "flsh/solve/scene.h"

namespace {

using namespace flsh;
using Clock = std::chrono::steady_clock;

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

double timeOf(const std::function<void()>& f) {
  const auto t0 = Clock::now();
  f();
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

// How the last sweep over the tape solved: steps factored, and PCG iterations over the others.
struct SolveCounts {
  int factored = 0, cg_iterations = 0;
};
SolveCounts solveCounts(const Tape& tape) {
  SolveCounts c;
  for (int t = 1; t <= tape.numSteps(); ++t) {
    c.factored += tape.stepInfo(t).factorization != "pcg";
    c.cg_iterations += tape.stepInfo(t).cg_iterations;
  }
  return c;
}

void printSolveCounts(const SolveCounts& c, int steps) {
  std::printf(
      "backward's solves     %d of %d steps factored, %.1f PCG iterations per other step "
      "(TapeSolveOptions)\n",
      c.factored, steps, double(c.cg_iterations) / std::max(1, steps - c.factored));
}

double peakResidentMB() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return double(usage.ru_maxrss) / 1024.0;  // kB on Linux
}

struct Setup {
  std::shared_ptr<SoftAvatar> avatar;
  std::shared_ptr<const Motion> walk;
  SimulableOptions options;
  Collider ground = Collider::plane(Vec3::Zero(), Vec3::UnitY());
};

std::shared_ptr<Simulable> makeSimulable(const Setup& s) {
  auto sim = std::make_shared<Simulable>(s.avatar, s.walk, s.options);
  sim->setColliders({s.ground});
  return sim;
}

struct Loss {
  RowMatX joint_targets, vertex_targets;  // T × 72, T × 3V

  double value(const Rollout& r) const {
    const RowMatX joints = r.joints();
    double L = 0.5 * (joints - joint_targets).squaredNorm();
    for (int t = 1; t <= r.numSteps(); ++t) {
      const MatX3 v = r.vertices(t);
      L += 0.5 *
           (Eigen::Map<const Eigen::RowVectorXd>(v.data(), v.size()) - vertex_targets.row(t - 1))
               .squaredNorm();
    }
    return L;
  }
  RowMatX verticesCotangent(const Rollout& r) const {
    return r.vertexTrajectory() - vertex_targets;
  }
  Rollout::TrajectoryCotangent cotangent(const Rollout& r, const RowMatX& dV) const {
    return r.trajectoryCotangent(r.joints() - joint_targets, dV);
  }
  Rollout::TrajectoryCotangent cotangent(const Rollout& r) const {
    return cotangent(r, verticesCotangent(r));
  }
  // The same, step by step with Rollout::verticesCotangent (how trajectoryCotangent summed the
  // soft models' surfaces before 2026-12-02).
  void cotangentStepByStep(const Rollout& r, const RowMatX& dV) const {
    const long nv = dV.cols() / 3;
    RowMatX states = RowMatX::Zero(r.numSteps(), r.numDofs());
    for (int t = 1; t <= r.numSteps(); ++t) {
      const Rollout::VerticesCotangent c =
          r.verticesCotangent(t, Eigen::Map<const MatX3>(dV.row(t - 1).data(), nv, 3));
      states.row(t - 1) += c.state.transpose();
    }
  }
};

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2 || (std::strcmp(argv[1], "fem") != 0 && std::strcmp(argv[1], "rom") != 0)) {
    std::fprintf(
        stderr,
        "usage: soft_adjoint_benchmark fem|rom [STEPS] [REPEATS=3] "
        "[--tolerance T] [--storage factors|snapshots] [--factor-every-step] [--memory-only] "
        "[--modes V:C]\n");
    return 2;
  }
  const bool rom = std::strcmp(argv[1], "rom") == 0;
  int steps = rom ? 100 : 30, repeats = 3;
  double tolerance = -1.0;
  bool memory_only = false;
  int vibration_modes = -1, modal_columns = 0;
  RolloutOptions rollout_options;
  int positional = 0;
  for (int i = 2; i < argc; ++i) {
    if (std::strcmp(argv[i], "--modes") == 0 && i + 1 < argc) {
      if (std::sscanf(argv[++i], "%d:%d", &vibration_modes, &modal_columns) != 2 ||
          vibration_modes < 0 || modal_columns < 0) {
        std::fprintf(stderr, "soft_adjoint_benchmark: --modes V:C with V, C >= 0\n");
        return 2;
      }
    } else if (std::strcmp(argv[i], "--factor-every-step") == 0) {
      rollout_options.tape_solve.iterative = false;
    } else if (std::strcmp(argv[i], "--memory-only") == 0) {
      memory_only = true;
    } else if (std::strcmp(argv[i], "--tolerance") == 0 && i + 1 < argc) {
      tolerance = std::atof(argv[++i]);
    } else if (std::strcmp(argv[i], "--storage") == 0 && i + 1 < argc) {
      const std::string storage = argv[++i];
      if (storage != "factors" && storage != "snapshots") {
        std::fprintf(stderr, "soft_adjoint_benchmark: --storage factors|snapshots\n");
        return 2;
      }
      rollout_options.tape_storage = storage == "factors" ? RolloutOptions::TapeStorage::Factors
                                                          : RolloutOptions::TapeStorage::Snapshots;
    } else if (positional == 0) {
      steps = std::atoi(argv[i]);
      ++positional;
    } else {
      repeats = std::atoi(argv[i]);
    }
  }
  if (steps < 1 || repeats < 1 || (tolerance != -1.0 && !(tolerance > 0.0))) {
    std::fprintf(stderr, "soft_adjoint_benchmark: STEPS and REPEATS ≥ 1, tolerance > 0\n");
    return 2;
  }
  try {
    Setup s;
    auto body = std::make_shared<BodyModel>(makeSyntheticBody({}));
    SoftAvatarSettings settings;
    settings.reduced.basis_kind = ReducedBasisKind::Handles;  // 87 handles unless --modes
    if (vibration_modes >= 0) {
      settings.reduced.basis_kind = ReducedBasisKind::Modes;
      settings.reduced.modes.vibration_modes = vibration_modes;
      settings.reduced.modes.columns = modal_columns;
    }
    s.avatar = std::make_shared<SoftAvatar>(body, VecX(), settings);
    s.avatar->enableSoftTissue();
    if (rom) {
      s.avatar->enableReducedModel();
      s.avatar->enableElasticCubature();
      s.avatar->enableInertialCubature();
    }
    const double build = timeOf([&] { s.avatar->initVolumetricData(); });
    s.walk = std::make_shared<Motion>(
        makeBuiltinMotion("walk", std::max(20.0, steps / 30.0 + 1.0), 30.0));
    s.options.time_step = 1.0 / 30.0;
    {
      Simulable probe(s.avatar, s.walk, s.options);
      probe.initialize();
      s.ground =
          Collider::plane(Vec3(0, probe.getNodes().col(1).minCoeff() - 0.002, 0), Vec3::UnitY());
    }
    if (tolerance > 0)
      for (NewtonOptions* n :
           {&rollout_options.soft_tissue_newton, &rollout_options.reduced_newton})
        n->gradient_tolerance = tolerance;
    const NewtonOptions& newton =
        rom ? rollout_options.reduced_newton : rollout_options.soft_tissue_newton;
    const int n = makeSimulable(s)->numDofs();
    std::printf(
        "%s%s: %d DoFs, avatar built/loaded in %.2f s; %d steps at h = 1/30 s, walk, "
        "ground; Newton tolerance %.1e (relative)\n",
        rom ? "ROM" : "FEM", rom && vibration_modes >= 0 ? " (modes)" : "", n, build, steps,
        newton.gradient_tolerance);

    if (memory_only) {
      const double before = peakResidentMB();
      auto sim = makeSimulable(s);
      Rollout rollout(sim, rollout_options);
      const double f = timeOf([&] { rollout.run(steps); });
      const RowMatX cotangent = 1e-3 * RowMatX::Random(steps, n);
      RolloutVariables g;
      const double b = timeOf([&] { g = rollout.backward(cotangent); });
      const double peak = peakResidentMB();
      std::printf("forward with tape     %8.3f s (%.2f steps/s)\n", f, steps / f);
      std::printf("backward              %8.3f s (%.2fx the forward with tape)\n", b, b / f);
      std::printf("peak resident memory  %8.0f MB (%.0f MB before the rollout: %.2f MB per step)\n",
                  peak, before, (peak - before) / steps);
      printSolveCounts(solveCounts(rollout.tape()), steps);
      std::printf("gradient: |shape| %.3g, |material| %.3g (finite: %s)\n", g.shape.norm(),
                  g.material.norm(), g.shape.allFinite() && g.material.allFinite() ? "yes" : "NO");
      return 0;
    }

    // Forward without a tape: the scene, at the rollout's Newton settings.
    std::vector<double> plain;
    for (int r = 0; r < repeats; ++r) {
      auto sim = makeSimulable(s);
      SceneOptions scene_options;
      scene_options.soft_tissue_newton = rollout_options.soft_tissue_newton;
      scene_options.reduced_newton = rollout_options.reduced_newton;
      Scene scene(scene_options);
      scene.addSimulable(sim);
      scene.addCollider(s.ground);
      scene.initialize();
      plain.push_back(timeOf([&] {
        for (int t = 0; t < steps; ++t) scene.step();
      }));
    }

    // The loss's targets from a base rollout.
    auto base_sim = makeSimulable(s);
    Rollout base(base_sim, rollout_options);
    base.run(steps);
    Loss loss;
    loss.joint_targets = base.joints() + 0.02 * RowMatX::Random(steps, 72);
    const int V = body->numVertices();
    loss.vertex_targets.resize(steps, 3 * V);
    for (int t = 1; t <= steps; ++t) {
      const MatX3 v = base.vertices(t);
      loss.vertex_targets.row(t - 1) = Eigen::Map<const Eigen::RowVectorXd>(v.data(), 3 * V);
    }
    loss.vertex_targets += 0.02 * RowMatX::Random(steps, 3 * V);

    std::vector<double> forward, backward, backward_cheap, cotangents, backward_factored, surfaces,
        surfaces_per_step, cotangents_per_step;
    RolloutVariables grad;
    double L = 0.0, factored_difference = 0.0;
    int newton_iterations = 0;
    SolveCounts solves;
    // The FEM's tape of snapshots solving by PCG: the same backward factoring every step.
    const bool compare_factored =
        !rom && rollout_options.tape_solve.iterative &&
        rollout_options.tape_storage != RolloutOptions::TapeStorage::Factors;
    for (int r = 0; r < repeats; ++r) {
      auto sim = makeSimulable(s);
      Rollout rollout(sim, rollout_options);
      forward.push_back(timeOf([&] { rollout.run(steps); }));
      Rollout::TrajectoryCotangent c;
      const RowMatX dV = loss.verticesCotangent(rollout);
      cotangents.push_back(timeOf([&] { c = loss.cotangent(rollout, dV); }));
      cotangents_per_step.push_back(timeOf([&] { loss.cotangentStepByStep(rollout, dV); }));
      // The surface of every step: all at once, and step by step (alternating, same process).
      RowMatX trajectory;
      surfaces.push_back(timeOf([&] { trajectory = rollout.vertexTrajectory(); }));
      surfaces_per_step.push_back(timeOf([&] {
        for (int t = 1; t <= steps; ++t)
          trajectory.row(t - 1) = rollout.vertices(t).reshaped<Eigen::RowMajor>().transpose();
      }));
      backward.push_back(timeOf([&] { grad = rollout.backward(c.states, c.direct); }));
      std::vector<SimParameter> cheap;  // every group but β and the material
      for (const SimParameterInfo& info : simParameters())
        if (info.id != SimParameter::Shape && info.id != SimParameter::Material)
          cheap.push_back(info.id);
      RolloutVariables without;
      backward_cheap.push_back(
          timeOf([&] { without = rollout.backward(c.states, c.direct, cheap); }));
      L = loss.value(rollout);
      newton_iterations = 0;
      for (int t = 1; t <= steps; ++t)
        newton_iterations += rollout.tape().stepInfo(t).newton_iterations;
      solves = solveCounts(rollout.tape());
      if (compare_factored) {
        RolloutOptions factored_options = rollout_options;
        factored_options.tape_solve.iterative = false;
        Rollout factored(makeSimulable(s), factored_options);
        factored.run(steps);
        const Rollout::TrajectoryCotangent fc = loss.cotangent(factored);
        RolloutVariables g;
        backward_factored.push_back(timeOf([&] { g = factored.backward(fc.states, fc.direct); }));
        const auto relative = [](const auto& a, const auto& b) {
          return (a - b).norm() / std::max(b.norm(), 1e-300);
        };
        factored_difference = std::max(
            {relative(grad.pose_targets, g.pose_targets), relative(grad.material, g.material),
             relative(grad.shape, g.shape), relative(grad.initial_state, g.initial_state),
             relative(grad.stiffnesses, g.stiffnesses)});
      }
    }
    const long material_size = makeSimulable(s)->parameterSize(SimParameter::Material);
    const long shape_size = makeSimulable(s)->parameterSize(SimParameter::Shape);
    const long parameters = long(steps) * 75 + 4 + 3 + 2L * n + material_size + shape_size;
    const double f_plain = median(plain), f_tape = median(forward), b = median(backward);
    std::printf("loss %.6g; Newton iterations per step %.2f\n", L,
                double(newton_iterations) / steps);
    std::printf("forward without tape  %8.3f s (%.2f steps/s)\n", f_plain, steps / f_plain);
    std::printf("forward with tape     %8.3f s (%.2fx the plain forward)\n", f_tape,
                f_tape / f_plain);
    std::printf(
        "loss's cotangent      %8.3f s (joints and surface of every step: "
        "Rollout::trajectoryCotangent; step by step with verticesCotangent: %.3f s)\n",
        median(cotangents), median(cotangents_per_step));
    std::printf(
        "surface of every step %8.3f s (Rollout::vertexTrajectory; step by step with "
        "vertices(t): %.3f s)\n",
        median(surfaces), median(surfaces_per_step));
    std::printf("backward              %8.3f s (%.2fx the plain forward, %.2fx with the tape)\n", b,
                b / f_plain, b / f_tape);
    if (solves.factored < steps || compare_factored) printSolveCounts(solves, steps);
    if (compare_factored)
      std::printf(
          "backward, every step factored %.3f s (%.2fx the plain forward; "
          "TapeSolveOptions::iterative = false); gradient's relative difference %.1e\n",
          median(backward_factored), median(backward_factored) / f_plain, factored_difference);
    std::printf(
        "backward without β and the material %.3f s (%.2fx the plain forward; "
        "Rollout::backward's groups)\n",
        median(backward_cheap), median(backward_cheap) / f_plain);
    std::printf(
        "backward, first run   %8.3f s (%.2fx the plain forward; the first on this avatar also "
        "builds what the avatar's simulables share, e.g. the ROM's table of every tet)\n",
        backward.front(), backward.front() / f_plain);
    std::printf("peak resident memory  %8.0f MB\n", peakResidentMB());
    std::printf(
        "central differences   %8.3g s (2 x %ld parameters x %.3f s, extrapolated): "
        "%.3gx the forward + backward\n",
        2.0 * double(parameters) * f_plain, parameters, f_plain,
        2.0 * double(parameters) * f_plain / (f_tape + b));

    // One direction against a central difference of re-run rollouts.
    RolloutVariables d;
    d.pose_targets = 0.05 * RowMatX::Random(steps, 72);
    d.stiffnesses = VecX::Zero(4);
    d.stiffnesses[1] = 0.05 * makeSimulable(s)->getParameter(SimParameter::Stiffnesses)[1];
    const double analytic = dot(grad, d);
    const double eps = 1e-4;
    auto along = [&](double e) {
      auto sim = makeSimulable(s);
      Rollout r(sim, rollout_options);
      RolloutInputs in;
      RowMatX pose(steps, 72);
      {
        Simulable targets(s.avatar, s.walk, s.options);
        targets.initialize();
        for (int t = 0; t < steps; ++t) {
          targets.preUpdate();
          pose.row(t) = targets.getParameter(SimParameter::PoseTargets).transpose();
          targets.postUpdate();
        }
      }
      in.pose_targets = pose + e * d.pose_targets;
      in.stiffnesses = sim->getParameter(SimParameter::Stiffnesses) + e * d.stiffnesses;
      r.run(steps, in);
      return loss.value(r);
    };
    const double fd = (along(eps) - along(-eps)) / (2 * eps);
    std::printf(
        "check: directional derivative %.10g, central difference %.10g (relative "
        "difference %.2g)\n",
        analytic, fd, std::abs(analytic - fd) / std::abs(fd));

    // The material vector along a random direction (every coefficient's log-value and
    // log-slopes): rollouts of SoftAvatar::withMaterial avatars; β likewise with withShape
    // avatars (the same discretization at β ± ε dβ).
    auto check = [&](const char* what, long size, double analytic,
                     const std::function<std::shared_ptr<SoftAvatar>(double)>& avatar_at) {
      auto along = [&](double e) {
        auto sim = std::make_shared<Simulable>(avatar_at(e), s.walk, s.options);
        sim->setColliders({s.ground});
        Rollout r(sim, rollout_options);
        r.run(steps);
        return loss.value(r);
      };
      const double fd = (along(eps) - along(-eps)) / (2 * eps);
      std::printf(
          "check (%s, %ld values): directional derivative %.10g, central difference %.10g "
          "(relative difference %.2g)\n",
          what, size, analytic, fd, std::abs(analytic - fd) / std::abs(fd));
    };
    RolloutVariables dm;
    dm.material = 0.05 * VecX::Random(material_size);
    const MaterialModel base_model = s.avatar->volumetricData().material_model;
    check("material", material_size, dot(grad, dm), [&](double e) {
      MaterialModel m = base_model;
      m.setParameters(base_model.parameters() + e * dm.material);
      return s.avatar->withMaterial(m);
    });
    RolloutVariables db;
    db.shape = 0.5 * VecX::Random(shape_size);
    check("shape", shape_size, dot(grad, db),
          [&](double e) { return s.avatar->withShape(s.avatar->betas() + e * db.shape); });
  } catch (const std::exception& e) {
    std::fprintf(stderr, "soft_adjoint_benchmark: %s\n", e.what());
    return 1;
  }
  return 0;
}
