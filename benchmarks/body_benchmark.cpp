// SMPL forward pass at SMPL scale (6890 vertices, 10 betas): one frame, one frame with all
// Jacobians, and a batch of 100 frames. Counter `ms_per_frame` is the figure to compare.
//
// Two models (benchmark argument 0 / 1):
//   dense:     random, SMPL's sizes, dense 20670 × 207 posedirs like real SMPL — the honest
//              worst case, since the pose blend product then reads 34 MB per frame;
//   synthetic: flsh's synthetic body with 6890 vertices (sparse pose blend shapes).
#include <benchmark/benchmark.h>

#include <random>

#include "flsh/body/body_forward.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/body/synthetic_body.h"

namespace {

using namespace flsh;

constexpr int kSmplVertices = 6890;
constexpr int kSmplBetas = 10;

// SMPL-sized model with dense blend shapes and four skinning weights per vertex.
BodyModel smplSizedRandomModel() {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> uni(-1.0, 1.0);
  BodyModel m;
  m.source = "benchmark-random-smpl-size";
  m.parents.assign(kSmplParents.begin(), kSmplParents.end());
  const int V = kSmplVertices;
  m.v_template.resize(V, 3);
  for (int i = 0; i < V; ++i)
    m.v_template.row(i) << 0.3 * uni(rng), 0.9 + 0.8 * uni(rng), 0.15 * uni(rng);
  m.shapedirs.resize(3 * V, kSmplBetas);
  for (long k = 0; k < m.shapedirs.size(); ++k) m.shapedirs.data()[k] = 0.01 * uni(rng);
  m.posedirs.resize(3 * V, kPoseFeatureSize);
  for (long k = 0; k < m.posedirs.size(); ++k) m.posedirs.data()[k] = 0.005 * uni(rng);
  m.weights = MatX::Zero(V, kNumJoints);
  std::vector<Triplet> regressor;
  for (int i = 0; i < V; ++i) {
    const int owner = i % kNumJoints;
    const int parent = std::max(0, m.parents[owner]);
    const int other1 = (owner + 5) % kNumJoints, other2 = (owner + 11) % kNumJoints;
    m.weights(i, owner) += 0.6;
    m.weights(i, parent) += 0.2;
    m.weights(i, other1) += 0.15;
    m.weights(i, other2) += 0.05;
    regressor.emplace_back(owner, i, 1.0);
  }
  m.J_regressor.resize(kNumJoints, V);
  m.J_regressor.setFromTriplets(regressor.begin(), regressor.end());
  for (int j = 0; j < kNumJoints; ++j) m.J_regressor.row(j) /= m.J_regressor.row(j).sum();
  m.faces.resize(V / 3, 3);
  for (int f = 0; f < V / 3; ++f) m.faces.row(f) << 3 * f, 3 * f + 1, 3 * f + 2;
  m.finalize();
  return m;
}

const BodyModel& model(const benchmark::State& state) {
  static const BodyModel dense = smplSizedRandomModel();
  static const BodyModel synthetic = makeSyntheticBody(SyntheticBodyOptions{kSmplVertices});
  return state.range(0) == 0 ? dense : synthetic;
}

void nameModel(benchmark::State& state) {
  state.SetLabel(state.range(0) == 0 ? "dense posedirs" : "synthetic body");
}

VecX randomPose(unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> uni(-0.6, 0.6);
  VecX pose(kSmplPoseSize);
  for (int k = 0; k < pose.size(); ++k) pose[k] = uni(rng);  // every joint bent: no skipping
  return pose;
}

void setPerFrame(benchmark::State& state, int frames) {
  state.counters["ms_per_frame"] = benchmark::Counter(
      1e-3 * frames, benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
}

void BM_PoseBody(benchmark::State& state) {
  const BodyModel& m = model(state);
  nameModel(state);
  const VecX betas = VecX::LinSpaced(kSmplBetas, -1.0, 1.0), pose = randomPose(1);
  for (auto _ : state) benchmark::DoNotOptimize(poseBody(m, betas, pose, Vec3(0.1, 0, 0)));
  setPerFrame(state, 1);
}
BENCHMARK(BM_PoseBody)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_PoseBodyWithJacobians(benchmark::State& state) {
  const BodyModel& m = model(state);
  nameModel(state);
  const VecX betas = VecX::LinSpaced(kSmplBetas, -1.0, 1.0), pose = randomPose(2);
  PosedBodyJacobians jac;
  for (auto _ : state) benchmark::DoNotOptimize(poseBody(m, betas, pose, Vec3(0.1, 0, 0), &jac));
  setPerFrame(state, 1);
}
BENCHMARK(BM_PoseBodyWithJacobians)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_PoseBodyBatch100(benchmark::State& state) {
  const BodyModel& m = model(state);
  nameModel(state);
  constexpr int kFrames = 100;
  const VecX betas = VecX::LinSpaced(kSmplBetas, -1.0, 1.0);
  RowMatX poses(kFrames, kSmplPoseSize), trans = RowMatX::Zero(kFrames, 3);
  for (int t = 0; t < kFrames; ++t) poses.row(t) = randomPose(100 + t).transpose();
  for (auto _ : state) benchmark::DoNotOptimize(poseBodyBatch(m, betas, poses, trans));
  setPerFrame(state, kFrames);
}
BENCHMARK(BM_PoseBodyBatch100)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
