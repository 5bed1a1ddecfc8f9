// The skeleton's local energy kernels against brute-force values and finite differences taken
// through the increment chart (t + δt, exp([δω]×) R), at random, near-zero and near-π
// rotations.
#include "flsh/energy/skeleton_energies.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "flsh/core/rotation.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::jacobianMatchesFiniteDifferences;

constexpr double kPi = 3.14159265358979323846;

struct Pose {
  Vec3 t;
  Mat3 R;
};

class Random {
 public:
  explicit Random(unsigned seed) : engine_(seed) {}
  double uniform(double a, double b) { return std::uniform_real_distribution<double>(a, b)(engine_); }
  Vec3 vec(double scale) { return Vec3(uniform(-1, 1), uniform(-1, 1), uniform(-1, 1)) * scale; }
  /// A rotation vector of angle `angle` about a random axis.
  Vec3 rotationVector(double angle) {
    Vec3 axis = vec(1.0);
    while (axis.norm() < 0.1) axis = vec(1.0);
    return axis.normalized() * angle;
  }
  Pose pose(double max_angle) { return {vec(0.5), rodrigues(rotationVector(uniform(0, max_angle)))}; }

 private:
  std::mt19937 engine_;
};

// Bones moved by increments d (6 per bone, [δt, δω]) as updateState moves them.
std::vector<Pose> moved(const std::vector<Pose>& bones, const VecX& d) {
  std::vector<Pose> out = bones;
  for (size_t b = 0; b < bones.size(); ++b) {
    out[b].t += d.segment<3>(6 * b);
    out[b].R = rodrigues(d.segment<3>(6 * b + 3)) * bones[b].R;
  }
  return out;
}

double minEigenvalue(const MatX& H) {
  return Eigen::SelfAdjointEigenSolver<MatX>(H).eigenvalues().minCoeff();
}

// Mass points of one bone and their BoneInertia about J.
struct MassPoints {
  std::vector<Vec3> X;
  std::vector<double> m;
  Vec3 J;
  BoneInertia inertia() const {
    BoneInertia I;
    for (size_t i = 0; i < X.size(); ++i) {
      const Vec3 p = X[i] - J;
      I.mass += m[i];
      I.first_moment += m[i] * p;
      I.second_moment += m[i] * p * p.transpose();
    }
    return I;
  }
};

MassPoints randomMassPoints(Random& rnd, int count) {
  MassPoints pts;
  pts.J = rnd.vec(0.3);
  for (int i = 0; i < count; ++i) {
    pts.X.push_back(pts.J + rnd.vec(0.2) + Vec3(0.05, 0.1, 0.0));
    pts.m.push_back(rnd.uniform(0.2, 2.0));
  }
  return pts;
}

// ---- rigid inertia -------------------------------------------------------------------------

struct InertiaCase {
  Pose q, q_n, q_nm1;
  MassPoints points;
  double h;
};

InertiaCase inertiaCase(unsigned seed, double max_angle, double h) {
  Random rnd(seed);
  InertiaCase c{rnd.pose(max_angle), rnd.pose(max_angle), rnd.pose(max_angle),
                randomMassPoints(rnd, 7), h};
  return c;
}

double inertiaAt(const InertiaCase& c, const Pose& q, Vec6* g = nullptr, Mat6* H = nullptr,
                 bool psd = false) {
  return rigidInertiaEnergy(q.t, q.R, c.q_n.t, c.q_n.R, c.q_nm1.t, c.q_nm1.R, c.points.inertia(),
                            c.h, g, H, psd);
}

TEST(RigidInertiaEnergy, MatchesTheSumOverMassPoints) {
  for (unsigned seed = 1; seed <= 5; ++seed) {
    const InertiaCase c = inertiaCase(seed, 3.0, 0.01 * seed);
    double brute = 0.0;
    for (size_t i = 0; i < c.points.X.size(); ++i) {
      const Vec3 p = c.points.X[i] - c.points.J;
      const Vec3 x = c.q.R * p + c.q.t;
      const Vec3 x_hat = 2.0 * (c.q_n.R * p + c.q_n.t) - (c.q_nm1.R * p + c.q_nm1.t);
      brute += c.points.m[i] * (x - x_hat).squaredNorm();
    }
    brute /= 2.0 * c.h * c.h;
    EXPECT_NEAR(inertiaAt(c, c.q), brute, 1e-10 * brute) << "seed " << seed;
  }
}

TEST(RigidInertiaEnergy, DerivativesMatchFiniteDifferences) {
  // Random rotations, near-zero rotations, and angles near π.
  const double angles[] = {3.0, 1e-7, kPi - 1e-4};
  unsigned seed = 10;
  for (double max_angle : angles) {
    for (double h : {1e-2, 1.0 / 60.0, 0.1}) {
      const InertiaCase c = inertiaCase(++seed, max_angle, h);
      Vec6 g;
      Mat6 H;
      inertiaAt(c, c.q, &g, &H, false);
      const auto energy = [&](const VecX& d) {
        return VecX::Constant(1, inertiaAt(c, moved({c.q}, d)[0]));
      };
      EXPECT_TRUE(jacobianMatchesFiniteDifferences(energy, VecX::Zero(6), g.transpose(), 1e-6))
          << "angle " << max_angle << " h " << h;
      const auto gradient = [&](const VecX& d) {
        Vec6 gd;
        inertiaAt(c, moved({c.q}, d)[0], &gd);
        return test::pullBackRotationGradient(gd, d);
      };
      EXPECT_TRUE(jacobianMatchesFiniteDifferences(gradient, VecX::Zero(6), H, 1e-6))
          << "angle " << max_angle << " h " << h;
      EXPECT_LT((H - H.transpose()).cwiseAbs().maxCoeff(), 1e-9 * H.cwiseAbs().maxCoeff());
    }
  }
}

TEST(RigidInertiaEnergy, GaussNewtonHessianIsPsdAndExactAtThePrediction) {
  for (unsigned seed = 30; seed < 35; ++seed) {
    InertiaCase c = inertiaCase(seed, 3.0, 1.0 / 60.0);
    Mat6 H_psd, H_exact;
    inertiaAt(c, c.q, nullptr, &H_psd, true);
    EXPECT_GT(H_psd.norm(), 0.0);
    EXPECT_GE(minEigenvalue(H_psd), -1e-9 * H_psd.norm());
    // With q_n = q_{n−1} = q the residual x − x̂ vanishes and the exact Hessian is Gauss–Newton.
    c.q_n = c.q_nm1 = c.q;
    inertiaAt(c, c.q, nullptr, &H_psd, true);
    inertiaAt(c, c.q, nullptr, &H_exact, false);
    EXPECT_LT((H_psd - H_exact).cwiseAbs().maxCoeff(), 1e-9 * H_psd.cwiseAbs().maxCoeff());
  }
}

TEST(RigidInertiaEnergy, PreviousStateDerivativesMatchFiniteDifferences) {
  for (unsigned seed = 40; seed < 44; ++seed) {
    const InertiaCase c = inertiaCase(seed, seed == 41 ? 1e-7 : 3.0, 1.0 / 60.0);
    Mat6 dg_n, dg_nm1;
    rigidInertiaGradientPreviousStates(c.q.t, c.q.R, c.q_n.t, c.q_n.R, c.q_nm1.t, c.q_nm1.R,
                                       c.points.inertia(), c.h, &dg_n, &dg_nm1);
    const auto gradient_vs_n = [&](const VecX& d) {
      InertiaCase moved_case = c;
      moved_case.q_n = moved({c.q_n}, d)[0];
      Vec6 g;
      inertiaAt(moved_case, c.q, &g);
      return VecX(g);
    };
    const auto gradient_vs_nm1 = [&](const VecX& d) {
      InertiaCase moved_case = c;
      moved_case.q_nm1 = moved({c.q_nm1}, d)[0];
      Vec6 g;
      inertiaAt(moved_case, c.q, &g);
      return VecX(g);
    };
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(gradient_vs_n, VecX::Zero(6), dg_n, 1e-6));
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(gradient_vs_nm1, VecX::Zero(6), dg_nm1, 1e-6));
  }
}

// ---- gravity -------------------------------------------------------------------------------

TEST(GravityEnergy, ValueAndDerivatives) {
  for (unsigned seed = 50; seed < 54; ++seed) {
    Random rnd(seed);
    const MassPoints pts = randomMassPoints(rnd, 5);
    const Pose q = rnd.pose(seed == 51 ? 1e-8 : 3.1);
    const Vec3 gravity(0.3, -9.81, 0.1);
    double brute = 0.0;
    for (size_t i = 0; i < pts.X.size(); ++i)
      brute -= pts.m[i] * gravity.dot(q.R * (pts.X[i] - pts.J) + q.t);
    Vec6 g;
    Mat6 H, H_psd;
    const double E = gravityEnergy(q.t, q.R, pts.inertia(), gravity, &g, &H, false);
    gravityEnergy(q.t, q.R, pts.inertia(), gravity, nullptr, &H_psd, true);
    EXPECT_NEAR(E, brute, 1e-10 * std::abs(brute));
    const auto energy = [&](const VecX& d) {
      const Pose m = moved({q}, d)[0];
      return VecX::Constant(1, gravityEnergy(m.t, m.R, pts.inertia(), gravity));
    };
    const auto gradient = [&](const VecX& d) {
      const Pose m = moved({q}, d)[0];
      Vec6 gd;
      gravityEnergy(m.t, m.R, pts.inertia(), gravity, &gd);
      return test::pullBackRotationGradient(gd, d);
    };
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(energy, VecX::Zero(6), g.transpose(), 1e-6));
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(gradient, VecX::Zero(6), H, 1e-6));
    EXPECT_GE(minEigenvalue(H_psd), -1e-9 * (1.0 + H_psd.norm()));
  }
}

// ---- joint spring --------------------------------------------------------------------------

TEST(JointSpringEnergy, ValueAndDerivatives) {
  const double angles[] = {3.0, 1e-8, kPi - 1e-4};
  unsigned seed = 60;
  for (double max_angle : angles) {
    for (int repeat = 0; repeat < 2; ++repeat) {
      Random rnd(++seed);
      const std::vector<Pose> bones = {rnd.pose(max_angle), rnd.pose(max_angle)};
      const Vec3 J_p = rnd.vec(0.5), J_b = rnd.vec(0.5);
      const double k = 1.0e5;
      const auto eval = [&](const std::vector<Pose>& q, Vec12* g, Mat12* H, bool psd) {
        return jointSpringEnergy(q[0].t, q[0].R, q[1].t, q[1].R, J_p, J_b, k, g, H, psd);
      };
      Vec12 g;
      Mat12 H, H_psd;
      const double E = eval(bones, &g, &H, false);
      eval(bones, nullptr, &H_psd, true);
      // Where bone p carries b's joint centre, against where b is.
      const Vec3 carried = bones[0].R * (J_b - J_p) + bones[0].t;
      EXPECT_NEAR(E, 0.5 * k * (carried - bones[1].t).squaredNorm(), 1e-9 * E);
      const auto energy = [&](const VecX& d) {
        return VecX::Constant(1, eval(moved(bones, d), nullptr, nullptr, false));
      };
      const auto gradient = [&](const VecX& d) {
        Vec12 gd;
        eval(moved(bones, d), &gd, nullptr, false);
        return test::pullBackRotationGradient(gd, d);
      };
      EXPECT_TRUE(jacobianMatchesFiniteDifferences(energy, VecX::Zero(12), g.transpose(), 1e-6));
      EXPECT_TRUE(jacobianMatchesFiniteDifferences(gradient, VecX::Zero(12), H, 1e-6));
      EXPECT_GE(minEigenvalue(H_psd), -1e-9 * H_psd.norm());
    }
  }
}

// ---- tracking spring -----------------------------------------------------------------------

// Parent, bone and target rotations whose tracking error e = log(R_targetᵀR_pᵀR_b) has angle
// `error_angle`.
struct TrackingCase {
  Mat3 R_p, R_b, R_target;
  Vec3 error;
};

TrackingCase trackingCase(unsigned seed, double parent_angle, double error_angle) {
  Random rnd(seed);
  TrackingCase c;
  c.R_p = rodrigues(rnd.rotationVector(parent_angle));
  c.R_target = rodrigues(rnd.rotationVector(rnd.uniform(0.0, 3.0)));
  c.error = rnd.rotationVector(error_angle);
  c.R_b = c.R_p * c.R_target * rodrigues(c.error);
  return c;
}

// Rotation-only increments [δω_p, δω_b] applied to (R_p, R_b).
std::pair<Mat3, Mat3> movedRotations(const Mat3& R_p, const Mat3& R_b, const VecX& d) {
  return {rodrigues(d.segment<3>(0)) * R_p, rodrigues(d.segment<3>(3)) * R_b};
}

VecX pulledBackRotations(const Vec6& g, const VecX& d) {
  VecX out(6);
  out.head<3>() = leftJacobianSO3(d.segment<3>(0)).transpose() * g.head<3>();
  out.tail<3>() = leftJacobianSO3(d.segment<3>(3)).transpose() * g.tail<3>();
  return out;
}

TEST(TrackingSpringEnergy, ValueAndDerivativesFromZeroToNearPi) {
  const double k = 37.0;
  const double error_angles[] = {0.0, 1e-7, 1e-3, 0.7, 2.0, kPi - 1e-3, kPi - 1e-6};
  unsigned seed = 70;
  for (double error_angle : error_angles) {
    for (double parent_angle : {1e-9, 2.5}) {
      const TrackingCase c = trackingCase(++seed, parent_angle, error_angle);
      Vec6 g;
      Mat6 H, H_psd;
      const double E = trackingSpringEnergy(c.R_p, c.R_b, c.R_target, k, &g, &H, false);
      trackingSpringEnergy(c.R_p, c.R_b, c.R_target, k, nullptr, &H_psd, true);
      ASSERT_TRUE(g.allFinite() && H.allFinite() && H_psd.allFinite()) << error_angle;
      EXPECT_NEAR(E, 0.5 * k * error_angle * error_angle, 1e-9 * k);
      EXPECT_GE(minEigenvalue(H_psd), -1e-9 * H_psd.norm());
      const auto energy = [&](const VecX& d) {
        const auto [R_p, R_b] = movedRotations(c.R_p, c.R_b, d);
        return VecX::Constant(1, trackingSpringEnergy(R_p, R_b, c.R_target, k));
      };
      const auto gradient = [&](const VecX& d) {
        const auto [R_p, R_b] = movedRotations(c.R_p, c.R_b, d);
        Vec6 gd;
        trackingSpringEnergy(R_p, R_b, c.R_target, k, &gd);
        return pulledBackRotations(gd, d);
      };
      // Near π a finite-difference step must not cross the cut of log: steps ≪ π − |e|.
      const double eps = error_angle > 3.1 ? 1e-8 : 1e-6;
      const double tol = error_angle > 3.1 ? 1e-4 : 1e-6;
      if (error_angle > 0.0)
        EXPECT_TRUE(jacobianMatchesFiniteDifferences(energy, VecX::Zero(6), g.transpose(), tol,
                                                     eps))
            << "error angle " << error_angle;
      else
        EXPECT_LT(g.norm(), 1e-12 * k);  // zero error: zero gradient (to round-off)
      EXPECT_TRUE(jacobianMatchesFiniteDifferences(gradient, VecX::Zero(6), H, tol, eps))
          << "error angle " << error_angle;
    }
  }
}

TEST(TrackingSpringEnergy, FiniteExactlyAtPi) {
  const TrackingCase c = trackingCase(90, 1.0, kPi);
  Vec6 g;
  Mat6 H, H_psd;
  const double E = trackingSpringEnergy(c.R_p, c.R_b, c.R_target, 5.0, &g, &H, false);
  trackingSpringEnergy(c.R_p, c.R_b, c.R_target, 5.0, nullptr, &H_psd, true);
  EXPECT_NEAR(E, 0.5 * 5.0 * kPi * kPi, 1e-8);
  EXPECT_TRUE(g.allFinite());
  EXPECT_TRUE(H.allFinite());
  EXPECT_TRUE(H_psd.allFinite());
  EXPECT_NEAR(g.norm(), std::sqrt(2.0) * 5.0 * kPi, 1e-6);
}

// ---- root spring ---------------------------------------------------------------------------

TEST(RootSpringEnergy, ValueAndDerivatives) {
  unsigned seed = 100;
  for (double error_angle : {1e-8, 1.2, kPi - 1e-3}) {
    Random rnd(++seed);
    const Pose target = rnd.pose(3.0);
    const Vec3 error = rnd.rotationVector(error_angle);
    const Pose q{target.t + rnd.vec(0.2), target.R * rodrigues(error)};
    const double k_pos = 3000.0, k_rot = 40.0;
    Vec6 g;
    Mat6 H, H_psd;
    const double E =
        rootSpringEnergy(q.t, q.R, target.t, target.R, k_pos, k_rot, &g, &H, false);
    rootSpringEnergy(q.t, q.R, target.t, target.R, k_pos, k_rot, nullptr, &H_psd, true);
    EXPECT_NEAR(E,
                0.5 * k_pos * (q.t - target.t).squaredNorm() +
                    0.5 * k_rot * error_angle * error_angle,
                1e-9 * E);
    const auto energy = [&](const VecX& d) {
      const Pose m = moved({q}, d)[0];
      return VecX::Constant(1, rootSpringEnergy(m.t, m.R, target.t, target.R, k_pos, k_rot));
    };
    const auto gradient = [&](const VecX& d) {
      const Pose m = moved({q}, d)[0];
      Vec6 gd;
      rootSpringEnergy(m.t, m.R, target.t, target.R, k_pos, k_rot, &gd);
      return test::pullBackRotationGradient(gd, d);
    };
    const double eps = error_angle > 3.1 ? 1e-8 : 1e-6;
    const double tol = error_angle > 3.1 ? 1e-4 : 1e-6;
    EXPECT_TRUE(
        jacobianMatchesFiniteDifferences(energy, VecX::Zero(6), g.transpose(), tol, eps));
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(gradient, VecX::Zero(6), H, tol, eps));
    EXPECT_GE(minEigenvalue(H_psd), -1e-9 * H_psd.norm());
  }
}

TEST(ProjectToPsd, ClampsNegativeEigenvaluesOnly) {
  Mat3 M;
  M << 2, 1, 0, 1, -3, 0.5, 0, 0.5, 1;
  const Mat3 P = projectToPSD<3>(M);
  EXPECT_GE(minEigenvalue(P), -1e-12);
  const Mat3 Q = Vec3(1, 2, 3).asDiagonal();
  EXPECT_LT((projectToPSD<3>(Q) - Q).norm(), 1e-12);
}

}  // namespace
}  // namespace flsh
