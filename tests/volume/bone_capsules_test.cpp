// fitBoneCapsules on the synthetic body: one capsule per bone, axes along the limbs, plausible
// radii, capsules inside the body, left/right symmetry; bones without vertices; input errors.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "flsh/volume/soft_avatar.h"
#include "support/test_support.h"
#include "volume/volume_test_meshes.h"

namespace flsh {
namespace {

using test::smallSyntheticBody;

struct FittedBody {
  MatX3 V, J;
  std::vector<BoneCapsule> capsules;
};
const FittedBody& fitted() {
  static const FittedBody fit = [] {
    const BodyModel& body = *smallSyntheticBody();
    FittedBody f{body.v_template, MatX3(body.J_regressor * body.v_template), {}};
    f.capsules = fitBoneCapsules(f.V, body.weights, f.J, body.parents);
    return f;
  }();
  return fit;
}

TEST(BoneCapsules, OnePerBoneAlongTheLimbs) {
  const FittedBody& f = fitted();
  ASSERT_EQ(f.capsules.size(), 24u);
  for (int j = 0; j < 24; ++j) {
    EXPECT_EQ(f.capsules[j].bone, j);
    EXPECT_GT(f.capsules[j].radius, 0.0) << kSmplJointNames[j];
    EXPECT_LT(f.capsules[j].radius, 0.2) << kSmplJointNames[j];
  }
  const BoneCapsule& arm = f.capsules[smplJointIndex("left_shoulder")];
  const Vec3 axis = (arm.b - arm.a).normalized();
  EXPECT_GT(axis.x(), 0.95) << axis.transpose();
  EXPECT_GT(arm.radius, 0.02);
  EXPECT_LT(arm.radius, 0.08);
  EXPECT_GT((arm.b - arm.a).norm(), 0.05);  // a segment, not a ball
  const BoneCapsule& thigh = f.capsules[smplJointIndex("right_hip")];
  EXPECT_LT((thigh.b - thigh.a).normalized().y(), -0.9);  // the thigh points down
  const BoneCapsule& head = f.capsules[smplJointIndex("head")];
  EXPECT_GT(head.a.y(), f.J(smplJointIndex("neck"), 1));  // the head sits above the neck
}

TEST(BoneCapsules, AxesLieInsideTheBody) {
  const FittedBody& f = fitted();
  const MatX3i& F = smallSyntheticBody()->faces;
  constexpr int kSamples = 21;
  for (const BoneCapsule& c : f.capsules) {
    int inside = 0;
    for (int s = 0; s < kSamples; ++s) {
      const Vec3 x = c.a + (c.b - c.a) * (double(s) / (kSamples - 1));
      if (test::windingNumber(f.V, F, x) > 0.5) ++inside;
    }
    EXPECT_GT(inside, 0.8 * kSamples) << kSmplJointNames[c.bone];
  }
}

TEST(BoneCapsules, MirroredBodyGivesMirroredCapsules) {
  // The fit is pure geometry: the body mirrored in x (left and right bones swapped) gives the
  // mirror images of the capsules (a multi-child bone's axis is re-oriented, so its ends may
  // swap).
  const FittedBody& f = fitted();
  const BodyModel& body = *smallSyntheticBody();
  std::vector<int> mirror_bone(24);
  for (int j = 0; j < 24; ++j) {
    std::string name = kSmplJointNames[j];
    if (name.rfind("left_", 0) == 0)
      name = "right_" + name.substr(5);
    else if (name.rfind("right_", 0) == 0)
      name = "left_" + name.substr(6);
    mirror_bone[j] = smplJointIndex(name);
  }
  MatX3 V = f.V, J(24, 3);
  V.col(0) *= -1;
  MatX W(body.weights.rows(), 24);
  for (int j = 0; j < 24; ++j) {
    W.col(mirror_bone[j]) = body.weights.col(j);
    J.row(mirror_bone[j]) = f.J.row(j);
  }
  J.col(0) *= -1;
  const std::vector<BoneCapsule> mirrored = fitBoneCapsules(V, W, J, body.parents);
  const Vec3 flip(-1, 1, 1);
  for (int j = 0; j < 24; ++j) {
    const BoneCapsule& original = f.capsules[j];
    const BoneCapsule& image = mirrored[mirror_bone[j]];
    EXPECT_NEAR(image.radius, original.radius, 1e-12) << kSmplJointNames[j];
    const Vec3 a = original.a.cwiseProduct(flip), b = original.b.cwiseProduct(flip);
    const double same = std::max((image.a - a).norm(), (image.b - b).norm());
    const double swapped = std::max((image.a - b).norm(), (image.b - a).norm());
    EXPECT_LT(std::min(same, swapped), 1e-12) << kSmplJointNames[j];
  }
}

TEST(BoneCapsules, LeftAndRightRoughlyMatch) {
  // The 1000-vertex mesh is itself only roughly mirror symmetric (vertices up to 3 cm off).
  const FittedBody& f = fitted();
  for (int left = 0; left < 24; ++left) {
    const std::string name = kSmplJointNames[left];
    if (name.rfind("left_", 0) != 0) continue;
    const BoneCapsule& l = f.capsules[left];
    const BoneCapsule& r = f.capsules[smplJointIndex("right_" + name.substr(5))];
    EXPECT_NEAR(l.radius, r.radius, 0.15 * l.radius) << name;
    const Vec3 mirror(-1, 1, 1);
    EXPECT_LT((l.a.cwiseProduct(mirror) - r.a).norm(), 0.03) << name;
    EXPECT_LT((l.b.cwiseProduct(mirror) - r.b).norm(), 0.03) << name;
  }
}

TEST(BoneCapsules, BonesWithoutVerticesGetZeroRadius) {
  // An icosphere split between bones 0 (x < 0) and 1 (x ≥ 0); the other 22 bones own nothing.
  const test::TriangleMesh sphere = test::icosphere(2, 0.1, Vec3::Zero());
  MatX w = MatX::Zero(sphere.V.rows(), 24);
  for (int v = 0; v < sphere.V.rows(); ++v) w(v, sphere.V(v, 0) < 0 ? 0 : 1) = 1;
  MatX3 J = MatX3::Zero(24, 3);
  for (int j = 0; j < 24; ++j) J.row(j) << 0.01 * j, 0.0, 0.0;
  const std::vector<BoneCapsule> capsules =
      fitBoneCapsules(sphere.V, w, J, std::vector<int>(kSmplParents.begin(), kSmplParents.end()));
  ASSERT_EQ(capsules.size(), 24u);
  EXPECT_GT(capsules[0].radius, 0.0);
  EXPECT_GT(capsules[1].radius, 0.0);
  for (int j = 2; j < 24; ++j) {
    EXPECT_EQ(capsules[j].radius, 0.0) << j;
    EXPECT_EQ(capsules[j].a, Vec3(J.row(j).transpose()));
    EXPECT_EQ(capsules[j].b, Vec3(J.row(j).transpose()));
  }
}

TEST(BoneCapsules, RejectsBadInputs) {
  const BodyModel& body = *smallSyntheticBody();
  const MatX3 J = body.J_regressor * body.v_template;
  std::string msg = test::messageOf<InputError>(
      [&] { fitBoneCapsules(body.v_template, body.weights.topRows(10), J, body.parents); });
  EXPECT_NE(msg.find("(10, 24)"), std::string::npos) << msg;
  std::vector<int> parents = body.parents;
  parents.pop_back();
  msg = test::messageOf<InputError>(
      [&] { fitBoneCapsules(body.v_template, body.weights, J, parents); });
  EXPECT_NE(msg.find("23"), std::string::npos) << msg;
  parents = body.parents;
  parents[5] = 7;
  msg = test::messageOf<InputError>(
      [&] { fitBoneCapsules(body.v_template, body.weights, J, parents); });
  EXPECT_NE(msg.find("parents[5]"), std::string::npos) << msg;
}

}  // namespace
}  // namespace flsh
