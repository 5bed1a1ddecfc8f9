// The ROM's precomputed data (reduced_data.h): handles, basis, the two cubatures with their
// held-out errors and node masses, the flags, the cache level (hits, bitwise equality, corrupted
// and invalid files, keys), settings errors, and the SoftAvatar wiring.
#include "flsh/volume/reduced_data.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <set>

#include "flsh/core/error.h"
#include "flsh/volume/soft_avatar.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::messageOf;

// The soft avatar of the 800-vertex synthetic body with a coarse interior (as in the soft-tissue
// tests), built once per binary; the reduced data are built on its volumetric body.
std::shared_ptr<const SoftAvatar> softAvatar() {
  static std::shared_ptr<const SoftAvatar> avatar = [] {
    SoftAvatarSettings settings;
    settings.voxel_size = 0.02;
    settings.volumetric.cache_dir = test::freshTempDir("reduced_data_volume_cache");
    settings.volumetric.tet_mesh.resolution = 0.5;
    auto a = std::make_shared<SoftAvatar>(test::smallScene(800).body, VecX(), settings);
    a->enableSoftTissue();
    a->initVolumetricData();
    return a;
  }();
  return avatar;
}

const VolumetricData& volume() { return softAvatar()->volumetricData(); }
const BodyModel& body() { return softAvatar()->body(); }

ReducedSettings smallSettings() {
  ReducedSettings s;
  // This file tests the handle basis, whatever the default.
  s.basis_kind = ReducedBasisKind::Handles;
  s.num_handles = 12;
  s.elastic_cubature_points = 60;
  s.inertial_cubature_points = 60;
  s.training_samples = 200;
  return s;
}

// Both cubatures, built once (without a cache) and shared by the tests that only read them.
const ReducedData& fullData() {
  static const ReducedData data =
      buildReducedData(volume(), body(), smallSettings(), true, true, nullptr);
  return data;
}

::testing::AssertionResult bitwiseEqual(const ReducedData& a, const ReducedData& b) {
  auto same = [](const auto& x, const auto& y) {
    return x.size() == y.size() && std::equal(x.data(), x.data() + x.size(), y.data());
  };
  if (!same(a.handles, b.handles)) return ::testing::AssertionFailure() << "handles differ";
  if (a.basis.rows() != b.basis.rows() || a.basis.cols() != b.basis.cols() ||
      a.basis.nonZeros() != b.basis.nonZeros() ||
      !std::equal(a.basis.outerIndexPtr(), a.basis.outerIndexPtr() + a.basis.cols() + 1,
                  b.basis.outerIndexPtr()) ||
      !std::equal(a.basis.innerIndexPtr(), a.basis.innerIndexPtr() + a.basis.nonZeros(),
                  b.basis.innerIndexPtr()) ||
      !std::equal(a.basis.valuePtr(), a.basis.valuePtr() + a.basis.nonZeros(), b.basis.valuePtr()))
    return ::testing::AssertionFailure() << "basis differs";
  if (a.basis_max_bound_violation != b.basis_max_bound_violation ||
      a.basis_max_constraint_error != b.basis_max_constraint_error ||
      a.basis_converged != b.basis_converged)
    return ::testing::AssertionFailure() << "basis figures differ";
  for (const auto& [x, y, ex, ey] :
       {std::tuple(&a.elastic, &b.elastic, a.elastic_test_error, b.elastic_test_error),
        std::tuple(&a.inertial, &b.inertial, a.inertial_test_error, b.inertial_test_error)})
    if (!same(x->elements, y->elements) || !same(x->weights, y->weights) ||
        x->training_error != y->training_error || x->rounds != y->rounds || ex != ey)
      return ::testing::AssertionFailure() << "a cubature differs";
  if (a.inertial_rigid_error != b.inertial_rigid_error)
    return ::testing::AssertionFailure() << "rigid-motion errors differ";
  if (a.key != b.key) return ::testing::AssertionFailure() << "keys differ";
  return ::testing::AssertionSuccess();
}

TEST(ReducedData, HandlesAreDistinctSoftSurfaceNodesFromTheFirstSoftVertex) {
  const ReducedData& d = fullData();
  const int V = body().numVertices();
  ASSERT_EQ(d.numHandles(), 12);
  std::set<int> distinct(d.handles.data(), d.handles.data() + d.handles.size());
  EXPECT_EQ(distinct.size(), 12u);
  for (int h = 0; h < d.numHandles(); ++h) {
    ASSERT_GE(d.handles[h], 0);
    ASSERT_LT(d.handles[h], V);
    EXPECT_EQ(volume().bone_of_node[d.handles[h]], -1) << "handle " << h;
  }
  int first = 0;
  while (volume().bone_of_node[first] >= 0) ++first;
  EXPECT_EQ(d.handles[0], first);
  EXPECT_EQ(d.handles, farthestPointSurfaceHandles(volume().rest_nodes.topRows(V), body().faces, 12,
                                                   first, volume().bone_of_node.head(V)));
}

TEST(ReducedData, BasisIsBoundedInterpolatingAndZeroOnBone) {
  const ReducedData& d = fullData();
  const VolumetricData& v = volume();
  ASSERT_EQ(d.basis.rows(), v.numNodes());
  ASSERT_EQ(d.basis.cols(), d.numHandles());
  const MatX phi = MatX(d.basis);
  for (int h = 0; h < d.numHandles(); ++h)
    for (int k = 0; k < d.numHandles(); ++k)
      EXPECT_EQ(phi(d.handles[k], h), h == k ? 1.0 : 0.0) << "handle " << k << ", column " << h;
  int bone_nodes = 0;
  for (int j = 0; j < v.numNodes(); ++j)
    if (v.bone_of_node[j] >= 0) {
      ++bone_nodes;
      EXPECT_EQ(phi.row(j).cwiseAbs().maxCoeff(), 0.0) << "bone node " << j;
    }
  EXPECT_GT(bone_nodes, 0);
  EXPECT_GE(phi.minCoeff(), -1e-9);
  EXPECT_LE(phi.maxCoeff(), 1 + 1e-9);
  for (int k = 0; k < d.basis.nonZeros(); ++k) EXPECT_GE(d.basis.valuePtr()[k], 1e-12);
  EXPECT_LE(d.basis_max_bound_violation, 1e-9);
  EXPECT_LE(d.basis_max_constraint_error, 1e-12);
  EXPECT_TRUE(d.basis_converged);
  // Each weight spreads beyond its handle (a basis of hats would move single nodes; measured:
  // at least 16 nodes per column on this coarse mesh).
  for (int h = 0; h < d.numHandles(); ++h)
    EXPECT_GE((phi.col(h).array() > 0).count(), 10) << "column " << h;
}

// basis_drop_below removes exactly the entries below it (the default's basis against one that
// keeps every entry above 1e-12), which leaves the interpolation and the zeros on bone nodes.
TEST(ReducedData, BasisDropsExactlyTheEntriesBelowTheThreshold) {
  const ReducedData& dropped = fullData();
  ASSERT_GT(smallSettings().basis_drop_below, 0.0);
  ReducedSettings keep_all = smallSettings();
  keep_all.basis_drop_below = 0.0;
  const ReducedData all = buildReducedData(volume(), body(), keep_all, false, false, nullptr);
  const double threshold = smallSettings().basis_drop_below;
  const MatX phi = MatX(dropped.basis), full = MatX(all.basis);
  ASSERT_EQ(phi.rows(), full.rows());
  ASSERT_EQ(phi.cols(), full.cols());
  // The tails are there to drop (measured: ~1/4 of the entries on this body) …
  EXPECT_LT(dropped.basis.nonZeros(), all.basis.nonZeros());
  int below = 0;
  for (Eigen::Index h = 0; h < full.cols(); ++h)
    for (Eigen::Index j = 0; j < full.rows(); ++j) {
      if (full(j, h) >= threshold)
        EXPECT_EQ(phi(j, h), full(j, h)) << "node " << j << ", handle " << h;
      else
        EXPECT_EQ(phi(j, h), 0.0) << "node " << j << ", handle " << h;
      below += full(j, h) > 0.0 && full(j, h) < threshold;
    }
  EXPECT_EQ(below, all.basis.nonZeros() - dropped.basis.nonZeros());
  for (int k = 0; k < dropped.basis.nonZeros(); ++k)
    EXPECT_GE(dropped.basis.valuePtr()[k], threshold);
}

// Smoothness: every column's biharmonic energy is below that of the hat function (1 at the
// handle, 0 elsewhere; measured ratios 0.10–0.67 on this coarse mesh, whose interior has few
// nodes), and below that of the same column made rough (each free entry scaled by a random
// factor in [0.7, 1.3], clipped to [0, 1]): a basis that is not the smooth minimizer fails.
TEST(ReducedData, BasisIsSmootherThanHatsAndRoughenedWeights) {
  const ReducedData& d = fullData();
  const VolumetricData& v = volume();
  const SpMat Q = biharmonicEnergyMatrix(v.templ->mesh, v.rest_nodes);
  std::vector<char> fixed(size_t(v.numNodes()), 0);
  for (int j = 0; j < v.numNodes(); ++j) fixed[size_t(j)] = v.bone_of_node[j] >= 0;
  for (int h = 0; h < d.numHandles(); ++h) fixed[size_t(d.handles[h])] = 1;
  for (int h = 0; h < d.numHandles(); ++h) {
    const VecX phi = VecX(d.basis.col(h));
    VecX hat = VecX::Zero(phi.size());
    hat[d.handles[h]] = 1;
    const VecX noise = test::randomVector(int(phi.size()), 0.3, 100 + h);
    VecX rough = phi;
    for (int j = 0; j < phi.size(); ++j)
      if (!fixed[size_t(j)]) rough[j] = std::clamp(phi[j] * (1 + noise[j]), 0.0, 1.0);
    ASSERT_GT((rough - phi).norm(), 1e-3) << "column " << h;
    const double energy = phi.dot(Q * phi);
    EXPECT_LT(energy, 0.8 * hat.dot(Q * hat)) << "column " << h;
    EXPECT_LT(energy, rough.dot(Q * rough)) << "column " << h;
  }
}

TEST(ReducedData, CubaturesAreValidAndGeneralize) {
  const ReducedData& d = fullData();
  const VolumetricData& v = volume();
  for (const Cubature* c : {&d.elastic, &d.inertial}) {
    ASSERT_GT(c->elements.size(), 0);
    EXPECT_LE(c->elements.size(), 60);
    ASSERT_EQ(c->elements.size(), c->weights.size());
    for (int k = 0; k < c->elements.size(); ++k) {
      EXPECT_GE(c->elements[k], 0);
      EXPECT_LT(c->elements[k], v.numTets());
      if (k > 0) {
        EXPECT_LT(c->elements[k - 1], c->elements[k]);
      }
      EXPECT_GT(c->weights[k], 0);
      EXPECT_TRUE(std::isfinite(c->weights[k]));
    }
  }
  // Elastic sample tets can deform: at least one soft node each.
  for (int k = 0; k < d.elastic.elements.size(); ++k) {
    const int t = d.elastic.elements[k];
    bool soft = false;
    for (int a = 0; a < 4; ++a) soft = soft || v.bone_of_node[v.templ->mesh.tets(t, a)] < 0;
    EXPECT_TRUE(soft) << "tet " << t;
  }
  // Measured: elastic 0.023, inertial 0.009 (held out) with 60 points and 200 samples.
  EXPECT_GT(d.elastic_test_error, 0);
  EXPECT_LT(d.elastic_test_error, 0.1);
  EXPECT_GT(d.inertial_test_error, 0);
  EXPECT_LT(d.inertial_test_error, 0.1);
  EXPECT_LT(d.elastic.training_error, 0.1);
  EXPECT_LT(d.inertial.training_error, 0.1);
}

TEST(ReducedData, InertialNodeMassesCarryTheBodyMassOnTheSampleTets) {
  const ReducedData& d = fullData();
  const VolumetricData& v = volume();
  const VecX masses = inertialNodeMasses(v, d.inertial);
  ASSERT_EQ(masses.size(), v.numNodes());
  std::vector<char> on_sample(size_t(v.numNodes()), 0);
  for (int k = 0; k < d.inertial.elements.size(); ++k)
    for (int a = 0; a < 4; ++a)
      on_sample[size_t(v.templ->mesh.tets(d.inertial.elements[k], a))] = 1;
  for (int j = 0; j < v.numNodes(); ++j) {
    if (on_sample[size_t(j)])
      EXPECT_GT(masses[j], 0) << "node " << j;
    else
      EXPECT_EQ(masses[j], 0) << "node " << j;
  }
  // A uniform velocity is among the training motions' components: the masses sum to the body
  // mass within a few times the held-out error.
  const double total = v.totalMass();
  EXPECT_NEAR(masses.sum(), total, std::max(3 * d.inertial_test_error, 0.01) * total);
  Cubature bad = d.inertial;
  bad.elements[0] = v.numTets();
  EXPECT_NE(messageOf<InputError>([&] { inertialNodeMasses(v, bad); }).find("element 0"),
            std::string::npos);
}

// The inertial cubature reproduces the skeleton's rigid inertia: twice the kinetic energy of each
// unit articulated motion — the root joint's translation, and each bone's rotation about its
// joint carrying the joints below along — with the cubature's node masses against every node's
// lumped mass. Trained on random velocities alone, the light distal bones' rotations (toes, hands)
// came out 0.23–5.7× their exact inertia on this body (the heavy parts dominate every random
// sample); with the rigid-motion rows every such motion is within 8 % here (full body: 1 %).
TEST(ReducedData, InertialCubatureHasTheSkeletonsRigidInertia) {
  const ReducedData& d = fullData();
  const VolumetricData& v = volume();
  const VecX masses = inertialNodeMasses(v, d.inertial);
  Cubature every;
  every.elements = VecXi::LinSpaced(v.numTets(), 0, v.numTets() - 1);
  every.weights = VecX::Ones(v.numTets());
  const VecX lumped = inertialNodeMasses(v, every);
  const MatX& W = v.templ->fields.weights;
  const std::vector<int>& parents = body().parents;
  const int B = int(W.cols());
  double largest = 0.0;
  for (int dof = 0; dof < 3 + 3 * B; ++dof) {
    // Joint velocities and angular velocities of the bones for this unit motion.
    std::vector<Vec3> linear(size_t(B), Vec3::Zero()), angular(size_t(B), Vec3::Zero());
    for (int b = 0; b < B; ++b) {
      if (dof >= 3 && (dof - 3) / 3 == b) angular[size_t(b)][(dof - 3) % 3] = 1.0;
      if (b == 0) {
        if (dof < 3) linear[0][dof] = 1.0;
        continue;
      }
      const int p = parents[size_t(b)];
      linear[size_t(b)] =
          linear[size_t(p)] +
          angular[size_t(p)].cross(Vec3(v.rest_joints.row(b) - v.rest_joints.row(p)));
    }
    double exact = 0.0, cubature = 0.0;
    for (int j = 0; j < v.numNodes(); ++j) {
      Vec3 velocity = Vec3::Zero();
      for (int b = 0; b < B; ++b)
        velocity +=
            W(j, b) * (linear[size_t(b)] +
                       angular[size_t(b)].cross(Vec3(v.rest_nodes.row(j) - v.rest_joints.row(b))));
      exact += lumped[j] * velocity.squaredNorm();
      cubature += masses[j] * velocity.squaredNorm();
    }
    ASSERT_GT(exact, 0.0) << "articulated motion " << dof;
    EXPECT_NEAR(cubature / exact, 1.0, 0.2) << "articulated motion " << dof;
    largest = std::max(largest, std::abs(cubature / exact - 1.0));
  }
  // The reported figure covers these motions and their coupled pairs: at least as large, and
  // measured the same way (the tets' lumped kinetic energies).
  EXPECT_GE(d.inertial_rigid_error, largest - 1e-9);
  EXPECT_LT(d.inertial_rigid_error, 0.2);
}

TEST(ReducedData, CubatureFlagsSwitchEachCubatureOff) {
  const ReducedData elastic_only =
      buildReducedData(volume(), body(), smallSettings(), true, false, nullptr);
  EXPECT_GT(elastic_only.elastic.elements.size(), 0);
  EXPECT_EQ(elastic_only.inertial.elements.size(), 0);
  EXPECT_EQ(elastic_only.inertial.weights.size(), 0);
  EXPECT_EQ(elastic_only.inertial_test_error, 0.0);
  EXPECT_EQ(elastic_only.inertial_rigid_error, 0.0);
  ReducedBuildReport report;
  const ReducedData none =
      buildReducedData(volume(), body(), smallSettings(), false, false, nullptr, &report);
  EXPECT_EQ(none.elastic.elements.size(), 0);
  EXPECT_EQ(none.inertial.elements.size(), 0);
  EXPECT_EQ(report.seconds_training, 0.0);
  EXPECT_EQ(report.seconds_cubature, 0.0);
  // The same handles and basis whatever the flags, and the same elastic cubature.
  EXPECT_EQ(none.handles, fullData().handles);
  EXPECT_EQ((MatX(none.basis) - MatX(fullData().basis)).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_EQ(elastic_only.elastic.elements, fullData().elastic.elements);
  EXPECT_NE(none.key, elastic_only.key);
  EXPECT_NE(none.key, fullData().key);
}

TEST(ReducedData, CacheHitIsBitwiseAndBadFilesAreRebuilt) {
  const std::string dir = test::freshTempDir("reduced_cache");
  const AvatarCache cache(dir);
  ReducedBuildReport cold, warm;
  const ReducedData built =
      buildReducedData(volume(), body(), smallSettings(), true, true, &cache, &cold);
  EXPECT_FALSE(cold.from_cache);
  EXPECT_TRUE(cold.warnings.empty()) << cold.warnings;
  EXPECT_GT(cold.seconds_basis, 0);
  EXPECT_GT(cold.seconds_training, 0);
  EXPECT_TRUE(bitwiseEqual(built, fullData()));
  ASSERT_TRUE(std::filesystem::exists(cache.pathFor(built.key)));
  const ReducedData loaded =
      buildReducedData(volume(), body(), smallSettings(), true, true, &cache, &warm);
  EXPECT_TRUE(warm.from_cache);
  EXPECT_TRUE(warm.warnings.empty()) << warm.warnings;
  EXPECT_EQ(warm.seconds_basis, 0.0);
  EXPECT_EQ(warm.seconds_training, 0.0);
  EXPECT_TRUE(bitwiseEqual(built, loaded));

  // Corrupted bytes: the checksum fails, a warning names the file, the rebuild is identical.
  {
    std::fstream f(cache.pathFor(built.key), std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(200);
    f.write("garbage!", 8);
  }
  ReducedBuildReport corrupted;
  const ReducedData rebuilt =
      buildReducedData(volume(), body(), smallSettings(), true, true, &cache, &corrupted);
  EXPECT_FALSE(corrupted.from_cache);
  EXPECT_NE(corrupted.warnings.find(cache.pathFor(built.key)), std::string::npos)
      << corrupted.warnings;
  EXPECT_TRUE(bitwiseEqual(built, rebuilt));

  // A well-formed file whose contents do not fit (a handle on another node range): rejected by
  // the validation, rebuilt, and the store replaces it.
  {
    io::NpzFile good(cache.pathFor(built.key));
    io::NpzWriter w;
    for (const auto& [name, array] : good.arrays()) {
      if (name.rfind("__", 0) == 0) continue;
      if (name == "handles") {
        std::vector<int64_t> handles = good.integers("handles", {12});
        handles[3] = volume().numNodes() + 5;
        w.add(name, handles.data(), {12});
      } else if (array.dtype == "<f8") {
        w.add(name, good.doubles(name, array.shape).data(), array.shape);
      } else {
        w.add(name, good.integers(name, array.shape).data(), array.shape);
      }
    }
    cache.store(built.key, w);
  }
  ReducedBuildReport invalid;
  const ReducedData rebuilt_again =
      buildReducedData(volume(), body(), smallSettings(), true, true, &cache, &invalid);
  EXPECT_FALSE(invalid.from_cache);
  EXPECT_NE(invalid.warnings.find("handles"), std::string::npos) << invalid.warnings;
  EXPECT_TRUE(bitwiseEqual(built, rebuilt_again));
  ReducedBuildReport healed;
  buildReducedData(volume(), body(), smallSettings(), true, true, &cache, &healed);
  EXPECT_TRUE(healed.from_cache) << healed.warnings;
}

TEST(ReducedData, KeyDependsOnEverySetting) {
  std::set<std::string> keys{fullData().key};
  // Cheap builds (2 handles, no cubature): only their keys are compared, and every field change
  // must give a new one.
  std::vector<ReducedSettings> variants;
  for (int k = 0; k < 10; ++k) {
    ReducedSettings s = smallSettings();
    s.num_handles = 2;
    s.training_samples = 3;
    s.elastic_cubature_points = 2;
    s.inertial_cubature_points = 2;
    switch (k) {
      case 1:
        s.num_handles = 3;
        break;
      case 2:
        s.elastic_cubature_points = 3;
        break;
      case 3:
        s.inertial_cubature_points = 3;
        break;
      case 4:
        s.training_samples = 4;
        break;
      case 5:
        s.training_amplitude = 0.02;
        break;
      case 6:
        s.seed = 7;
        break;
      case 7:
        s.basis.kkt_tolerance = 1e-7;
        break;
      case 8:
        s.basis.initial_radius_factor = 2.0;
        break;
      case 9:
        s.basis_drop_below = 1e-3;
        break;
      default:
        break;
    }
    variants.push_back(s);
  }
  for (const ReducedSettings& s : variants)
    EXPECT_TRUE(
        keys.insert(buildReducedData(volume(), body(), s, false, false, nullptr).key).second);
  ReducedSettings threads = variants[0];
  threads.basis.threads = 1;  // the weights do not depend on the thread count
  EXPECT_EQ(buildReducedData(volume(), body(), threads, false, false, nullptr).key,
            buildReducedData(volume(), body(), variants[0], false, false, nullptr).key);
  EXPECT_TRUE(keys.insert(buildReducedData(volume(), body(), variants[0], true, false, nullptr).key)
                  .second);
}

TEST(ReducedData, SettingsErrorsNameTheField) {
  auto messageFor = [&](auto change) {
    ReducedSettings s = smallSettings();
    change(s);
    return messageOf<InputError>(
        [&] { buildReducedData(volume(), body(), s, true, true, nullptr); });
  };
  std::string msg = messageFor([](ReducedSettings& s) { s.num_handles = 0; });
  EXPECT_NE(msg.find("ReducedSettings::num_handles = 0, expected ≥ 1"), std::string::npos) << msg;
  msg = messageFor([](ReducedSettings& s) { s.elastic_cubature_points = 0; });
  EXPECT_NE(msg.find("elastic_cubature_points = 0"), std::string::npos) << msg;
  msg = messageFor([](ReducedSettings& s) { s.inertial_cubature_points = -2; });
  EXPECT_NE(msg.find("inertial_cubature_points = -2"), std::string::npos) << msg;
  msg = messageFor([](ReducedSettings& s) { s.training_samples = 0; });
  EXPECT_NE(msg.find("training_samples = 0"), std::string::npos) << msg;
  msg = messageFor([](ReducedSettings& s) { s.training_amplitude = 0; });
  EXPECT_NE(msg.find("training_amplitude = 0"), std::string::npos) << msg;
  msg = messageFor([](ReducedSettings& s) { s.training_amplitude = std::nan(""); });
  EXPECT_NE(msg.find("training_amplitude = nan"), std::string::npos) << msg;
  msg = messageFor([](ReducedSettings& s) { s.basis.kkt_tolerance = -1; });
  EXPECT_NE(msg.find("basis.kkt_tolerance = -1"), std::string::npos) << msg;
  msg = messageFor([](ReducedSettings& s) { s.basis_drop_below = 0.02; });
  EXPECT_NE(msg.find("basis_drop_below = 0.02, expected in [0, 0.01]"), std::string::npos) << msg;
  msg = messageFor([](ReducedSettings& s) { s.basis_drop_below = std::nan(""); });
  EXPECT_NE(msg.find("basis_drop_below = nan"), std::string::npos) << msg;
  msg = messageFor([](ReducedSettings& s) { s.num_handles = 1000000; });
  EXPECT_NE(msg.find("num_handles = 1000000"), std::string::npos) << msg;
  EXPECT_NE(msg.find("soft-tissue surface nodes"), std::string::npos) << msg;
}

TEST(ReducedData, SoftAvatarBuildsItWithTheReducedModel) {
  const std::shared_ptr<const SoftAvatar> fem = softAvatar();
  EXPECT_FALSE(fem->hasReducedData());
  std::string msg = messageOf<Error>([&] { fem->reducedData(); });
  EXPECT_NE(msg.find("reduced model is off"), std::string::npos) << msg;

  SoftAvatarSettings settings = fem->settings();
  settings.reduced = smallSettings();
  SoftAvatar rom(fem->bodyPtr(), fem->betas(), settings);
  rom.enableSoftTissue();
  rom.enableReducedModel();
  rom.enableElasticCubature();
  rom.enableInertialCubature();
  msg = messageOf<Error>([&] { rom.reducedData(); });
  EXPECT_NE(msg.find("initVolumetricData() first"), std::string::npos) << msg;
  rom.initVolumetricData();
  ASSERT_TRUE(rom.hasReducedData());
  EXPECT_TRUE(rom.volumetricBuildReport().data_from_cache);
  EXPECT_TRUE(rom.reducedBuildReport().warnings.empty()) << rom.reducedBuildReport().warnings;
  EXPECT_TRUE(bitwiseEqual(rom.reducedData(), fullData()));

  // Same avatar again: the third level comes from the cache directory of the volumetric body.
  SoftAvatar again(fem->bodyPtr(), fem->betas(), settings);
  again.enableSoftTissue();
  again.enableReducedModel();
  again.enableElasticCubature();
  again.enableInertialCubature();
  again.initVolumetricData();
  EXPECT_TRUE(again.reducedBuildReport().from_cache);
  EXPECT_TRUE(bitwiseEqual(again.reducedData(), fullData()));

  SoftAvatar without_soft_tissue(fem->bodyPtr(), fem->betas(), settings);
  without_soft_tissue.enableReducedModel();
  msg = messageOf<InputError>([&] { without_soft_tissue.initVolumetricData(); });
  EXPECT_NE(msg.find("enableSoftTissue()"), std::string::npos) << msg;
  EXPECT_FALSE(without_soft_tissue.initialized());
}

// The experimental surface partition of unity: the soft surface rows sum to 1 (where a handle
// reaches), handles stay unit rows, bone rows empty, entries within [0, 1], a different key.
TEST(ReducedData, SurfacePartitionOfUnityOption) {
  ReducedSettings settings = smallSettings();
  settings.surface_partition_of_unity = true;
  const ReducedData pou = buildReducedData(volume(), body(), settings, false, false, nullptr);
  const ReducedData plain =
      buildReducedData(volume(), body(), smallSettings(), false, false, nullptr);
  EXPECT_NE(pou.key, plain.key);
  const MatX B = MatX(pou.basis), P = MatX(plain.basis);
  const VolumetricData& v = volume();
  const int V = v.templ->mesh.num_surface_nodes;
  ASSERT_EQ(B.rows(), v.numNodes());
  EXPECT_GE(B.minCoeff(), 0.0);
  EXPECT_LE(B.maxCoeff(), 1.0 + 1e-12);
  int reached = 0;
  double plain_sum = 0.0;
  for (int j = 0; j < V; ++j) {
    if (v.bone_of_node[j] >= 0) {
      EXPECT_EQ(B.row(j).norm(), 0.0);
      continue;
    }
    if (P.row(j).sum() <= 1e-9) continue;
    ++reached;
    plain_sum += P.row(j).sum();
    EXPECT_NEAR(B.row(j).sum(), 1.0, 1e-9) << "surface node " << j;
  }
  ASSERT_GT(reached, 0);
  EXPECT_LT(plain_sum / reached, 0.99) << "the plain weights are not a partition of unity";
  for (int h = 0; h < pou.numHandles(); ++h) {
    EXPECT_NEAR(B(pou.handles[h], h), 1.0, 1e-12);
    EXPECT_NEAR(B.row(pou.handles[h]).sum(), 1.0, 1e-12);
  }
  for (int j = V; j < v.numNodes(); ++j)
    if (v.bone_of_node[j] >= 0) {
      EXPECT_EQ(B.row(j).norm(), 0.0);
    }
}

}  // namespace
}  // namespace flsh
