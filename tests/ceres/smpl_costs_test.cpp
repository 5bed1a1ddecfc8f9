// SMPL keypoint and prior cost functions: analytic Jacobians against Ceres' GradientChecker at
// random poses (after requiring them to be nonzero), values against poseBody and the camera
// formula, points behind the camera, constant parameter blocks, and construction errors.
#include "flsh/ceres/smpl_costs.h"

#include <ceres/gradient_checker.h>
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <memory>
#include <vector>

#include "flsh/body/body_forward.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "support/test_support.h"

namespace flsh::ceres_costs {
namespace {

using test::messageOf;
using test::randomVector;

std::shared_ptr<const BodyModel> smallBody() {
  static const auto body = std::make_shared<const BodyModel>(makeSyntheticBody({800, 1.70}));
  return body;
}

// Joints across the tree (pelvis, knee, ankle, foot, head, wrists) and vertices spread over the
// surface.
KeypointSelection mixedSelection() {
  KeypointSelection s;
  s.joints = {0, 4, 7, 10, 15, 20, 21, 12};
  s.vertices = {3, 150, 333, 512, 640, 799};
  return s;
}

// A body 3 m in front of a camera looking at it from slightly above and to the side.
PinholeCamera frontCamera() {
  return PinholeCamera::lookAt(Vec3(0.4, 1.2, 3.0), Vec3(0.0, 0.9, 0.0), Vec3::UnitY(), 1100.0,
                               1050.0, 480.0, 520.0);
}

struct Parameters {
  VecX pose, betas;
  Vec3 trans;
  std::vector<const double*> pointers() const { return {pose.data(), betas.data(), trans.data()}; }
};

Parameters randomParameters(int num_betas, unsigned seed) {
  Parameters p;
  p.pose = randomVector(72, 0.6, seed);
  p.betas = randomVector(num_betas, 1.5, seed + 100);
  p.trans = randomVector(3, 0.2, seed + 200);
  return p;
}

// Runs Ceres' GradientChecker after asserting that every analytic Jacobian block is nonzero.
// Probe gets no ProbeResults: its Eigen members would be allocated inside libceres (built
// without -march=native) and freed here with a different alignment scheme. The nonzero check
// and, on failure, the size of the error come from this test's own evaluation.
::testing::AssertionResult passesGradientChecker(const ceres::CostFunction& cost,
                                                 const std::vector<const double*>& parameters,
                                                 double relative_precision = 1e-5) {
  const std::vector<int32_t>& sizes = cost.parameter_block_sizes();
  const int n = cost.num_residuals();
  std::vector<RowMatX> analytic;
  std::vector<double*> blocks;
  for (int32_t size : sizes) analytic.emplace_back(n, size);
  for (RowMatX& block : analytic) blocks.push_back(block.data());
  VecX residuals(n);
  if (!cost.Evaluate(parameters.data(), residuals.data(), blocks.data()))
    return ::testing::AssertionFailure() << "Evaluate returned false";
  for (size_t b = 0; b < analytic.size(); ++b)
    if (analytic[b].cwiseAbs().maxCoeff() < 1e-8)
      return ::testing::AssertionFailure() << "analytic Jacobian block " << b << " is zero";

  ceres::NumericDiffOptions options;
  const ceres::GradientChecker checker(
      &cost, static_cast<const std::vector<const ceres::Manifold*>*>(nullptr), options);
  if (checker.Probe(parameters.data(), relative_precision, nullptr))
    return ::testing::AssertionSuccess();
  auto failure = ::testing::AssertionFailure() << "GradientChecker rejected the Jacobians;";
  for (size_t b = 0; b < sizes.size(); ++b) {
    const auto f = [&](const VecX& x) {
      std::vector<const double*> moved = parameters;
      moved[b] = x.data();
      VecX r(n);
      cost.Evaluate(moved.data(), r.data(), nullptr);
      return r;
    };
    const VecX x0 = Eigen::Map<const VecX>(parameters[b], sizes[b]);
    const MatX fd = test::finiteDifferenceJacobian(f, x0);
    failure << " block " << b << ": max |analytic − central difference| = "
            << (MatX(analytic[b]) - fd).cwiseAbs().maxCoeff() << " (max |entry| "
            << fd.cwiseAbs().maxCoeff() << ");";
  }
  return failure;
}

TEST(SmplKeypoints3dCost, JacobiansPassGradientCheckerAtRandomPoses) {
  const auto body = smallBody();
  const KeypointSelection sel = mixedSelection();
  for (unsigned seed : {1u, 2u, 3u}) {
    // The first 7 of the model's 10 β: the synthetic body's "chest" direction (β_7) moves
    // these keypoints by ~1e-10 m per unit, derivative entries below the numeric difference's
    // noise, which Ceres' entry-wise relative check cannot tell from errors.
    const Parameters p = randomParameters(7, seed);
    const MatX3 observed = MatX3::Random(sel.size(), 3);
    const VecX weights = VecX::Random(sel.size()).cwiseAbs() + VecX::Constant(sel.size(), 0.5);
    const SmplKeypoints3dCost cost(body, sel, observed, weights, 7);
    ASSERT_EQ(cost.num_residuals(), 3 * sel.size());
    ASSERT_EQ(cost.parameter_block_sizes(), (std::vector<int32_t>{72, 7, 3}));
    EXPECT_TRUE(passesGradientChecker(cost, p.pointers())) << "seed " << seed;
  }
}

TEST(SmplKeypoints2dCost, JacobiansPassGradientCheckerAtRandomPoses) {
  const auto body = smallBody();
  const KeypointSelection sel = mixedSelection();
  for (unsigned seed : {4u, 5u, 6u}) {
    const Parameters p = randomParameters(7, seed);  // 7 β: see the 3D test
    const MatX2 observed = 300.0 * MatX2::Random(sel.size(), 2);
    const VecX weights = VecX::Random(sel.size()).cwiseAbs() + VecX::Constant(sel.size(), 0.5);
    const SmplKeypoints2dCost cost(body, sel, frontCamera(), observed, weights, 7);
    ASSERT_EQ(cost.num_residuals(), 2 * sel.size());
    // Pixels of ~500 carry ~1e-13 round-off, so numeric entries are good to ~1e-5 relative.
    EXPECT_TRUE(passesGradientChecker(cost, p.pointers(), 1e-4)) << "seed " << seed;
  }
}

TEST(Priors, JacobiansPassGradientChecker) {
  const VecX pose = randomVector(72, 0.8, 7);
  const VecX betas = randomVector(10, 2.0, 8);
  const PosePriorCost uniform(3.0);
  EXPECT_TRUE(passesGradientChecker(uniform, {pose.data()}));
  const PosePriorCost per_joint(VecX::LinSpaced(24, 0.5, 2.0));
  EXPECT_TRUE(passesGradientChecker(per_joint, {pose.data()}));
  const ShapePriorCost shape(10, 0.7);
  EXPECT_TRUE(passesGradientChecker(shape, {betas.data()}));
}

TEST(Priors, ValuesAreTheWeightedParameters) {
  const VecX pose = randomVector(72, 0.8, 9);
  const PosePriorCost prior(2.0);
  VecX r(72);
  const double* params[] = {pose.data()};
  ASSERT_TRUE(prior.Evaluate(params, r.data(), nullptr));
  EXPECT_TRUE(r.head<3>().isZero(0.0));  // the root orientation is free by default
  EXPECT_TRUE(r.tail<69>().isApprox(2.0 * pose.tail<69>()));
  const VecX betas = randomVector(4, 1.0, 10);
  const ShapePriorCost shape(4, 0.5);
  VecX rb(4);
  const double* bparams[] = {betas.data()};
  ASSERT_TRUE(shape.Evaluate(bparams, rb.data(), nullptr));
  EXPECT_TRUE(rb.isApprox(0.5 * betas));
}

TEST(SmplKeypoints3dCost, ResidualsAreWeightedOffsetsOfPoseBodyPoints) {
  const auto body = smallBody();
  const KeypointSelection sel = mixedSelection();
  const Parameters p = randomParameters(10, 11);
  const PosedBody posed = poseBody(*body, p.betas, p.pose, p.trans);
  const MatX3 observed = MatX3::Random(sel.size(), 3);
  const VecX weights = VecX::LinSpaced(sel.size(), 0.5, 3.0);
  const SmplKeypoints3dCost cost(body, sel, observed, weights);
  VecX r(cost.num_residuals());
  ASSERT_TRUE(cost.Evaluate(p.pointers().data(), r.data(), nullptr));
  const int nj = int(sel.joints.size());
  for (int k = 0; k < sel.size(); ++k) {
    const Vec3 x = k < nj ? Vec3(posed.joints.row(sel.joints[k]))
                          : Vec3(posed.vertices.row(sel.vertices[k - nj]));
    EXPECT_TRUE(r.segment<3>(3 * k).isApprox(weights[k] * (x - observed.row(k).transpose()), 1e-12))
        << k;
  }
}

TEST(PinholeCamera, ProjectsWithTheOpenCvConvention) {
  const PinholeCamera camera = frontCamera();
  const Vec3 x(0.1, 1.3, -0.2);
  const Vec3 p = camera.rotation * x + camera.translation;
  const Vec2 pixel = camera.project(x);
  EXPECT_NEAR(pixel.x(), 1100.0 * p.x() / p.z() + 480.0, 1e-9);
  EXPECT_NEAR(pixel.y(), 1050.0 * p.y() / p.z() + 520.0, 1e-9);
  // The target projects to the principal point; world up is image up (smaller v).
  EXPECT_TRUE(camera.project(Vec3(0.0, 0.9, 0.0)).isApprox(Vec2(480.0, 520.0), 1e-9));
  EXPECT_LT(camera.project(Vec3(0.0, 1.4, 0.0)).y(), 520.0);
  // A point to the camera's right (world +x seen from +z) has larger u.
  EXPECT_GT(camera.project(Vec3(0.5, 0.9, 0.0)).x(), 480.0);
}

TEST(SmplKeypoints2dCost, ResidualIsZeroAtTheObservedProjection) {
  const auto body = smallBody();
  const KeypointSelection sel = mixedSelection();
  const Parameters p = randomParameters(10, 12);
  const PosedBody posed = poseBody(*body, p.betas, p.pose, p.trans);
  const PinholeCamera camera = frontCamera();
  MatX2 observed(sel.size(), 2);
  const int nj = int(sel.joints.size());
  for (int k = 0; k < sel.size(); ++k) {
    const Vec3 x = k < nj ? Vec3(posed.joints.row(sel.joints[k]))
                          : Vec3(posed.vertices.row(sel.vertices[k - nj]));
    observed.row(k) = camera.project(x).transpose();
  }
  const SmplKeypoints2dCost cost(body, sel, camera, observed);
  VecX r(cost.num_residuals());
  ASSERT_TRUE(cost.Evaluate(p.pointers().data(), r.data(), nullptr));
  EXPECT_LT(r.cwiseAbs().maxCoeff(), 1e-9);
}

TEST(SmplKeypoints2dCost, PointsBehindTheCameraGiveFiniteContinuousResiduals) {
  const auto body = smallBody();
  KeypointSelection sel;
  sel.joints = {0};
  // A camera 0.5 m in front of the pelvis, looking away from it: the pelvis is behind it.
  const PosedBody rest = poseBody(*body, VecX::Zero(10), VecX::Zero(72));
  const Vec3 pelvis = rest.joints.row(0).transpose();
  const PinholeCamera camera =
      PinholeCamera::lookAt(pelvis + Vec3(0, 0, 0.5), pelvis + Vec3(0, 0, 3.0), Vec3::UnitY(),
                            1000.0, 1000.0, 500.0, 500.0);
  const SmplKeypoints2dCost cost(body, sel, camera, MatX2::Constant(1, 2, 500.0));
  Parameters p{VecX::Zero(72), VecX::Zero(10), Vec3(0.02, -0.01, 0.0)};
  VecX r(2);
  RowMatX J0(2, 72), J1(2, 10), J2(2, 3);
  double* jacobians[] = {J0.data(), J1.data(), J2.data()};
  ASSERT_TRUE(cost.Evaluate(p.pointers().data(), r.data(), jacobians));
  EXPECT_TRUE(r.allFinite());
  EXPECT_TRUE(J0.allFinite() && J1.allFinite() && J2.allFinite());
  EXPECT_GT(J2.cwiseAbs().maxCoeff(), 0.0);  // sideways motion still changes the residual
  // Depth alone does not change a clamped point's pixel (zero derivative along the view axis).
  const Vec3 x = pelvis + p.trans;
  const Vec3 view_axis = camera.rotation.row(2).transpose();
  EXPECT_TRUE(camera.project(x).isApprox(camera.project(x - 0.3 * view_axis), 1e-12));
  // Continuous across min_depth: just in front of and just behind the clamp plane agree (the
  // pixel moves 1e7 px per m of depth there, so ±1e-11 m may move it 1e-4 px).
  const Vec3 centre = -camera.rotation.transpose() * camera.translation;
  const Vec3 side = camera.rotation.row(0).transpose();
  const Vec3 at_clamp = centre + camera.min_depth * view_axis + 0.01 * side;
  EXPECT_NEAR(
      (camera.project(at_clamp + 1e-11 * view_axis) - camera.project(at_clamp - 1e-11 * view_axis))
          .norm(),
      0.0, 1e-3);
}

TEST(SmplKeypoints3dCost, ConstantBlocksAndNonFiniteParameters) {
  const auto body = smallBody();
  const KeypointSelection sel = mixedSelection();
  const Parameters p = randomParameters(10, 13);
  const SmplKeypoints3dCost cost(body, sel, MatX3::Zero(sel.size(), 3));
  const int n = cost.num_residuals();
  VecX r(n);
  RowMatX full_pose(n, 72), only_pose(n, 72);
  RowMatX betas_block(n, 10), trans_block(n, 3);
  double* all[] = {full_pose.data(), betas_block.data(), trans_block.data()};
  ASSERT_TRUE(cost.Evaluate(p.pointers().data(), r.data(), all));
  // β and trans held constant by Ceres: their blocks are null, the pose block is unchanged.
  double* pose_only[] = {only_pose.data(), nullptr, nullptr};
  ASSERT_TRUE(cost.Evaluate(p.pointers().data(), r.data(), pose_only));
  EXPECT_EQ(only_pose, full_pose);
  // d/dtrans is w_k times identity blocks.
  for (int k = 0; k < sel.size(); ++k)
    EXPECT_TRUE(trans_block.middleRows<3>(3 * k).isIdentity(0.0)) << k;
  // Non-finite parameters: false, no exception.
  Parameters bad = p;
  bad.pose[17] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(cost.Evaluate(bad.pointers().data(), r.data(), all));
  bad = p;
  bad.trans[1] = std::numeric_limits<double>::infinity();
  EXPECT_FALSE(cost.Evaluate(bad.pointers().data(), r.data(), nullptr));
}

TEST(SmplCosts, BadConstructionArgumentsThrowNamingTheArgument) {
  const auto body = smallBody();
  const KeypointSelection sel = mixedSelection();
  const int N = sel.size();
  const MatX3 observed = MatX3::Zero(N, 3);
  std::string msg;

  msg = messageOf<InputError>([&] { (void)SmplKeypoints3dCost(nullptr, sel, observed); });
  EXPECT_NE(msg.find("model is null"), std::string::npos) << msg;
  msg = messageOf<InputError>(
      [&] { (void)SmplKeypoints3dCost(body, KeypointSelection{}, MatX3(0, 3)); });
  EXPECT_NE(msg.find("empty"), std::string::npos) << msg;
  KeypointSelection bad_joint = sel;
  bad_joint.joints[2] = 24;
  msg = messageOf<InputError>([&] { (void)SmplKeypoints3dCost(body, bad_joint, observed); });
  EXPECT_NE(msg.find("joints[2] = 24"), std::string::npos) << msg;
  KeypointSelection bad_vertex = sel;
  bad_vertex.vertices[1] = 800;
  msg = messageOf<InputError>([&] { (void)SmplKeypoints3dCost(body, bad_vertex, observed); });
  EXPECT_NE(msg.find("vertices[1] = 800"), std::string::npos) << msg;
  EXPECT_NE(msg.find("0..799"), std::string::npos) << msg;
  msg = messageOf<InputError>([&] { (void)SmplKeypoints3dCost(body, sel, MatX3::Zero(N - 1, 3)); });
  EXPECT_NE(msg.find("(13, 3)"), std::string::npos) << msg;
  EXPECT_NE(msg.find("(14, 3)"), std::string::npos) << msg;
  MatX3 nan_observed = observed;
  nan_observed(4, 1) = std::numeric_limits<double>::quiet_NaN();
  msg = messageOf<InputError>([&] { (void)SmplKeypoints3dCost(body, sel, nan_observed); });
  EXPECT_NE(msg.find("NaN"), std::string::npos) << msg;
  msg =
      messageOf<InputError>([&] { (void)SmplKeypoints3dCost(body, sel, observed, VecX::Ones(3)); });
  EXPECT_NE(msg.find("weights has 3 values"), std::string::npos) << msg;
  VecX negative = VecX::Ones(N);
  negative[5] = -1.0;
  msg = messageOf<InputError>([&] { (void)SmplKeypoints3dCost(body, sel, observed, negative); });
  EXPECT_NE(msg.find("weights[5]"), std::string::npos) << msg;
  for (int num_betas : {0, 11}) {
    msg = messageOf<InputError>(
        [&] { (void)SmplKeypoints3dCost(body, sel, observed, VecX(), num_betas); });
    EXPECT_NE(msg.find("num_betas = " + std::to_string(num_betas)), std::string::npos) << msg;
    EXPECT_NE(msg.find("1..10"), std::string::npos) << msg;
  }
  BodyModel unfinalized = *body;
  unfinalized.derived.reset();
  EXPECT_THROW(SmplKeypoints3dCost(std::make_shared<const BodyModel>(unfinalized), sel, observed),
               InputError);

  // Camera and 2D observations.
  const MatX2 pixels = MatX2::Zero(N, 2);
  PinholeCamera camera = frontCamera();
  camera.fx = 0.0;
  msg = messageOf<InputError>([&] { (void)SmplKeypoints2dCost(body, sel, camera, pixels); });
  EXPECT_NE(msg.find("fx"), std::string::npos) << msg;
  camera = frontCamera();
  camera.rotation(0, 0) += 0.1;
  msg = messageOf<InputError>([&] { (void)SmplKeypoints2dCost(body, sel, camera, pixels); });
  EXPECT_NE(msg.find("rotation"), std::string::npos) << msg;
  camera = frontCamera();
  camera.rotation = -camera.rotation;  // orthogonal but a reflection
  msg = messageOf<InputError>([&] { (void)SmplKeypoints2dCost(body, sel, camera, pixels); });
  EXPECT_NE(msg.find("det R = -1"), std::string::npos) << msg;
  camera = frontCamera();
  camera.min_depth = 0.0;
  msg = messageOf<InputError>([&] { (void)SmplKeypoints2dCost(body, sel, camera, pixels); });
  EXPECT_NE(msg.find("min_depth"), std::string::npos) << msg;
  msg = messageOf<InputError>(
      [&] { (void)SmplKeypoints2dCost(body, sel, frontCamera(), MatX2::Zero(2, 2)); });
  EXPECT_NE(msg.find("(2, 2)"), std::string::npos) << msg;
  EXPECT_THROW(PinholeCamera::lookAt(Vec3::Zero(), Vec3::Zero(), Vec3::UnitY(), 1, 1, 0, 0),
               InputError);
  EXPECT_THROW(PinholeCamera::lookAt(Vec3::Zero(), Vec3::UnitY(), Vec3::UnitY(), 1, 1, 0, 0),
               InputError);

  // Priors.
  msg = messageOf<InputError>([&] { (void)PosePriorCost(VecX::Ones(23)); });
  EXPECT_NE(msg.find("23 values, expected 24"), std::string::npos) << msg;
  EXPECT_THROW(PosePriorCost(-1.0), InputError);
  EXPECT_THROW((void)PosePriorCost(std::numeric_limits<double>::quiet_NaN()), InputError);
  EXPECT_THROW(ShapePriorCost(0, 1.0), InputError);
  EXPECT_THROW(ShapePriorCost(10, -2.0), InputError);
}

}  // namespace
}  // namespace flsh::ceres_costs
