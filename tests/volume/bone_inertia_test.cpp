// computeBoneInertia: analytic solids (box, icosphere) for mass, centre of mass and second
// moment, convergence as voxels shrink, invariance to sub-voxel shifts, the synthetic body's
// total and per-bone masses, symmetric PSD second moments, determinism and input errors.
#include <gtest/gtest.h>
#include <omp.h>

#include <Eigen/Eigenvalues>
#include <cmath>
#include <cstring>
#include <string>

#include "flsh/body/body_forward.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "flsh/volume/soft_avatar.h"
#include "support/test_support.h"
#include "volume/volume_test_meshes.h"
#include "volume/voxel_columns.h"

namespace flsh {
namespace {

using test::boxMesh;
using test::icosphere;
using test::solidIntegrals;
using test::TriangleMesh;
using test::weightsOnBoneZero;

constexpr double kDensity = 1000.0;

MatX3 jointsAt(const Vec3& j0) {
  MatX3 J = MatX3::Zero(24, 3);
  J.row(0) = j0.transpose();
  return J;
}

// Relative errors of bone 0's mass, centre of mass (relative to the solid's size) and second
// moment (max-norm relative to the exact one's) against a mesh's exact solid integrals.
struct Errors {
  double mass, centre, second;
};
Errors errorsAgainstExact(const TriangleMesh& m, const Vec3& j0, double voxel) {
  const std::vector<BoneInertia> bones =
      computeBoneInertia(m.V, m.F, weightsOnBoneZero(m.V.rows()), jointsAt(j0), kDensity, voxel);
  const test::SolidIntegrals exact = solidIntegrals(m);
  const double mass = kDensity * exact.volume;
  const Vec3 centre = exact.first / exact.volume;
  // Σ m (X − J)(X − J)ᵀ = ρ (∫XXᵀ − ∫X Jᵀ − J ∫Xᵀ + V J Jᵀ)
  const Mat3 second =
      kDensity * (exact.second - exact.first * j0.transpose() - j0 * exact.first.transpose() +
                  exact.volume * j0 * j0.transpose());
  const double size = (m.V.colwise().maxCoeff() - m.V.colwise().minCoeff()).maxCoeff();
  for (size_t b = 1; b < bones.size(); ++b) EXPECT_EQ(bones[b].mass, 0.0) << "bone " << b;
  return {std::abs(bones[0].mass - mass) / mass, (bones[0].centerOfMass(j0) - centre).norm() / size,
          (bones[0].second_moment - second).cwiseAbs().maxCoeff() / second.cwiseAbs().maxCoeff()};
}

TEST(BoneInertia, TestMeshesAreClosedAndOutward) {
  const TriangleMesh box = boxMesh({0.3, 0.2, 0.1}, {0.05, -0.02, 0.01});
  EXPECT_NEAR(solidIntegrals(box).volume, 0.3 * 0.2 * 0.1, 1e-15);
  const TriangleMesh sphere = icosphere(3, 0.1, {0.0, 0.0, 0.0});
  EXPECT_NEAR(solidIntegrals(sphere).volume, 4.0 / 3.0 * M_PI * 1e-3,
              0.02 * 4.0 / 3.0 * M_PI * 1e-3);
}

TEST(BoneInertia, BoxMatchesTheAnalyticSolid) {
  const Vec3 size(0.3, 0.2, 0.1), centre(0.05, -0.02, 0.01), j0(0.1, 0.05, -0.03);
  const TriangleMesh box = boxMesh(size, centre);
  const Errors e = errorsAgainstExact(box, j0, 0.01);
  EXPECT_LT(e.mass, 0.03);
  EXPECT_LT(e.centre, 0.01);
  EXPECT_LT(e.second, 0.03);
  // The box's own analytic values, written out: m = ρ abc, S = m ((c − J)(c − J)ᵀ + diag/12).
  const std::vector<BoneInertia> bones =
      computeBoneInertia(box.V, box.F, weightsOnBoneZero(8), jointsAt(j0), kDensity, 0.005);
  const double mass = kDensity * size.prod();
  Mat3 second = mass * (centre - j0) * (centre - j0).transpose();
  second.diagonal() += mass / 12 * size.cwiseProduct(size);
  EXPECT_NEAR(bones[0].mass, mass, 0.02 * mass);
  EXPECT_LT((bones[0].first_moment - mass * (centre - j0)).norm(),
            0.02 * mass * (centre - j0).norm());
  EXPECT_LT((bones[0].second_moment - second).norm(), 0.03 * second.norm());
}

TEST(BoneInertia, IcosphereMatchesTheAnalyticSolidAndConverges) {
  const TriangleMesh sphere = icosphere(3, 0.1, {0.01, 0.2, -0.03});
  const Vec3 j0(0.0, 0.15, 0.0);
  const Errors coarse = errorsAgainstExact(sphere, j0, 0.02);
  const Errors medium = errorsAgainstExact(sphere, j0, 0.01);
  const Errors fine = errorsAgainstExact(sphere, j0, 0.0025);
  EXPECT_LT(medium.mass, 0.03);
  EXPECT_LT(medium.centre, 0.01);
  EXPECT_LT(medium.second, 0.03);
  // Converges: a 8× finer voxel is markedly closer.
  EXPECT_LT(fine.mass, 0.005);
  EXPECT_LT(fine.second, 0.005);
  EXPECT_LT(fine.mass, 0.5 * coarse.mass + 1e-4);
  EXPECT_LT(fine.second, 0.5 * coarse.second + 1e-4);
  // Against the round sphere too (the icosphere is within 1 % of it): I_c = 2/5 m r² about the
  // centre in every axis, so Σ m (X − c)(X − c)ᵀ = m r²/5 · I.
  const MatX3 J = jointsAt(Vec3(0.01, 0.2, -0.03));
  const std::vector<BoneInertia> bones = computeBoneInertia(
      sphere.V, sphere.F, weightsOnBoneZero(sphere.V.rows()), J, kDensity, 0.005);
  const double mass = kDensity * 4.0 / 3.0 * M_PI * 1e-3;
  EXPECT_NEAR(bones[0].mass, mass, 0.03 * mass);
  EXPECT_LT(bones[0].first_moment.norm(), 0.01 * mass * 0.1);
  EXPECT_LT((bones[0].second_moment - Mat3::Identity() * mass * 0.01 / 5).norm(),
            0.05 * mass * 0.01 / 5);
}

TEST(BoneInertia, SubVoxelSizeChangesStayWithinTheVoxelError) {
  // Boxes whose edges are not multiples of the voxel: the columns cover the box's cross-section
  // only up to a voxel row, so the mass error is bounded by about h/2 per side, the centre's by
  // h/2, and both shrink with h.
  const Vec3 j0(0.02, -0.01, 0.03);
  for (int step = 0; step < 8; ++step) {
    const Vec3 size = Vec3(0.2, 0.15, 0.1) + Vec3(0.37, 0.61, 0.73) * 0.01 * step / 8.0;
    const TriangleMesh box = boxMesh(size, Vec3(0.01, 0.02, -0.01));
    const double h = 0.01;
    const Errors e = errorsAgainstExact(box, j0, h);
    const double bound = 0.5 * h * (1 / size.x() + 1 / size.y());
    EXPECT_LT(e.mass, bound) << "step " << step;
    EXPECT_LT(e.centre * size.maxCoeff(), 0.5 * h) << "step " << step;
    const Errors fine = errorsAgainstExact(box, j0, h / 4);
    EXPECT_LT(fine.mass, bound / 4) << "step " << step;
    EXPECT_LT(fine.centre * size.maxCoeff(), 0.5 * h / 4) << "step " << step;
  }
}

TEST(BoneInertia, GridAlignedBoxWithVerticesOnRoundCoordinates) {
  // A box on round coordinates and a voxel that divides its edges: no column may be lost or
  // doubled on the shared diagonals of the faces.
  const TriangleMesh box = boxMesh({0.2, 0.2, 0.2}, {0.1, 0.1, 0.1});
  const Errors e = errorsAgainstExact(box, Vec3::Zero(), 0.02);
  EXPECT_LT(e.mass, 0.1);
  const Errors fine = errorsAgainstExact(box, Vec3::Zero(), 0.005);
  EXPECT_LT(fine.mass, 0.02);
}

// A box [0, 0.2]² × [0, 0.1] whose top and bottom faces are triangulated on a grid through
// every column centre: each column passes exactly through a vertex shared by six triangles and
// along their edges. The fill rule must count exactly one crossing on each face; a rule that
// counts such points in no triangle or in several loses whole columns.
TEST(BoneInertia, ColumnsThroughVerticesAndEdgesAreCountedOnce) {
  const double h = 0.01, side = 0.2, height = 0.1;
  const voxel::ColumnGrid grid = voxel::columnGrid(Vec3::Zero(), Vec3(side, side, height), h);
  std::vector<double> xs = {0.0}, ys = {0.0};
  for (long i = 0; grid.columnX(i) < side; ++i) xs.push_back(grid.columnX(i));
  for (long j = 0; grid.columnY(j) < side; ++j) ys.push_back(grid.columnY(j));
  xs.push_back(side);
  ys.push_back(side);
  const int nx = int(xs.size()), ny = int(ys.size());
  ASSERT_EQ(nx, 22);  // 20 columns and the two sides
  TriangleMesh m;
  m.V.resize(2 * nx * ny, 3);
  auto node = [&](int i, int j, int top) { return top * nx * ny + j * nx + i; };
  for (int top = 0; top < 2; ++top)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) m.V.row(node(i, j, top)) << xs[i], ys[j], top * height;
  std::vector<Eigen::Vector3i> faces;
  for (int j = 0; j + 1 < ny; ++j)
    for (int i = 0; i + 1 < nx; ++i) {
      const int a = node(i, j, 1), b = node(i + 1, j, 1), c = node(i + 1, j + 1, 1),
                d = node(i, j + 1, 1);
      faces.push_back({a, b, c});  // top, facing +z
      faces.push_back({a, c, d});
      const int e = node(i, j, 0), f = node(i + 1, j, 0), g = node(i + 1, j + 1, 0),
                k = node(i, j + 1, 0);
      faces.push_back({e, g, f});  // bottom, facing −z
      faces.push_back({e, k, g});
    }
  // Sides: the boundary loop, counter-clockwise seen from above, joined top to bottom.
  std::vector<std::pair<int, int>> loop;
  for (int i = 0; i + 1 < nx; ++i) loop.push_back({i, 0});
  for (int j = 0; j + 1 < ny; ++j) loop.push_back({nx - 1, j});
  for (int i = nx - 1; i > 0; --i) loop.push_back({i, ny - 1});
  for (int j = ny - 1; j > 0; --j) loop.push_back({0, j});
  for (size_t s = 0; s < loop.size(); ++s) {
    const auto [pi, pj] = loop[s];
    const auto [qi, qj] = loop[(s + 1) % loop.size()];
    const int bp = node(pi, pj, 0), bq = node(qi, qj, 0), tp = node(pi, pj, 1),
              tq = node(qi, qj, 1);
    faces.push_back({bp, bq, tq});
    faces.push_back({bp, tq, tp});
  }
  m.F.resize(faces.size(), 3);
  for (size_t f = 0; f < faces.size(); ++f) m.F.row(f) = faces[f].transpose();
  const double exact_volume = side * side * height;
  ASSERT_NEAR(solidIntegrals(m).volume, exact_volume, 1e-15);  // closed and outward

  const std::vector<BoneInertia> bones = computeBoneInertia(m.V, m.F, weightsOnBoneZero(m.V.rows()),
                                                            jointsAt(Vec3::Zero()), kDensity, h);
  // 20 × 20 columns of height 0.1, each fully inside: exactly the box's mass.
  EXPECT_NEAR(bones[0].mass, kDensity * exact_volume, 1e-9 * kDensity * exact_volume);
}

class SyntheticBodyInertia : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    const auto body = test::smallSyntheticBody();
    vertices_ = new MatX3(shapedVertices(*body, VecX::Zero(0)));
    joints_ = new MatX3(body->J_regressor * *vertices_);
    bones_ = new std::vector<BoneInertia>(
        computeBoneInertia(*vertices_, body->faces, body->weights, *joints_, 1010.0, 0.01));
  }
  static void TearDownTestSuite() {
    delete vertices_;
    delete joints_;
    delete bones_;
  }
  static MatX3* vertices_;
  static MatX3* joints_;
  static std::vector<BoneInertia>* bones_;
};
MatX3* SyntheticBodyInertia::vertices_ = nullptr;
MatX3* SyntheticBodyInertia::joints_ = nullptr;
std::vector<BoneInertia>* SyntheticBodyInertia::bones_ = nullptr;

TEST_F(SyntheticBodyInertia, TotalMassIsDensityTimesVolume) {
  const auto body = test::smallSyntheticBody();
  const double volume = solidIntegrals({*vertices_, body->faces}).volume;
  ASSERT_GT(volume, 0.0);
  double total = 0;
  for (const BoneInertia& b : *bones_) total += b.mass;
  EXPECT_NEAR(total, 1010.0 * volume, 0.02 * 1010.0 * volume);
  // The synthetic 1.70 m body is slim (about 0.057 m³ at 1000 vertices, 0.059 m³ at 6890).
  EXPECT_GT(total, 50.0);
  EXPECT_LT(total, 90.0);
}

TEST_F(SyntheticBodyInertia, PerBoneMassesArePlausibleAndSymmetric) {
  const auto& b = *bones_;
  const int left_thigh = smplJointIndex("left_hip"), left_forearm = smplJointIndex("left_elbow");
  EXPECT_GT(b[left_thigh].mass, 2 * b[left_forearm].mass);
  EXPECT_GT(b[smplJointIndex("spine1")].mass + b[smplJointIndex("spine2")].mass +
                b[smplJointIndex("spine3")].mass,
            b[left_thigh].mass);
  for (int j = 0; j < 24; ++j) EXPECT_GT(b[j].mass, 0.0) << kSmplJointNames[j];
  const std::pair<const char*, const char*> pairs[] = {
      {"left_hip", "right_hip"},       {"left_knee", "right_knee"},
      {"left_ankle", "right_ankle"},   {"left_foot", "right_foot"},
      {"left_collar", "right_collar"}, {"left_shoulder", "right_shoulder"},
      {"left_elbow", "right_elbow"},   {"left_wrist", "right_wrist"},
      {"left_hand", "right_hand"}};
  // The 1000-vertex mesh itself is not exactly mirror symmetric (its vertices miss their
  // mirror images by up to 3 cm; the default 6890-vertex body is within 1.5 %): the large parts
  // match within 3 %, the small ones (hands, forearms, feet) within 10 %.
  for (const auto& [left, right] : pairs) {
    const double ml = b[smplJointIndex(left)].mass, mr = b[smplJointIndex(right)].mass;
    const double tolerance = std::max(ml, mr) > 1.0 ? 0.03 : 0.10;
    EXPECT_NEAR(ml, mr, tolerance * std::max(ml, mr)) << left << " vs " << right;
  }
}

TEST_F(SyntheticBodyInertia, MirroredBodyGivesMirroredBones) {
  // The body mirrored in x (faces reversed, left and right bones swapped) lies differently on
  // the voxel grid; its left bones must match the original's right bones within the voxel error.
  const auto body = test::smallSyntheticBody();
  std::vector<int> mirror_bone(24);
  for (int j = 0; j < 24; ++j) {
    std::string name = kSmplJointNames[j];
    if (name.rfind("left_", 0) == 0)
      name = "right_" + name.substr(5);
    else if (name.rfind("right_", 0) == 0)
      name = "left_" + name.substr(6);
    mirror_bone[j] = smplJointIndex(name);
  }
  MatX3 V = *vertices_;
  V.col(0) *= -1;
  MatX3i F = body->faces;
  F.col(1).swap(F.col(2));
  MatX W(body->weights.rows(), 24);
  MatX3 J(24, 3);
  for (int j = 0; j < 24; ++j) {
    W.col(mirror_bone[j]) = body->weights.col(j);
    J.row(mirror_bone[j]) = joints_->row(j);
  }
  J.col(0) *= -1;
  const std::vector<BoneInertia> mirrored = computeBoneInertia(V, F, W, J, 1010.0, 0.01);
  const Vec3 flip(-1, 1, 1);
  for (int j = 0; j < 24; ++j) {
    const BoneInertia& original = (*bones_)[j];
    const BoneInertia& image = mirrored[mirror_bone[j]];
    EXPECT_NEAR(image.mass, original.mass, 0.03 * original.mass) << kSmplJointNames[j];
    EXPECT_LT((image.first_moment - original.first_moment.cwiseProduct(flip)).norm(),
              0.005 * original.mass + 0.03 * original.first_moment.norm())  // h/2 + 3 %
        << kSmplJointNames[j];
  }
}

TEST_F(SyntheticBodyInertia, SecondMomentsAreSymmetricPositiveSemidefinite) {
  for (int j = 0; j < 24; ++j) {
    const BoneInertia& b = (*bones_)[j];
    EXPECT_EQ((b.second_moment - b.second_moment.transpose()).cwiseAbs().maxCoeff(), 0.0);
    const Eigen::SelfAdjointEigenSolver<Mat3> eigen(b.second_moment);
    EXPECT_GT(eigen.eigenvalues().minCoeff(), 0.0) << kSmplJointNames[j];
    // Cauchy–Schwarz: f fᵀ ≤ m S, i.e. S − f fᵀ/m (the moment about the centre of mass) is PSD.
    const Mat3 central = b.second_moment - b.first_moment * b.first_moment.transpose() / b.mass;
    EXPECT_GT(Eigen::SelfAdjointEigenSolver<Mat3>(central).eigenvalues().minCoeff(), 0.0)
        << kSmplJointNames[j];
  }
}

TEST_F(SyntheticBodyInertia, CentresOfMassLieNearTheirBones) {
  // Each bone's centre of mass is within 40 cm of its joint and the left upper arm's lies on the
  // +x side of the shoulder (the arm points along +x in the T-pose).
  for (int j = 0; j < 24; ++j) {
    const BoneInertia& b = (*bones_)[j];
    EXPECT_LT((b.centerOfMass(joints_->row(j).transpose()) - joints_->row(j).transpose()).norm(),
              0.4)
        << kSmplJointNames[j];
  }
  const int arm = smplJointIndex("left_shoulder");
  EXPECT_GT((*bones_)[arm].first_moment.x(), 0.0);
}

TEST_F(SyntheticBodyInertia, DeterministicWhateverTheThreadCount) {
  const auto body = test::smallSyntheticBody();
  const int threads = omp_get_max_threads();
  omp_set_num_threads(threads == 1 ? 2 : 1);
  const std::vector<BoneInertia> again =
      computeBoneInertia(*vertices_, body->faces, body->weights, *joints_, 1010.0, 0.01);
  omp_set_num_threads(threads);
  ASSERT_EQ(again.size(), bones_->size());
  for (size_t j = 0; j < again.size(); ++j) {
    EXPECT_EQ(again[j].mass, (*bones_)[j].mass);
    EXPECT_EQ(again[j].first_moment, (*bones_)[j].first_moment);
    EXPECT_EQ(again[j].second_moment, (*bones_)[j].second_moment);
  }
}

TEST(BoneInertia, RejectsBadInputs) {
  const TriangleMesh box = boxMesh({0.2, 0.2, 0.2}, Vec3::Zero());
  const MatX w = weightsOnBoneZero(8);
  const MatX3 J = jointsAt(Vec3::Zero());
  using test::messageOf;
  std::string msg =
      messageOf<InputError>([&] { computeBoneInertia(box.V, box.F, w, J, 0.0, 0.01); });
  EXPECT_NE(msg.find("density"), std::string::npos) << msg;
  msg = messageOf<InputError>([&] { computeBoneInertia(box.V, box.F, w, J, 1000, -0.01); });
  EXPECT_NE(msg.find("voxel_size"), std::string::npos) << msg;
  msg = messageOf<InputError>([&] { computeBoneInertia(box.V, box.F, w, J, 1000, 1e-6); });
  EXPECT_NE(msg.find("voxels"), std::string::npos) << msg;
  msg = messageOf<InputError>(
      [&] { computeBoneInertia(box.V, box.F, MatX::Ones(7, 24), J, 1000, 0.01); });
  EXPECT_NE(msg.find("(7, 24)"), std::string::npos) << msg;
  msg = messageOf<InputError>(
      [&] { computeBoneInertia(box.V, box.F, w, MatX3::Zero(23, 3), 1000, 0.01); });
  EXPECT_NE(msg.find("(23, 3)"), std::string::npos) << msg;
  MatX3i bad_faces = box.F;
  bad_faces(3, 1) = 8;
  msg = messageOf<InputError>([&] { computeBoneInertia(box.V, bad_faces, w, J, 1000, 0.01); });
  EXPECT_NE(msg.find("indices"), std::string::npos) << msg;
  MatX3 nan_vertices = box.V;
  nan_vertices(2, 2) = std::nan("");
  msg = messageOf<InputError>([&] { computeBoneInertia(nan_vertices, box.F, w, J, 1000, 0.01); });
  EXPECT_NE(msg.find("NaN"), std::string::npos) << msg;
}

}  // namespace
}  // namespace flsh
