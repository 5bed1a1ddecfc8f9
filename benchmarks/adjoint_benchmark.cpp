// The gradient of a 100-step loss with respect to β and all pose targets (issue 8): forward
// time with and without the tape, backward (adjoint) time, and the cost of the same gradient by
// central finite differences, in one run. SMPL-size synthetic body (6890 vertices), the built-in
// walk, a ground plane, h = 1/60 s.
//
// Loss: L = Σ_t ½‖J_t − Ĵ_t‖² over the 24 simulated joint positions of every step, plus
// Σ_{t ∈ {25, 50, 75, 100}} ½‖V_t − V̂_t‖² over all 6890 skinned vertices (targets: the base
// rollout's points moved by a fixed random offset of up to 2 cm).
//
// Central differences over β (K) and all pose targets (100 × 72) need 2·(K + 7200) rollouts; a
// few of them are timed and the total is extrapolated (the output says so). A few random
// directions check that the adjoint and central-difference directional derivatives agree
// (rollouts converged to 1e-12 relative for that check; ε = 1e-6, and 1e-4 to show the effect
// of contact events).
//
// Also timed: forward sensitivities (Rollout::forwardSensitivities) along one direction of β and
// all pose targets.
//
// Usage: [OMP_NUM_THREADS=1] adjoint_benchmark [repeats = 5]; every time is the median of
// `repeats` runs, wall clock and process CPU time.
#include <Eigen/Core>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <functional>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "flsh/body/motion.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/diff/rollout.h"
#include "flsh/solve/scene.h"

namespace {

using namespace flsh;

constexpr int kSteps = 100;
constexpr double kTimeStep = 1.0 / 60.0;
const std::vector<int> kVertexSteps = {25, 50, 75, 100};

// Wall-clock and process CPU time of one call, s. On a machine shared with other jobs the CPU
// time of a single-threaded run (OMP_NUM_THREADS=1) is the stable figure.
struct Time {
  double wall = 0.0, cpu = 0.0;
};

double cpuNow() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

Time timeOf(const std::function<void()>& f) {
  const double cpu0 = cpuNow();
  const auto start = std::chrono::steady_clock::now();
  f();
  Time t;
  t.wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  t.cpu = cpuNow() - cpu0;
  return t;
}

/// Median wall and median CPU time of `repeats` calls.
Time medianTime(const std::vector<Time>& times) {
  std::vector<double> wall, cpu;
  for (const Time& t : times) wall.push_back(t.wall), cpu.push_back(t.cpu);
  std::nth_element(wall.begin(), wall.begin() + wall.size() / 2, wall.end());
  std::nth_element(cpu.begin(), cpu.begin() + cpu.size() / 2, cpu.end());
  return {wall[wall.size() / 2], cpu[cpu.size() / 2]};
}

Time medianTime(int repeats, const std::function<void()>& f) {
  std::vector<Time> t;
  for (int i = 0; i < repeats; ++i) t.push_back(timeOf(f));
  return medianTime(t);
}

struct Setup {
  std::shared_ptr<const BodyModel> body;
  std::shared_ptr<const SoftAvatar> avatar;
  std::shared_ptr<const Motion> walk;
  SimulableOptions options;
  std::vector<Collider> colliders;
  RowMatX pose_targets;  // T × 72, the mocap's at steps 1..T
};

Setup makeSetup() {
  Setup s;
  s.body = std::make_shared<BodyModel>(makeSyntheticBody({}));  // 6890 vertices
  auto avatar = std::make_shared<SoftAvatar>(s.body, VecX());
  avatar->initVolumetricData();
  s.avatar = avatar;
  s.walk = std::make_shared<Motion>(makeBuiltinMotion("walk", 4.0, 30.0));
  s.options.time_step = kTimeStep;
  Simulable sim(s.avatar, s.walk, s.options);
  sim.initialize();
  // The plane of skeleton_benchmark: 5 mm below the lowest vertex; the walk's feet reach it.
  s.colliders = {
      Collider::plane(Vec3(0, sim.getNodes().col(1).minCoeff() - 0.005, 0), Vec3::UnitY())};
  s.pose_targets.resize(kSteps, 72);
  for (int t = 0; t < kSteps; ++t) {
    sim.preUpdate();
    s.pose_targets.row(t) = sim.getParameter(SimParameter::PoseTargets).transpose();
    sim.postUpdate();
  }
  return s;
}

std::shared_ptr<Simulable> makeSimulable(const Setup& s, const VecX& betas) {
  std::shared_ptr<const SoftAvatar> avatar = s.avatar;
  if (betas.size() && betas != s.avatar->betas()) {
    auto shaped = std::make_shared<SoftAvatar>(s.body, betas, s.avatar->settings());
    shaped->initVolumetricData();
    avatar = shaped;
  }
  auto sim = std::make_shared<Simulable>(avatar, s.walk, s.options);
  sim->setColliders(s.colliders);
  return sim;
}

struct Loss {
  RowMatX joint_targets;            // T × 72
  std::vector<MatX3> vertex_targets;  // one per kVertexSteps entry, #V × 3

  double value(const Rollout& r) const {
    const double joints = 0.5 * (r.joints() - joint_targets).squaredNorm();
    double vertices = 0.0;
    for (size_t i = 0; i < kVertexSteps.size(); ++i)
      vertices += 0.5 * (r.vertices(kVertexSteps[i]) - vertex_targets[i]).squaredNorm();
    return joints + vertices;
  }
  // dL/dstates (T × numDofs) and the loss's direct β dependence.
  void cotangent(const Rollout& r, RowMatX& a, RolloutVariables& direct) const {
    const RowMatX dJ = r.joints() - joint_targets;
    a.resize(kSteps, r.numDofs());
    for (int t = 0; t < kSteps; ++t)
      a.row(t) = r.jointsCotangent(Eigen::Map<const MatX3>(dJ.row(t).data(), 24, 3)).transpose();
    direct = RolloutVariables();
    for (size_t i = 0; i < kVertexSteps.size(); ++i) {
      const int t = kVertexSteps[i];
      const Rollout::VerticesCotangent v =
          r.verticesCotangent(t, r.vertices(t) - vertex_targets[i]);
      a.row(t - 1) += v.state.transpose();
      accumulate(direct, v.direct);
    }
  }
};

Loss makeLoss(const Rollout& base) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> offset(-0.02, 0.02);
  Loss loss;
  loss.joint_targets = base.joints();
  for (int i = 0; i < loss.joint_targets.size(); ++i) loss.joint_targets.data()[i] += offset(rng);
  for (int t : kVertexSteps) {
    MatX3 v = base.vertices(t);
    for (int i = 0; i < v.size(); ++i) v.data()[i] += offset(rng);
    loss.vertex_targets.push_back(v);
  }
  return loss;
}

// Times of one configuration (Eigen's GEMM thread count set by the caller).
struct Figures {
  Time plain, forward, loss, backward, tangent;
  double plain_iterations = 0, contacts = 0, iterations = 0;
  RolloutVariables gradient;  // kept so that the timed backward's result is used
  std::vector<RowMatX> sensitivities;  // and the forward sensitivities
};

Figures measure(const Setup& s, const RolloutInputs& inputs, double tolerance, int repeats,
                std::unique_ptr<Loss>& loss) {
  Figures f;
  std::vector<Time> plain;
  for (int i = 0; i < repeats; ++i) {  // Scene stepping as skeleton_benchmark, no tape
    auto sim = makeSimulable(s, VecX());
    Scene scene;
    scene.addSimulable(sim);
    for (const Collider& c : s.colliders) scene.addCollider(c);
    scene.initialize();
    long iterations = 0, contacts = 0;
    plain.push_back(timeOf([&] {
      for (int t = 0; t < kSteps; ++t) {
        const StepStats stats = scene.step();
        iterations += stats.newton.iterations;
        contacts += stats.active_contacts;
      }
    }));
    f.plain_iterations = double(iterations) / kSteps;
    f.contacts = double(contacts) / kSteps;
  }
  f.plain = medianTime(plain);
  RolloutOptions options;
  options.newton.gradient_tolerance = tolerance;
  Rollout rollout(makeSimulable(s, VecX()), options);
  f.forward = medianTime(repeats, [&] { rollout.run(kSteps, inputs); });
  for (int t = 1; t <= kSteps; ++t) f.iterations += rollout.tape().stepInfo(t).newton_iterations;
  f.iterations /= kSteps;
  if (!loss) loss = std::make_unique<Loss>(makeLoss(rollout));
  RowMatX a;
  RolloutVariables direct;
  f.loss = medianTime(repeats, [&] { loss->cotangent(rollout, a, direct); });
  f.backward = medianTime(repeats, [&] { f.gradient = rollout.backward(a, direct); });
  // Forward sensitivities along one direction of β and every pose target (the tangent sweep:
  // each step's Jacobian–vector products and a solve with the taped factor).
  RolloutVariables direction;
  std::mt19937 rng(9);
  std::normal_distribution<double> normal;
  direction.shape = VecX::NullaryExpr(s.avatar->betas().size(), [&] { return normal(rng); });
  direction.pose_targets = RowMatX::NullaryExpr(kSteps, 72, [&] { return 0.01 * normal(rng); });
  f.tangent =
      medianTime(repeats, [&] { f.sensitivities = rollout.forwardSensitivities({direction}); });
  return f;
}

void print(const char* title, const Figures& f) {
  std::printf("%s                               wall ms   (CPU ms)\n", title);
  const auto row = [](const char* name, const Time& t) {
    std::printf("  %-44s %9.2f  (%7.2f)\n", name, 1e3 * t.wall, 1e3 * t.cpu);
  };
  row("plain forward (Scene::step, no tape)", f.plain);
  row("forward with tape (Rollout::run)", f.forward);
  row("loss + cotangents (joints, 4 x all vertices)", f.loss);
  row("backward (Rollout::backward)", f.backward);
  row("forward sensitivities (1 direction)", f.tangent);
  std::printf("  %-44s %9.3f  (%7.3f)\n", "ratio backward / forward with tape",
              f.backward.wall / f.forward.wall, f.backward.cpu / f.forward.cpu);
  std::printf("  %-44s %9.3f  (%7.3f)\n", "ratio backward / plain forward",
              f.backward.wall / f.plain.wall, f.backward.cpu / f.plain.cpu);
  std::printf("  Newton iterations per step %.2f (plain %.2f), active contacts per step %.1f\n",
              f.iterations, f.plain_iterations, f.contacts);
}

}  // namespace

int main(int argc, char** argv) {
  const int repeats = argc > 1 ? std::max(1, std::atoi(argv[1])) : 5;
  std::printf("flsh adjoint benchmark: gradient of a %d-step loss w.r.t. beta and all pose "
              "targets\n", kSteps);
  const Setup s = makeSetup();
  const int K = s.body->numBetas();
  RolloutInputs inputs;
  inputs.pose_targets = s.pose_targets;
  const int eigen_threads = Eigen::nbThreads();
  std::printf("body: %d vertices, K = %d, 24 bones (144 DoFs), h = 1/60 s, walk + ground plane; "
              "Newton tolerance 1e-6; medians of %d runs\n\n", s.body->numVertices(), K, repeats);

  std::unique_ptr<Loss> loss;
  const Figures threaded = measure(s, inputs, 1e-6, repeats, loss);
  const std::string title =
      "Eigen dense products on " + std::to_string(eigen_threads) + " OpenMP thread(s) (the default):";
  print(title.c_str(), threaded);
  // The per-step parameter Jacobians contain small dense GEMMs that Eigen runs in OpenMP
  // parallel regions; on a busy machine those wait for a descheduled thread.
  Eigen::setNbThreads(1);
  const Figures single = measure(s, inputs, 1e-6, repeats, loss);
  print("Eigen dense products on 1 thread (Eigen::setNbThreads(1)):", single);

  // ---- central finite differences: time a few rollouts and extrapolate ---------------------
  RolloutOptions fd_options;  // the default tolerance: the cheapest rollouts, favouring FD
  const int samples = std::max(2, repeats);
  std::vector<Time> shape_runs, target_runs;
  for (int i = 0; i < samples; ++i) {
    VecX betas = s.avatar->betas();
    betas[i % K] += 1e-6;
    shape_runs.push_back(timeOf([&] {  // a new avatar of the moved β, then the rollout
      Rollout r(makeSimulable(s, betas), fd_options);
      r.run(kSteps, inputs);
      volatile double v = loss->value(r);
      (void)v;
    }));
  }
  {
    Rollout r(makeSimulable(s, VecX()), fd_options);  // reused: its solver analysis is kept
    for (int i = 0; i < samples; ++i) {
      RolloutInputs moved = inputs;
      moved.pose_targets(i % kSteps, (7 * i) % 72) += 1e-6;
      target_runs.push_back(timeOf([&] {
        r.run(kSteps, moved);
        volatile double v = loss->value(r);
        (void)v;
      }));
    }
  }
  const Time shape_run = medianTime(shape_runs), target_run = medianTime(target_runs);
  const long target_count = long(kSteps) * 72;
  const auto total = [&](double shape, double target) {
    return 2.0 * K * shape + 2.0 * target_count * target;
  };
  const Time fd{total(shape_run.wall, target_run.wall), total(shape_run.cpu, target_run.cpu)};
  std::printf("\ncentral differences, EXTRAPOLATED from %d timed rollouts of each kind "
              "(Eigen on 1 thread)\n                                               wall ms   (CPU ms)\n",
              samples);
  std::printf("  one rollout + loss, moved beta (new avatar)  %9.2f  (%7.2f)  x 2K = %ld\n",
              1e3 * shape_run.wall, 1e3 * shape_run.cpu, 2L * K);
  std::printf("  one rollout + loss, moved pose target        %9.2f  (%7.2f)  x 2*%ld = %ld\n",
              1e3 * target_run.wall, 1e3 * target_run.cpu, target_count, 2 * target_count);
  std::printf("  total for the gradient (%ld rollouts)     %9.1f s (%.1f s CPU)\n",
              2L * (K + target_count), fd.wall, fd.cpu);
  for (const auto& [name, f] : {std::pair<const char*, const Figures*>{"default threads", &threaded},
                                {"Eigen on 1 thread", &single}}) {
    const double wall = f->forward.wall + f->loss.wall + f->backward.wall;
    const double cpu = f->forward.cpu + f->loss.cpu + f->backward.cpu;
    std::printf("adjoint gradient (%s): forward + loss + backward = %.2f ms (%.2f ms CPU): "
                "%.0fx (CPU %.0fx) faster than central differences\n",
                name, 1e3 * wall, 1e3 * cpu, fd.wall / wall, fd.cpu / cpu);
  }

  // ---- agreement: adjoint vs central differences along random directions ------------------
  std::printf("\ndirectional derivatives dL/dp . d, rollouts converged to 1e-12:\n");
  RolloutOptions check_options;
  check_options.newton.gradient_tolerance = 1e-12;
  Rollout base(makeSimulable(s, VecX()), check_options);
  base.run(kSteps, inputs);
  RowMatX a;
  RolloutVariables direct;
  loss->cotangent(base, a, direct);
  const RolloutVariables gradient = base.backward(a, direct);
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  double worst = 0.0;
  for (int k = 0; k < 3; ++k) {
    RolloutVariables d;
    d.shape = VecX::NullaryExpr(K, [&] { return unit(rng); });
    d.pose_targets = RowMatX::NullaryExpr(kSteps, 72, [&] { return unit(rng); });
    if (k == 0) d.pose_targets.setZero();  // three kinds: β, targets, both
    if (k == 1) d.shape.setZero();
    const auto along = [&](double e) {
      Rollout r(makeSimulable(s, s.avatar->betas() + e * d.shape), check_options);
      RolloutInputs moved = inputs;
      moved.pose_targets += e * d.pose_targets;
      r.run(kSteps, moved);
      return loss->value(r);
    };
    const double adjoint = dot(gradient, d);
    std::printf("  direction %d (%s): adjoint %.10e\n", k,
                k == 0 ? "beta" : k == 1 ? "all pose targets" : "beta + pose targets", adjoint);
    // A larger step crosses contact events (a vertex meeting the ground), where the loss is
    // only C¹; 1e-6 resolves the derivative.
    for (double eps : {1e-4, 1e-6}) {
      const double fd = (along(eps) - along(-eps)) / (2 * eps);
      const double rel = std::abs(adjoint - fd) / std::max(std::abs(fd), 1e-300);
      if (eps == 1e-6) worst = std::max(worst, rel);
      std::printf("      central difference, eps %.0e: %.10e  rel. error %.1e\n", eps, fd, rel);
    }
  }
  std::printf("worst relative error at eps 1e-6: %.1e\n", worst);
  return 0;
}
