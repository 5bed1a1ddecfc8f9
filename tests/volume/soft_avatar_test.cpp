// SoftAvatar (skeleton model): constructor checks and β padding, the soft-tissue error, the
// rest data it builds (shape, joints, vertex areas, volume, masses, capsules), idempotence,
// determinism and the effect of β.
#include "flsh/volume/soft_avatar.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "flsh/body/body_forward.h"
#include "flsh/core/error.h"
#include "support/test_support.h"
#include "volume/volume_test_meshes.h"

namespace flsh {
namespace {

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
  msg = messageOf<InputError>([&] { SoftAvatar(body, VecX::Zero(10), {0.0, 0.01}); });
  EXPECT_NE(msg.find("density"), std::string::npos) << msg;
  msg = messageOf<InputError>([&] { SoftAvatar(body, VecX::Zero(10), {1000.0, 0.0}); });
  EXPECT_NE(msg.find("voxel_size"), std::string::npos) << msg;
  msg = messageOf<InputError>([&] {
    SoftAvatar(body, VecX::Zero(10), {1000.0, std::numeric_limits<double>::infinity()});
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

TEST(SoftAvatar, SoftTissueIsNotAvailableYet) {
  SoftAvatar avatar(smallSyntheticBody(), VecX::Zero(10));
  avatar.enableSoftTissue(true);
  const std::string msg = messageOf<Error>([&] { avatar.initVolumetricData(); });
  EXPECT_NE(msg.find("soft tissue"), std::string::npos) << msg;
  EXPECT_NE(msg.find("not available"), std::string::npos) << msg;
  EXPECT_FALSE(avatar.initialized());
  avatar.enableSoftTissue(false);
  avatar.initVolumetricData();
  EXPECT_TRUE(avatar.initialized());
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
  SoftAvatar light(smallSyntheticBody(), VecX::Zero(0), {505.0, 0.01});
  light.initVolumetricData();
  EXPECT_NEAR(light.totalMass(), 0.5 * meanAvatar().totalMass(), 1e-9 * light.totalMass());
}

}  // namespace
}  // namespace flsh
