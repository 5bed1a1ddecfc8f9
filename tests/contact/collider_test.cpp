// Colliders: paths, analytic signed distances, derivatives against finite differences, and the
// degenerate places (sphere centre, capsule axis, zero-length capsule, far away).
#include "flsh/contact/collider.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include "flsh/core/error.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::jacobianMatchesFiniteDifferences;
using test::messageOf;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

Vec3 randomPoint(std::mt19937& rng, double half_width) {
  std::uniform_real_distribution<double> uni(-half_width, half_width);
  return Vec3(uni(rng), uni(rng), uni(rng));
}

// d, ∇d and ∇²d of a collider as functions of x (for the finite-difference checker).
VecX distanceOf(const Collider& c, double t, const VecX& x) {
  return VecX::Constant(1, c.signedDistance(x, t));
}
VecX gradientOf(const Collider& c, double t, const VecX& x) {
  Vec3 g;
  c.signedDistance(x, t, &g);
  return g;
}

// Closest-point parameter of x on segment ab (unclamped), to keep FD points off region borders.
double segmentParameter(const Vec3& x, const Vec3& a, const Vec3& b) {
  return (x - a).dot(b - a) / (b - a).squaredNorm();
}

// ---------------------------------------------------------------------------------------------
// ColliderPath

TEST(ColliderPath, InterpolatesLinearlyAndHoldsOutsideTheKeys) {
  ColliderPath path;
  path.times = {1.0, 2.0, 4.0};
  path.offsets = {Vec3(0, 0, 0), Vec3(1, 2, 3), Vec3(1, 0, 3)};
  EXPECT_TRUE(path.offsetAt(-5.0).isApprox(Vec3(0, 0, 0)));
  EXPECT_TRUE(path.offsetAt(1.0).isZero());
  EXPECT_TRUE(path.offsetAt(1.5).isApprox(Vec3(0.5, 1.0, 1.5)));
  EXPECT_TRUE(path.offsetAt(2.0).isApprox(Vec3(1, 2, 3)));
  EXPECT_TRUE(path.offsetAt(3.0).isApprox(Vec3(1, 1, 3)));
  EXPECT_TRUE(path.offsetAt(4.0).isApprox(Vec3(1, 0, 3)));
  EXPECT_TRUE(path.offsetAt(100.0).isApprox(Vec3(1, 0, 3)));

  EXPECT_TRUE(path.velocityAt(0.5).isZero());
  EXPECT_TRUE(path.velocityAt(1.0).isApprox(Vec3(1, 2, 3)));  // right derivative at a key
  EXPECT_TRUE(path.velocityAt(1.7).isApprox(Vec3(1, 2, 3)));
  EXPECT_TRUE(path.velocityAt(2.0).isApprox(Vec3(0, -1, 0)));  // slope of the next segment
  EXPECT_TRUE(path.velocityAt(3.9).isApprox(Vec3(0, -1, 0)));
  EXPECT_TRUE(path.velocityAt(4.0).isZero());  // held after the last key
  EXPECT_NO_THROW(path.validate("test path"));
}

TEST(ColliderPath, EmptyAndSingleKeyPathsAreStatic) {
  ColliderPath empty;
  EXPECT_TRUE(empty.offsetAt(3.0).isZero());
  EXPECT_TRUE(empty.velocityAt(3.0).isZero());
  EXPECT_NO_THROW(empty.validate("empty"));
  ColliderPath single;
  single.times = {0.5};
  single.offsets = {Vec3(1, 2, 3)};
  EXPECT_TRUE(single.offsetAt(-1.0).isApprox(Vec3(1, 2, 3)));
  EXPECT_TRUE(single.offsetAt(9.0).isApprox(Vec3(1, 2, 3)));
  EXPECT_TRUE(single.velocityAt(0.5).isZero());
}

TEST(ColliderPath, ConstantVelocity) {
  const ColliderPath path = ColliderPath::constantVelocity(Vec3(0.5, 0, -1), 2.0);
  ASSERT_EQ(path.times.size(), 2u);
  EXPECT_EQ(path.times[0], 0.0);
  EXPECT_EQ(path.times[1], 2.0);
  EXPECT_TRUE(path.offsetAt(0.0).isZero());
  EXPECT_TRUE(path.offsetAt(1.0).isApprox(Vec3(0.5, 0, -1)));
  EXPECT_TRUE(path.offsetAt(5.0).isApprox(Vec3(1.0, 0, -2)));
  EXPECT_TRUE(path.velocityAt(0.3).isApprox(Vec3(0.5, 0, -1)));
  EXPECT_NE(messageOf<InputError>([] {
              ColliderPath::constantVelocity(Vec3(1, 0, 0), 0.0);
            }).find("duration"),
            std::string::npos);
  EXPECT_NE(messageOf<InputError>([] {
              ColliderPath::constantVelocity(Vec3(kNaN, 0, 0), 1.0);
            }).find("velocity"),
            std::string::npos);
}

TEST(ColliderPath, ValidateNamesTheColliderAndTheProblem) {
  ColliderPath sizes;
  sizes.times = {0.0, 1.0};
  sizes.offsets = {Vec3::Zero()};
  std::string m = messageOf<InputError>([&] { sizes.validate("collider 'floor'"); });
  EXPECT_NE(m.find("collider 'floor'"), std::string::npos) << m;
  EXPECT_NE(m.find("2"), std::string::npos) << m;
  EXPECT_THROW(sizes.offsetAt(0.5), InputError);  // never reads past the end

  ColliderPath order;
  order.times = {0.0, 1.0, 1.0};
  order.offsets = {Vec3::Zero(), Vec3::Zero(), Vec3::Zero()};
  m = messageOf<InputError>([&] { order.validate("ball"); });
  EXPECT_NE(m.find("ball"), std::string::npos) << m;
  EXPECT_NE(m.find("strictly increasing"), std::string::npos) << m;

  ColliderPath nan_time;
  nan_time.times = {0.0, kNaN};
  nan_time.offsets = {Vec3::Zero(), Vec3::Zero()};
  m = messageOf<InputError>([&] { nan_time.validate("wall"); });
  EXPECT_NE(m.find("wall"), std::string::npos) << m;
  EXPECT_NE(m.find("finite"), std::string::npos) << m;

  ColliderPath nan_offset;
  nan_offset.times = {0.0, 1.0};
  nan_offset.offsets = {Vec3::Zero(), Vec3(0, kNaN, 0)};
  m = messageOf<InputError>([&] { nan_offset.validate("bar"); });
  EXPECT_NE(m.find("bar"), std::string::npos) << m;
  EXPECT_NE(m.find("offset 1"), std::string::npos) << m;
}

// ---------------------------------------------------------------------------------------------
// Construction

TEST(Collider, FactoriesCheckTheirArguments) {
  EXPECT_NE(
      messageOf<InputError>([] { Collider::plane(Vec3::Zero(), Vec3::Zero()); }).find("normal"),
      std::string::npos);
  EXPECT_NE(messageOf<InputError>([] { Collider::sphere(Vec3::Zero(), -1.0); }).find("radius"),
            std::string::npos);
  EXPECT_NE(messageOf<InputError>([] { Collider::sphere(Vec3::Zero(), kNaN); }).find("radius"),
            std::string::npos);
  EXPECT_NE(messageOf<InputError>([] { Collider::sphere(Vec3(kNaN, 0, 0), 1.0); }).find("center"),
            std::string::npos);
  EXPECT_NE(messageOf<InputError>([] {
              Collider::capsule(Vec3::Zero(), Vec3::UnitX(), 0.0);
            }).find("radius"),
            std::string::npos);
  EXPECT_THROW(Collider::capsule(Vec3::Zero(), Vec3(0, 0, INFINITY), 1.0), InputError);
  EXPECT_NO_THROW(Collider::capsule(Vec3::Ones(), Vec3::Ones(), 0.1));  // a == b: a sphere

  const Collider p = Collider::plane(Vec3(0, 1, 0), Vec3(0, 3, 4));
  EXPECT_EQ(p.shape(), ColliderShape::Plane);
  EXPECT_NEAR(p.p1().norm(), 1.0, 1e-15);
  EXPECT_TRUE(p.p1().isApprox(Vec3(0, 0.6, 0.8)));
}

// ---------------------------------------------------------------------------------------------
// Analytic signed distances

TEST(Collider, PlaneSignedDistance) {
  const Collider floor = Collider::plane(Vec3(0, 0.1, 0), Vec3(0, 2, 0));
  EXPECT_NEAR(floor.signedDistance(Vec3(3, 0.5, -2), 0), 0.4, 1e-15);
  EXPECT_NEAR(floor.signedDistance(Vec3(3, -0.2, -2), 0), -0.3, 1e-15);
  EXPECT_NEAR(floor.signedDistance(Vec3(0, 0.1, 9), 0), 0.0, 1e-15);

  const Collider slope = Collider::plane(Vec3::Zero(), Vec3(1, 1, 0));
  EXPECT_NEAR(slope.signedDistance(Vec3(1, 1, 5), 0), std::sqrt(2.0), 1e-14);

  Collider rising = floor;
  rising.path = ColliderPath::constantVelocity(Vec3(0, 0.5, 0), 2.0);  // y offset 0.5 t, t ≤ 2
  for (double t : {0.0, 0.4, 1.0, 2.0, 3.0}) {
    const double y = 0.1 + 0.5 * std::min(t, 2.0);
    EXPECT_NEAR(rising.signedDistance(Vec3(1, 0.3, 1), t), 0.3 - y, 1e-14) << "t = " << t;
  }
}

TEST(Collider, SphereSignedDistance) {
  const Collider ball = Collider::sphere(Vec3(1, 2, 3), 0.5);
  EXPECT_NEAR(ball.signedDistance(Vec3(1, 2, 4), 0), 0.5, 1e-15);      // outside
  EXPECT_NEAR(ball.signedDistance(Vec3(1, 2.2, 3), 0), -0.3, 1e-15);   // inside
  EXPECT_NEAR(ball.signedDistance(Vec3(1.3, 2.4, 3), 0), 0.0, 1e-15);  // on the surface
  EXPECT_NEAR(ball.signedDistance(Vec3(1, 2, 3), 0), -0.5, 1e-15);     // centre

  Collider moving = ball;
  moving.path.times = {0.0, 1.0, 2.0};
  moving.path.offsets = {Vec3::Zero(), Vec3(1, 0, 0), Vec3(1, 1, 0)};
  const Vec3 x(2, 2, 3);
  EXPECT_NEAR(moving.signedDistance(x, 0.0), 0.5, 1e-14);
  EXPECT_NEAR(moving.signedDistance(x, 0.5), 0.0, 1e-14);
  EXPECT_NEAR(moving.signedDistance(x, 1.0), -0.5, 1e-14);
  EXPECT_NEAR(moving.signedDistance(x, 1.5), 0.0, 1e-14);
  EXPECT_NEAR(moving.signedDistance(x, 7.0), 0.5, 1e-14);
}

TEST(Collider, CapsuleSignedDistance) {
  const Collider bar = Collider::capsule(Vec3(0, 0, 0), Vec3(2, 0, 0), 0.25);
  EXPECT_NEAR(bar.signedDistance(Vec3(1, 1, 0), 0), 0.75, 1e-15);       // beside the middle
  EXPECT_NEAR(bar.signedDistance(Vec3(0.5, 0, 0.1), 0), -0.15, 1e-15);  // inside
  EXPECT_NEAR(bar.signedDistance(Vec3(-0.5, 0, 0), 0), 0.25, 1e-15);    // beyond cap a
  EXPECT_NEAR(bar.signedDistance(Vec3(2.3, 0.4, 0), 0), 0.25, 1e-15);   // beyond cap b
  EXPECT_NEAR(bar.signedDistance(Vec3(2.1, 0, 0), 0), -0.15, 1e-15);    // inside cap b
  EXPECT_NEAR(bar.signedDistance(Vec3(1.5, 0, 0), 0), -0.25, 1e-15);    // on the axis

  Collider moving = bar;
  moving.path = ColliderPath::constantVelocity(Vec3(0, 0, 1), 1.0);
  for (double t : {0.0, 0.25, 0.5, 1.0, 1.5}) {
    const double z = std::min(t, 1.0);
    EXPECT_NEAR(moving.signedDistance(Vec3(1, 0, 0.5), t), std::abs(0.5 - z) - 0.25, 1e-14)
        << "t = " << t;
  }
}

TEST(Collider, ZeroLengthCapsuleIsASphere) {
  const Collider dot = Collider::capsule(Vec3(1, 1, 1), Vec3(1, 1, 1), 0.3);
  const Collider ball = Collider::sphere(Vec3(1, 1, 1), 0.3);
  std::mt19937 rng(7);
  for (int k = 0; k < 20; ++k) {
    const Vec3 x = Vec3(1, 1, 1) + randomPoint(rng, 1.0);
    Vec3 g1, g2;
    Mat3 H1, H2;
    EXPECT_NEAR(dot.signedDistance(x, 0, &g1, &H1), ball.signedDistance(x, 0, &g2, &H2), 1e-14);
    EXPECT_TRUE(g1.isApprox(g2, 1e-12));
    EXPECT_TRUE(H1.isApprox(H2, 1e-12));
  }
}

// ---------------------------------------------------------------------------------------------
// Derivatives w.r.t. x against finite differences

TEST(Collider, PlaneGradientMatchesFiniteDifferencesAndHessianIsZero) {
  Collider slope = Collider::plane(Vec3(0.1, -0.2, 0.3), Vec3(0.3, 1.0, -0.2));
  slope.path = ColliderPath::constantVelocity(Vec3(0.2, 0.1, 0), 1.0);
  std::mt19937 rng(1);
  for (int k = 0; k < 10; ++k) {
    const Vec3 x = randomPoint(rng, 1.0);
    Vec3 g;
    Mat3 H;
    slope.signedDistance(x, 0.4, &g, &H);
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(
        [&](const VecX& y) { return distanceOf(slope, 0.4, y); }, x, g.transpose()));
    EXPECT_TRUE(H.isZero(0.0));
  }
}

TEST(Collider, SphereDerivativesMatchFiniteDifferences) {
  Collider ball = Collider::sphere(Vec3(0.2, 0.1, -0.3), 0.4);
  ball.path = ColliderPath::constantVelocity(Vec3(0.0, -0.3, 0.1), 2.0);
  std::mt19937 rng(2);
  for (int k = 0; k < 20; ++k) {
    const Vec3 x = randomPoint(rng, 1.0);
    const double t = 0.1 * k;
    Vec3 g;
    Mat3 H;
    ball.signedDistance(x, t, &g, &H);
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(
        [&](const VecX& y) { return distanceOf(ball, t, y); }, x, g.transpose()));
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(
        [&](const VecX& y) { return gradientOf(ball, t, y); }, x, H, 1e-5));
  }
}

TEST(Collider, CapsuleDerivativesMatchFiniteDifferencesInEveryRegion) {
  const Vec3 a(-0.3, 0.1, 0.0), b(0.4, -0.2, 0.3);
  Collider bar = Collider::capsule(a, b, 0.15);
  bar.path = ColliderPath::constantVelocity(Vec3(0.1, 0.0, -0.2), 1.0);
  const double t = 0.5;
  const Vec3 shift = bar.path.offsetAt(t);
  std::mt19937 rng(3);
  int interior = 0, caps = 0;
  for (int k = 0; k < 200 && (interior < 10 || caps < 10); ++k) {
    const Vec3 x = randomPoint(rng, 1.0);
    const double s = segmentParameter(x, a + shift, b + shift);
    if (std::abs(s) < 0.05 || std::abs(s - 1.0) < 0.05) continue;  // region borders: C¹ only
    (s > 0 && s < 1 ? interior : caps)++;
    Vec3 g;
    Mat3 H;
    bar.signedDistance(x, t, &g, &H);
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(
        [&](const VecX& y) { return distanceOf(bar, t, y); }, x, g.transpose()));
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(
        [&](const VecX& y) { return gradientOf(bar, t, y); }, x, H, 1e-5))
        << "s = " << s;
  }
  EXPECT_GE(interior, 10);
  EXPECT_GE(caps, 10);
}

TEST(Collider, OffsetGradientIsMinusTheSpatialGradient) {
  // A one-key path is a static translation o: check ∂d/∂o against finite differences in o.
  const Collider shapes[] = {Collider::plane(Vec3(0, 0.1, 0), Vec3(0.2, 1, 0)),
                             Collider::sphere(Vec3(0.1, 0.2, 0), 0.3),
                             Collider::capsule(Vec3(-0.2, 0, 0), Vec3(0.3, 0.1, 0.2), 0.1)};
  const Vec3 x(0.35, 0.42, -0.13);
  for (const Collider& shape : shapes) {
    auto distanceAtOffset = [&](const VecX& o) {
      Collider moved = shape;
      moved.path.times = {0.0};
      moved.path.offsets = {Vec3(o)};
      return VecX::Constant(1, moved.signedDistance(x, 0.0));
    };
    Collider at = shape;
    const Vec3 o0(0.01, -0.02, 0.03);
    at.path.times = {0.0};
    at.path.offsets = {o0};
    const Vec3 g = at.distanceGradientOffset(x, 0.0);
    Vec3 gx;
    at.signedDistance(x, 0.0, &gx);
    EXPECT_TRUE(g.isApprox(-gx));
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(distanceAtOffset, o0, g.transpose()));
  }
}

// ---------------------------------------------------------------------------------------------
// Degenerate places: finite values, unit subgradients, zero Hessians

TEST(Collider, DegeneratePointsGiveFiniteOutputs) {
  const Collider ball = Collider::sphere(Vec3(1, 2, 3), 0.5);
  const Collider bar = Collider::capsule(Vec3(0, 0, 0), Vec3(0, 0, 2), 0.2);
  const Collider dot = Collider::capsule(Vec3(1, 0, 0), Vec3(1, 0, 1e-12), 0.2);
  struct Case {
    const Collider* collider;
    Vec3 x;
    double distance;
  };
  const Case cases[] = {
      {&ball, Vec3(1, 2, 3), -0.5},   // sphere centre
      {&bar, Vec3(0, 0, 1.3), -0.2},  // capsule axis, interior
      {&bar, Vec3(0, 0, 0), -0.2},    // capsule end point a
      {&bar, Vec3(0, 0, 2), -0.2},    // capsule end point b
      {&dot, Vec3(1, 0, 0), -0.2},    // zero-length capsule at its point
      {&ball, Vec3(1e6, -1e6, 1e6), Vec3(1e6 - 1, -1e6 - 2, 1e6 - 3).norm() - 0.5},  // far
      {&bar, Vec3(-1e7, 3e7, 1e8), Vec3(-1e7, 3e7, 1e8 - 2).norm() - 0.2},
  };
  for (const Case& c : cases) {
    Vec3 g;
    Mat3 H;
    const double d = c.collider->signedDistance(c.x, 0.0, &g, &H);
    EXPECT_NEAR(d, c.distance, 1e-9 * std::max(1.0, std::abs(c.distance)));
    EXPECT_TRUE(g.allFinite());
    EXPECT_NEAR(g.norm(), 1.0, 1e-12);
    EXPECT_TRUE(H.allFinite());
    EXPECT_TRUE(c.collider->distanceGradientOffset(c.x, 0.0).allFinite());
  }
  // On the axis the subgradient is perpendicular to the axis.
  Vec3 g;
  Mat3 H;
  bar.signedDistance(Vec3(0, 0, 1.3), 0.0, &g, &H);
  EXPECT_NEAR(g.z(), 0.0, 1e-15);
  EXPECT_TRUE(H.isZero(0.0));
}

// ---------------------------------------------------------------------------------------------
// capsuleDistance: derivatives with respect to all nine inputs (x, a, b)

struct CapsuleInputs {
  Vec3 x, a, b;
  VecX stacked() const {
    VecX y(9);
    y << x, a, b;
    return y;
  }
};

VecX capsuleValue(const VecX& y, double r) {
  return VecX::Constant(1, capsuleDistance(y.segment<3>(0), y.segment<3>(3), y.segment<3>(6), r));
}
VecX capsuleGradient(const VecX& y, double r) {
  Vec9 g;
  capsuleDistance(y.segment<3>(0), y.segment<3>(3), y.segment<3>(6), r, &g);
  return g;
}

TEST(CapsuleDistance, DerivativesMatchFiniteDifferencesInInteriorAndCaps) {
  const double r = 0.1;
  std::mt19937 rng(11);
  int counts[3] = {0, 0, 0};  // cap a, interior, cap b
  for (int k = 0; k < 400 && (counts[0] < 6 || counts[1] < 6 || counts[2] < 6); ++k) {
    CapsuleInputs in{randomPoint(rng, 1.0), randomPoint(rng, 0.6), randomPoint(rng, 0.6)};
    if ((in.b - in.a).norm() < 0.2) continue;
    const double s = segmentParameter(in.x, in.a, in.b);
    if (std::abs(s) < 0.05 || std::abs(s - 1.0) < 0.05) continue;
    const int region = s < 0 ? 0 : (s < 1 ? 1 : 2);
    if (counts[region] >= 6) continue;
    ++counts[region];
    const VecX y = in.stacked();
    Vec9 g;
    Mat9 H;
    const double d = capsuleDistance(in.x, in.a, in.b, r, &g, &H);
    EXPECT_TRUE(std::isfinite(d));
    EXPECT_TRUE(jacobianMatchesFiniteDifferences([&](const VecX& v) { return capsuleValue(v, r); },
                                                 y, g.transpose()))
        << "region " << region;
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(
        [&](const VecX& v) { return capsuleGradient(v, r); }, y, H, 1e-5))
        << "region " << region;
    EXPECT_LT((H - H.transpose()).cwiseAbs().maxCoeff(), 1e-9 * H.cwiseAbs().maxCoeff());
    // Translating everything together changes nothing: gradient blocks sum to zero.
    EXPECT_LT((g.segment<3>(0) + g.segment<3>(3) + g.segment<3>(6)).norm(), 1e-12);
  }
  EXPECT_EQ(counts[0], 6);
  EXPECT_EQ(counts[1], 6);
  EXPECT_EQ(counts[2], 6);
}

TEST(CapsuleDistance, ValueAndGradientAreContinuousAcrossRegionBorders) {
  // At s = 0 and s = 1 the interior formula meets the cap formula: d and ∇d must agree (C¹).
  const Vec3 a(0.1, -0.2, 0.3), b(0.6, 0.1, 0.1), side(0.3, -0.2, 0.45);
  const Vec3 u = b - a;
  const Vec3 across = (side - side.dot(u) / u.squaredNorm() * u).normalized();
  for (const Vec3& end : {a, b}) {
    const Vec3 x = end + 0.3 * across;  // exactly on the border plane of the end cap
    const double h = 1e-9;
    Vec9 g_before, g_after;
    const double d_before = capsuleDistance(x - h * u, a, b, 0.1, &g_before);
    const double d_after = capsuleDistance(x + h * u, a, b, 0.1, &g_after);
    EXPECT_NEAR(d_before, d_after, 1e-8);
    EXPECT_LT((g_before - g_after).cwiseAbs().maxCoeff(), 1e-7);
    EXPECT_GT(g_before.cwiseAbs().maxCoeff(), 0.1);
  }
}

TEST(CapsuleDistance, AgreesWithTheCapsuleCollider) {
  const Vec3 a(0.1, -0.2, 0.3), b(-0.4, 0.5, 0.1);
  const Collider bar = Collider::capsule(a, b, 0.12);
  std::mt19937 rng(5);
  for (int k = 0; k < 30; ++k) {
    const Vec3 x = randomPoint(rng, 0.8);
    Vec9 g;
    Mat9 H;
    Vec3 gx;
    Mat3 Hx;
    const double d = capsuleDistance(x, a, b, 0.12, &g, &H);
    EXPECT_NEAR(d, bar.signedDistance(x, 0.0, &gx, &Hx), 1e-14);
    EXPECT_TRUE(g.segment<3>(0).isApprox(gx, 1e-12));
    EXPECT_LT((H.block<3, 3>(0, 0) - Hx).cwiseAbs().maxCoeff(), 1e-10 * (1 + Hx.norm()));
  }
}

TEST(CapsuleDistance, DegenerateInputsGiveFiniteOutputs) {
  const double r = 0.2;
  struct Case {
    Vec3 x, a, b;
    double distance;
  };
  const Case cases[] = {
      {Vec3(0, 0, 0.5), Vec3(0, 0, 0), Vec3(0, 0, 1), -r},             // on the axis
      {Vec3(0, 0, 0), Vec3(0, 0, 0), Vec3(0, 0, 1), -r},               // at end point a
      {Vec3(0, 0, 1), Vec3(0, 0, 0), Vec3(0, 0, 1), -r},               // at end point b
      {Vec3(0.3, 0, 0), Vec3(0, 0, 0), Vec3(0, 0, 0), 0.3 - r},        // zero length
      {Vec3(0, 0, 0), Vec3(0, 0, 0), Vec3(0, 0, 0), -r},               // zero length, at it
      {Vec3(0, 0.3, 0), Vec3(0, 0, 0), Vec3(1e-14, 0, 0), 0.3 - r},    // nearly zero length
      {Vec3(0, 1e-13, 0.5), Vec3(0, 0, 0), Vec3(0, 0, 1), 1e-13 - r},  // nearly on the axis
      {Vec3(5e6, 0, 1), Vec3(0, 0, 0), Vec3(0, 0, 1), 5e6 - r},        // far away
  };
  for (const Case& c : cases) {
    Vec9 g;
    Mat9 H;
    const double d = capsuleDistance(c.x, c.a, c.b, r, &g, &H);
    EXPECT_NEAR(d, c.distance, 1e-12 * std::max(1.0, std::abs(c.distance)));
    EXPECT_TRUE(g.allFinite());
    EXPECT_TRUE(H.allFinite());
    EXPECT_NEAR(g.segment<3>(0).norm(), 1.0, 1e-12);
    EXPECT_LT((g.segment<3>(0) + g.segment<3>(3) + g.segment<3>(6)).norm(), 1e-12);
  }
  EXPECT_NE(messageOf<InputError>([] {
              capsuleDistance(Vec3(kNaN, 0, 0), Vec3::Zero(), Vec3::UnitX(), 0.1);
            }).find("capsuleDistance"),
            std::string::npos);
}

}  // namespace
}  // namespace flsh
