// Scene with soft-tissue DoFs: the general Hessian pattern (HessianAssembler) against
// setFromTriplets, growth and cached slots; the skeleton on the general pattern (same Hessian,
// bitwise the same states as the block pattern); avatar–avatar contact gradient and exact
// Hessian against finite differences for two skeletons and for a soft-tissue avatar against a
// skeleton (u part: M_iᵀ f, u–u, u–bone blocks and the rotation–displacement term).
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <limits>
#include <memory>
#include <random>

#include "flsh/contact/contact_energy.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "flsh/solve/scene.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::expanded;
using test::jacobianMatchesFiniteDifferences;
using test::randomVector;

const test::SmallScene& shared() { return test::smallScene(600, 1.0); }

SpMat summed(const std::vector<Triplet>& triplets, int n) {
  SpMat S(n, n);
  S.setFromTriplets(triplets.begin(), triplets.end());
  return S;
}

double maxAbs(const SpMat& A) {
  double m = 0.0;
  for (int k = 0; k < A.outerSize(); ++k)
    for (SpMat::InnerIterator it(A, k); it; ++it) m = std::max(m, std::abs(it.value()));
  return m;
}

/// Random triplets on random blocks of DoF groups (sizes 6 and 3), with duplicates.
std::vector<Triplet> randomBlockTriplets(const std::vector<int>& group_start, int blocks,
                                         unsigned seed) {
  std::mt19937 rng(seed);
  const int groups = int(group_start.size()) - 1;
  std::uniform_int_distribution<int> pick(0, groups - 1);
  std::uniform_real_distribution<double> value(-1.0, 1.0);
  std::vector<Triplet> out;
  for (int k = 0; k < blocks; ++k) {
    const int gr = pick(rng), gc = pick(rng);
    for (int c = group_start[gc]; c < group_start[gc + 1]; ++c)
      for (int r = group_start[gr]; r < group_start[gr + 1]; ++r)
        if (value(rng) > -0.6) out.emplace_back(r, c, value(rng));  // blocks not always full
  }
  return out;
}

TEST(HessianAssembler, SumsLikeSetFromTripletsAndGrowsByGroupBlocks) {
  // Two "bones" (6 DoFs) and five "nodes" (3 DoFs).
  const std::vector<int> group_start{0, 6, 12, 15, 18, 21, 24, 27};
  const int n = 27;
  HessianAssembler assembler;
  assembler.setGroups(group_start);
  std::vector<Triplet> triplets = randomBlockTriplets(group_start, 12, 1);
  const size_t half = triplets.size() / 2;
  const std::vector<size_t> segments{half, triplets.size()};
  SpMat H;
  assembler.assemble(triplets, segments, n, H);
  ASSERT_GT(maxAbs(H), 0.0);
  EXPECT_EQ(maxAbs(H - summed(triplets, n)), 0.0);  // same sums in the same order
  EXPECT_EQ(assembler.numPatternBuilds(), 2);       // diagonal blocks, then the triplets' blocks
  // The pattern holds whole group blocks (every diagonal one among them).
  EXPECT_EQ(assembler.pattern().nonZeros(), H.nonZeros());
  std::vector<int> group_of(n);
  for (size_t g = 0; g + 1 < group_start.size(); ++g)
    std::fill(group_of.begin() + group_start[g], group_of.begin() + group_start[g + 1], int(g));
  Eigen::MatrixXi stored = Eigen::MatrixXi::Zero(n, n), blocks = stored;
  for (int k = 0; k < n; ++k)
    for (SpMat::InnerIterator it(H, k); it; ++it) stored(it.row(), k) = 1;
  for (int c = 0; c < n; ++c)
    for (int r = 0; r < n; ++r)
      if (stored(r, c) || group_of[r] == group_of[c])
        for (int cc = group_start[group_of[c]]; cc < group_start[group_of[c] + 1]; ++cc)
          for (int rr = group_start[group_of[r]]; rr < group_start[group_of[r] + 1]; ++rr)
            blocks(rr, cc) = 1;
  EXPECT_EQ(stored, blocks);
  EXPECT_LT(stored.sum(), n * n);  // not dense: some blocks are left out

  // The same positions with new values: every slot cached, no lookup, no growth.
  for (Triplet& t : triplets) t = Triplet(t.row(), t.col(), 2.0 * t.value() + 0.25);
  assembler.assemble(triplets, segments, n, H);
  EXPECT_EQ(assembler.lastLookups(), 0u);
  EXPECT_EQ(assembler.numPatternBuilds(), 2);
  EXPECT_LT(maxAbs(H - summed(triplets, n)), 1e-12 * maxAbs(H));

  // The first segment grows (its later slots move): the second segment keeps its slots, and
  // new blocks grow the pattern once.
  std::vector<Triplet> longer(triplets.begin(), triplets.begin() + half);
  const std::vector<Triplet> extra = randomBlockTriplets(group_start, 6, 2);
  longer.insert(longer.end(), extra.begin(), extra.end());
  const size_t first_end = longer.size();
  longer.insert(longer.end(), triplets.begin() + half, triplets.end());
  const Eigen::Index nnz_before = H.nonZeros();
  assembler.assemble(longer, {first_end, longer.size()}, n, H);
  EXPECT_EQ(assembler.numPatternBuilds(), 3);
  EXPECT_GT(H.nonZeros(), nnz_before);
  EXPECT_LE(assembler.lastLookups(), extra.size());
  EXPECT_LT(maxAbs(H - summed(longer, n)), 1e-12 * maxAbs(H));

  // Without groups: the union of the positions seen (plus the diagonal).
  HessianAssembler plain;
  const std::vector<Triplet> few{{3, 1, 1.5}, {1, 3, 1.5}, {3, 1, -0.5}, {0, 4, 2.0}};
  plain.assemble(few, {}, 5, H);
  EXPECT_EQ(H.nonZeros(), 5 + 3);
  EXPECT_EQ(H.coeff(3, 1), 1.0);
  EXPECT_EQ(H.coeff(0, 4), 2.0);
}

TEST(HessianAssembler, DenseStorageSumsLikeSetFromTriplets) {
  const std::vector<int> group_start{0, 6, 12, 15, 18, 21, 24, 27};
  const int n = 27;
  HessianAssembler assembler;
  assembler.setGroups(group_start);
  assembler.setDense(true);
  EXPECT_TRUE(assembler.dense());
  std::vector<Triplet> triplets = randomBlockTriplets(group_start, 12, 4);
  triplets.emplace_back(3, 20, 0.5);  // outside any block the sparse pattern would start with
  SpMat H;
  assembler.assemble(triplets, {triplets.size() / 3, triplets.size()}, n, H);
  ASSERT_GT(maxAbs(H), 0.0);
  EXPECT_LE(maxAbs(H - summed(triplets, n)), 1e-12 * maxAbs(H));
  EXPECT_EQ(H.nonZeros(), Eigen::Index(n) * n);  // every entry stored, column-major
  for (int c = 0; c < n; ++c) EXPECT_EQ(H.outerIndexPtr()[c], c * n);
  EXPECT_EQ(assembler.numPatternBuilds(), 1);
  // Other positions and counts next time: no rebuild, no lookups.
  const std::vector<Triplet> other = randomBlockTriplets(group_start, 5, 5);
  assembler.assemble(other, {}, n, H);
  EXPECT_LE(maxAbs(H - summed(other, n)), 1e-12 * maxAbs(H));
  EXPECT_EQ(assembler.numPatternBuilds(), 1);
  EXPECT_EQ(assembler.lastLookups(), 0u);
  // Bad input is still named; too many DoFs for dense storage are refused.
  std::string message =
      test::messageOf<InputError>([&] { assembler.assemble({Triplet(0, 27, 1.0)}, {}, n, H); });
  EXPECT_NE(message.find("(0, 27)"), std::string::npos) << message;
  HessianAssembler large;
  large.setDense(true);
  const int too_many = HessianAssembler::kMaxDenseDofs + 1;
  message = test::messageOf<InputError>([&] { large.assemble({}, {}, too_many, H); });
  EXPECT_NE(message.find(std::to_string(too_many)), std::string::npos) << message;
  // Back to the sparse pattern.
  assembler.setDense(false);
  assembler.assemble(triplets, {}, n, H);
  EXPECT_LT(H.nonZeros(), Eigen::Index(n) * n);
  EXPECT_LE(maxAbs(H - summed(triplets, n)), 1e-12 * maxAbs(H));
}

TEST(HessianAssembler, FixedBlocksSumLikeTheirTriplets) {
  // Two "bones" (6 DoFs) and five "nodes" (3 DoFs); the block lists sit on node DoFs, one of
  // them shifted by an offset of 3 (as a simulable's list at its offset).
  const std::vector<int> group_start{0, 6, 12, 15, 18, 21, 24, 27};
  const int n = 27;
  std::mt19937 rng(21);
  std::uniform_real_distribution<double> value(-1.0, 1.0);
  auto randomBlocks = [&](size_t count) {
    std::vector<Mat3> v(count);
    for (Mat3& B : v) B = Mat3::NullaryExpr([&] { return value(rng); });
    return v;
  };
  const std::vector<std::pair<int, int>> positions_a{{12, 12}, {15, 12}, {12, 15}, {24, 21}};
  const std::vector<std::pair<int, int>> positions_b{{9, 9}, {18, 9}};  // + offset 3
  std::vector<Mat3> values_a = randomBlocks(4), values_b = randomBlocks(2);
  std::vector<FixedHessianBlocks> blocks(3);  // the middle list empty (a skeleton simulable)
  blocks[0] = {&positions_a, &values_a, 0};
  blocks[2] = {&positions_b, &values_b, 3};
  const std::vector<Triplet> triplets = randomBlockTriplets(group_start, 6, 22);
  auto all = [&] {
    std::vector<Triplet> t = triplets;
    const std::vector<Triplet> b = expanded(blocks);
    t.insert(t.end(), b.begin(), b.end());
    return t;
  };
  HessianAssembler assembler;
  assembler.setGroups(group_start);
  SpMat H;
  assembler.assemble(triplets, {}, blocks, n, H);
  ASSERT_GT(maxAbs(H), 0.0);
  EXPECT_LE(maxAbs(H - summed(all(), n)), 1e-14 * maxAbs(H));
  EXPECT_NE(H.coeff(18 + 3 + 2, 9 + 3 + 1), 0.0);  // list b's second block, offset applied
  const int builds = assembler.numPatternBuilds();
  // New values at the same positions: cached slots, no growth.
  values_a = randomBlocks(4);
  values_b = randomBlocks(2);
  assembler.assemble(triplets, {}, blocks, n, H);
  EXPECT_EQ(assembler.numPatternBuilds(), builds);
  EXPECT_LE(maxAbs(H - summed(all(), n)), 1e-14 * maxAbs(H));
  // A block where the pattern has none grows it once; the others are looked up again.
  std::vector<std::pair<int, int>> moved = positions_a;
  moved.back() = {6, 24};  // bone 1's translation rows × node 4
  blocks[0].positions = &moved;
  assembler.assemble(triplets, {}, blocks, n, H);
  EXPECT_EQ(assembler.numPatternBuilds(), builds + 1);
  EXPECT_LE(maxAbs(H - summed(all(), n)), 1e-14 * maxAbs(H));
  EXPECT_NE(H.coeff(8, 26), 0.0);
  // Dense storage adds the same blocks.
  HessianAssembler dense;
  dense.setDense(true);
  dense.assemble(triplets, {}, blocks, n, H);
  EXPECT_LE(maxAbs(H - summed(all(), n)), 1e-14 * maxAbs(H));
  // Two blocks at one position would race in the parallel fill: refused.
  std::vector<std::pair<int, int>> twice{{12, 12}, {12, 12}};
  std::vector<Mat3> two = randomBlocks(2);
  std::string message = test::messageOf<InputError>([&] {
    assembler.assemble(triplets, {}, {{&twice, &two, 0}}, n, H);
  });
  EXPECT_NE(message.find("same position"), std::string::npos) << message;
  // Outside the matrix, and a size mismatch.
  std::vector<std::pair<int, int>> outside{{25, 0}};
  std::vector<Mat3> one = randomBlocks(1);
  message = test::messageOf<InputError>([&] {
    assembler.assemble(triplets, {}, {{&outside, &one, 0}}, n, H);
  });
  EXPECT_NE(message.find("(25, 0)"), std::string::npos) << message;
  message = test::messageOf<InputError>([&] {
    assembler.assemble(triplets, {}, {{&positions_a, &one, 0}}, n, H);
  });
  EXPECT_NE(message.find("4 positions but 1 values"), std::string::npos) << message;
}

// From 256 DoFs the dense fill runs on two threads, each owning half of the columns: blocks
// that straddle the split, lists that share positions and repeated triplets sum as on one
// thread, and bad positions are still reported (from inside the parallel region).
TEST(HessianAssembler, DenseFillOnTwoThreadsSumsLikeTheTriplets) {
  std::vector<int> group_start{0};
  for (int b = 0; b < 10; ++b) group_start.push_back(group_start.back() + 6);
  while (group_start.back() < 300) group_start.push_back(group_start.back() + 3);
  const int n = group_start.back();
  ASSERT_GE(n, 256);
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> value(-1.0, 1.0);
  std::uniform_int_distribution<int> position(0, n - 3);
  std::vector<std::pair<int, int>> positions{{0, n / 2 - 2}, {n / 2 - 1, n / 2 - 1}, {n - 3, 0}};
  for (int k = 0; k < 200; ++k) positions.emplace_back(position(rng), position(rng));
  std::vector<Mat3> values_a(positions.size()), values_b(positions.size());
  for (auto* values : {&values_a, &values_b})
    for (Mat3& B : *values) B = Mat3::NullaryExpr([&] { return value(rng); });
  const std::vector<FixedHessianBlocks> blocks{{&positions, &values_a, 0},
                                               {&positions, &values_b, 0}};
  std::vector<Triplet> triplets = randomBlockTriplets(group_start, 60, 7);
  triplets.emplace_back(5, n / 2, 0.25);
  triplets.emplace_back(5, n / 2, 0.5);  // repeated
  std::vector<Triplet> all = triplets;
  const std::vector<Triplet> b = expanded(blocks);
  all.insert(all.end(), b.begin(), b.end());
  HessianAssembler dense;
  dense.setDense(true);
  SpMat H;
  dense.assemble(triplets, {}, blocks, n, H);
  ASSERT_GT(maxAbs(H), 0.0);
  EXPECT_LE(maxAbs(H - summed(all, n)), 1e-14 * maxAbs(H));
  // Again (storage kept, values zeroed by the threads): the same matrix.
  const SpMat first = H;
  dense.assemble(triplets, {}, blocks, n, H);
  EXPECT_EQ(maxAbs(H - first), 0.0);
  // Bad input named from inside the parallel fill.
  std::vector<std::pair<int, int>> outside{{1, n - 2}};
  std::vector<Mat3> one(1, Mat3::Identity());
  std::string message = test::messageOf<InputError>([&] {
    dense.assemble(triplets, {}, {{&outside, &one, 0}}, n, H);
  });
  EXPECT_NE(message.find("(1, " + std::to_string(n - 2) + ")"), std::string::npos) << message;
  message = test::messageOf<InputError>([&] { dense.assemble({Triplet(2, n, 1.0)}, {}, n, H); });
  EXPECT_NE(message.find("(2, " + std::to_string(n) + ")"), std::string::npos) << message;
}

TEST(HessianAssembler, RejectsBadInput) {
  HessianAssembler assembler;
  SpMat H;
  std::string message =
      test::messageOf<InputError>([&] { assembler.assemble({Triplet(0, 7, 1.0)}, {}, 5, H); });
  EXPECT_NE(message.find("(0, 7)"), std::string::npos) << message;
  message = test::messageOf<InputError>([&] { assembler.setGroups({0, 6, 6}); });
  EXPECT_NE(message.find("increase"), std::string::npos) << message;
  assembler.setGroups({0, 6, 9});
  message = test::messageOf<InputError>([&] { assembler.assemble({}, {}, 12, H); });
  EXPECT_NE(message.find("n = 12"), std::string::npos) << message;
  message =
      test::messageOf<InputError>([&] { assembler.assemble({Triplet(0, 0, 1.0)}, {0}, 9, H); });
  EXPECT_NE(message.find("segment_end"), std::string::npos) << message;
}

// ---- scenes ------------------------------------------------------------------------------------

using test::translateBones;

/// A (walking when `walk`) and B (at rest) in one scene, B moved along z until the avatars just
/// stop touching, then `overlap` metres back into A.
std::unique_ptr<Scene> twoInContact(std::shared_ptr<const SoftAvatar> avatar_a,
                                    std::shared_ptr<const SoftAvatar> avatar_b, double overlap,
                                    bool walk, const SceneOptions& options = {}) {
  auto scene = std::make_unique<Scene>(options);
  scene->addSimulable(std::make_shared<Simulable>(avatar_a, walk ? shared().walk : nullptr));
  scene->addSimulable(std::make_shared<Simulable>(avatar_b));
  scene->initialize();
  test::touchAlongZ(*scene, 1, overlap);
  return scene;
}

/// The merged gradient at the state moved by d pulled back to the chart at d = 0: rotation
/// entries of every bone times J_l(δω)ᵀ; soft-tissue displacements are additive (unchanged).
VecX pullBack(const Scene& scene, const VecX& g, const VecX& d) {
  VecX out = g;
  for (size_t i = 0; i < scene.simulables().size(); ++i) {
    const int offset = scene.offset(int(i));
    for (int b = 0; b < scene.simulables()[i]->numBoneDofs() / 6; ++b) {
      const int k = offset + 6 * b + 3;
      out.segment<3>(k) = leftJacobianSO3(d.segment<3>(k)).transpose() * g.segment<3>(k);
    }
  }
  return out;
}

template <class F>
auto atMoved(Scene& scene, const VecX& d, F&& f) {
  scene.push();
  scene.step(d);
  auto result = f();
  scene.pop();
  return result;
}

/// Avatar–avatar contact gradient (against the energy) and exact Hessian (against the
/// gradient) by central differences, over every bone DoF and every DoF the Hessian touches.
void expectAvatarContactDerivativesMatch(Scene& scene) {
  const int n = scene.numDofs();
  int active = 0;
  const double e0 = scene.avatarContactEnergy(nullptr, nullptr, true, &active);
  ASSERT_GT(active, 10) << "the avatars must overlap";
  ASSERT_GT(e0, 0.0);
  VecX g = VecX::Zero(n);
  std::vector<Triplet> exact, psd;
  scene.avatarContactEnergy(&g, &exact, false);
  scene.avatarContactEnergy(nullptr, &psd, true);
  const MatX H = MatX(summed(exact, n));
  std::vector<int> columns;
  for (int k = 0; k < n; ++k) {
    bool bone = false;
    for (size_t i = 0; i < scene.simulables().size(); ++i)
      bone = bone || (k >= scene.offset(int(i)) &&
                      k < scene.offset(int(i)) + scene.simulables()[i]->numBoneDofs());
    if (bone || H.col(k).norm() > 0.0) columns.push_back(k);
  }
  const auto expand = [&](const VecX& z) {
    VecX d = VecX::Zero(n);
    for (size_t j = 0; j < columns.size(); ++j) d[columns[j]] = z[j];
    return d;
  };
  MatX g_columns(1, columns.size()), H_columns(n, columns.size());
  for (size_t j = 0; j < columns.size(); ++j) {
    g_columns(0, j) = g[columns[j]];
    H_columns.col(j) = H.col(columns[j]);
  }
  const auto energy = [&](const VecX& z) {
    return atMoved(scene, expand(z), [&] {
      return VecX::Constant(1, scene.avatarContactEnergy(nullptr, nullptr, true));
    });
  };
  const auto gradient = [&](const VecX& z) {
    const VecX d = expand(z);
    return atMoved(scene, d, [&] {
      VecX gd = VecX::Zero(n);
      scene.avatarContactEnergy(&gd, nullptr, true);
      return pullBack(scene, gd, d);
    });
  };
  const VecX z0 = VecX::Zero(columns.size());
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(energy, z0, g_columns, 1e-6));
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(gradient, z0, H_columns, 1e-5));
  // Gauss–Newton form: symmetric positive semidefinite.
  const MatX Hpsd = MatX(summed(psd, n));
  EXPECT_LT((Hpsd - Hpsd.transpose()).norm(), 1e-12 * Hpsd.norm());
  EXPECT_GT(Eigen::SelfAdjointEigenSolver<MatX>(Hpsd).eigenvalues()[0], -1e-9 * Hpsd.norm());
}

double lowestNodeHeight(const Scene& scene) {
  double lowest = std::numeric_limits<double>::infinity();
  for (const auto& sim : scene.simulables())
    lowest = std::min(lowest, sim->getNodes().col(1).minCoeff());
  return lowest;
}

/// Σ of the triplets the scene's Hessian is made of, through the public calls.
SpMat sceneTripletSum(Scene& scene, bool psd) {
  std::vector<Triplet> triplets;
  for (size_t i = 0; i < scene.simulables().size(); ++i) {
    scene.simulables()[i]->getDynamicHessianTripletVector(triplets, scene.offset(int(i)), psd);
    scene.simulables()[i]->getPotentialHessianTripletVector(triplets, scene.offset(int(i)), psd);
  }
  scene.avatarContactEnergy(nullptr, &triplets, psd);
  return summed(triplets, scene.numDofs());
}

TEST(SceneSoft, SkeletonAvatarContactDerivativesMatchFiniteDifferences) {
  auto scene = twoInContact(shared().avatar, shared().avatar, 0.04, true);
  scene->step(randomVector(scene->numDofs(), 0.02, 3));  // a generic configuration
  expectAvatarContactDerivativesMatch(*scene);
}

TEST(SceneSoft, GeneralPatternHessianEqualsTheSummedTriplets) {
  SceneOptions general;
  general.general_hessian_pattern = true;
  auto scene = twoInContact(shared().avatar, shared().avatar, 0.03, true, general);
  auto reference = twoInContact(shared().avatar, shared().avatar, 0.03, true);
  const int n = scene->numDofs();
  const double ground = lowestNodeHeight(*scene) + 0.015;
  for (auto* s : {scene.get(), reference.get()}) {
    s->addCollider(Collider::plane(Vec3(0, ground, 0), Vec3::UnitY()));
    for (auto& sim : s->simulables()) sim->preUpdate();
    s->step(randomVector(n, 0.02, 5));
  }
  for (bool psd : {false, true}) {
    SpMat H, H_block;
    scene->hessian(H, psd);
    reference->hessian(H_block, psd);
    const SpMat S = sceneTripletSum(*scene, psd);
    ASSERT_GT(maxAbs(S), 0.0);
    EXPECT_LE(maxAbs(H - S), 1e-12 * maxAbs(S)) << "psd = " << psd;
    // The general pattern of a skeleton is the block pattern, values bitwise equal.
    ASSERT_EQ(H.nonZeros(), H_block.nonZeros());
    EXPECT_TRUE(std::equal(H.outerIndexPtr(), H.outerIndexPtr() + n + 1, H_block.outerIndexPtr()));
    EXPECT_TRUE(
        std::equal(H.innerIndexPtr(), H.innerIndexPtr() + H.nonZeros(), H_block.innerIndexPtr()));
    EXPECT_TRUE(std::equal(H.valuePtr(), H.valuePtr() + H.nonZeros(), H_block.valuePtr()));
  }
  EXPECT_FALSE(scene->hasSoftTissue());
  EXPECT_EQ(&scene->newtonOptions(), &scene->options().newton);
}

TEST(SceneSoft, SkeletonStatesAreBitwiseEqualOnEitherPattern) {
  SceneOptions general;
  general.general_hessian_pattern = true;
  auto scene = twoInContact(shared().avatar, shared().avatar, 0.03, true, general);
  auto reference = twoInContact(shared().avatar, shared().avatar, 0.03, true);
  int contacts = 0;
  const double ground = lowestNodeHeight(*scene) + 0.005;
  for (auto* s : {scene.get(), reference.get()})
    s->addCollider(Collider::plane(Vec3(0, ground, 0), Vec3::UnitY()));
  for (int step = 0; step < 20; ++step) {
    const StepStats a = scene->step(), b = reference->step();
    EXPECT_TRUE(a.newton.converged) << "step " << step << ": " << a.newton.message;
    EXPECT_EQ(a.newton.iterations, b.newton.iterations) << "step " << step;
    contacts = std::max(contacts, a.active_contacts);
    for (int i = 0; i < 2; ++i) {
      const VecX qa = scene->simulables()[i]->getState();
      const VecX qb = reference->simulables()[i]->getState();
      ASSERT_EQ(qa, qb) << "simulable " << i << ", step " << step;
    }
  }
  EXPECT_GT(contacts, 0);
  EXPECT_EQ(scene->linearSolver()->name(), reference->linearSolver()->name());
}

TEST(SceneSoft, SoftTissueNewtonDefaults) {
  const NewtonOptions o = SceneOptions().soft_tissue_newton;
  EXPECT_TRUE(o.exact_hessian);  // tried first at every iteration, the PSD form as fallback
  EXPECT_EQ(o.linear_solver, LinearSolverType::Cholmod);
  EXPECT_TRUE(o.lagged.enabled);
  EXPECT_TRUE(SceneOptions().newton.exact_hessian);
}

// ---- soft tissue ---------------------------------------------------------------------------

/// The FEM avatar of the small synthetic body (coarse interior, cache in a temp dir).
std::shared_ptr<const SoftAvatar> softAvatar() {
  static const std::shared_ptr<const SoftAvatar> avatar = [] {
    SoftAvatarSettings settings;
    settings.voxel_size = 0.02;
    settings.volumetric.cache_dir = test::freshTempDir("scene_soft_cache");
    settings.volumetric.tet_mesh.resolution = 0.3;
    auto a = std::make_shared<SoftAvatar>(shared().body, VecX(), settings);
    a->enableSoftTissue();
    a->initVolumetricData();
    return a;
  }();
  return avatar;
}

TEST(SceneSoft, SoftAvatarContactDerivativesMatchFiniteDifferences) {
  auto scene = twoInContact(softAvatar(), shared().avatar, 0.04, false);
  const Simulable& soft = *scene->simulables()[0];
  if (!soft.hasSoftTissue()) GTEST_SKIP() << "FEM model not present";
  ASSERT_TRUE(scene->hasSoftTissue());
  const int n = scene->numDofs();
  VecX d = randomVector(n, 0.02, 7);
  // Soft displacements of a few mm, so Y ≠ X̄ and the u part is generic.
  for (int k = scene->offset(0) + soft.numBoneDofs(); k < scene->offset(1); ++k) d[k] *= 0.2;
  scene->step(d);
  ASSERT_GT(soft.getSoftTissueDisplacements().norm(), 0.0);
  expectAvatarContactDerivativesMatch(*scene);
  // The u part is there: some soft vertex in contact has a nonzero gradient.
  VecX g = VecX::Zero(n);
  scene->avatarContactEnergy(&g, nullptr, true);
  const int soft_dofs = soft.numDofs() - soft.numBoneDofs();
  EXPECT_GT(g.segment(scene->offset(0) + soft.numBoneDofs(), soft_dofs).norm(), 0.0);
}

// The scene's skinning of the moving surface against Simulable::getNodes, vertex by vertex.
TEST(SceneSoft, SoftAvatarContactEnergyEqualsTheBruteForceSum) {
  auto scene = twoInContact(softAvatar(), shared().avatar, 0.05, false);
  if (!scene->simulables()[0]->hasSoftTissue()) GTEST_SKIP() << "FEM model not present";
  scene->step(randomVector(scene->numDofs(), 0.01, 12));
  const ContactOptions& options = scene->options().avatar_contact_options;
  double brute = 0.0;
  for (int ia = 0; ia < 2; ++ia) {
    const Simulable& A = *scene->simulables()[ia];
    const Simulable& B = *scene->simulables()[1 - ia];
    const MatX3 nodes = A.getNodes();
    const VecX& areas = A.avatar().vertexAreas();
    for (const BoneCapsule& c : B.avatar().boneCapsules()) {
      if (c.radius <= 0.0) continue;
      const Mat3& R = B.boneRotations()[c.bone];
      const Vec3 t = B.bonePositions().row(c.bone).transpose();
      const Vec3 J = B.avatar().restJoints().row(c.bone).transpose();
      for (int v = 0; v < nodes.rows(); ++v)
        brute +=
            vertexCapsulePenalty(nodes.row(v).transpose(), R * (c.a - J) + t, R * (c.b - J) + t,
                                 c.radius, options.stiffness * areas[v], options);
    }
  }
  ASSERT_GT(brute, 0.0);
  EXPECT_NEAR(scene->avatarContactEnergy(nullptr, nullptr, true), brute, 1e-10 * brute);
}

TEST(SceneSoft, FixedBlocksPlusTripletsAreTheTripletHessian) {
  auto scene = twoInContact(softAvatar(), shared().avatar, 0.03, true);
  if (!scene->simulables()[0]->hasSoftTissue()) GTEST_SKIP() << "FEM model not present";
  scene->step(randomVector(scene->numDofs(), 0.01, 14));
  const int n = scene->numDofs();
  for (int i = 0; i < 2; ++i) {
    const Simulable& sim = *scene->simulables()[size_t(i)];
    for (bool psd : {true, false}) {
      for (bool dynamic : {true, false}) {
        std::vector<Triplet> plain, rest;
        std::vector<FixedHessianBlocks> blocks;
        if (dynamic) {
          sim.getDynamicHessianTripletVector(plain, scene->offset(i), psd);
          sim.getDynamicHessianTripletVector(rest, blocks, scene->offset(i), psd);
        } else {
          sim.getPotentialHessianTripletVector(plain, scene->offset(i), psd);
          sim.getPotentialHessianTripletVector(rest, blocks, scene->offset(i), psd);
        }
        const std::vector<Triplet> block_triplets = expanded(blocks);
        if (sim.hasSoftTissue()) {
          // Inertia: its coupling list; potential: the elastic node pairs (column-major) and
          // gravity's rotation–displacement list (empty in the PSD form: it keeps its place).
          ASSERT_EQ(blocks.size(), dynamic ? 1u : 2u);
          EXPECT_LT(rest.size(), plain.size());
          if (!dynamic) {
            const auto& p = *blocks[0].positions;
            for (size_t k = 1; k < p.size(); ++k)
              ASSERT_TRUE(std::make_pair(p[k - 1].second, p[k - 1].first) <
                          std::make_pair(p[k].second, p[k].first));
            double largest = 0.0;
            for (const Mat3& B : *blocks[1].values)
              largest = std::max(largest, B.cwiseAbs().maxCoeff());
            if (psd)
              EXPECT_TRUE(blocks[1].empty());  // gravity couples bones and tissue only exactly
            else
              EXPECT_GT(largest, 0.0);
          }
        } else {
          EXPECT_TRUE(blocks.empty());
          EXPECT_EQ(rest.size(), plain.size());
        }
        rest.insert(rest.end(), block_triplets.begin(), block_triplets.end());
        const SpMat S = summed(plain, n);
        ASSERT_GT(maxAbs(S), 0.0);
        EXPECT_LE(maxAbs(summed(rest, n) - S), 1e-12 * maxAbs(S))
            << "simulable " << i << (dynamic ? ", dynamic" : ", potential") << ", psd " << psd;
      }
    }
  }
}

// The lagged PCG's coarse level (LaggedFactorOptions::coarse_correction, on in the soft-tissue
// defaults): the scene names every simulable's bone DoFs; a walking FEM avatar reaches the same
// states as without it in fewer PCG iterations.
TEST(SceneSoft, CoarseLevelIsTheBonesAndSavesPcgIterations) {
  if (!softAvatar()->volumetricData().numTets()) GTEST_SKIP() << "FEM model not present";
  EXPECT_TRUE(SceneOptions().soft_tissue_newton.lagged.coarse_correction);
  EXPECT_FALSE(NewtonOptions().lagged.coarse_correction);
  const auto run = [&](bool coarse_correction, int& cg_iterations) {
    SceneOptions options;
    options.soft_tissue_newton.lagged.coarse_correction = coarse_correction;
    options.soft_tissue_newton.gradient_tolerance = 1e-8;
    auto scene = std::make_unique<Scene>(options);
    scene->addSimulable(std::make_shared<Simulable>(softAvatar(), shared().walk));
    // A second avatar, 2 m away: the coarse DoFs of both.
    auto other = std::make_shared<Simulable>(shared().avatar);
    scene->addSimulable(other);
    scene->initialize();
    translateBones(*other, Vec3(2.0, 0.0, 0.0));
    scene->addCollider(
        Collider::plane(Vec3(0, lowestNodeHeight(*scene) - 0.002, 0), Vec3::UnitY()));
    std::vector<int> dofs;
    scene->coarseDofs(dofs);
    std::vector<int> bones;
    for (int i = 0; i < 2; ++i)
      for (int k = 0; k < scene->simulables()[size_t(i)]->numBoneDofs(); ++k)
        bones.push_back(scene->offset(i) + k);
    EXPECT_EQ(dofs, bones);
    cg_iterations = 0;
    for (int step = 0; step < 6; ++step) {
      const StepStats stats = scene->step();
      EXPECT_TRUE(stats.newton.converged) << "step " << step << ": " << stats.newton.message;
      cg_iterations += stats.newton.cg_iterations;
    }
    return scene->simulables()[0]->getNodes();
  };
  int with = 0, without = 0;
  const MatX3 a = run(true, with), b = run(false, without);
  EXPECT_GT(without, 0);
  EXPECT_LT(with, without);
  EXPECT_LE((a - b).cwiseAbs().maxCoeff(), 1e-6);
}

TEST(SceneSoft, SoftSceneHessianAndSteps) {
  auto scene = twoInContact(softAvatar(), shared().avatar, 0.03, true);
  if (!scene->simulables()[0]->hasSoftTissue()) GTEST_SKIP() << "FEM model not present";
  EXPECT_EQ(&scene->newtonOptions(), &scene->options().soft_tissue_newton);
  for (auto& sim : scene->simulables()) sim->preUpdate();
  scene->push();
  scene->step(randomVector(scene->numDofs(), 0.01, 9));
  for (bool psd : {true, false}) {
    SpMat H;
    scene->hessian(H, psd);
    const SpMat S = sceneTripletSum(*scene, psd);
    ASSERT_GT(maxAbs(S), 0.0);
    EXPECT_LE(maxAbs(H - S), 1e-12 * maxAbs(S)) << "psd = " << psd;
  }
  scene->pop();
  for (int step = 0; step < 3; ++step) {
    const StepStats stats = scene->step();
    EXPECT_TRUE(stats.newton.converged) << "step " << step << ": " << stats.newton.message;
    // Newton's timings reach the step's report and fit in it.
    EXPECT_GT(stats.newton.seconds_hessian, 0.0);
    EXPECT_LE(stats.newton.seconds_energy + stats.newton.seconds_gradient +
                  stats.newton.seconds_hessian + stats.newton.seconds_factorization +
                  stats.newton.seconds_solve,
              stats.seconds);
  }
  EXPECT_EQ(scene->linearSolver()->name(), makeLinearSolver(LinearSolverType::Cholmod, 1)->name());
}

}  // namespace
}  // namespace flsh
