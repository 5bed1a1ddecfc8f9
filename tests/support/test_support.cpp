#include "support/test_support.h"

#include <cstdlib>
#include <filesystem>
#include <map>
#include <mutex>
#include <random>

#include "flsh/body/smpl_skeleton.h"
#include "flsh/body/smplh.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/core/rotation.h"

namespace flsh::test {

MatX finiteDifferenceJacobian(const std::function<VecX(const VecX&)>& f, const VecX& x,
                              double eps) {
  const VecX f0 = f(x);
  MatX J(f0.size(), x.size());
  VecX xp = x, xm = x;
  for (int k = 0; k < x.size(); ++k) {
    xp[k] = x[k] + eps;
    xm[k] = x[k] - eps;
    J.col(k) = (f(xp) - f(xm)) / (2.0 * eps);
    xp[k] = xm[k] = x[k];
  }
  return J;
}

::testing::AssertionResult jacobianMatchesFiniteDifferences(
    const std::function<VecX(const VecX&)>& f, const VecX& x, const MatX& analytic, double tol,
    double eps) {
  const double amax = analytic.size() ? analytic.cwiseAbs().maxCoeff() : 0.0;
  if (!(amax > 1e-12))
    return ::testing::AssertionFailure()
           << "analytic derivative is zero (max |A| = " << amax << "): the check would be vacuous";
  const MatX fd = finiteDifferenceJacobian(f, x, eps);
  if (fd.rows() != analytic.rows() || fd.cols() != analytic.cols())
    return ::testing::AssertionFailure()
           << "shape mismatch: analytic " << analytic.rows() << "x" << analytic.cols()
           << ", finite differences " << fd.rows() << "x" << fd.cols();
  const double scale = std::max(1.0, fd.cwiseAbs().maxCoeff());
  Eigen::Index r = 0, c = 0;
  const double err = (analytic - fd).cwiseAbs().maxCoeff(&r, &c);
  if (!(err <= tol * scale))
    return ::testing::AssertionFailure()
           << "max |analytic − FD| = " << err << " at (" << r << ", " << c << "): analytic "
           << analytic(r, c) << ", FD " << fd(r, c) << " (tolerance " << tol * scale << ")";
  return ::testing::AssertionSuccess() << "max error " << err;
}

VecX randomVector(int n, double scale, unsigned seed) {
  std::mt19937 engine(seed);
  std::uniform_real_distribution<double> u(-scale, scale);
  VecX v(n);
  for (int i = 0; i < n; ++i) v[i] = u(engine);
  return v;
}

std::string freshTempDir(const std::string& name) {
  namespace fs = std::filesystem;
  const char* base = std::getenv("FLSH_TEST_TMP");
  fs::path root = base ? fs::path(base) : fs::temp_directory_path() / "flsh_tests";
  // ctest runs each test in its own process, several at once: qualify the directory by the
  // running test's name so that two tests asking for the same name never share it.
  std::string qualified = name;
  if (const auto* info = ::testing::UnitTest::GetInstance()->current_test_info())
    qualified = std::string(info->test_suite_name()) + "." + info->name() + "." + name;
  for (char& c : qualified)
    if (c == '/') c = '_';
  fs::path dir = root / qualified;
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir.string();
}

BodyModel makeRandomModel(int vertices, int betas, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> uni(-1.0, 1.0);
  std::normal_distribution<double> gauss(0.0, 1.0);
  BodyModel m;
  m.source = "random-test-model";
  m.parents.assign(kSmplParents.begin(), kSmplParents.end());
  // Joint centres: a crude human layout, so that chains have real lever arms.
  MatX3 J(kNumJoints, 3);
  for (int j = 0; j < kNumJoints; ++j) {
    const int p = m.parents[j];
    const Vec3 base = p < 0 ? Vec3(0, 0.9, 0) : Vec3(J.row(p));
    J.row(j) = base + 0.15 * Vec3(uni(rng), uni(rng), uni(rng));
  }
  m.v_template.resize(vertices, 3);
  m.weights = MatX::Zero(vertices, kNumJoints);
  std::vector<int> owner(vertices);
  for (int i = 0; i < vertices; ++i) {
    const int j = i % kNumJoints;
    owner[i] = j;
    m.v_template.row(i) = J.row(j) + 0.08 * Vec3(uni(rng), uni(rng), uni(rng)).transpose();
    // Weight on the owner, its parent and one random joint: positive, rows sum to 1.
    double w0 = 0.5 + 0.3 * std::abs(uni(rng));
    const int p = std::max(0, m.parents[j]);
    const int r = int(std::abs(uni(rng)) * (kNumJoints - 1));
    m.weights(i, j) += w0;
    m.weights(i, p) += (1.0 - w0) * 0.7;
    m.weights(i, r) += (1.0 - w0) * 0.3;
  }
  m.shapedirs.resize(3 * vertices, betas);
  for (int k = 0; k < m.shapedirs.size(); ++k) m.shapedirs.data()[k] = 0.01 * gauss(rng);
  m.posedirs.resize(3 * vertices, kPoseFeatureSize);
  for (int k = 0; k < m.posedirs.size(); ++k) m.posedirs.data()[k] = 0.005 * gauss(rng);
  // Regressor: each joint averages the vertices it owns (positive, rows sum to 1).
  std::vector<Triplet> trips;
  std::vector<int> count(kNumJoints, 0);
  for (int i = 0; i < vertices; ++i) ++count[owner[i]];
  for (int i = 0; i < vertices; ++i) trips.emplace_back(owner[i], i, 1.0 / count[owner[i]]);
  m.J_regressor.resize(kNumJoints, vertices);
  m.J_regressor.setFromTriplets(trips.begin(), trips.end());
  // Faces: consecutive vertex triples (topology is irrelevant to the forward pass).
  m.faces.resize(vertices / 3, 3);
  for (int f = 0; f < vertices / 3; ++f) m.faces.row(f) << 3 * f, 3 * f + 1, 3 * f + 2;
  m.finalize();
  return m;
}

SoftAvatarSettings smallSoftAvatarSettings(const std::string& cache_dir) {
  SoftAvatarSettings s;
  s.voxel_size = 0.02;
  s.volumetric.cache_dir = cache_dir;
  s.volumetric.tet_mesh.resolution = 0.5;
  // The small ROM of these tests is the handle basis, whatever the default: the handle tests
  // read their handles, and SoftModel::RomModes covers the modes.
  s.reduced.basis_kind = ReducedBasisKind::Handles;
  s.reduced.num_handles = 16;
  s.reduced.elastic_cubature_points = 60;
  s.reduced.inertial_cubature_points = 60;
  s.reduced.training_samples = 80;
  return s;
}

const SmallScene& smallScene(int vertices, double walk_seconds) {
  static std::mutex mutex;
  static std::map<std::pair<int, double>, SmallScene> cache;
  std::lock_guard<std::mutex> lock(mutex);
  auto it = cache.find({vertices, walk_seconds});
  if (it != cache.end()) return it->second;
  SmallScene scene;
  SyntheticBodyOptions body_options;
  body_options.vertices = vertices;
  scene.body = std::make_shared<BodyModel>(makeSyntheticBody(body_options));
  SoftAvatarSettings settings;
  settings.voxel_size = 0.02;
  auto avatar = std::make_shared<SoftAvatar>(scene.body, VecX(), settings);
  avatar->initVolumetricData();
  scene.avatar = avatar;
  scene.walk = std::make_shared<Motion>(makeBuiltinMotion("walk", walk_seconds, 30.0));
  return cache.emplace(std::make_pair(vertices, walk_seconds), scene).first->second;
}

MatX denseFromTriplets(const std::vector<Triplet>& H, int n) {
  MatX D = MatX::Zero(n, n);
  for (const Triplet& t : H) D(t.row(), t.col()) += t.value();
  return D;
}

std::vector<Triplet> expanded(const std::vector<FixedHessianBlocks>& blocks) {
  std::vector<Triplet> out;
  appendBlockTriplets(blocks, out);
  return out;
}

VecX pullBackRotationGradient(const VecX& g, const VecX& d) {
  VecX out = g;
  for (int b = 0; b < d.size() / 6; ++b)
    out.segment<3>(6 * b + 3) =
        leftJacobianSO3(d.segment<3>(6 * b + 3)).transpose() * g.segment<3>(6 * b + 3);
  return out;
}

BodyModel smplhFrom(const BodyModel& smpl) {
  std::mt19937 rng(11);
  std::normal_distribution<double> normal(0.0, 1e-3);
  const long V = smpl.numVertices(), K = smpl.numBetas();
  BodyModel h;
  h.v_template = smpl.v_template;
  h.faces = smpl.faces;
  h.parents.assign(kSmplhParents.begin(), kSmplhParents.end());
  h.shapedirs = MatX::Zero(3 * V, K + 6);
  h.shapedirs.leftCols(K) = smpl.shapedirs;
  for (long k = 0; k < 3 * V * 6; ++k) h.shapedirs.rightCols(6).data()[k] = normal(rng);
  h.posedirs = MatX::Zero(3 * V, 9 * 51);
  h.posedirs.leftCols(9 * 21) = smpl.posedirs.leftCols(9 * 21);
  for (long k = 0; k < 3 * V * 9 * 30; ++k) h.posedirs.rightCols(9 * 30).data()[k] = normal(rng);
  h.weights = MatX::Zero(V, kNumSmplhJoints);
  h.weights.leftCols(22) = smpl.weights.leftCols(22);
  const MatX dense_regressor = MatX(smpl.J_regressor);
  MatX regressor(kNumSmplhJoints, V);
  regressor.topRows(22) = dense_regressor.topRows(22);
  for (int hand = 0; hand < 2; ++hand) {
    const int first = 22 + 15 * hand, smpl_hand = 22 + hand;
    const VecX w = smpl.weights.col(smpl_hand);
    h.weights.col(first + 3) += 0.5 * w;   // middle1
    h.weights.col(first) += 0.3 * w;       // index1
    h.weights.col(first + 12) += 0.2 * w;  // thumb1
    for (int j = first; j < first + 15; ++j) regressor.row(j) = dense_regressor.row(smpl_hand);
  }
  h.J_regressor = regressor.sparseView(1.0, 0.0);
  h.source = "smplh-from-synthetic";
  return h;
}

void translateBones(Simulable& sim, const Vec3& shift) {
  VecX d = VecX::Zero(sim.numDofs());
  for (int b = 0; b < sim.numBoneDofs() / 6; ++b) d.segment<3>(6 * b) = shift;
  sim.updateState(d);
  sim.postUpdate();
  sim.postUpdate();
}

void touchAlongZ(Scene& scene, int moving, double overlap) {
  Simulable& b = *scene.simulables()[size_t(moving)];
  translateBones(b, Vec3(0, 0, -0.05));
  int active = 1;
  for (double moved = 0.0; active > 0 && moved < 2.0; moved += 0.01) {
    translateBones(b, Vec3(0, 0, 0.01));
    scene.avatarContactEnergy(nullptr, nullptr, true, &active);
  }
  translateBones(b, Vec3(0, 0, -overlap));
}

}  // namespace flsh::test
