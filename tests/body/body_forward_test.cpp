// SMPL forward pass: values against a hand computation and an independent reference
// implementation, batch vs single frame, SMPL-H poses, every Jacobian block against central
// differences (random, zero, near-π and large root rotations), and input errors.
#include "flsh/body/body_forward.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <limits>
#include <random>

#include "body/body_model_derived.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "support/test_support.h"

namespace flsh {
namespace {

const double kPi = 3.14159265358979323846;

VecX randomVector(int n, double scale, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> uni(-1.0, 1.0);
  VecX v(n);
  for (int k = 0; k < n; ++k) v[k] = scale * uni(rng);
  return v;
}

VecX flatten(const MatX3& points) { return Eigen::Map<const VecX>(points.data(), points.size()); }

Mat3 angleAxis(const Vec3& theta) {
  const double angle = theta.norm();
  return angle > 0 ? Mat3(Eigen::AngleAxisd(angle, theta / angle)) : Mat3::Identity();
}

// Straight transcription of ARCHITECTURE.md §2 with 4 × 4 matrices, dense arrays and Eigen's
// AngleAxis: shares no code with the library's forward pass.
MatX3 referenceVertices(const BodyModel& m, const VecX& betas, const VecX& pose72,
                        const Vec3& trans, MatX3* joints = nullptr) {
  const int V = m.numVertices();
  VecX beta = VecX::Zero(m.numBetas());
  beta.head(betas.size()) = betas;
  MatX3 v_shaped = m.v_template;
  for (int i = 0; i < V; ++i)
    for (int c = 0; c < 3; ++c) v_shaped(i, c) += m.shapedirs.row(3 * i + c).dot(beta);
  const MatX J = MatX(m.J_regressor) * MatX(v_shaped);
  std::vector<Mat3> R(kNumJoints);
  for (int j = 0; j < kNumJoints; ++j) R[j] = angleAxis(pose72.segment<3>(3 * j));
  VecX feature(kPoseFeatureSize);
  for (int j = 1; j < kNumJoints; ++j)
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c)
        feature[9 * (j - 1) + 3 * r + c] = R[j](r, c) - (r == c ? 1.0 : 0.0);
  MatX3 v_posed = v_shaped;
  for (int i = 0; i < V; ++i)
    for (int c = 0; c < 3; ++c) v_posed(i, c) += m.posedirs.row(3 * i + c).dot(feature);
  std::vector<Mat4> G(kNumJoints), A(kNumJoints);
  for (int j = 0; j < kNumJoints; ++j) {
    const int p = m.parents[j];
    Mat4 local = Mat4::Identity();
    local.topLeftCorner<3, 3>() = R[j];
    local.topRightCorner<3, 1>() =
        p < 0 ? Vec3(J.row(j).transpose()) : Vec3((J.row(j) - J.row(p)).transpose());
    G[j] = p < 0 ? local : Mat4(G[p] * local);
    Mat4 unrest = Mat4::Identity();
    unrest.topRightCorner<3, 1>() = -J.row(j).transpose();
    A[j] = G[j] * unrest;
  }
  MatX3 out(V, 3);
  for (int i = 0; i < V; ++i) {
    Vec4 x = Vec4::Zero();
    for (int j = 0; j < kNumJoints; ++j)
      x += m.weights(i, j) * A[j] * Vec4(v_posed(i, 0), v_posed(i, 1), v_posed(i, 2), 1.0);
    out.row(i) = (x.head<3>() + trans).transpose();
  }
  if (joints) {
    joints->resize(kNumJoints, 3);
    for (int j = 0; j < kNumJoints; ++j)
      joints->row(j) = (G[j].topRightCorner<3, 1>() + trans).transpose();
  }
  return out;
}

double maxAbsDiff(const MatX3& a, const MatX3& b) { return (a - b).cwiseAbs().maxCoeff(); }

TEST(BodyForward, ZeroPoseAndBetasGiveTemplate) {
  const BodyModel m = test::makeRandomModel(200, 10, 2);
  const Vec3 trans(0.3, -0.2, 1.5);
  const PosedBody out = poseBody(m, VecX::Zero(10), VecX::Zero(72), trans);
  const MatX3 expected = m.v_template.rowwise() + trans.transpose();
  EXPECT_LT(maxAbsDiff(out.vertices, expected), 1e-14);
  const MatX3 J = MatX(m.J_regressor) * MatX(m.v_template);
  EXPECT_LT(maxAbsDiff(out.rest_joints, J), 1e-14);
  EXPECT_LT(maxAbsDiff(out.joints, J.rowwise() + trans.transpose()), 1e-14);
  ASSERT_EQ(out.transforms.size(), size_t(kNumJoints));
  for (int j = 0; j < kNumJoints; ++j) {
    EXPECT_LT((out.transforms[j].topLeftCorner<3, 3>() - Mat3::Identity()).norm(), 1e-15);
    EXPECT_LT((out.transforms[j].topRightCorner<3, 1>() - J.row(j).transpose()).norm(), 1e-14);
    EXPECT_EQ(out.transforms[j].row(3), Vec4(0, 0, 0, 1).transpose());
  }
  // An empty β means the mean shape too.
  EXPECT_EQ(poseBody(m, VecX(), VecX::Zero(72), trans).vertices, out.vertices);
}

TEST(BodyForward, RootRotationIsRigidAboutRootJoint) {
  const BodyModel m = test::makeRandomModel(200, 10, 3);
  const VecX betas = randomVector(10, 1.0, 4);
  const PosedBody rest = poseBody(m, betas, VecX::Zero(72));
  VecX pose = VecX::Zero(72);
  pose.head<3>() << 0.4, -1.1, 2.0;
  const Vec3 trans(0.1, 0.2, -0.3);
  const PosedBody turned = poseBody(m, betas, pose, trans);
  const Mat3 R = angleAxis(pose.head<3>());
  const Vec3 J0 = rest.rest_joints.row(0).transpose();
  for (int i = 0; i < m.numVertices(); ++i) {
    const Vec3 expected = R * (Vec3(rest.vertices.row(i).transpose()) - J0) + J0 + trans;
    EXPECT_LT((Vec3(turned.vertices.row(i).transpose()) - expected).norm(), 1e-13) << i;
  }
  for (int j = 0; j < kNumJoints; ++j) {
    const Vec3 expected = R * (Vec3(rest.joints.row(j).transpose()) - J0) + J0 + trans;
    EXPECT_LT((Vec3(turned.joints.row(j).transpose()) - expected).norm(), 1e-13) << j;
    EXPECT_LT((turned.transforms[j].topLeftCorner<3, 3>() - R).norm(), 1e-14);
  }
}

// Four vertices, two bones used (pelvis and left hip), one shape direction and one pose
// blend entry, worked out by hand.
BodyModel handModel() {
  BodyModel m;
  m.source = "hand-model";
  m.parents.assign(kSmplParents.begin(), kSmplParents.end());
  m.v_template.resize(4, 3);
  m.v_template << 0, 0, 0,  // v0: on the pelvis
      1, 0, 0,              // v1: at the hip joint
      1, 1, 0,              // v2: half pelvis, half hip
      0, 0, 1;              // v3: on the pelvis
  m.shapedirs = MatX::Zero(12, 1);
  m.shapedirs(3 * 1 + 0, 0) = 1.0;  // β moves v1 (and so the hip joint) along +x
  m.posedirs = MatX::Zero(12, kPoseFeatureSize);
  m.posedirs(3 * 2 + 1, 0) = 0.1;  // v2.y += 0.1 · (R_1 − I)_00
  m.weights = MatX::Zero(4, kNumJoints);
  m.weights(0, 0) = 1.0;
  m.weights(1, 1) = 1.0;
  m.weights(2, 0) = 0.5;
  m.weights(2, 1) = 0.5;
  m.weights(3, 0) = 1.0;
  std::vector<Triplet> regressor;
  for (int j = 0; j < kNumJoints; ++j) regressor.emplace_back(j, j == 1 ? 1 : 0, 1.0);
  m.J_regressor.resize(kNumJoints, 4);
  m.J_regressor.setFromTriplets(regressor.begin(), regressor.end());
  m.faces.resize(2, 3);
  m.faces << 0, 1, 2, 0, 2, 3;
  m.finalize();
  return m;
}

TEST(BodyForward, HandComputedOneJointExample) {
  const BodyModel m = handModel();
  VecX pose = VecX::Zero(72);
  pose.segment<3>(3) << 0, 0, kPi / 2;  // left hip: 90° about z, (x, y, z) ↦ (−y, x, z)
  const Vec3 trans(0.1, 0.2, 0.3);
  VecX betas(1);
  betas << 0.5;
  const PosedBody out = poseBody(m, betas, pose, trans);
  // Shaped: v1 = (1.5, 0, 0) = J_1; J_0 = v0 = 0. R_1 − I has (0,0) entry −1, so the pose
  // blend moves v2 to (1, 0.9, 0). v2 = ½ (1, 0.9, 0) + ½ [R_1 ((1, 0.9, 0) − J_1) + J_1]
  //   = ½ (1, 0.9, 0) + ½ ((−0.9, −0.5, 0) + (1.5, 0, 0)) = (0.8, 0.2, 0).
  MatX3 expected(4, 3);
  expected << 0, 0, 0, 1.5, 0, 0, 0.8, 0.2, 0, 0, 0, 1;
  expected.rowwise() += trans.transpose();
  EXPECT_LT(maxAbsDiff(out.vertices, expected), 1e-14) << out.vertices;
  // Left knee (joint 4, child of the hip) rests at the origin: R_1 (0 − J_1) + J_1.
  EXPECT_LT((out.joints.row(1) - Eigen::RowVector3d(1.6, 0.2, 0.3)).norm(), 1e-14);
  EXPECT_LT((out.joints.row(4) - Eigen::RowVector3d(1.6, -1.3, 0.3)).norm(), 1e-14);
  EXPECT_LT((out.joints.row(2) - Eigen::RowVector3d(0.1, 0.2, 0.3)).norm(), 1e-14);
}

TEST(BodyForward, MatchesReferenceImplementation) {
  const BodyModel m = test::makeRandomModel(300, 10, 5);
  const VecX betas = randomVector(10, 1.5, 6);
  const Vec3 trans(-0.4, 0.9, 0.2);
  // A generic pose and one with only a few non-neighbouring joints bent (feature skipping).
  VecX sparse_pose = VecX::Zero(72);
  sparse_pose.segment<3>(3 * 4) << 0.3, -0.2, 0.5;
  sparse_pose.segment<3>(3 * 5) << -0.1, 0.6, 0.2;
  sparse_pose.segment<3>(3 * 18) << 1.0, 0.1, -0.4;
  for (const VecX& pose : {randomVector(72, 0.8, 7), sparse_pose}) {
    MatX3 joints;
    const MatX3 expected = referenceVertices(m, betas, pose, trans, &joints);
    const PosedBody out = poseBody(m, betas, pose, trans);
    EXPECT_LT(maxAbsDiff(out.vertices, expected), 1e-12);
    EXPECT_LT(maxAbsDiff(out.joints, joints), 1e-12);
  }
}

// Large enough for the parallel vertex loop, with a last chunk that is not full.
TEST(BodyForward, MatchesReferenceOnLargeModel) {
  const BodyModel m = test::makeRandomModel(2600, 8, 8);
  const VecX betas = randomVector(8, 1.0, 9), pose = randomVector(72, 0.7, 10);
  const Vec3 trans(0.5, 0.0, -0.1);
  EXPECT_LT(maxAbsDiff(poseBody(m, betas, pose, trans).vertices,
                       referenceVertices(m, betas, pose, trans)),
            1e-12);
}

BodyModel sparsePosedirsModel(int vertices, unsigned seed) {
  BodyModel m = test::makeRandomModel(vertices, 10, seed);
  // Keep one pose blend entry in ten, like corrective shapes local to each joint.
  for (long k = 0; k < m.posedirs.size(); ++k)
    if (k % 10 != 0) m.posedirs.data()[k] = 0.0;
  m.finalize();
  return m;
}

TEST(BodyForward, SparsePoseBlendShapesMatchReference) {
  const BodyModel m = sparsePosedirsModel(300, 11);
  ASSERT_TRUE(m.derived->use_sparse_posedirs);
  const VecX betas = randomVector(10, 1.0, 12), pose = randomVector(72, 0.8, 13);
  const Vec3 trans(0.1, 0.1, 0.1);
  EXPECT_LT(maxAbsDiff(poseBody(m, betas, pose, trans).vertices,
                       referenceVertices(m, betas, pose, trans)),
            1e-12);
}

TEST(BodyForward, SmplhPoseEqualsSmplPoseWithoutHands) {
  const BodyModel m = test::makeRandomModel(200, 10, 14);
  const VecX betas = randomVector(10, 1.0, 15);
  const VecX smplh = randomVector(kSmplhPoseSize, 0.6, 16);
  VecX smpl = VecX::Zero(72);
  smpl.head(66) = smplh.head(66);
  const PosedBody a = poseBody(m, betas, smplh), b = poseBody(m, betas, smpl);
  EXPECT_EQ(a.vertices, b.vertices);
  EXPECT_EQ(a.joints, b.joints);
}

TEST(BodyForward, ShorterBetasAreZeroPadded) {
  const BodyModel m = test::makeRandomModel(200, 10, 17);
  const VecX pose = randomVector(72, 0.5, 18);
  VecX padded = VecX::Zero(10);
  padded.head(3) << 0.5, -1.0, 2.0;
  EXPECT_EQ(poseBody(m, padded.head(3), pose).vertices, poseBody(m, padded, pose).vertices);
  EXPECT_EQ(shapedVertices(m, padded.head(3)), shapedVertices(m, padded));
}

TEST(BodyForward, ShapedVerticesAddShapeDirections) {
  const BodyModel m = test::makeRandomModel(200, 10, 19);
  const VecX betas = randomVector(10, 2.0, 20);
  const MatX3 shaped = shapedVertices(m, betas);
  const VecX expected = flatten(m.v_template) + m.shapedirs * betas;
  EXPECT_LT((flatten(shaped) - expected).cwiseAbs().maxCoeff(), 1e-14);
  EXPECT_LT(maxAbsDiff(poseBody(m, betas, VecX::Zero(72)).vertices, shaped), 1e-14);
}

void expectBatchMatchesFrames(const BodyModel& m, int frames, int pose_size) {
  const VecX betas = randomVector(m.numBetas(), 1.0, 21);
  const VecX pose_values = randomVector(frames * pose_size, 0.7, 22);
  const RowMatX poses = Eigen::Map<const RowMatX>(pose_values.data(), frames, pose_size);
  const VecX trans_values = randomVector(frames * 3, 1.0, 23);
  const RowMatX trans = Eigen::Map<const RowMatX>(trans_values.data(), frames, 3);
  const PosedBatch batch = poseBodyBatch(m, betas, poses, trans);
  ASSERT_EQ(batch.vertices.rows(), frames);
  ASSERT_EQ(batch.vertices.cols(), 3 * m.numVertices());
  ASSERT_EQ(batch.joints.rows(), frames);
  ASSERT_EQ(batch.joints.cols(), 72);
  for (int t = 0; t < frames; ++t) {
    const PosedBody frame = poseBody(m, betas, poses.row(t).transpose(), trans.row(t).transpose());
    EXPECT_LT((batch.vertices.row(t).transpose() - flatten(frame.vertices)).cwiseAbs().maxCoeff(),
              1e-12)
        << "frame " << t;
    EXPECT_LT((batch.joints.row(t).transpose() - flatten(frame.joints)).cwiseAbs().maxCoeff(),
              1e-12)
        << "frame " << t;
  }
}

TEST(BodyForward, BatchEqualsPerFramePoses) {
  // 70 frames: more than one block of frames of the batched pose blend product.
  expectBatchMatchesFrames(test::makeRandomModel(150, 10, 24), 70, kSmplPoseSize);
  expectBatchMatchesFrames(test::makeRandomModel(150, 10, 25), 3, kSmplhPoseSize);
  expectBatchMatchesFrames(sparsePosedirsModel(150, 26), 4, kSmplPoseSize);
  expectBatchMatchesFrames(test::makeRandomModel(2100, 4, 27), 2, kSmplPoseSize);
}

TEST(BodyForward, EmptyBatch) {
  const BodyModel m = test::makeRandomModel(100, 10, 28);
  const PosedBatch batch = poseBodyBatch(m, VecX(), RowMatX(0, 72), RowMatX(0, 3));
  EXPECT_EQ(batch.vertices.rows(), 0);
  EXPECT_EQ(batch.vertices.cols(), 300);
}

// Checks the six Jacobian blocks against central differences at (β, θ, trans).
void expectJacobiansMatchFiniteDifferences(const BodyModel& m, const VecX& betas, const VecX& pose,
                                           const Vec3& trans) {
  PosedBodyJacobians jac;
  poseBody(m, betas, pose, trans, &jac);
  const int V = m.numVertices(), K = m.numBetas();
  ASSERT_EQ(jac.vertices_betas.rows(), 3 * V);
  ASSERT_EQ(jac.vertices_betas.cols(), K);
  ASSERT_EQ(jac.vertices_pose.cols(), 72);
  ASSERT_EQ(jac.joints_pose.rows(), 72);
  const auto vertices_of = [&](const VecX& b, const VecX& p, const Vec3& t) {
    return flatten(poseBody(m, b, p, t).vertices);
  };
  const auto joints_of = [&](const VecX& b, const VecX& p, const Vec3& t) {
    return flatten(poseBody(m, b, p, t).joints);
  };
  const double tol = 1e-7;
  EXPECT_TRUE(test::jacobianMatchesFiniteDifferences(
      [&](const VecX& b) { return vertices_of(b, pose, trans); }, betas, jac.vertices_betas, tol))
      << "vertices / betas";
  EXPECT_TRUE(test::jacobianMatchesFiniteDifferences(
      [&](const VecX& p) { return vertices_of(betas, p, trans); }, pose, jac.vertices_pose, tol))
      << "vertices / pose";
  EXPECT_TRUE(test::jacobianMatchesFiniteDifferences(
      [&](const VecX& t) { return vertices_of(betas, pose, Vec3(t)); }, trans, jac.vertices_trans,
      tol))
      << "vertices / trans";
  EXPECT_TRUE(test::jacobianMatchesFiniteDifferences(
      [&](const VecX& b) { return joints_of(b, pose, trans); }, betas, jac.joints_betas, tol))
      << "joints / betas";
  EXPECT_TRUE(test::jacobianMatchesFiniteDifferences(
      [&](const VecX& p) { return joints_of(betas, p, trans); }, pose, jac.joints_pose, tol))
      << "joints / pose";
  EXPECT_TRUE(test::jacobianMatchesFiniteDifferences(
      [&](const VecX& t) { return joints_of(betas, pose, Vec3(t)); }, trans, jac.joints_trans, tol))
      << "joints / trans";
}

TEST(BodyForwardJacobian, RandomPoses) {
  const BodyModel m = test::makeRandomModel(240, 10, 30);
  for (unsigned seed = 31; seed < 34; ++seed)
    expectJacobiansMatchFiniteDifferences(m, randomVector(10, 1.5, seed),
                                          randomVector(72, 0.9, seed + 100), Vec3(0.2, -0.5, 1.0));
}

TEST(BodyForwardJacobian, ZeroPose) {
  const BodyModel m = test::makeRandomModel(240, 10, 35);
  expectJacobiansMatchFiniteDifferences(m, VecX::Zero(10), VecX::Zero(72), Vec3::Zero());
}

TEST(BodyForwardJacobian, JointRotationNearPi) {
  const BodyModel m = test::makeRandomModel(240, 10, 36);
  VecX pose = randomVector(72, 0.5, 37);
  pose.segment<3>(3 * 4) = (kPi - 1e-3) * Vec3(1, -2, 0.5).normalized();   // left knee
  pose.segment<3>(3 * 16) = (kPi - 1e-3) * Vec3(0.2, 1, -1).normalized();  // left shoulder
  expectJacobiansMatchFiniteDifferences(m, randomVector(10, 1.0, 38), pose, Vec3(0, 0, 0.5));
}

TEST(BodyForwardJacobian, LargeRootRotations) {
  const BodyModel m = test::makeRandomModel(240, 10, 39);
  for (double angle : {2.0, 3.0, kPi - 1e-3}) {
    VecX pose = randomVector(72, 0.6, 40);
    pose.head<3>() = angle * Vec3(-0.3, 0.8, 0.5).normalized();
    expectJacobiansMatchFiniteDifferences(m, randomVector(10, 1.0, 41), pose, Vec3(1, 2, 3));
  }
}

TEST(BodyForwardJacobian, SparsePoseBlendShapes) {
  const BodyModel m = sparsePosedirsModel(240, 42);
  ASSERT_TRUE(m.derived->use_sparse_posedirs);
  expectJacobiansMatchFiniteDifferences(m, randomVector(10, 1.0, 43), randomVector(72, 0.8, 44),
                                        Vec3(0.1, 0.2, 0.3));
}

TEST(BodyForwardJacobian, ParallelVertexLoop) {
  const BodyModel m = test::makeRandomModel(2200, 3, 45);
  expectJacobiansMatchFiniteDifferences(m, randomVector(3, 1.0, 46), randomVector(72, 0.8, 47),
                                        Vec3(0.1, 0.2, 0.3));
}

TEST(BodyForwardJacobian, JacobiansDoNotChangeOutputs) {
  const BodyModel m = test::makeRandomModel(300, 10, 48);
  const VecX betas = randomVector(10, 1.0, 49), pose = randomVector(72, 0.8, 50);
  const Vec3 trans(0.3, 0.2, 0.1);
  const PosedBody plain = poseBody(m, betas, pose, trans);
  PosedBodyJacobians jac;
  const PosedBody with_jacobians = poseBody(m, betas, pose, trans, &jac);
  EXPECT_EQ(plain.vertices, with_jacobians.vertices);
  EXPECT_EQ(plain.joints, with_jacobians.joints);
  EXPECT_EQ(plain.rest_joints, with_jacobians.rest_joints);
  for (int j = 0; j < kNumJoints; ++j) EXPECT_EQ(plain.transforms[j], with_jacobians.transforms[j]);
}

TEST(BodyForwardJacobian, TransBlocksAreIdentity) {
  const BodyModel m = test::makeRandomModel(100, 10, 51);
  PosedBodyJacobians jac;
  poseBody(m, VecX::Zero(10), randomVector(72, 0.5, 52), Vec3::Zero(), &jac);
  for (int i = 0; i < 100; ++i)
    EXPECT_EQ(Mat3(jac.vertices_trans.middleRows<3>(3 * i)), Mat3::Identity());
  for (int j = 0; j < kNumJoints; ++j)
    EXPECT_EQ(Mat3(jac.joints_trans.middleRows<3>(3 * j)), Mat3::Identity());
}

// Expects `call` to throw InputError whose message contains every string of `parts`.
template <class F>
void expectInputError(F&& call, std::initializer_list<const char*> parts) {
  try {
    call();
    ADD_FAILURE() << "no InputError thrown";
  } catch (const InputError& e) {
    for (const char* part : parts)
      EXPECT_NE(std::string(e.what()).find(part), std::string::npos)
          << "message '" << e.what() << "' lacks '" << part << "'";
  }
}

TEST(BodyForward, LargeAnglesWithinTheBoundAreRotations) {
  // |θ| up to kMaxRotationAngle is accepted and means the angle modulo 2π.
  const BodyModel m = test::makeRandomModel(100, 10, 54);
  const double turns = 100000.0;  // 6.3e5 rad, below the bound
  VecX pose = VecX::Zero(72), wound = VecX::Zero(72);
  pose.segment<3>(3 * 4) = Vec3(0.0, 0.7, 0.0);
  wound.segment<3>(3 * 4) = Vec3(0.0, 0.7 + 2.0 * kPi * turns, 0.0);
  EXPECT_LT(maxAbsDiff(poseBody(m, VecX(), pose).vertices, poseBody(m, VecX(), wound).vertices),
            1e-9);
}

TEST(BodyForward, InputErrors) {
  const BodyModel m = test::makeRandomModel(100, 10, 53);
  const VecX pose = VecX::Zero(72);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  expectInputError([&] { poseBody(m, VecX::Zero(11), pose); }, {"betas", "11", "at most 10"});
  expectInputError([&] { shapedVertices(m, VecX::Zero(12)); }, {"betas", "12", "10"});
  expectInputError([&] { poseBody(m, VecX::Zero(10), VecX::Zero(70)); },
                   {"pose", "72", "156", "70"});
  VecX bad_betas = VecX::Zero(10);
  bad_betas[3] = nan;
  expectInputError([&] { poseBody(m, bad_betas, pose); }, {"betas", "NaN"});
  VecX bad_pose = pose;
  bad_pose[40] = inf;
  expectInputError([&] { poseBody(m, VecX(), bad_pose); }, {"pose", "Inf"});
  expectInputError([&] { poseBody(m, VecX(), pose, Vec3(0, nan, 0)); }, {"trans", "NaN"});

  const RowMatX poses = RowMatX::Zero(5, 72), trans = RowMatX::Zero(5, 3);
  expectInputError([&] { poseBodyBatch(m, VecX(), poses, RowMatX::Zero(4, 3)); },
                   {"trans", "(4, 3)", "(5, 3)", "(5, 72)"});
  expectInputError([&] { poseBodyBatch(m, VecX(), RowMatX::Zero(5, 70), trans); },
                   {"poses", "(5, 70)"});
  expectInputError([&] { poseBodyBatch(m, VecX::Zero(11), poses, trans); }, {"betas", "11", "10"});
  RowMatX bad_poses = poses;
  bad_poses(2, 7) = nan;
  expectInputError([&] { poseBodyBatch(m, VecX(), bad_poses, trans); }, {"poses", "NaN"});
  RowMatX bad_trans = trans;
  bad_trans(4, 0) = inf;
  expectInputError([&] { poseBodyBatch(m, VecX(), poses, bad_trans); }, {"trans", "Inf"});

  // Finite but absurd values (issue 23: a pose of 1e300 gave all-NaN vertices, no error).
  bad_pose = pose;
  bad_pose[3 * 5 + 1] = 1e300;
  expectInputError([&] { poseBody(m, VecX(), bad_pose); },
                   {"pose", "joint 5 (right_knee)", "1e+300 rad", "at most 1e6 rad"});
  bad_poses = poses;
  bad_poses(3, 2) = -2e6;
  expectInputError([&] { poseBodyBatch(m, VecX(), bad_poses, trans); },
                   {"poses", "frame 3", "joint 0 (pelvis)", "2e+06"});
  bad_betas = VecX::Zero(10);
  bad_betas[2] = 1e300;
  expectInputError([&] { poseBody(m, bad_betas, pose); }, {"betas[2]", "1e+300", "[-100, 100]"});
  expectInputError([&] { shapedVertices(m, bad_betas); }, {"betas[2]"});

  BodyModel unfinalized = m;
  unfinalized.derived.reset();
  expectInputError([&] { poseBody(unfinalized, VecX(), pose); }, {"finalize"});
}

}  // namespace
}  // namespace flsh
