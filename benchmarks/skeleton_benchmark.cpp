// Articulated-skeleton simulation at SMPL scale (synthetic body, 6890 vertices), h = 1/60 s:
//   OneAvatarWalk:   one avatar tracking the built-in walk on a ground plane;
//   TwoAvatarsOverlapping: two walking avatars, the second 2 cm into the first (continuous
//                    avatar–avatar contact), both on the ground;
//   GetVertices:     SMPL skinning of the simulated pose (the mesh output of one frame).
// Argument: the linear solver (0 = Auto, which is the simplicial sparse LLT in a Scene,
// 1 = dense, 2 = CHOLMOD, 3 = simplicial sparse LLT).
// Counter `steps_per_s` (or `frames_per_s`) is the figure to compare with the goals (≥ 3000
// steps/s for one avatar, ≥ 800 for two); `newton_iterations` and `contacts` are per step.
#include <benchmark/benchmark.h>

#include <memory>

#include "flsh/body/motion.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/solve/scene.h"

namespace {

using namespace flsh;

constexpr double kTimeStep = 1.0 / 60.0;
constexpr double kMotionSeconds = 20.0;

struct Shared {
  std::shared_ptr<const SoftAvatar> avatar;
  std::shared_ptr<const Motion> walk;
};

const Shared& shared() {
  static const Shared s = [] {
    Shared out;
    auto body = std::make_shared<BodyModel>(makeSyntheticBody({}));  // 6890 vertices
    auto avatar = std::make_shared<SoftAvatar>(body, VecX());
    avatar->initVolumetricData();
    out.avatar = avatar;
    out.walk = std::make_shared<Motion>(makeBuiltinMotion("walk", kMotionSeconds, 30.0));
    return out;
  }();
  return s;
}

SimulableOptions simulableOptions() {
  SimulableOptions options;
  options.time_step = kTimeStep;
  return options;
}

double lowestNodeHeight(const Simulable& sim) { return sim.getNodes().col(1).minCoeff(); }

/// The walk moved `dz` metres ahead (+z, the walking direction).
std::shared_ptr<const Motion> walkAhead(double dz) {
  auto motion = std::make_shared<Motion>(*shared().walk);
  motion->trans.col(2).array() += dz;
  return motion;
}

/// Runs scene steps; restarts the motion (outside the timing) before it runs out.
void runSteps(benchmark::State& state, Scene& scene) {
  long newton_iterations = 0, contacts = 0;
  for (auto _ : state) {
    if (scene.time() + 2 * kTimeStep > kMotionSeconds) {
      state.PauseTiming();
      scene.initialize();
      state.ResumeTiming();
    }
    const StepStats stats = scene.step();
    newton_iterations += stats.newton.iterations;
    contacts += stats.active_contacts;
    if (!stats.newton.converged) state.counters["not_converged"] += 1;
  }
  state.counters["steps_per_s"] =
      benchmark::Counter(double(state.iterations()), benchmark::Counter::kIsRate);
  state.counters["newton_iterations"] =
      benchmark::Counter(double(newton_iterations), benchmark::Counter::kAvgIterations);
  state.counters["contacts"] =
      benchmark::Counter(double(contacts), benchmark::Counter::kAvgIterations);
  state.counters["factorizations"] = double(scene.linearSolver()->numFactorizations());
  state.counters["analyses"] = double(scene.linearSolver()->numAnalyses());
}

/// Benchmark argument: 0 = the default (Auto) linear solver, 1 = dense, 2 = CHOLMOD, 3 = sparse
/// simplicial LLT.
SceneOptions sceneOptions(const benchmark::State& state) {
  SceneOptions options;
  const LinearSolverType types[] = {LinearSolverType::Auto, LinearSolverType::Dense,
                                    LinearSolverType::Cholmod, LinearSolverType::SparseLLT};
  options.newton.linear_solver = types[state.range(0)];
  return options;
}

void BM_OneAvatarWalk(benchmark::State& state) {
  const Shared& s = shared();
  auto sim = std::make_shared<Simulable>(s.avatar, s.walk, simulableOptions());
  Scene scene(sceneOptions(state));
  scene.addSimulable(sim);
  scene.initialize();
  scene.addCollider(Collider::plane(Vec3(0, lowestNodeHeight(*sim) - 0.005, 0), Vec3::UnitY()));
  runSteps(state, scene);
}
BENCHMARK(BM_OneAvatarWalk)->Arg(0)->Arg(1)->Arg(2)->Arg(3)->Unit(benchmark::kMicrosecond)->UseRealTime();

void BM_TwoAvatarsOverlapping(benchmark::State& state) {
  const Shared& s = shared();
  auto a = std::make_shared<Simulable>(s.avatar, s.walk, simulableOptions());
  // Find where the second avatar's capsules stop touching the first's vertices (walking
  // ahead of it), then place it 2 cm closer.
  double ahead = 0.2;
  std::shared_ptr<Simulable> b;
  std::unique_ptr<Scene> scene;
  for (int active = 1; active > 0; ahead += 0.01) {
    b = std::make_shared<Simulable>(s.avatar, walkAhead(ahead), simulableOptions());
    scene = std::make_unique<Scene>();
    scene->addSimulable(a);
    scene->addSimulable(b);
    scene->initialize();
    scene->avatarContactEnergy(nullptr, nullptr, true, &active);
  }
  b = std::make_shared<Simulable>(s.avatar, walkAhead(ahead - 0.03), simulableOptions());
  scene = std::make_unique<Scene>(sceneOptions(state));
  scene->addSimulable(a);
  scene->addSimulable(b);
  scene->initialize();
  const double ground = std::min(lowestNodeHeight(*a), lowestNodeHeight(*b)) - 0.005;
  scene->addCollider(Collider::plane(Vec3(0, ground, 0), Vec3::UnitY()));
  runSteps(state, *scene);
}
BENCHMARK(BM_TwoAvatarsOverlapping)
    ->Arg(0)
    ->Arg(1)
    ->Arg(2)
    ->Arg(3)
    ->Unit(benchmark::kMicrosecond)
    ->UseRealTime();

void BM_GetVertices(benchmark::State& state) {
  const Shared& s = shared();
  Simulable sim(s.avatar, s.walk, simulableOptions());
  sim.initialize();
  sim.preUpdate();  // a walking pose
  for (auto _ : state) benchmark::DoNotOptimize(sim.getVertices());
  state.counters["frames_per_s"] =
      benchmark::Counter(double(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_GetVertices)->Unit(benchmark::kMicrosecond)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
