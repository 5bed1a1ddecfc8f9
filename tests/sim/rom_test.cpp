// The ROM soft skeleton against the FEM one it reduces: without cubature its energies, gradients
// and Hessians are the FEM's at u = Φz, pulled back through the basis (the chain rule, exactly);
// with the cubatures they approximate them within the held-out cubature error.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <memory>

#include "flsh/core/error.h"
#include "flsh/sim/simulable.h"
#include "flsh/solve/scene.h"
#include "support/small_soft_avatar.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::randomVector;

SoftAvatarSettings settings() {
  static const std::string cache = test::freshTempDir("rom_test_cache");
  return test::smallSoftAvatarSettings(cache);
}

// kind 0: FEM; 1: ROM with exact integration; 2: ROM with both cubatures; 3 and 4: ROM with
// exact integration on the small modes (test::useSmallModes), alone (3) and with the handles (4).
std::shared_ptr<const SoftAvatar> avatar(int kind) {
  static std::shared_ptr<const SoftAvatar> avatars[5];
  if (!avatars[kind]) {
    SoftAvatarSettings s = settings();
    if (kind >= 3)
      test::useSmallModes(s,
                          kind == 3 ? ReducedBasisKind::Modes : ReducedBasisKind::ModesAndHandles);
    auto a = std::make_shared<SoftAvatar>(test::smallScene(800).body, VecX(), s);
    a->enableSoftTissue();
    a->enableReducedModel(kind > 0);
    a->enableElasticCubature(kind == 2);
    a->enableInertialCubature(kind == 2);
    a->initVolumetricData();
    avatars[kind] = a;
  }
  return avatars[kind];
}

// P = ∂(FEM state)/∂(ROM state): identity on the bones, φ_h(j) I₃ from z_h to u_j.
SpMat reductionMatrix(const Simulable& fem, const Simulable& rom) {
  std::vector<Triplet> T;
  for (int i = 0; i < fem.numBoneDofs(); ++i) T.emplace_back(i, i, 1.0);
  for (int k = 0; k < fem.softNodes().size(); ++k) {
    const int j = fem.softNodes()[k];
    for (const auto& [index, block] : rom.nodeDisplacementBasis(j))
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
          if (block(r, c) != 0.0) T.emplace_back(fem.nodeSoftDof(j) + r, index + c, block(r, c));
  }
  SpMat P(fem.numDofs(), rom.numDofs());
  P.setFromTriplets(T.begin(), T.end());
  return P;
}

struct Pair {
  std::unique_ptr<Simulable> fem, rom;
  SpMat P;
};

// A FEM and an exact ROM simulable (avatar `kind`) at the same walking state one step in: bones
// moved, z random, u = Φz; a ground plane 1.5 cm above the lowest vertex.
Pair samePair(unsigned seed, int kind = 1) {
  Pair p;
  p.fem = std::make_unique<Simulable>(avatar(0), test::smallScene(800).walk);
  p.rom = std::make_unique<Simulable>(avatar(kind), test::smallScene(800).walk);
  for (Simulable* s : {p.fem.get(), p.rom.get()}) {
    s->initialize();
    s->preUpdate();
  }
  p.P = reductionMatrix(*p.fem, *p.rom);
  VecX d = randomVector(p.rom->numDofs(), 0.03, seed);
  d.tail(p.rom->numDofs() - 144) = randomVector(p.rom->numDofs() - 144, 0.01, seed + 1);
  p.rom->updateState(d);
  VecX q = VecX(p.P * p.rom->getState());
  p.fem->setState(q);
  const Collider ground =
      Collider::plane(Vec3(0, p.fem->getNodes().col(1).minCoeff() + 0.015, 0), Vec3::UnitY());
  p.fem->setColliders({ground});
  p.rom->setColliders({ground});
  return p;
}

// Every basis kind: handles (1), modes (3), modes and handles (4).
class ReducedModelKinds : public ::testing::TestWithParam<int> {};

TEST_P(ReducedModelKinds, ExactIntegrationIsTheFemThroughTheBasis) {
  Pair p = samePair(3, GetParam());
  const int nf = p.fem->numDofs(), nr = p.rom->numDofs();
  ASSERT_GT(p.rom->getSoftTissueDisplacements().norm(), 0.0);
  EXPECT_LT((p.rom->getVertices() - p.fem->getVertices()).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((p.rom->getVolumeNodes() - p.fem->getVolumeNodes()).cwiseAbs().maxCoeff(), 1e-12);

  const double Ef = p.fem->getPotentialEnergyScalar(), Er = p.rom->getPotentialEnergyScalar();
  ASSERT_GT(std::abs(Ef), 0.0);
  EXPECT_NEAR(Er, Ef, 1e-10 * std::abs(Ef));
  const double Df = p.fem->getDynamicEnergyScalar(), Dr = p.rom->getDynamicEnergyScalar();
  ASSERT_GT(Df, 0.0);
  EXPECT_NEAR(Dr, Df, 1e-10 * Df);

  for (bool dynamic : {false, true}) {
    VecX gf = VecX::Zero(nf), gr = VecX::Zero(nr);
    if (dynamic) {
      p.fem->getDynamicGradientVector(gf);
      p.rom->getDynamicGradientVector(gr);
    } else {
      p.fem->getPotentialGradientVector(gf);
      p.rom->getPotentialGradientVector(gr);
    }
    const VecX expected = p.P.transpose() * gf;
    ASSERT_GT(gr.tail(nr - 144).norm(), 0.0);
    EXPECT_LT((gr - expected).cwiseAbs().maxCoeff(), 1e-9 * expected.cwiseAbs().maxCoeff())
        << (dynamic ? "dynamic" : "potential");
    for (bool psd : {false, true}) {
      std::vector<Triplet> Tf, Tr;
      if (dynamic) {
        p.fem->getDynamicHessianTripletVector(Tf, 0, psd);
        p.rom->getDynamicHessianTripletVector(Tr, 0, psd);
      } else {
        p.fem->getPotentialHessianTripletVector(Tf, 0, psd);
        p.rom->getPotentialHessianTripletVector(Tr, 0, psd);
      }
      SpMat Hf(nf, nf), Hr(nr, nr);
      Hf.setFromTriplets(Tf.begin(), Tf.end());
      Hr.setFromTriplets(Tr.begin(), Tr.end());
      const MatX reduced = MatX(p.P.transpose() * Hf * p.P);
      const MatX H = MatX(Hr);
      ASSERT_GT(H.bottomRightCorner(nr - 144, nr - 144).norm(), 0.0);
      EXPECT_LT((H - reduced).cwiseAbs().maxCoeff(), 1e-9 * reduced.cwiseAbs().maxCoeff())
          << (dynamic ? "dynamic" : "potential") << (psd ? " psd" : " exact");
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Kinds, ReducedModelKinds, ::testing::Values(1, 3, 4),
                         [](const ::testing::TestParamInfo<int>& info) {
                           return std::string(info.param == 1   ? "Handles"
                                              : info.param == 3 ? "Modes"
                                                                : "ModesAndHandles");
                         });

TEST(ReducedModel, CubatureApproximatesExactIntegration) {
  const ReducedData& data = avatar(2)->reducedData();
  ASSERT_GT(data.elastic.elements.size(), 0);
  ASSERT_GT(data.inertial.elements.size(), 0);
  // Same state in the exact ROM and the cubature ROM (same basis: the cubature does not change it).
  ASSERT_TRUE(avatar(1)->reducedData().basis.isApprox(data.basis));
  SimulableOptions options;
  options.gravity.setZero();  // the potential is then elastic (the springs are at rest)
  const auto walk = test::smallScene(800).walk;
  Simulable exact(avatar(1), walk, options), cubature(avatar(2), walk, options);
  for (Simulable* s : {&exact, &cubature}) {
    s->initialize();
    s->preUpdate();
  }
  VecX d = VecX::Zero(exact.numDofs());
  d.tail(exact.numDofs() - 144) = randomVector(exact.numDofs() - 144, 0.01, 8);
  exact.updateState(d);
  cubature.updateState(d);
  const double elastic_exact = exact.getPotentialEnergyScalar();
  const double elastic_cub = cubature.getPotentialEnergyScalar();
  ASSERT_TRUE(std::isfinite(elastic_cub));
  // Within a few times the held-out errors (which are relative to the whole sum).
  const double tolerance = 5.0 * std::max(data.elastic_test_error, data.inertial_test_error) + 0.02;
  EXPECT_NEAR(elastic_cub, elastic_exact, tolerance * std::abs(elastic_exact));
  const double kinetic_exact = exact.getDynamicEnergyScalar();
  const double kinetic_cub = cubature.getDynamicEnergyScalar();
  ASSERT_GT(kinetic_exact, 0.0);
  EXPECT_NEAR(kinetic_cub, kinetic_exact, tolerance * kinetic_exact);
}

// The rest-stiffness split: whatever tets the elastic cubature drew, its stiffness at rest is the
// exact one (small deformations such as gravity's sag see the exactly integrated subspace), and
// far from rest it still follows the cubature (not the exact energy, nor the quadratic alone).
TEST(ReducedModel, ElasticCubatureHasTheExactRestStiffness) {
  const ReducedData& data = avatar(2)->reducedData();
  const int T = avatar(2)->volumetricData().numTets();
  ASSERT_GT(data.elastic.elements.size(), 0);
  ASSERT_LT(data.elastic.elements.size(), T / 4);  // a real subset of the tets
  ASSERT_EQ(data.elastic_rest_stiffness.rows(), 3 * data.numHandles());
  SimulableOptions options;
  options.gravity.setZero();  // the z–z potential Hessian is then elastic only
  const auto walk = test::smallScene(800).walk;
  Simulable exact(avatar(1), walk, options), cubature(avatar(2), walk, options);
  for (Simulable* s : {&exact, &cubature}) {
    s->initialize();
    s->preUpdate();
  }
  const int n = exact.numDofs(), m = n - 144;
  const auto elastic = [&](Simulable& s) {
    std::vector<Triplet> T;
    s.getPotentialHessianTripletVector(T, 0, false);
    return MatX(test::denseFromTriplets(T, n).bottomRightCorner(m, m));
  };
  const MatX He = elastic(exact), Hc = elastic(cubature);
  ASSERT_GT(He.norm(), 0.0);
  EXPECT_LT((Hc - He).cwiseAbs().maxCoeff(), 1e-9 * He.cwiseAbs().maxCoeff());
  // The same matrix as the stored K (the bones at rest do not enter the elastic energy).
  EXPECT_LT((data.elastic_rest_stiffness - He).cwiseAbs().maxCoeff(),
            1e-9 * He.cwiseAbs().maxCoeff());
  // 2 cm of random handle displacement: the energies differ from each other and from ½ zᵀ K z.
  VecX d = VecX::Zero(n);
  d.tail(m) = randomVector(m, 0.02, 9);
  exact.updateState(d);
  cubature.updateState(d);
  const double quadratic = 0.5 * d.tail(m).dot(data.elastic_rest_stiffness * d.tail(m));
  const double Ee = exact.getPotentialEnergyScalar(), Ec = cubature.getPotentialEnergyScalar();
  ASSERT_GT(quadratic, 0.0);
  EXPECT_GT(std::abs(Ec - quadratic), 1e-3 * quadratic);
  EXPECT_GT(std::abs(Ec - Ee), 1e-6 * Ee);
  EXPECT_GT(Ec, 0.0);
}

// Far from rest the split elastic energy keeps at least half of the exact rest stiffness
// (restSplitFloors; the guarantee itself is checked on a synthetic subspace in
// fem_material_test): E(z) ≥ ½ · ½ zᵀ K z for handle displacements of 1 to 30 cm in random
// directions and their opposites, and for every handle pushed 0.5 to 8 cm towards its nearest
// joint (compressing, then inverting the tissue, where StVK softens and the excess is negative).
TEST(ReducedModel, ElasticCubatureKeepsHalfTheRestStiffnessFarFromRest) {
  const ReducedData& data = avatar(2)->reducedData();
  const MatX& K = data.elastic_rest_stiffness;
  ASSERT_GT(K.norm(), 0.0);
  SimulableOptions options;
  options.gravity.setZero();  // the potential is then the elastic energy (bones at their targets)
  Simulable cubature(avatar(2), test::smallScene(800).walk, options);
  cubature.initialize();
  cubature.preUpdate();
  const int n = cubature.numDofs(), m = n - 144;
  ASSERT_EQ(m, K.rows());
  const double E0 = cubature.getPotentialEnergyScalar();
  double lowest_ratio = std::numeric_limits<double>::infinity();
  const auto check = [&](const VecX& z) {
    VecX d = VecX::Zero(n);
    d.tail(m) = z;
    cubature.pushState();
    cubature.updateState(d);
    const double E = cubature.getPotentialEnergyScalar() - E0;
    cubature.popState();
    const double quadratic = 0.5 * z.dot(K * z);
    ASSERT_GT(quadratic, 0.0);
    ASSERT_TRUE(std::isfinite(E));
    EXPECT_GE(E, 0.5 * quadratic * (1.0 - 1e-9)) << "|z|inf " << z.lpNorm<Eigen::Infinity>();
    lowest_ratio = std::min(lowest_ratio, E / quadratic);
  };
  for (double amplitude : {0.01, 0.1, 0.3})
    for (int seed = 0; seed < 4; ++seed)
      for (double sign : {1.0, -1.0}) check(sign * randomVector(m, amplitude, 40 + seed));
  const MatX3& X = avatar(2)->restVertices();
  const MatX3& J = avatar(2)->restJoints();
  VecX inward = VecX::Zero(m);
  for (int h = 0; h < data.numHandles(); ++h) {
    const Vec3 x = X.row(data.handles[h]).transpose();
    Eigen::Index nearest = 0;
    (J.rowwise() - x.transpose()).rowwise().squaredNorm().minCoeff(&nearest);
    inward.segment<3>(3 * h) = (J.row(nearest).transpose() - x).normalized();
  }
  for (double depth : {0.005, 0.01, 0.02, 0.04, 0.08}) check(depth * inward);
  EXPECT_LT(lowest_ratio, 0.99);  // the excess lowers the energy below the quadratic somewhere
}

// A "cubature" of every tet with weight 1 (and the exact rest stiffness of the split) is exact
// integration: the same energies, gradients and Hessians as the ROM without cubature, to
// rounding.
TEST(ReducedModel, CubatureOfEveryTetWithUnitWeightsIsExactIntegration) {
  auto custom = std::make_shared<SoftAvatar>(test::smallScene(800).body, VecX(), settings());
  custom->enableSoftTissue();
  custom->enableReducedModel();
  custom->initVolumetricData();
  auto data = std::make_shared<ReducedData>(avatar(1)->reducedData());
  const int T = custom->volumetricData().numTets();
  for (Cubature* c : {&data->elastic, &data->inertial}) {
    c->elements = VecXi::LinSpaced(T, 0, T - 1);
    c->weights = VecX::Ones(T);
  }
  // With the rest-stiffness split, as the elastic cubature uses it: unit weights never reach
  // its bounded branch, and ½ zᵀ K z plus every tet's excess over its rest quadratic is the sum.
  data->elastic_rest_stiffness = elasticRestStiffness(custom->volumetricData(), data->basis);
  ASSERT_GT(data->elastic_rest_stiffness.norm(), 0.0);
  custom->setReducedData(data);
  const auto walk = test::smallScene(800).walk;
  Simulable exact(avatar(1), walk), cubature(custom, walk);
  const VecX d = randomVector(exact.numDofs(), 0.01, 5);
  for (Simulable* s : {&exact, &cubature}) {
    s->initialize();
    s->preUpdate();
    s->updateState(d);
    s->setColliders(
        {Collider::plane(Vec3(0, exact.getNodes().col(1).minCoeff() + 0.015, 0), Vec3::UnitY())});
  }
  const int n = exact.numDofs();
  const double Ee = exact.getPotentialEnergyScalar() + exact.getDynamicEnergyScalar();
  const double Ec = cubature.getPotentialEnergyScalar() + cubature.getDynamicEnergyScalar();
  ASSERT_GT(std::abs(Ee), 0.0);
  EXPECT_NEAR(Ec, Ee, 1e-11 * std::abs(Ee));
  VecX ge = VecX::Zero(n), gc = VecX::Zero(n);
  exact.getPotentialGradientVector(ge);
  exact.getDynamicGradientVector(ge);
  cubature.getPotentialGradientVector(gc);
  cubature.getDynamicGradientVector(gc);
  ASSERT_GT(ge.tail(n - 144).norm(), 0.0);
  EXPECT_LT((gc - ge).cwiseAbs().maxCoeff(), 1e-10 * ge.cwiseAbs().maxCoeff());
  std::vector<Triplet> Te, Tc;
  exact.getPotentialHessianTripletVector(Te, 0, false);
  exact.getDynamicHessianTripletVector(Te, 0, false);
  cubature.getPotentialHessianTripletVector(Tc, 0, false);
  cubature.getDynamicHessianTripletVector(Tc, 0, false);
  const MatX He = test::denseFromTriplets(Te, n), Hc = test::denseFromTriplets(Tc, n);
  ASSERT_GT(He.bottomRightCorner(n - 144, n - 144).norm(), 0.0);
  EXPECT_LT((Hc - He).cwiseAbs().maxCoeff(), 1e-10 * He.cwiseAbs().maxCoeff());
}

// A simulable of avatar(kind) one walking step in, at a random state (bones moved, soft state
// random), with a ground plane 1.5 cm above its lowest vertex.
std::unique_ptr<Simulable> movedOnTheGround(int kind, unsigned seed) {
  auto sim = std::make_unique<Simulable>(avatar(kind), test::smallScene(800).walk);
  sim->initialize();
  sim->preUpdate();
  VecX d = randomVector(sim->numDofs(), 0.03, seed);
  d.tail(sim->numDofs() - 144) = randomVector(sim->numDofs() - 144, 0.01, seed + 1);
  sim->updateState(d);
  sim->setColliders(
      {Collider::plane(Vec3(0, sim->getNodes().col(1).minCoeff() + 0.015, 0), Vec3::UnitY())});
  return sim;
}

// The block overloads return the ROM's bone–z and z–z blocks as one fixed list per part (same
// positions in both parts and every call), summing with the remaining triplets to the triplet
// overloads' Hessian, the triplets left being bone–bone ones; the list is symmetric (its lower
// blocks mirror the upper ones) and covers every block even with the ground in contact.
TEST(ReducedModel, HessianBlocksComeAsOneFixedListPerPart) {
  for (int kind : {1, 2}) {
    const auto moved = movedOnTheGround(kind, 5);
    const Simulable& sim = *moved;
    const int n = sim.numDofs(), offset = 7;
    const std::vector<std::pair<int, int>>* positions = nullptr;
    for (bool psd : {false, true})
      for (bool dynamic : {true, false}) {
        SCOPED_TRACE(std::string(kind == 2 ? "cubature" : "exact") +
                     (dynamic ? ", dynamic" : ", potential") + (psd ? ", psd" : ", exact form"));
        std::vector<Triplet> plain, rest;
        std::vector<FixedHessianBlocks> blocks;
        if (dynamic) {
          sim.getDynamicHessianTripletVector(plain, offset, psd);
          sim.getDynamicHessianTripletVector(rest, blocks, offset, psd);
        } else {
          sim.getPotentialHessianTripletVector(plain, offset, psd);
          sim.getPotentialHessianTripletVector(rest, blocks, offset, psd);
        }
        ASSERT_EQ(blocks.size(), 1u);
        ASSERT_EQ(blocks[0].offset, offset);
        if (!positions) positions = blocks[0].positions;
        EXPECT_EQ(blocks[0].positions, positions);  // one pattern for both parts
        for (const Triplet& t : rest)               // the triplets left are bone–bone ones
          ASSERT_TRUE(t.row() < offset + 144 && t.col() < offset + 144)
              << t.row() << ", " << t.col();
        const MatX S = test::denseFromTriplets(plain, n + offset);
        const MatX B = test::denseFromTriplets(test::expanded(blocks), n + offset);
        ASSERT_GT(B.bottomRightCorner(n - 144, n - 144).cwiseAbs().maxCoeff(), 0.0);
        EXPECT_LE((B - B.transpose()).cwiseAbs().maxCoeff(), 1e-14 * B.cwiseAbs().maxCoeff());
        const MatX sum = test::denseFromTriplets(rest, n + offset) + B;
        EXPECT_LE((sum - S).cwiseAbs().maxCoeff(), 1e-12 * S.cwiseAbs().maxCoeff());
      }
  }
}

// getHessianTripletVector (both parts at once) returns the two block overloads' lists (same
// positions) and triplets. The FEM's: the dynamic ones bit for bit and in order, the potential
// ones summing to the same up to round-off. The ROM's (inertia on one thread beside contact,
// gravity and the elastic tets on another, a tenth of inertia's mass nodes moved to the second
// to balance them): the parts differ from the overloads' (that share of inertia comes with the
// potential part) but the whole Hessian is the same up to round-off.
TEST(ReducedModel, BothHessianPartsAtOnceAreThePartsInOrder) {
  for (int kind : {0, 1, 2}) {
    const auto moved = movedOnTheGround(kind, 8);
    const Simulable& sim = *moved;
    const int n = sim.numDofs() + 3;
    for (bool psd : {false, true}) {
      SCOPED_TRACE("kind " + std::to_string(kind) + (psd ? ", psd" : ", exact form"));
      std::vector<Triplet> parts;
      std::vector<FixedHessianBlocks> part_blocks;
      sim.getDynamicHessianTripletVector(parts, part_blocks, 3, psd);
      const size_t dynamic_count = parts.size();
      std::vector<std::vector<Mat3>> part_values;
      for (const auto& list : part_blocks) part_values.push_back(*list.values);
      const size_t dynamic_lists = part_blocks.size();
      std::vector<Triplet> dynamic_whole = parts;  // with its lists, before they are reused
      for (const Triplet& t : test::expanded(part_blocks)) dynamic_whole.push_back(t);
      sim.getPotentialHessianTripletVector(parts, part_blocks, 3, psd);
      for (size_t k = dynamic_lists; k < part_blocks.size(); ++k)
        part_values.push_back(*part_blocks[k].values);
      std::vector<Triplet> potential_whole(parts.begin() + long(dynamic_count), parts.end());
      for (const Triplet& t :
           test::expanded({part_blocks.begin() + long(dynamic_lists), part_blocks.end()}))
        potential_whole.push_back(t);
      const MatX expected =
          test::denseFromTriplets(dynamic_whole, n) + test::denseFromTriplets(potential_whole, n);
      ASSERT_GT(expected.cwiseAbs().maxCoeff(), 0.0);

      std::vector<Triplet> both = {Triplet(0, 0, 1.0)};  // appended after what is there
      std::vector<FixedHessianBlocks> both_blocks;
      const size_t potential_start = sim.getHessianTripletVector(both, both_blocks, 3, psd);
      ASSERT_EQ(both_blocks.size(), part_blocks.size());
      ASSERT_EQ(both_blocks.size(), kind == 0 ? 3u : 2u);
      for (size_t k = 0; k < both_blocks.size(); ++k) {
        EXPECT_EQ(both_blocks[k].positions, part_blocks[k].positions);
        EXPECT_EQ(both_blocks[k].offset, 3);
        ASSERT_EQ(both_blocks[k].values->size(), part_values[k].size());
      }
      // The whole Hessian (the first triplet was there before).
      std::vector<Triplet> whole(both.begin() + 1, both.end());
      for (const Triplet& t : test::expanded(both_blocks)) whole.push_back(t);
      EXPECT_LE((test::denseFromTriplets(whole, n) - expected).cwiseAbs().maxCoeff(),
                1e-14 * expected.cwiseAbs().maxCoeff());
      if (kind > 0) {
        // The ROM's split: both parts carry inertia's blocks (list 0 and the bone pairs).
        EXPECT_GT(potential_start, 1u);
        EXPECT_LT(potential_start, both.size());
        continue;
      }
      EXPECT_EQ(potential_start, 1 + dynamic_count);
      ASSERT_EQ(both.size(), 1 + parts.size());
      for (size_t k = 0; k < dynamic_count; ++k) {  // the dynamic part in its order
        ASSERT_EQ(both[k + 1].row(), parts[k].row());
        ASSERT_EQ(both[k + 1].col(), parts[k].col());
        ASSERT_EQ(both[k + 1].value(), parts[k].value());
      }
      const MatX potential = test::denseFromTriplets(
          std::vector<Triplet>(parts.begin() + long(dynamic_count), parts.end()), n);
      const MatX got = test::denseFromTriplets(
          std::vector<Triplet>(both.begin() + long(1 + dynamic_count), both.end()), n);
      EXPECT_LE((got - potential).cwiseAbs().maxCoeff(), 1e-14 * potential.cwiseAbs().maxCoeff());
      for (size_t k = 0; k < both_blocks.size(); ++k) {
        double largest = 0.0;  // 0 for the FEM's gravity list in the PSD form
        for (const Mat3& B : part_values[k]) largest = std::max(largest, B.cwiseAbs().maxCoeff());
        if (k < 2) {
          ASSERT_GT(largest, 0.0) << "list " << k;
        }
        for (size_t b = 0; b < part_values[k].size(); ++b) {
          const Mat3& got_block = (*both_blocks[k].values)[b];
          if (k < dynamic_lists)
            ASSERT_EQ(got_block, part_values[k][b]) << "list " << k << " block " << b;
          else
            ASSERT_LE((got_block - part_values[k][b]).cwiseAbs().maxCoeff(), 1e-14 * largest)
                << "list " << k << " block " << b;
        }
      }
    }
  }
}

// getGradientVector (ROM: inertia and gravity beside contact on two threads, the elastic tets
// split between them) is the sum of the two parts' gradients, added at an offset, contact
// included; getEnergyAndGradientVector gives the same gradient and the sum of the two energies.
TEST(ReducedModel, BothGradientsAtOnceAreTheirSum) {
  for (int kind : {0, 1, 2}) {  // (the FEM's are the separate calls, with their energies)
    SCOPED_TRACE("kind " + std::to_string(kind));
    const auto moved = movedOnTheGround(kind, 9);
    Simulable& sim = *moved;
    // Lower the ground to 3 mm into the body: moderate contact forces.
    sim.setColliders(
        {Collider::plane(Vec3(0, sim.getNodes().col(1).minCoeff() + 0.003, 0), Vec3::UnitY())});
    const int n = sim.numDofs(), offset = 5;
    VecX parts = VecX::Zero(n + offset);
    sim.getDynamicGradientVector(parts, offset);
    sim.getPotentialGradientVector(parts, offset);
    VecX both = VecX::Constant(n + offset, 0.5);  // added to what is there
    sim.getGradientVector(both, offset);
    both.array() -= 0.5;
    const double scale = parts.cwiseAbs().maxCoeff();
    ASSERT_GT(parts.tail(n - 144).cwiseAbs().maxCoeff(), 0.0);
    EXPECT_LE((both - parts).cwiseAbs().maxCoeff(), 1e-13 * scale);
    EXPECT_EQ(both.head(offset).cwiseAbs().maxCoeff(), 0.0);
    VecX fused = VecX::Constant(n + offset, 0.5);
    const double energy = sim.getEnergyAndGradientVector(fused, offset);
    fused.array() -= 0.5;
    EXPECT_LE((fused - parts).cwiseAbs().maxCoeff(), 1e-13 * scale);
    const double dynamic = sim.getDynamicEnergyScalar(), potential = sim.getPotentialEnergyScalar();
    ASSERT_GT(std::abs(dynamic), 0.0);
    ASSERT_GT(std::abs(potential), 0.0);
    EXPECT_NEAR(energy, dynamic + potential, 1e-12 * (std::abs(dynamic) + std::abs(potential)));
    // With the ground in contact (the gradient changes without it).
    Simulable alone(avatar(kind), test::smallScene(800).walk);
    alone.initialize();
    alone.preUpdate();
    alone.setState(sim.getState());
    VecX free = VecX::Zero(n + offset);
    alone.getGradientVector(free, offset);
    EXPECT_GT((free - parts).cwiseAbs().maxCoeff(), 1.0);  // N: 3 mm deep over the sole
    VecX free_fused = VecX::Zero(n + offset);
    const double free_energy = alone.getEnergyAndGradientVector(free_fused, offset);
    EXPECT_NEAR(free_energy, alone.getDynamicEnergyScalar() + alone.getPotentialEnergyScalar(),
                1e-12 * std::abs(free_energy));
    EXPECT_LE((free_fused - free).cwiseAbs().maxCoeff(), 1e-13 * scale);
  }
}

// A soft state that overflowed to infinity: the elastic kernels' InputError reaches the caller
// from inside the parallel regions (energy, gradient, both Hessian parts at once), no crash.
TEST(ReducedModel, NonFiniteSoftStateIsAnInputErrorFromEveryEvaluation) {
  for (int kind : {0, 1, 2}) {
    SCOPED_TRACE("kind " + std::to_string(kind));
    Simulable sim(avatar(kind), test::smallScene(800).walk);
    sim.initialize();
    sim.preUpdate();
    VecX d = VecX::Zero(sim.numDofs());
    d.tail(sim.numDofs() - 144).setConstant(1e308);
    sim.updateState(d);
    sim.updateState(d);  // 2e308: +inf
    ASSERT_FALSE(sim.getState().allFinite());
    EXPECT_THROW(sim.getPotentialEnergyScalar(), InputError);
    VecX g = VecX::Zero(sim.numDofs());
    EXPECT_THROW(sim.getPotentialGradientVector(g), InputError);
    EXPECT_THROW(sim.getGradientVector(g), InputError);
    std::vector<Triplet> H;
    std::vector<FixedHessianBlocks> blocks;
    EXPECT_THROW(sim.getHessianTripletVector(H, blocks, 0, true), InputError);
  }
}

TEST(ReducedModel, SceneOnTheDenseSolverStoresItsHessianDense) {
  // A reduced-model scene (a few hundred DoFs) gets the dense solver, and its Hessian full n × n
  // storage: the same sums as the simulable's triplets, and steps that converge.
  auto sim = std::make_shared<Simulable>(avatar(2), test::smallScene(800).walk);
  Scene scene;
  scene.addSimulable(sim);
  scene.initialize();
  scene.addCollider(
      Collider::plane(Vec3(0, sim->getNodes().col(1).minCoeff() + 0.01, 0), Vec3::UnitY()));
  for (int step = 0; step < 3; ++step) {
    const StepStats stats = scene.step();
    EXPECT_TRUE(stats.newton.converged) << "step " << step << ": " << stats.newton.message;
  }
  EXPECT_EQ(scene.linearSolver()->name(), makeLinearSolver(LinearSolverType::Dense, 1)->name());
  const int n = scene.numDofs();
  for (bool psd : {false, true}) {
    SpMat H;
    scene.hessian(H, psd);
    EXPECT_EQ(H.nonZeros(), Eigen::Index(n) * n);
    std::vector<Triplet> triplets;
    sim->getDynamicHessianTripletVector(triplets, 0, psd);
    sim->getPotentialHessianTripletVector(triplets, 0, psd);
    SpMat S(n, n);
    S.setFromTriplets(triplets.begin(), triplets.end());
    const double scale = MatX(S).cwiseAbs().maxCoeff();
    ASSERT_GT(scale, 0.0);
    EXPECT_LE((MatX(H) - MatX(S)).cwiseAbs().maxCoeff(), 1e-12 * scale) << "psd = " << psd;
  }
}

TEST(ReducedModel, SetReducedDataChecksItsInput) {
  auto custom = std::make_shared<SoftAvatar>(test::smallScene(800).body, VecX(), settings());
  custom->enableSoftTissue();
  custom->enableReducedModel();
  EXPECT_THROW(custom->setReducedData(std::make_shared<ReducedData>()), Error);  // not built yet
  custom->initVolumetricData();
  const ReducedData& good = avatar(1)->reducedData();
  auto bad = std::make_shared<ReducedData>(good);
  bad->handles[1] = bad->handles[0];
  EXPECT_NE(test::messageOf<InputError>([&] { custom->setReducedData(bad); }).find("handles[1]"),
            std::string::npos);
  bad = std::make_shared<ReducedData>(good);
  bad->basis = SpMat(3, good.numHandles());
  EXPECT_NE(test::messageOf<InputError>([&] { custom->setReducedData(bad); }).find("basis is 3"),
            std::string::npos);
  bad = std::make_shared<ReducedData>(good);
  bad->elastic.elements = VecXi::Constant(1, custom->volumetricData().numTets());
  bad->elastic.weights = VecX::Ones(1);
  EXPECT_NE(test::messageOf<InputError>([&] { custom->setReducedData(bad); }).find("elastic"),
            std::string::npos);
  bad->elastic.elements[0] = 0;
  bad->elastic.weights[0] = -1.0;
  EXPECT_THROW(custom->setReducedData(bad), InputError);
  EXPECT_NO_THROW(custom->setReducedData(std::make_shared<ReducedData>(good)));
}

}  // namespace
}  // namespace flsh
