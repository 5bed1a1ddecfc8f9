// SoftAvatar: constructor checks and β padding, the FEM volumetric body with its cache, the
// reduced model's need for soft tissue, the rest data it builds (shape, joints, vertex areas,
// volume, masses, capsules), idempotence, determinism and the effect of β; derived data (built
// once per avatar, not copied).
#include "flsh/volume/soft_avatar.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <limits>

#include "flsh/body/body_forward.h"
#include "flsh/core/error.h"
#include "flsh/volume/avatar_cache.h"
#include "support/test_support.h"
#include "volume/volume_test_meshes.h"

namespace flsh {
namespace {

SoftAvatarSettings densityAndVoxel(double density, double voxel_size) {
  SoftAvatarSettings settings;
  settings.density = density;
  settings.voxel_size = voxel_size;
  return settings;
}

using test::messageOf;
using test::smallSyntheticBody;

const SoftAvatar& meanAvatar() {
  static const SoftAvatar avatar = [] {
    SoftAvatar a(smallSyntheticBody(), VecX::Zero(0));
    a.initVolumetricData();
    return a;
  }();
  return avatar;
}

TEST(SoftAvatar, RejectsBadConstruction) {
  const auto body = smallSyntheticBody();
  EXPECT_NE(messageOf<InputError>([] { SoftAvatar(nullptr, VecX::Zero(10)); }).find("null"),
            std::string::npos);
  std::string msg = messageOf<InputError>([&] { SoftAvatar(body, VecX::Zero(11)); });
  EXPECT_NE(msg.find("11"), std::string::npos) << msg;
  EXPECT_NE(msg.find("at most 10"), std::string::npos) << msg;
  VecX nan_betas = VecX::Zero(3);
  nan_betas[1] = std::numeric_limits<double>::quiet_NaN();
  msg = messageOf<InputError>([&] { SoftAvatar(body, nan_betas); });
  EXPECT_NE(msg.find("NaN"), std::string::npos) << msg;
  msg =
      messageOf<InputError>([&] { SoftAvatar(body, VecX::Zero(10), densityAndVoxel(0.0, 0.01)); });
  EXPECT_NE(msg.find("density"), std::string::npos) << msg;
  msg = messageOf<InputError>(
      [&] { SoftAvatar(body, VecX::Zero(10), densityAndVoxel(1000.0, 0.0)); });
  EXPECT_NE(msg.find("voxel_size"), std::string::npos) << msg;
  msg = messageOf<InputError>([&] {
    SoftAvatar(body, VecX::Zero(10),
               densityAndVoxel(1000.0, std::numeric_limits<double>::infinity()));
  });
  EXPECT_NE(msg.find("voxel_size"), std::string::npos) << msg;
  auto unfinalized = std::make_shared<BodyModel>(*body);
  unfinalized->derived.reset();
  msg = messageOf<InputError>([&] { SoftAvatar(unfinalized, VecX::Zero(10)); });
  EXPECT_NE(msg.find("finalize"), std::string::npos) << msg;
}

TEST(SoftAvatar, PadsShortBetas) {
  VecX betas(3);
  betas << 0.5, -1.0, 0.25;
  const SoftAvatar avatar(smallSyntheticBody(), betas);
  ASSERT_EQ(avatar.betas().size(), 10);
  EXPECT_EQ(avatar.betas().head(3), betas);
  EXPECT_TRUE(avatar.betas().tail(7).isZero(0.0));
  EXPECT_FALSE(avatar.initialized());
}

SoftAvatarSettings cachedSettings(const std::string& cache_dir) {
  SoftAvatarSettings settings;
  settings.volumetric.cache_dir = cache_dir;
  return settings;
}

// The reduced model is a soft-tissue model: without soft tissue it is an input error, and the
// avatar stays buildable once the settings are fixed (the ROM itself: reduced_data_test.cpp).
TEST(SoftAvatar, ReducedModelNeedsSoftTissue) {
  SoftAvatar avatar(smallSyntheticBody(), VecX::Zero(10),
                    cachedSettings(test::freshTempDir("rom_needs_soft_tissue")));
  avatar.enableReducedModel(true);
  const std::string msg = messageOf<InputError>([&] { avatar.initVolumetricData(); });
  EXPECT_NE(msg.find("soft tissue is off"), std::string::npos) << msg;
  EXPECT_NE(msg.find("enableSoftTissue()"), std::string::npos) << msg;
  EXPECT_FALSE(avatar.initialized());
  avatar.enableReducedModel(false);
  avatar.initVolumetricData();
  EXPECT_TRUE(avatar.initialized());
  EXPECT_FALSE(avatar.hasVolumetricData());
  EXPECT_FALSE(avatar.hasReducedData());
}

TEST(SoftAvatar, SkeletonAvatarBuildsNoTetMesh) {
  const SoftAvatar& avatar = meanAvatar();
  EXPECT_FALSE(avatar.hasVolumetricData());
  EXPECT_NE(messageOf<Error>([&] { avatar.volumetricData(); }).find("soft tissue is off"),
            std::string::npos);
  EXPECT_EQ(avatar.volumetricBuildReport().seconds_meshing, 0.0);
}

// The FEM avatar: surface nodes are the SMPL shaped vertices for any β, fields are consistent,
// bone nodes exist, the second creation comes from the cache bitwise, a corrupted cache file is
// rebuilt with a warning, and two shapes get different materials.
TEST(SoftAvatar, ShapeThatFoldsTheTetMeshIsRefusedNamingBeta) {
  // The tet mesh follows β through the extended shape directions; far out (the belly drawn in
  // by β6 = −20) tets fold inside out. The error names β, not the first element that meets the
  // folded tet (the stability sweep's β6 = −5 on its body was reported as "tet 3040: inverted").
  VecX betas = VecX::Zero(10);
  betas(6) = -20.0;
  auto avatar = std::make_shared<SoftAvatar>(smallSyntheticBody(), betas,
                                             cachedSettings(test::freshTempDir("folded")));
  avatar->enableSoftTissue();
  const std::string message = test::messageOf<InputError>([&] { avatar->initVolumetricData(); });
  for (const char* part : {"betas", "β6 = -20", "inside out", "smaller |β|"})
    EXPECT_NE(message.find(part), std::string::npos) << message;
}

TEST(SoftAvatar, FemAvatarVolumetricBodyAndCache) {
  const std::string cache_dir = test::freshTempDir("fem_avatar_cache");
  VecX betas = VecX::Zero(10);
  betas(0) = 0.8;
  betas(1) = -0.6;
  auto build = [&](const VecX& b) {
    auto avatar = std::make_shared<SoftAvatar>(smallSyntheticBody(), b, cachedSettings(cache_dir));
    avatar->enableSoftTissue();
    avatar->initVolumetricData();
    return avatar;
  };
  const auto cold = build(betas);
  const VolumetricData& d = cold->volumetricData();
  const VolumetricBuildReport& cold_report = cold->volumetricBuildReport();
  EXPECT_FALSE(cold_report.template_from_cache);
  EXPECT_FALSE(cold_report.data_from_cache);
  EXPECT_GT(cold_report.seconds_meshing, 0.0);
  EXPECT_TRUE(cold_report.warnings.empty()) << cold_report.warnings;

  const int V = smallSyntheticBody()->numVertices();
  ASSERT_GT(d.numNodes(), V);
  EXPECT_EQ(d.templ->mesh.num_surface_nodes, V);
  EXPECT_TRUE(d.rest_nodes.topRows(V).isApprox(cold->restVertices(), 1e-12));
  EXPECT_TRUE(d.rest_joints.isApprox(cold->restJoints(), 1e-12));
  const VecX weight_sums = d.templ->fields.weights.rowwise().sum();
  EXPECT_LT((weight_sums.array() - 1.0).abs().maxCoeff(), 1e-12);
  EXPECT_GT(d.numBoneNodes(), 0);
  EXPECT_LT(d.numBoneNodes(), d.numNodes() - V);
  EXPECT_EQ(d.materials.density.size(), d.numTets());
  // Mass of the soft body: density in the human band times the enclosed volume.
  EXPECT_NEAR(d.totalMass() / cold->volume(), 1040.0, 40.0);

  // Warm: both levels from the cache, bitwise equal.
  const auto warm = build(betas);
  const VolumetricData& w = warm->volumetricData();
  EXPECT_TRUE(warm->volumetricBuildReport().template_from_cache);
  EXPECT_TRUE(warm->volumetricBuildReport().data_from_cache);
  EXPECT_EQ(warm->volumetricBuildReport().seconds_meshing, 0.0);
  EXPECT_EQ(w.templ->mesh.nodes, d.templ->mesh.nodes);
  EXPECT_EQ(w.templ->mesh.tets, d.templ->mesh.tets);
  EXPECT_EQ(w.templ->fields.weights, d.templ->fields.weights);
  EXPECT_EQ(w.templ->fields.shapedirs, d.templ->fields.shapedirs);
  EXPECT_EQ(w.templ->fields.posedirs, d.templ->fields.posedirs);
  EXPECT_EQ(w.rest_nodes, d.rest_nodes);
  EXPECT_EQ(w.bone_of_node, d.bone_of_node);
  EXPECT_EQ(w.materials.young, d.materials.young);
  EXPECT_EQ(w.materials.frame[7], d.materials.frame[7]);

  // Another shape reuses the template (cache hit) but gets its own materials.
  VecX other = betas;
  other(1) = 1.5;
  const auto shaped = build(other);
  EXPECT_TRUE(shaped->volumetricBuildReport().template_from_cache);
  EXPECT_FALSE(shaped->volumetricBuildReport().data_from_cache);
  const VolumetricData& o = shaped->volumetricData();
  EXPECT_EQ(o.templ->mesh.tets, d.templ->mesh.tets);
  EXPECT_GT((o.materials.young - d.materials.young).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_GT((o.materials.density - d.materials.density).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_TRUE(o.rest_nodes.topRows(V).isApprox(shaped->restVertices(), 1e-12));

  // Corrupt the template entry: rebuilt with a warning naming the file, same result.
  const std::string path = AvatarCache(cache_dir).pathFor(d.templ->key);
  std::filesystem::resize_file(path, std::filesystem::file_size(path) - 100);
  const auto rebuilt = build(betas);
  const VolumetricBuildReport& r = rebuilt->volumetricBuildReport();
  EXPECT_FALSE(r.template_from_cache);
  EXPECT_NE(r.warnings.find(path), std::string::npos) << r.warnings;
  EXPECT_NE(r.warnings.find("rebuilding"), std::string::npos) << r.warnings;
  EXPECT_EQ(rebuilt->volumetricData().templ->mesh.tets, d.templ->mesh.tets);
  EXPECT_TRUE(build(betas)->volumetricBuildReport().template_from_cache);
}

TEST(SoftAvatar, BuildsTheRestData) {
  const SoftAvatar& avatar = meanAvatar();
  const BodyModel& body = *smallSyntheticBody();
  ASSERT_TRUE(avatar.initialized());
  EXPECT_EQ(avatar.restVertices(), shapedVertices(body, VecX::Zero(10)));
  EXPECT_TRUE(avatar.restJoints().isApprox(MatX3(body.J_regressor * avatar.restVertices()), 1e-14));
  ASSERT_EQ(avatar.restJoints().rows(), 24);
  ASSERT_EQ(avatar.boneInertia().size(), 24u);
  ASSERT_EQ(avatar.boneCapsules().size(), 24u);

  // Vertex areas: positive and summing to the surface area.
  double area = 0;
  const MatX3& V = avatar.restVertices();
  for (int f = 0; f < body.numFaces(); ++f) {
    const Vec3 a = V.row(body.faces(f, 0)), b = V.row(body.faces(f, 1)),
               c = V.row(body.faces(f, 2));
    area += 0.5 * (b - a).cross(c - a).norm();
  }
  ASSERT_EQ(avatar.vertexAreas().size(), body.numVertices());
  EXPECT_GT(avatar.vertexAreas().minCoeff(), 0.0);
  EXPECT_NEAR(avatar.vertexAreas().sum(), area, 1e-12 * area);
  EXPECT_GT(area, 1.2);  // a 1.70 m adult has about 1.5–2 m² of skin
  EXPECT_LT(area, 2.5);

  // Volume by the divergence theorem, and mass = density × volume up to the voxel error.
  EXPECT_NEAR(avatar.volume(), test::solidIntegrals({V, body.faces}).volume, 1e-12);
  EXPECT_GT(avatar.volume(), 0.05);
  EXPECT_LT(avatar.volume(), 0.09);
  const double expected_mass = avatar.settings().density * avatar.volume();
  EXPECT_NEAR(avatar.totalMass(), expected_mass, 0.02 * expected_mass);
}

TEST(SoftAvatar, InitializationIsIdempotentAndDeterministic) {
  const SoftAvatar& built = meanAvatar();
  SoftAvatar avatar(smallSyntheticBody(), VecX::Zero(10));
  avatar.initVolumetricData();
  avatar.initVolumetricData();
  EXPECT_EQ(avatar.restVertices(), built.restVertices());
  EXPECT_EQ(avatar.vertexAreas(), built.vertexAreas());
  EXPECT_EQ(avatar.volume(), built.volume());
  for (int j = 0; j < 24; ++j) {
    EXPECT_EQ(avatar.boneInertia()[j].mass, built.boneInertia()[j].mass);
    EXPECT_EQ(avatar.boneInertia()[j].second_moment, built.boneInertia()[j].second_moment);
    EXPECT_EQ(avatar.boneCapsules()[j].a, built.boneCapsules()[j].a);
    EXPECT_EQ(avatar.boneCapsules()[j].radius, built.boneCapsules()[j].radius);
  }
}

TEST(SoftAvatar, BetasShapeTheBody) {
  // β₁ is "weight" on the synthetic body: a heavier shape has more volume and mass.
  VecX betas = VecX::Zero(2);
  betas[1] = 2.0;
  SoftAvatar heavy(smallSyntheticBody(), betas);
  heavy.initVolumetricData();
  const SoftAvatar& mean = meanAvatar();
  EXPECT_GT(heavy.volume(), 1.05 * mean.volume());
  EXPECT_GT(heavy.totalMass(), 1.05 * mean.totalMass());
  EXPECT_FALSE(heavy.restJoints().isApprox(mean.restJoints(), 1e-9) &&
               heavy.restVertices().isApprox(mean.restVertices(), 1e-9));
}

TEST(SoftAvatar, UsesTheDensitySetting) {
  SoftAvatar light(smallSyntheticBody(), VecX::Zero(0), densityAndVoxel(505.0, 0.01));
  light.initVolumetricData();
  EXPECT_NEAR(light.totalMass(), 0.5 * meanAvatar().totalMass(), 1e-9 * light.totalMass());
}

// Bone inertia as a function of β (soft_avatar.h): at β = 0 it is computeBoneInertia of the
// template; for β ≠ 0 the template's vertex moments move with the shaped vertices and scale to
// the shaped volume.
TEST(SoftAvatar, BoneInertiaAtZeroShapeIsTheVoxelizedTemplate) {
  const SoftAvatar& avatar = meanAvatar();
  const BodyModel& body = *smallSyntheticBody();
  const auto direct =
      computeBoneInertia(avatar.restVertices(), body.faces, body.weights, avatar.restJoints(),
                         avatar.settings().density, avatar.settings().voxel_size);
  for (int b = 0; b < 24; ++b) {
    EXPECT_EQ(avatar.boneInertia()[b].mass, direct[b].mass) << b;
    EXPECT_EQ(avatar.boneInertia()[b].first_moment, direct[b].first_moment) << b;
    EXPECT_EQ(avatar.boneInertia()[b].second_moment, direct[b].second_moment) << b;
  }
  EXPECT_EQ(avatar.templateVolume(), avatar.volume());
}

TEST(SoftAvatar, ShapedMassIsDensityTimesShapedVolume) {
  VecX betas = VecX::Zero(3);
  betas << 0.8, 2.0, -0.5;
  SoftAvatar shaped(smallSyntheticBody(), betas);
  shaped.initVolumetricData();
  const SoftAvatar& mean = meanAvatar();
  EXPECT_NEAR(shaped.totalMass() / mean.totalMass(), shaped.volume() / mean.volume(), 1e-12);
  // The same template moments are shared, not voxelized again.
  EXPECT_EQ(&shaped.templateMassMoments(), &mean.templateMassMoments());
}

// Every β Jacobian of the rest data against central differences of avatars built at β ± ε.
TEST(SoftAvatar, ShapeJacobiansMatchFiniteDifferences) {
  VecX beta0 = VecX::Zero(10);
  beta0.head(4) << 0.5, -1.0, 0.3, 0.8;
  SoftAvatar avatar(smallSyntheticBody(), beta0);
  avatar.initVolumetricData();
  const auto build = [&](const VecX& beta) {
    auto a = std::make_unique<SoftAvatar>(smallSyntheticBody(), beta);
    a->initVolumetricData();
    return a;
  };
  const auto inertia = [&](const VecX& beta) {
    const auto a = build(beta);
    VecX out(240);
    for (int b = 0; b < 24; ++b) {
      const BoneInertia& in = a->boneInertia()[b];
      const Mat3& S = in.second_moment;
      out.segment<10>(10 * b) << in.mass, in.first_moment, S(0, 0), S(1, 1), S(2, 2), S(0, 1),
          S(0, 2), S(1, 2);
    }
    return out;
  };
  const auto joints = [&](const VecX& beta) {
    const MatX3 J = build(beta)->restJoints();
    return VecX(Eigen::Map<const VecX>(J.data(), 72));
  };
  const auto areas = [&](const VecX& beta) { return VecX(build(beta)->vertexAreas()); };
  const auto volume = [&](const VecX& beta) { return VecX::Constant(1, build(beta)->volume()); };
  ASSERT_EQ(avatar.boneInertiaShapeJacobian().rows(), 240);
  ASSERT_EQ(avatar.boneInertiaShapeJacobian().cols(), 10);
  EXPECT_TRUE(test::jacobianMatchesFiniteDifferences(
      inertia, beta0, avatar.boneInertiaShapeJacobian(), 1e-8, 1e-4));
  EXPECT_TRUE(test::jacobianMatchesFiniteDifferences(joints, beta0,
                                                     avatar.restJointsShapeJacobian(), 1e-8, 1e-4));
  EXPECT_TRUE(test::jacobianMatchesFiniteDifferences(
      areas, beta0, avatar.vertexAreasShapeJacobian(), 1e-8, 1e-4));
  EXPECT_TRUE(test::jacobianMatchesFiniteDifferences(
      volume, beta0, MatX(avatar.volumeShapeGradient().transpose()), 1e-8, 1e-4));
}

TEST(SoftAvatar, LumpBoneInertiaRejectsMismatchedSizes) {
  const SoftAvatar& avatar = meanAvatar();
  const BodyModel& body = *smallSyntheticBody();
  const MatX3 fewer = avatar.restVertices().topRows(10);
  std::string msg = messageOf<InputError>([&] {
    lumpBoneInertia(avatar.templateMassMoments(), fewer, body.weights, avatar.restJoints());
  });
  EXPECT_NE(msg.find("expected V's 10"), std::string::npos) << msg;
  msg = messageOf<InputError>([&] {
    lumpBoneInertia(avatar.templateMassMoments(), avatar.restVertices(), body.weights,
                    avatar.restJoints(), -1.0);
  });
  EXPECT_NE(msg.find("mass_scale"), std::string::npos) << msg;
}

// derived(): built once per key and shared; a copy starts empty; initVolumetricData() forgets.
TEST(SoftAvatar, DerivedDataIsBuiltOncePerAvatarAndNotCopied) {
  SoftAvatar avatar(smallSyntheticBody(), VecX::Zero(0));
  int builds = 0;
  const auto make = [&] {
    ++builds;
    return new int(7);
  };
  const std::shared_ptr<const int> first = avatar.derived<int>("answer", make);
  const std::shared_ptr<const int> again = avatar.derived<int>("answer", make);
  EXPECT_EQ(builds, 1);
  EXPECT_EQ(first.get(), again.get());
  EXPECT_EQ(*avatar.derived<double>("other", [] { return new double(2.5); }), 2.5);
  const SoftAvatar copy = avatar;
  EXPECT_NE(copy.derived<int>("answer", make).get(), first.get());
  EXPECT_EQ(builds, 2);
  avatar.initVolumetricData();
  EXPECT_NE(avatar.derived<int>("answer", make).get(), first.get());
  EXPECT_EQ(builds, 3);
  EXPECT_EQ(*first, 7);  // callers keep what they were given
}

}  // namespace
}  // namespace flsh
