// The synthetic SMPL-format body: mesh validity at two sizes, exact counts, size, axes and
// symmetry, skeleton, joint regressor, skinning weights, shape and pose blend shapes,
// determinism, input errors, and a PLY of the default body.
#include "flsh/body/synthetic_body.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <cstring>
#include <set>

#include "body/synthetic_body_detail.h"
#include "body/synthetic_mesh_checks.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "flsh/format/mesh_io.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using synthetic::SyntheticBodyBuild;

// One small and one default-size body per test binary (generation takes ~1–2 s).
const SyntheticBodyBuild& smallBody() {
  static const SyntheticBodyBuild build = synthetic::buildSyntheticBody({900, 1.70});
  return build;
}
const SyntheticBodyBuild& defaultBody() {
  static const SyntheticBodyBuild build = synthetic::buildSyntheticBody(SyntheticBodyOptions{});
  return build;
}

MatX3 regressedJoints(const BodyModel& m) { return MatX3(m.J_regressor * m.v_template); }

MatX3 displaced(const MatX3& V, const VecX& offsets) {
  MatX3 out = V;
  for (int i = 0; i < V.rows(); ++i) out.row(i) += offsets.segment<3>(3 * i).transpose();
  return out;
}

double height(const MatX3& V) { return V.col(1).maxCoeff() - V.col(1).minCoeff(); }

// Smallest cosine between a face's normal before and after a deformation (< 0: inverted).
double minNormalCosine(const MatX3& before, const MatX3& after, const MatX3i& F) {
  double worst = 1;
  for (int f = 0; f < F.rows(); ++f) {
    auto normal = [&](const MatX3& V) {
      const Vec3 a = V.row(F(f, 0)), b = V.row(F(f, 1)), c = V.row(F(f, 2));
      return Vec3((b - a).cross(c - a).normalized());
    };
    worst = std::min(worst, normal(before).dot(normal(after)));
  }
  return worst;
}

std::set<std::pair<int, int>> meshEdges(const MatX3i& F) {
  std::set<std::pair<int, int>> edges;
  for (int f = 0; f < F.rows(); ++f)
    for (int e = 0; e < 3; ++e) {
      const int a = F(f, e), b = F(f, (e + 1) % 3);
      edges.insert({std::min(a, b), std::max(a, b)});
    }
  return edges;
}

// One body per option set per process: the same object again, another one for other options,
// equal to a freshly generated body; bad options throw as makeSyntheticBody's.
TEST(SyntheticBody, SharedBodyIsGeneratedOncePerOptions) {
  SyntheticBodyOptions small;
  small.vertices = 400;
  SyntheticBodyOptions other = small;
  other.vertices = 420;
  const std::shared_ptr<const BodyModel> a = sharedSyntheticBody(small);
  EXPECT_EQ(sharedSyntheticBody(small).get(), a.get());
  const std::shared_ptr<const BodyModel> b = sharedSyntheticBody(other);
  EXPECT_NE(b.get(), a.get());
  EXPECT_EQ(b->numVertices(), 420);
  EXPECT_EQ(sharedSyntheticBody(small).get(), a.get());  // both kept
  const BodyModel fresh = makeSyntheticBody(small);
  EXPECT_EQ((fresh.v_template - a->v_template).norm(), 0.0);
  EXPECT_EQ((fresh.shapedirs - a->shapedirs).norm(), 0.0);
  SyntheticBodyOptions bad;
  bad.vertices = 10;
  EXPECT_THROW(sharedSyntheticBody(bad), InputError);
}

TEST(SyntheticBody, RejectsBadOptions) {
  EXPECT_THROW(makeSyntheticBody({199, 1.70}), InputError);
  EXPECT_THROW(makeSyntheticBody({-5, 1.70}), InputError);
  EXPECT_THROW(makeSyntheticBody({1000, 0.0}), InputError);
  EXPECT_THROW(makeSyntheticBody({1000, std::nan("")}), InputError);
  EXPECT_THROW(makeSyntheticBody({1000, 1e300}), InputError);  // finite but absurd
  EXPECT_THROW(makeSyntheticBody({1000, kMaxSyntheticHeight * 1.01}), InputError);
  EXPECT_THROW(makeSyntheticBody({1000, kMinSyntheticHeight * 0.99}), InputError);
  try {
    makeSyntheticBody({150, 1.70});
    FAIL() << "expected InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("vertices = 150"), std::string::npos) << e.what();
  }
}

TEST(SyntheticBody, SmallestAllowedBodyHasExactCounts) {
  const BodyModel m = makeSyntheticBody({200, 1.70});
  EXPECT_EQ(m.numVertices(), 200);
  EXPECT_EQ(m.numFaces(), 396);
  EXPECT_TRUE(test::isClosedGenus0Manifold(m.v_template, m.faces));
}

TEST(SyntheticBody, CountsShapesAndSource) {
  const BodyModel& m = defaultBody().model;
  EXPECT_EQ(m.numVertices(), 6890);
  EXPECT_EQ(m.numFaces(), 13776);
  EXPECT_EQ(m.numBetas(), 10);
  EXPECT_EQ(m.numJoints(), kNumJoints);
  EXPECT_EQ(m.posedirs.rows(), 3 * 6890);
  EXPECT_EQ(m.posedirs.cols(), kPoseFeatureSize);
  EXPECT_EQ(m.weights.rows(), 6890);
  EXPECT_EQ(m.weights.cols(), kNumJoints);
  EXPECT_EQ(m.J_regressor.rows(), kNumJoints);
  EXPECT_EQ(m.J_regressor.cols(), 6890);
  EXPECT_EQ(m.source, "synthetic(vertices=6890, height=1.7)");
  EXPECT_NE(m.derived, nullptr) << "finalize() was called";
  EXPECT_EQ(smallBody().model.numVertices(), 900);
  EXPECT_EQ(smallBody().model.numFaces(), 1796);
  ASSERT_EQ(kSyntheticShapeNames.size(), 10u);
  EXPECT_EQ(kSyntheticShapeNames[0], "height");
  EXPECT_EQ(kSyntheticShapeNames[1], "weight");
}

TEST(SyntheticBody, MeshIsClosedGenus0ManifoldAtTwoSizes) {
  for (const SyntheticBodyBuild* build : {&smallBody(), &defaultBody()}) {
    const BodyModel& m = build->model;
    SCOPED_TRACE(m.source);
    EXPECT_TRUE(test::isClosedGenus0Manifold(m.v_template, m.faces));
    EXPECT_EQ(test::countSelfIntersections(m.v_template, m.faces), 0);
    const auto q = test::meshQuality(m.v_template, m.faces);
    EXPECT_GT(q.min_angle_deg, 15.0);
    EXPECT_GT(q.min_area, 1e-7);
    std::printf("[ quality  ] %s: min angle %.1f deg, edges %.4f..%.4f m (mean %.4f)\n",
                m.source.c_str(), q.min_angle_deg, q.min_edge, q.max_edge, q.mean_edge);
  }
}

TEST(SyntheticBody, HeightAxesAndPelvisAtOrigin) {
  for (const SyntheticBodyBuild* build : {&smallBody(), &defaultBody()}) {
    const BodyModel& m = build->model;
    EXPECT_NEAR(height(m.v_template), 1.70, 0.03);
    const MatX3 J = regressedJoints(m);
    EXPECT_LT(J.row(0).norm(), 0.01) << "pelvis joint at the origin";
    EXPECT_GT(J(smplJointIndex("left_hip"), 0), 0.03) << "left is +x";
    EXPECT_GT(J(smplJointIndex("left_wrist"), 0), 0.5);
    EXPECT_LT(J(smplJointIndex("right_wrist"), 0), -0.5);
    EXPECT_GT(J(smplJointIndex("head"), 1), 0.4) << "y up";
    EXPECT_LT(J(smplJointIndex("left_ankle"), 1), -0.7);
    EXPECT_GT(J(smplJointIndex("left_foot"), 2), J(smplJointIndex("left_ankle"), 2) + 0.05)
        << "the feet point forward (+z)";
    // Arms horizontal (T-pose): shoulder, elbow and wrist at about the same height.
    EXPECT_NEAR(J(smplJointIndex("left_wrist"), 1), J(smplJointIndex("left_shoulder"), 1), 0.02);
    // Arm span about the height, as for real people.
    const double span = m.v_template.col(0).maxCoeff() - m.v_template.col(0).minCoeff();
    EXPECT_NEAR(span / height(m.v_template), 1.0, 0.06);
  }
}

TEST(SyntheticBody, HeightOptionScalesTheBody) {
  const BodyModel tall = makeSyntheticBody({300, 1.90});
  const BodyModel small = makeSyntheticBody({300, 1.50});
  EXPECT_NEAR(height(tall.v_template), 1.90, 1e-9);
  EXPECT_NEAR(height(small.v_template), 1.50, 1e-9);
  EXPECT_EQ(tall.faces, small.faces) << "the height is a pure scale";
  EXPECT_NEAR((tall.v_template / 1.90 - small.v_template / 1.50).cwiseAbs().maxCoeff(), 0, 1e-12);
}

TEST(SyntheticBody, MirrorSymmetric) {
  for (const SyntheticBodyBuild* build : {&smallBody(), &defaultBody()}) {
    const BodyModel& m = build->model;
    const MatX3& V = m.v_template;
    EXPECT_NEAR(V.col(0).maxCoeff(), -V.col(0).minCoeff(), 0.01);
    // Each vertex mirrored (x → −x) lands within an edge length of some vertex.
    const double edge = test::meshQuality(V, m.faces).mean_edge;
    double worst = 0;
    for (int i = 0; i < V.rows(); ++i) {
      const Eigen::RowVector3d mirrored(-V(i, 0), V(i, 1), V(i, 2));
      worst =
          std::max(worst, std::sqrt((V.rowwise() - mirrored).rowwise().squaredNorm().minCoeff()));
    }
    EXPECT_LT(worst, edge) << "mean edge " << edge;
    // Joints: left and right twins mirror each other; the spine is on the mid-plane.
    const auto& J = build->joints;
    for (int j = 0; j < kNumJoints; ++j) {
      const std::string name = kSmplJointNames[j];
      if (name.rfind("left_", 0) == 0) {
        const Vec3 right = J[smplJointIndex("right_" + name.substr(5))];
        EXPECT_NEAR((right - Vec3(-J[j].x(), J[j].y(), J[j].z())).norm(), 0, 1e-12) << name;
      } else if (name.rfind("right_", 0) != 0) {
        EXPECT_EQ(J[j].x(), 0.0) << name;
      }
    }
  }
}

TEST(SyntheticBody, SkeletonIsSmpl) {
  const BodyModel& m = smallBody().model;
  ASSERT_EQ(m.parents.size(), std::size_t(kNumJoints));
  for (int j = 0; j < kNumJoints; ++j) EXPECT_EQ(m.parents[j], kSmplParents[j]);
  // Every joint centre is inside the body: a ray to +y hits the surface an odd number of times.
  const MatX3 J = regressedJoints(m);
  for (int j = 0; j < kNumJoints; ++j) {
    int crossings = 0;
    const Vec3 p = J.row(j).transpose(), q = p + Vec3(1e-4, 10.0, 3e-5);
    for (int f = 0; f < m.numFaces(); ++f)
      crossings += test::detail::segmentHitsTriangle(p, q, m.v_template.row(m.faces(f, 0)),
                                                     m.v_template.row(m.faces(f, 1)),
                                                     m.v_template.row(m.faces(f, 2)));
    EXPECT_EQ(crossings % 2, 1) << kSmplJointNames[j] << " is outside the body";
  }
}

TEST(SyntheticBody, RegressorReproducesDesignedJoints) {
  for (const SyntheticBodyBuild* build : {&smallBody(), &defaultBody()}) {
    const BodyModel& m = build->model;
    const MatX3 J = regressedJoints(m);
    for (int j = 0; j < kNumJoints; ++j) {
      double sum = 0, lowest = 1;
      int count = 0;
      for (SpMatR::InnerIterator it(m.J_regressor, j); it; ++it) {
        sum += it.value();
        lowest = std::min(lowest, it.value());
        ++count;
      }
      EXPECT_NEAR(sum, 1.0, 1e-12) << kSmplJointNames[j];
      EXPECT_GE(lowest, 0.0) << kSmplJointNames[j] << ": nonnegative";
      EXPECT_GE(count, 8);
      EXPECT_LE(count, 256) << "sparse";
      EXPECT_LT((J.row(j).transpose() - build->joints[j]).norm(), 1e-9) << kSmplJointNames[j];
    }
  }
}

TEST(SyntheticBody, SkinningWeightsArePartitionOfUnityAndSmooth) {
  const BodyModel& m = smallBody().model;
  const MatX& W = m.weights;
  EXPECT_GE(W.minCoeff(), 0.0);
  for (int i = 0; i < W.rows(); ++i) {
    EXPECT_NEAR(W.row(i).sum(), 1.0, 1e-12);
    EXPECT_LE((W.row(i).array() > 0).count(), 4) << "vertex " << i;
  }
  // Smooth: weights change little across an edge (a hard partition would jump by 1).
  double worst = 0, mean = 0;
  const auto edges = meshEdges(m.faces);
  for (const auto& [a, b] : edges) {
    const double d = (W.row(a) - W.row(b)).cwiseAbs().maxCoeff();
    worst = std::max(worst, d);
    mean += d;
  }
  mean /= double(edges.size());
  EXPECT_LT(worst, 0.6);
  EXPECT_LT(mean, 0.15);
  // Every joint (including the toes 10/11 and fingers 22/23) dominates some vertices.
  std::vector<int> dominant(kNumJoints, 0);
  for (int i = 0; i < W.rows(); ++i) {
    int j;
    W.row(i).maxCoeff(&j);
    ++dominant[j];
  }
  for (int j = 0; j < kNumJoints; ++j) EXPECT_GT(dominant[j], 0) << kSmplJointNames[j];
  // Ownership: the fingertips belong to the hand joints, the top of the head to the head,
  // the soles' lowest points to the feet and ankles.
  const MatX3& V = m.v_template;
  const MatX3 J = regressedJoints(m);
  for (int i = 0; i < V.rows(); ++i) {
    int j;
    W.row(i).maxCoeff(&j);
    if (V(i, 0) > J(22, 0) + 0.04) {
      EXPECT_EQ(j, 22) << "left fingers, vertex " << i;
    }
    if (V(i, 0) < J(23, 0) - 0.04) {
      EXPECT_EQ(j, 23) << "right fingers, vertex " << i;
    }
    if (V(i, 1) > J(15, 1) + 0.08) {
      EXPECT_EQ(j, 15) << "head, vertex " << i;
    }
    if (V(i, 1) < J(7, 1) - 0.06) {
      EXPECT_TRUE(j == 7 || j == 8 || j == 10 || j == 11) << "feet, vertex " << i;
    }
  }
}

TEST(SyntheticBody, ShapeDirectionsHaveTheirMeaning) {
  const BodyModel& m = smallBody().model;
  const MatX3& V = m.v_template;
  const double volume = test::enclosedVolume(V, m.faces);
  EXPECT_NEAR(volume, 0.065, 0.025) << "a 1.70 m adult has about 65 litres";
  auto shaped = [&](int k, double beta) {
    VecX b = VecX::Zero(10);
    b[k] = beta;
    return displaced(V, m.shapedirs * b);
  };
  // height
  EXPECT_GT(height(shaped(0, 1.0)), height(V) + 0.04);
  EXPECT_LT(height(shaped(0, -1.0)), height(V) - 0.04);
  // weight: more volume, same height (about)
  EXPECT_GT(test::enclosedVolume(shaped(1, 1.0), m.faces), 1.08 * volume);
  EXPECT_LT(test::enclosedVolume(shaped(1, -1.0), m.faces), 0.92 * volume);
  EXPECT_NEAR(height(shaped(1, 1.0)), height(V), 0.02);
  // leg length: the ankles move down relative to the pelvis (joints follow the shape).
  {
    const BodyModel& mm = m;
    const MatX3 J0 = regressedJoints(mm);
    const MatX3 J1 = MatX3(mm.J_regressor * shaped(2, 1.0));
    EXPECT_LT(J1(7, 1) - J1(0, 1), J0(7, 1) - J0(0, 1) - 0.02);
    const MatX3 J3 = MatX3(mm.J_regressor * shaped(3, 1.0));
    EXPECT_GT(J3(20, 0) - J3(16, 0), J0(20, 0) - J0(16, 0) + 0.015) << "arm length";
    const MatX3 J4 = MatX3(mm.J_regressor * shaped(4, 1.0));
    EXPECT_GT(J4(16, 0) - J4(17, 0), J0(16, 0) - J0(17, 0) + 0.015) << "shoulder width";
    const MatX3 J8 = MatX3(mm.J_regressor * shaped(8, 1.0));
    EXPECT_NEAR(J8(15, 1), J0(15, 1), 0.01) << "head size keeps the head joint";
  }
  for (int k = 0; k < 10; ++k) {
    SCOPED_TRACE(kSyntheticShapeNames[k]);
    EXPECT_GT(m.shapedirs.col(k).cwiseAbs().maxCoeff(), 0.005) << "moves some vertices";
    for (double beta : {-3.0, 3.0}) {
      const MatX3 S = shaped(k, beta);
      EXPECT_GT(minNormalCosine(V, S, m.faces), 0.2) << "beta " << beta << ": a face inverted";
      EXPECT_GT(test::meshQuality(S, m.faces).min_area, 0.0);
    }
  }
  // belly: the front of the abdomen moves forward, the back does not
  const VecX belly = m.shapedirs.col(6);
  double front = 0, back = 0;
  for (int i = 0; i < V.rows(); ++i) {
    if (std::abs(V(i, 0)) < 0.05 && std::abs(V(i, 1) - 0.1 * height(V) / 1.7) < 0.05) {
      if (V(i, 2) > 0) front = std::max(front, belly[3 * i + 2]);
      if (V(i, 2) < 0) back = std::max(back, std::abs(belly[3 * i + 2]));
    }
  }
  EXPECT_GT(front, 0.01);
  EXPECT_LT(back, 0.002);
}

TEST(SyntheticBody, ShapedBodyHasNoSelfIntersections) {
  const BodyModel& m = smallBody().model;
  for (int k : {0, 1, 5, 9}) {
    for (double beta : {-3.0, 3.0}) {
      VecX b = VecX::Zero(10);
      b[k] = beta;
      EXPECT_EQ(test::countSelfIntersections(displaced(m.v_template, m.shapedirs * b), m.faces), 0)
          << kSyntheticShapeNames[k] << " beta " << beta;
    }
  }
}

TEST(SyntheticBody, PoseCorrectivesAreLocalSparseAndZeroAtRest) {
  const BodyModel& m = smallBody().model;
  const MatX& P = m.posedirs;
  const MatX3 J = regressedJoints(m);
  EXPECT_LT(double((P.array() != 0).count()) / double(P.size()), 0.05) << "sparse";
  // Zero pose: R = I for every joint, so the pose feature and the offset vanish.
  VecX feature = VecX::Zero(kPoseFeatureSize);
  EXPECT_EQ((P * feature).cwiseAbs().maxCoeff(), 0.0);
  // Only the diagonal entries (r, r) of each joint's block are used.
  for (int j = 1; j < kNumJoints; ++j)
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c)
        if (r != c) {
          EXPECT_EQ(P.col(9 * (j - 1) + 3 * r + c).cwiseAbs().maxCoeff(), 0.0);
        }
  // A 90° bend: a bulge of about 1–3 cm, only near that joint (hips and shoulders blend over
  // a wider region than knees and elbows).
  for (int j : {4, 5, 18, 19, 1, 16}) {
    const double local_radius = (j == 1 || j == 16) ? 0.35 : 0.2;
    SCOPED_TRACE(kSmplJointNames[j]);
    feature.setZero();
    const Mat3 R = Eigen::AngleAxisd(M_PI / 2, Vec3::UnitZ()).toRotationMatrix();
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) feature[9 * (j - 1) + 3 * r + c] = R(r, c) - (r == c);
    const VecX offset = P * feature;
    double largest = 0, far = 0;
    for (int i = 0; i < m.numVertices(); ++i) {
      const double d = offset.segment<3>(3 * i).norm();
      const double dist = (m.v_template.row(i) - J.row(j)).norm();
      largest = std::max(largest, d);
      if (dist > local_radius) far = std::max(far, d);
    }
    EXPECT_GT(largest, 0.005);
    EXPECT_LT(largest, 0.04);
    EXPECT_EQ(far, 0.0) << "exact zeros away from the joint";
  }
}

TEST(SyntheticBody, Deterministic) {
  const BodyModel a = makeSyntheticBody({300, 1.70});
  const BodyModel b = makeSyntheticBody({300, 1.70});
  auto same = [](const auto& x, const auto& y) {
    return x.size() == y.size() &&
           std::memcmp(x.data(), y.data(), sizeof(*x.data()) * std::size_t(x.size())) == 0;
  };
  EXPECT_TRUE(same(a.v_template, b.v_template));
  EXPECT_TRUE(same(a.faces, b.faces));
  EXPECT_TRUE(same(a.weights, b.weights));
  EXPECT_TRUE(same(a.shapedirs, b.shapedirs));
  EXPECT_TRUE(same(a.posedirs, b.posedirs));
  EXPECT_TRUE(MatX(a.J_regressor).cwiseEqual(MatX(b.J_regressor)).all());
}

TEST(SyntheticBody, DefaultBodyWritesAsPly) {
  const BodyModel& m = defaultBody().model;
  const std::string path = test::freshTempDir("synthetic_body") + "/synthetic_body.ply";
  io::writePly(path, m.v_template, m.faces);
  MatX3 V;
  MatX3i F;
  io::readMesh(path, V, F);
  EXPECT_EQ(V, m.v_template);
  EXPECT_EQ(F, m.faces);
}

}  // namespace
}  // namespace flsh
