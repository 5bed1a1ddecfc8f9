// The reduced data with modes (ReducedBasisKind::Modes and ModesAndHandles, issue 26): the modal
// columns as ReducedData holds them, the cache level (bitwise round trip, invalid files rebuilt,
// keys), the subspace's exact rest stiffness through the assembled K_uu against the per-tet sum,
// the cubatures trained on modal samples, and SoftAvatar::setReducedData's checks.
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <filesystem>
#include <set>

#include "flsh/core/error.h"
#include "flsh/format/npz.h"
#include "flsh/volume/elastic_tets.h"
#include "flsh/volume/reduced_data.h"
#include "flsh/volume/soft_avatar.h"
#include "support/test_support.h"
#include "volume/subspace_tets.h"

namespace flsh {
namespace {

SoftAvatarSettings avatarSettings() {
  SoftAvatarSettings settings;
  settings.voxel_size = 0.02;
  settings.volumetric.cache_dir = test::freshTempDir("modal_reduced_data_cache");
  settings.volumetric.tet_mesh.resolution = 0.5;
  return settings;
}

std::shared_ptr<const SoftAvatar> softAvatar() {
  static std::shared_ptr<const SoftAvatar> avatar = [] {
    auto a = std::make_shared<SoftAvatar>(test::smallScene(800).body, VecX(), avatarSettings());
    a->enableSoftTissue();
    a->initVolumetricData();
    return a;
  }();
  return avatar;
}

const VolumetricData& volume() { return softAvatar()->volumetricData(); }
const BodyModel& body() { return softAvatar()->body(); }

ReducedSettings modalSettings(ReducedBasisKind kind) {
  ReducedSettings s;
  s.basis_kind = kind;
  s.num_handles = 8;
  s.modes.vibration_modes = 4;
  s.modes.columns = 26;  // cut to 24
  s.elastic_cubature_points = 60;
  s.inertial_cubature_points = 60;
  s.training_samples = 120;
  return s;
}

const ReducedData& modesAndHandles() {
  static const ReducedData data = buildReducedData(
      volume(), body(), modalSettings(ReducedBasisKind::ModesAndHandles), true, true, nullptr);
  return data;
}

TEST(ModalReducedData, ModesAreWholeGroupsZeroOnBoneNodesAndMassOrthonormal) {
  for (ReducedBasisKind kind : {ReducedBasisKind::Modes, ReducedBasisKind::ModesAndHandles}) {
    const ReducedData d =
        kind == ReducedBasisKind::Modes
            ? buildReducedData(volume(), body(), modalSettings(kind), false, false, nullptr)
            : modesAndHandles();
    EXPECT_EQ(d.basis_kind, kind);
    ASSERT_EQ(d.numModes(), 24) << "26 columns cut to a multiple of 3";
    EXPECT_EQ(d.modes.rows(), 3 * volume().numNodes());
    EXPECT_EQ(d.numHandles(), kind == ReducedBasisKind::Modes ? 0 : 8);
    EXPECT_EQ(d.basis.rows(), volume().numNodes());
    EXPECT_EQ(d.numSoftDofs(), 3 * d.numHandles() + 24);
    VecX masses = VecX::Zero(3 * volume().numNodes());
    const VecX nodes = inertialNodeMasses(volume(), exactCubature(volume().numTets()));
    for (int j = 0; j < volume().numNodes(); ++j) {
      masses.segment<3>(3 * j).setConstant(nodes[j]);
      if (volume().bone_of_node[j] >= 0) {
        EXPECT_TRUE(d.modes.middleRows<3>(3 * j).isZero(0.0));
      }
    }
    const MatX gram = d.modes.transpose() * masses.asDiagonal() * d.modes;
    EXPECT_LT((gram - MatX::Identity(24, 24)).cwiseAbs().maxCoeff(), 1e-8);
  }
}

// K through the assembled K_uu (one sparse product) is the per-tet sum V Dᵀ A₀ D of
// subspace_tets.h over every elastic tet, handles' and modes' entries alike.
TEST(ModalReducedData, RestStiffnessIsThePerTetSum) {
  const ReducedData& d = modesAndHandles();
  const int m = d.numSoftDofs();
  ASSERT_EQ(d.elastic_rest_stiffness.rows(), m);
  const ElasticTets tets = deformableTets(volume());
  const SpMat rows = d.basis.transpose();
  MatX K = MatX::Zero(m, m);
  for (int k = 0; k < tets.size(); ++k) {
    const detail::SubspaceTet st =
        detail::subspaceTet(volume(), d, rows, tets.rest[size_t(k)], tets.tets[size_t(k)]);
    const MatX Ke = tets.rest[size_t(k)].volume * st.D.transpose() *
                    detail::restTangent(tets.materials[size_t(k)]) * st.D;
    for (size_t a = 0; a < st.dofs.size(); ++a)
      for (size_t b = 0; b < st.dofs.size(); ++b)
        K(st.dofs[a], st.dofs[b]) += Ke(Eigen::Index(a), Eigen::Index(b));
  }
  ASSERT_GT(K.norm(), 0.0);
  EXPECT_LT((d.elastic_rest_stiffness - K).cwiseAbs().maxCoeff(), 1e-9 * K.cwiseAbs().maxCoeff());
  EXPECT_LT((elasticRestStiffness(volume(), d) - d.elastic_rest_stiffness).cwiseAbs().maxCoeff(),
            1e-12 * K.cwiseAbs().maxCoeff());
  // Symmetric positive definite.
  EXPECT_EQ(K.llt().info(), Eigen::Success);
  // The handles' block is the handle basis' own rest stiffness.
  EXPECT_LT(
      (d.elastic_rest_stiffness.topLeftCorner(24, 24) - elasticRestStiffness(volume(), d.basis))
          .cwiseAbs()
          .maxCoeff(),
      1e-9 * K.cwiseAbs().maxCoeff());
}

TEST(ModalReducedData, CubaturesTrainOnModalSamplesAndGeneralize) {
  const ReducedData& d = modesAndHandles();
  ASSERT_GT(d.elastic.elements.size(), 0);
  ASSERT_GT(d.inertial.elements.size(), 0);
  // Bounds of the handle basis' tests (reduced_data_test.cpp) on the same small body; measured
  // here: rigid motions within 8 %.
  EXPECT_GT(d.elastic_test_error, 0.0);
  EXPECT_LT(d.elastic_test_error, 0.1);
  EXPECT_GT(d.inertial_test_error, 0.0);
  EXPECT_LT(d.inertial_test_error, 0.1);
  EXPECT_LT(d.inertial_rigid_error, 0.2);
}

TEST(ModalReducedData, CacheRoundTripIsBitwiseAndInvalidModesAreRebuilt) {
  const std::string dir = test::freshTempDir("modal_reduced_cache");
  const AvatarCache cache(dir);
  const ReducedSettings s = modalSettings(ReducedBasisKind::ModesAndHandles);
  ReducedBuildReport cold, warm;
  const ReducedData built = buildReducedData(volume(), body(), s, true, true, &cache, &cold);
  EXPECT_FALSE(cold.from_cache);
  EXPECT_GT(cold.modes.static_columns, 0);
  const ReducedData loaded = buildReducedData(volume(), body(), s, true, true, &cache, &warm);
  ASSERT_TRUE(warm.from_cache) << warm.warnings;
  EXPECT_EQ(loaded.basis_kind, built.basis_kind);
  EXPECT_TRUE(loaded.modes == built.modes);
  EXPECT_TRUE(loaded.elastic_rest_stiffness == built.elastic_rest_stiffness);
  EXPECT_TRUE(loaded.handles == built.handles);
  EXPECT_TRUE(loaded.elastic.elements == built.elastic.elements);

  // Modes that move a bone node: rejected by the validation (the warning names the key), rebuilt.
  int bone = 0;
  while (volume().bone_of_node[bone] < 0) ++bone;
  {
    io::NpzFile good(cache.pathFor(built.key));
    io::NpzWriter w;
    for (const auto& [name, array] : good.arrays()) {
      if (name.rfind("__", 0) == 0) continue;
      if (name == "modes") {
        RowMatX modes = good.matrix("modes");
        modes(3 * bone, 0) = 0.5;
        w.add(name, modes);
      } else if (array.dtype == "<f8") {
        w.add(name, good.doubles(name, array.shape).data(), array.shape);
      } else {
        w.add(name, good.integers(name, array.shape).data(), array.shape);
      }
    }
    cache.store(built.key, w);
  }
  ReducedBuildReport invalid;
  const ReducedData rebuilt = buildReducedData(volume(), body(), s, true, true, &cache, &invalid);
  EXPECT_FALSE(invalid.from_cache);
  EXPECT_NE(invalid.warnings.find("modes"), std::string::npos) << invalid.warnings;
  EXPECT_TRUE(rebuilt.modes == built.modes);
}

// C++ code written when handles were the default sets num_handles (or the partition of unity)
// without a basis kind: the modal basis then says that they are not used.
TEST(ModalReducedData, HandleSettingsBesideTheModalBasisAloneAreReported) {
  ReducedSettings s = modalSettings(ReducedBasisKind::Modes);
  s.num_handles = 16;
  s.surface_partition_of_unity = true;
  ReducedBuildReport report;
  buildReducedData(volume(), body(), s, false, false, nullptr, &report);
  EXPECT_NE(report.warnings.find("ReducedSettings::num_handles = 16 is not used by basis_kind = "
                                 "Modes"),
            std::string::npos)
      << report.warnings;
  EXPECT_NE(report.warnings.find("surface_partition_of_unity is not used"), std::string::npos)
      << report.warnings;
  s.num_handles = ReducedSettings().num_handles;
  s.surface_partition_of_unity = false;
  ReducedBuildReport quiet;
  buildReducedData(volume(), body(), s, false, false, nullptr, &quiet);
  EXPECT_EQ(quiet.warnings, "");
  s.basis_kind = ReducedBasisKind::ModesAndHandles;  // handles used: nothing to say
  s.num_handles = 16;
  ReducedBuildReport both;
  buildReducedData(volume(), body(), s, false, false, nullptr, &both);
  EXPECT_EQ(both.warnings.find("not used"), std::string::npos) << both.warnings;
}

TEST(ModalReducedData, KeyDependsOnTheKindAndTheModalSettingsOnly) {
  ReducedSettings handles;
  handles.basis_kind = ReducedBasisKind::Handles;
  handles.num_handles = 2;
  handles.training_samples = 3;
  const std::string base = buildReducedData(volume(), body(), handles, false, false, nullptr).key;
  // Modal settings do not change the handle kind's key (its caches stay valid).
  ReducedSettings other_modes = handles;
  other_modes.modes.vibration_modes = 3;
  EXPECT_EQ(buildReducedData(volume(), body(), other_modes, false, false, nullptr).key, base);
  std::set<std::string> keys{base};
  for (int k = 0; k < 5; ++k) {
    ReducedSettings s = handles;
    s.basis_kind = k == 1 ? ReducedBasisKind::ModesAndHandles : ReducedBasisKind::Modes;
    s.modes.vibration_modes = k == 2 ? 1 : 0;
    s.modes.columns = k == 3 ? 9 : 0;
    s.modes.static_modes = true;
    if (k == 4) s.modes.seed = 5;
    EXPECT_TRUE(
        keys.insert(buildReducedData(volume(), body(), s, false, false, nullptr).key).second)
        << k;
  }
}

TEST(ModalReducedData, BasisKindNamesRoundTripAndBadNamesAreInputErrors) {
  for (ReducedBasisKind kind :
       {ReducedBasisKind::Handles, ReducedBasisKind::Modes, ReducedBasisKind::ModesAndHandles})
    EXPECT_EQ(parseReducedBasisKind(reducedBasisKindName(kind), "test"), kind);
  EXPECT_THROW(parseReducedBasisKind("mode", "scene.json: avatars[0].basis"), InputError);
  EXPECT_NE(test::messageOf<InputError>([] {
              parseReducedBasisKind("x", "where");
            }).find("modes+handles"),
            std::string::npos);
}

TEST(ModalReducedData, SetReducedDataChecksTheModes) {
  auto avatar = std::make_shared<SoftAvatar>(test::smallScene(800).body, VecX(), avatarSettings());
  avatar->enableSoftTissue();
  avatar->enableReducedModel();
  avatar->initVolumetricData();
  const int n = avatar->volumetricData().numNodes();
  auto expectRejected = [&](const ReducedData& d, const std::string& part) {
    const std::string message = test::messageOf<InputError>(
        [&] { avatar->setReducedData(std::make_shared<ReducedData>(d)); });
    EXPECT_NE(message.find(part), std::string::npos) << message;
  };
  ReducedData good;
  good.basis_kind = ReducedBasisKind::Modes;
  good.basis.resize(n, 0);
  good.modes = modesAndHandles().modes;
  avatar->setReducedData(std::make_shared<ReducedData>(good));  // accepted
  ReducedData bad = good;
  bad.modes.conservativeResize(Eigen::NoChange, 23);
  expectRejected(bad, "multiple of 3");
  bad = good;
  int bone = 0;
  while (avatar->volumetricData().bone_of_node[bone] < 0) ++bone;
  bad.modes(3 * bone + 1, 2) = 1.0;
  expectRejected(bad, "bone node");
  bad = good;
  bad.handles = modesAndHandles().handles;
  bad.basis = modesAndHandles().basis;
  expectRejected(bad, "handles");
  bad = good;
  bad.elastic_rest_stiffness = MatX::Identity(10, 10);
  expectRejected(bad, "elastic_rest_stiffness");
  bad = good;
  bad.basis_kind = ReducedBasisKind::Handles;
  expectRejected(bad, "handles");
}

}  // namespace
}  // namespace flsh
