// Penalty contact energies: value, gradient and Hessian (exact and PSD) against finite
// differences and a brute-force reference; inactive points; input errors.
#include "flsh/contact/contact_energy.h"

#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
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

MatX3 asPoints(const VecX& flat) {
  return Eigen::Map<const MatX3>(flat.data(), flat.size() / 3, 3);
}
VecX flatten(const MatX3& X) { return Eigen::Map<const VecX>(X.data(), X.size()); }

MatX denseFrom(const std::vector<Triplet>& triplets, int size) {
  SpMat sparse(size, size);
  sparse.setFromTriplets(triplets.begin(), triplets.end());
  return MatX(sparse);
}

// A floor, a ball that moves with time, and a tilted capsule; points placed so that several
// penetrate each collider by a few centimetres (none within 1 mm of a contact boundary).
struct ContactScene {
  std::vector<Collider> colliders;
  MatX3 X;
  VecX areas;
  double t = 0.3;

  ContactScene() {
    colliders.push_back(Collider::plane(Vec3(0, 0, 0), Vec3(0, 1, 0)));
    Collider ball = Collider::sphere(Vec3(1.0, 0.5, 0.0), 0.3);
    ball.path = ColliderPath::constantVelocity(Vec3(0, 0.2, 0), 1.0);  // centre y 0.56 at t
    colliders.push_back(ball);
    colliders.push_back(Collider::capsule(Vec3(-1.0, 0.4, 0.0), Vec3(-0.5, 0.8, 0.2), 0.15));
    X.resize(9, 3);
    X << 0.2, -0.03, 0.1,   // below the floor
        -0.3, -0.05, 0.4,   // below the floor
        0.5, 0.2, 0.0,      // above everything: inactive
        1.1, 0.62, 0.05,    // inside the ball
        0.9, 0.45, -0.1,    // inside the ball
        1.0, 0.95, 0.0,     // above the ball: inactive
        -0.75, 0.65, 0.15,  // inside the capsule, interior region
        -1.05, 0.38, 0.02,  // inside the capsule's cap a
        -0.45, 0.85, 0.25;  // inside the capsule's cap b
    areas.resize(9);
    areas << 0.011, 0.013, 0.009, 0.012, 0.014, 0.010, 0.008, 0.015, 0.012;
  }
};

ContactOptions testOptions(bool exact) {
  ContactOptions o;
  o.stiffness = 500.0;  // moderate, so that finite differences are well scaled
  o.exact_hessian = exact;
  return o;
}

TEST(ColliderContactEnergy, ValueMatchesTheDefinition) {
  ContactScene scene;
  const ContactOptions options = testOptions(false);
  double expected = 0.0;
  int expected_active = 0;
  for (int i = 0; i < scene.X.rows(); ++i)
    for (const Collider& c : scene.colliders) {
      const double d = c.signedDistance(scene.X.row(i).transpose(), scene.t);
      if (d < 0) {
        expected += 0.5 * options.stiffness * scene.areas[i] * d * d;
        ++expected_active;
      }
    }
  std::vector<ContactPoint> active;
  const double energy = colliderContactEnergy(scene.X, scene.areas, scene.colliders, scene.t,
                                              options, nullptr, nullptr, 0, &active);
  EXPECT_GT(energy, 0.0);
  EXPECT_NEAR(energy, expected, 1e-14 * expected);
  EXPECT_EQ(expected_active, 7);
  ASSERT_EQ(static_cast<int>(active.size()), expected_active);
  for (const ContactPoint& p : active) {
    EXPECT_LT(p.distance, 0.0);
    EXPECT_NEAR(
        p.distance,
        scene.colliders[p.collider].signedDistance(scene.X.row(p.vertex).transpose(), scene.t),
        1e-15);
  }
}

TEST(ColliderContactEnergy, GradientAndExactHessianMatchFiniteDifferences) {
  ContactScene scene;
  const ContactOptions options = testOptions(true);
  const int n = static_cast<int>(scene.X.rows());
  auto energyAt = [&](const VecX& flat) {
    return VecX::Constant(
        1, colliderContactEnergy(asPoints(flat), scene.areas, scene.colliders, scene.t, options));
  };
  auto gradientAt = [&](const VecX& flat) {
    VecX g;
    colliderContactEnergy(asPoints(flat), scene.areas, scene.colliders, scene.t, options, &g);
    return g;
  };
  VecX g;
  std::vector<Triplet> triplets;
  colliderContactEnergy(scene.X, scene.areas, scene.colliders, scene.t, options, &g, &triplets);
  const VecX x0 = flatten(scene.X);
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(energyAt, x0, g.transpose()));
  const MatX H = denseFrom(triplets, 3 * n);
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(gradientAt, x0, H, 1e-5));
  EXPECT_LT((H - H.transpose()).cwiseAbs().maxCoeff(), 1e-12 * H.cwiseAbs().maxCoeff());
}

TEST(ColliderContactEnergy, PsdHessianIsGaussNewtonAndPositiveSemidefinite) {
  ContactScene scene;
  const int n = static_cast<int>(scene.X.rows());
  std::vector<Triplet> psd_triplets, exact_triplets;
  VecX g_psd, g_exact;
  const double e_psd = colliderContactEnergy(scene.X, scene.areas, scene.colliders, scene.t,
                                             testOptions(false), &g_psd, &psd_triplets);
  const double e_exact = colliderContactEnergy(scene.X, scene.areas, scene.colliders, scene.t,
                                               testOptions(true), &g_exact, &exact_triplets);
  EXPECT_EQ(e_psd, e_exact);
  EXPECT_TRUE(g_psd == g_exact);  // the option only changes the Hessian
  const MatX H_psd = denseFrom(psd_triplets, 3 * n);
  const MatX H_exact = denseFrom(exact_triplets, 3 * n);
  Eigen::SelfAdjointEigenSolver<MatX> psd(H_psd), exact(H_exact);
  const double scale = H_psd.cwiseAbs().maxCoeff();
  ASSERT_GT(scale, 0.0);
  EXPECT_GE(psd.eigenvalues().minCoeff(), -1e-12 * scale);
  // Penetrating a convex collider, the curvature term d ∇²d is negative: exact is indefinite.
  EXPECT_LT(exact.eigenvalues().minCoeff(), -1e-6 * scale);
  // Gauss–Newton: each block is k a ∇d ∇dᵀ, so the plane blocks agree exactly.
  const Mat3 plane_psd = H_psd.block(0, 0, 3, 3), plane_exact = H_exact.block(0, 0, 3, 3);
  EXPECT_TRUE(plane_psd.isApprox(plane_exact));
}

TEST(ColliderContactEnergy, InactivePointsContributeExactlyZero) {
  ContactScene scene;
  const int n = static_cast<int>(scene.X.rows());
  VecX g;
  std::vector<Triplet> triplets;
  std::vector<ContactPoint> active;
  colliderContactEnergy(scene.X, scene.areas, scene.colliders, scene.t, testOptions(true), &g,
                        &triplets, 0, &active);
  for (int i : {2, 5}) {
    EXPECT_TRUE(g.segment<3>(3 * i).isZero(0.0)) << "vertex " << i;
    for (const Triplet& tr : triplets) {
      EXPECT_NE(tr.row() / 3, i);
      EXPECT_NE(tr.col() / 3, i);
    }
    for (const ContactPoint& p : active) EXPECT_NE(p.vertex, i);
  }
  EXPECT_EQ(triplets.size(), 9u * active.size());  // full 3 × 3 block per active pair

  // Everything lifted far above: zero energy, zero gradient, no triplets, no contacts.
  MatX3 lifted = scene.X;
  lifted.col(1).array() += 10.0;
  VecX g_far;
  std::vector<Triplet> far_triplets;
  std::vector<ContactPoint> far_active;
  const double e = colliderContactEnergy(lifted, scene.areas, scene.colliders, scene.t,
                                         testOptions(true), &g_far, &far_triplets, 0, &far_active);
  EXPECT_EQ(e, 0.0);
  EXPECT_EQ(g_far.size(), 3 * n);
  EXPECT_TRUE(g_far.isZero(0.0));
  EXPECT_TRUE(far_triplets.empty());
  EXPECT_TRUE(far_active.empty());

  // Zero-area points never contribute, even inside a collider.
  VecX no_area = VecX::Zero(n);
  std::vector<Triplet> none;
  EXPECT_EQ(colliderContactEnergy(scene.X, no_area, scene.colliders, scene.t, testOptions(true),
                                  nullptr, &none),
            0.0);
  EXPECT_TRUE(none.empty());
}

TEST(ColliderContactEnergy, TripletsAreOffsetFullBlocksAndGradientAccumulates) {
  ContactScene scene;
  const int n = static_cast<int>(scene.X.rows());
  const int offset = 17;
  std::vector<Triplet> plain, shifted;
  colliderContactEnergy(scene.X, scene.areas, scene.colliders, scene.t, testOptions(true), nullptr,
                        &plain);
  colliderContactEnergy(scene.X, scene.areas, scene.colliders, scene.t, testOptions(true), nullptr,
                        &shifted, offset);
  ASSERT_EQ(plain.size(), shifted.size());
  for (size_t k = 0; k < plain.size(); ++k) {
    EXPECT_EQ(shifted[k].row(), plain[k].row() + offset);
    EXPECT_EQ(shifted[k].col(), plain[k].col() + offset);
    EXPECT_EQ(shifted[k].value(), plain[k].value());
    EXPECT_EQ(plain[k].row() / 3, plain[k].col() / 3);  // only diagonal 3 × 3 blocks
  }
  // The gradient is added to what is there already (and must have size 3 #X).
  VecX once;
  colliderContactEnergy(scene.X, scene.areas, scene.colliders, scene.t, testOptions(false), &once);
  VecX twice = once;
  colliderContactEnergy(scene.X, scene.areas, scene.colliders, scene.t, testOptions(false), &twice);
  EXPECT_TRUE(twice.isApprox(2.0 * once));
  VecX wrong = VecX::Zero(3 * n + 1);
  EXPECT_NE(messageOf<InputError>([&] {
              colliderContactEnergy(scene.X, scene.areas, scene.colliders, scene.t,
                                    testOptions(false), &wrong);
            }).find("gradient"),
            std::string::npos);
}

TEST(ColliderContactEnergy, DeepPenetrationAndDegeneratePointsStayFinite) {
  // Points at the sphere centre, on the capsule axis and at a capsule end point.
  std::vector<Collider> colliders = {Collider::sphere(Vec3(0, 1, 0), 0.5),
                                     Collider::capsule(Vec3(2, 0, 0), Vec3(2, 1, 0), 0.3),
                                     Collider::plane(Vec3(0, 100, 0), Vec3(0, 1, 0))};
  MatX3 X(3, 3);
  X << 0, 1, 0, 2, 0.5, 0, 2, 0, 0;
  const VecX areas = VecX::Constant(3, 0.01);
  for (bool exact : {false, true}) {
    VecX g;
    std::vector<Triplet> H;
    const double e = colliderContactEnergy(X, areas, colliders, 0.0, testOptions(exact), &g, &H);
    EXPECT_TRUE(std::isfinite(e));
    EXPECT_GT(e, 0.0);
    EXPECT_TRUE(g.allFinite());
    for (const Triplet& tr : H) EXPECT_TRUE(std::isfinite(tr.value()));
  }
}

TEST(ColliderContactEnergy, BroadPhaseAgreesWithBruteForceOnManyPoints) {
  // 7000 points × 3 colliders (the size of a body surface): the early rejections must not drop
  // any contact. Compared with a per-point, per-collider evaluation through signedDistance.
  std::mt19937 rng(21);
  std::uniform_real_distribution<double> uni(-1.0, 1.0);
  const int n = 7000;
  MatX3 X(n, 3);
  for (int i = 0; i < n; ++i) X.row(i) = Vec3(uni(rng), 0.9 * uni(rng) + 0.8, uni(rng));
  const VecX areas = VecX::Constant(n, 1e-4);
  std::vector<Collider> colliders = {
      Collider::plane(Vec3(0, 0, 0), Vec3(0, 1, 0.1)), Collider::sphere(Vec3(0.3, 0.9, -0.2), 0.35),
      Collider::capsule(Vec3(-0.6, 1.2, 0), Vec3(0.2, 1.4, 0.5), 0.2)};
  colliders[1].path = ColliderPath::constantVelocity(Vec3(0.1, 0, 0), 1.0);
  ContactOptions options;  // default stiffness
  options.exact_hessian = true;
  const double t = 0.6;

  VecX g;
  std::vector<Triplet> triplets;
  std::vector<ContactPoint> active;
  const double energy =
      colliderContactEnergy(X, areas, colliders, t, options, &g, &triplets, 0, &active);

  double expected = 0.0;
  VecX expected_g = VecX::Zero(3 * n);
  int expected_active = 0;
  for (int i = 0; i < n; ++i)
    for (const Collider& c : colliders) {
      Vec3 grad;
      const double d = c.signedDistance(X.row(i).transpose(), t, &grad);
      if (d < 0) {
        expected += 0.5 * options.stiffness * areas[i] * d * d;
        expected_g.segment<3>(3 * i) += options.stiffness * areas[i] * d * grad;
        ++expected_active;
      }
    }
  EXPECT_GT(expected_active, 300);  // all three colliders are in play
  EXPECT_EQ(static_cast<int>(active.size()), expected_active);
  EXPECT_NEAR(energy, expected, 1e-12 * expected);
  EXPECT_LT((g - expected_g).cwiseAbs().maxCoeff(), 1e-12 * expected_g.cwiseAbs().maxCoeff());
  EXPECT_EQ(triplets.size(), 9u * active.size());
}

TEST(ColliderContactEnergy, RejectsBadInputs) {
  ContactScene scene;
  const ContactOptions options = testOptions(false);
  const VecX short_areas = VecX::Constant(3, 0.01);
  std::string m = messageOf<InputError>(
      [&] { colliderContactEnergy(scene.X, short_areas, scene.colliders, 0.0, options); });
  EXPECT_NE(m.find("areas"), std::string::npos) << m;
  EXPECT_NE(m.find("9"), std::string::npos) << m;

  MatX3 bad_x = scene.X;
  bad_x(4, 1) = kNaN;
  m = messageOf<InputError>(
      [&] { colliderContactEnergy(bad_x, scene.areas, scene.colliders, 0.0, options); });
  EXPECT_NE(m.find("X"), std::string::npos) << m;

  VecX negative = scene.areas;
  negative[2] = -0.5;
  m = messageOf<InputError>(
      [&] { colliderContactEnergy(scene.X, negative, scene.colliders, 0.0, options); });
  EXPECT_NE(m.find("nonnegative"), std::string::npos) << m;

  ContactOptions bad_stiffness = options;
  bad_stiffness.stiffness = -1.0;
  m = messageOf<InputError>(
      [&] { colliderContactEnergy(scene.X, scene.areas, scene.colliders, 0.0, bad_stiffness); });
  EXPECT_NE(m.find("stiffness"), std::string::npos) << m;

  std::vector<Collider> bad_path = scene.colliders;
  bad_path[1].name = "ball";
  bad_path[1].path.times = {0.0, 2.0, 1.0};
  bad_path[1].path.offsets = {Vec3::Zero(), Vec3::Zero(), Vec3::Zero()};
  m = messageOf<InputError>(
      [&] { colliderContactEnergy(scene.X, scene.areas, bad_path, 0.0, options); });
  EXPECT_NE(m.find("ball"), std::string::npos) << m;
  EXPECT_NE(m.find("increasing"), std::string::npos) << m;
}

// ---------------------------------------------------------------------------------------------
// vertexCapsulePenalty

VecX penaltyValue(const VecX& y, double r, double ka, const ContactOptions& o) {
  return VecX::Constant(
      1, vertexCapsulePenalty(y.segment<3>(0), y.segment<3>(3), y.segment<3>(6), r, ka, o));
}
VecX penaltyGradient(const VecX& y, double r, double ka, const ContactOptions& o) {
  Vec9 g;
  vertexCapsulePenalty(y.segment<3>(0), y.segment<3>(3), y.segment<3>(6), r, ka, o, &g);
  return g;
}

TEST(VertexCapsulePenalty, DerivativesMatchFiniteDifferencesInEveryRegion) {
  const double r = 0.2, ka = 3.0;
  const ContactOptions exact = testOptions(true);
  const Vec3 a(0.1, 0.0, -0.1), b(0.5, 0.3, 0.2);
  const Vec3 axis = (b - a).normalized();
  const Vec3 side = axis.cross(Vec3::UnitZ()).normalized();
  // Penetrating points: interior (beside the middle), beyond cap a, beyond cap b.
  const Vec3 points[] = {0.5 * (a + b) + 0.12 * side, a - 0.1 * axis + 0.05 * side,
                         b + 0.08 * axis - 0.06 * side};
  for (const Vec3& x : points) {
    VecX y(9);
    y << x, a, b;
    Vec9 g;
    Mat9 H;
    const double e = vertexCapsulePenalty(x, a, b, r, ka, exact, &g, &H);
    EXPECT_GT(e, 0.0);
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(
        [&](const VecX& v) { return penaltyValue(v, r, ka, exact); }, y, g.transpose()));
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(
        [&](const VecX& v) { return penaltyGradient(v, r, ka, exact); }, y, H, 1e-5));
  }
}

TEST(VertexCapsulePenalty, PsdModeIsPositiveSemidefiniteAndZeroOutside) {
  const Vec3 a(0, 0, 0), b(1, 0, 0);
  Vec9 g;
  Mat9 H_psd, H_exact;
  vertexCapsulePenalty(Vec3(0.4, 0.05, 0.02), a, b, 0.2, 2.0, testOptions(false), &g, &H_psd);
  vertexCapsulePenalty(Vec3(0.4, 0.05, 0.02), a, b, 0.2, 2.0, testOptions(true), &g, &H_exact);
  ASSERT_GT(H_psd.cwiseAbs().maxCoeff(), 0.0);
  Eigen::SelfAdjointEigenSolver<Mat9> psd(H_psd), exact(H_exact);
  EXPECT_GE(psd.eigenvalues().minCoeff(), -1e-12 * H_psd.cwiseAbs().maxCoeff());
  EXPECT_LT(exact.eigenvalues().minCoeff(), 0.0);

  // Outside: exactly zero value and derivatives, whatever was in the outputs before.
  g.setConstant(7.0);
  H_psd.setConstant(7.0);
  EXPECT_EQ(vertexCapsulePenalty(Vec3(0.5, 0.3, 0), a, b, 0.2, 2.0, testOptions(true), &g, &H_psd),
            0.0);
  EXPECT_TRUE(g.isZero(0.0));
  EXPECT_TRUE(H_psd.isZero(0.0));

  // On the axis (deepest point) and with a zero-length capsule: finite.
  for (const Vec3& end : {b, a}) {
    const double e =
        vertexCapsulePenalty(Vec3(0, 0, 0), a, end, 0.2, 2.0, testOptions(true), &g, &H_exact);
    EXPECT_NEAR(e, 0.5 * 2.0 * 0.04, 1e-15);
    EXPECT_TRUE(g.allFinite());
    EXPECT_TRUE(H_exact.allFinite());
  }
  EXPECT_NE(messageOf<InputError>([&] {
              vertexCapsulePenalty(Vec3::Zero(), a, b, 0.2, -1.0, testOptions(true));
            }).find("stiffness_area"),
            std::string::npos);
}

TEST(VertexCapsulePenalty, MatchesTheColliderEnergyForTheVertexBlock) {
  const Vec3 a(-0.2, 0.1, 0), b(0.3, 0.2, 0.1);
  const double r = 0.15, area = 0.02;
  const ContactOptions options = testOptions(true);
  const Vec3 x(0.05, 0.22, 0.06);
  MatX3 X(1, 3);
  X.row(0) = x.transpose();
  VecX g_energy;
  std::vector<Triplet> triplets;
  const double e_collider = colliderContactEnergy(
      X, VecX::Constant(1, area), {Collider::capsule(a, b, r)}, 0.0, options, &g_energy, &triplets);
  Vec9 g;
  Mat9 H;
  const double e_pair = vertexCapsulePenalty(x, a, b, r, options.stiffness * area, options, &g, &H);
  EXPECT_GT(e_pair, 0.0);
  EXPECT_NEAR(e_pair, e_collider, 1e-15);
  EXPECT_TRUE(g.segment<3>(0).isApprox(g_energy));
  const Mat3 vertex_block = H.block<3, 3>(0, 0);
  EXPECT_TRUE(vertex_block.isApprox(denseFrom(triplets, 3), 1e-12));
}

}  // namespace
}  // namespace flsh
