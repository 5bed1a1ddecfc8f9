// Volume fields on structured tet meshes (no CGAL): the P1 Laplacian, harmonic extension (linear
// precision, Dirichlet rows, maximum principle), the body's fields on all nodes, shaped rest
// nodes, and bone-node selection (exact on a box, stable, monotone in depth); input errors.
#include "flsh/volume/volume_fields.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include <cmath>
#include <random>

#include "flsh/body/body_forward.h"
#include "flsh/core/error.h"
#include "flsh/volume/materials.h"
#include "support/test_support.h"
#include "volume/volume_test_meshes.h"

namespace flsh {
namespace {

using test::gridTetMesh;
using test::messageOf;

const Vec3 kBoxSize(0.3, 0.2, 0.25);
const Vec3 kBoxOrigin(-0.1, 0.05, 0.2);

const TetMesh& box() {
  static const TetMesh mesh = gridTetMesh({6, 4, 5}, kBoxSize, kBoxOrigin);
  return mesh;
}

/// makeRandomModel with its template replaced by the mesh's surface nodes: a body whose tet
/// mesh is `mesh` (random weights, dense random shape and pose blend shapes).
BodyModel bodyOnSurface(const TetMesh& mesh, unsigned seed = 3) {
  BodyModel body = test::makeRandomModel(mesh.num_surface_nodes, 10, seed);
  body.v_template = mesh.nodes.topRows(mesh.num_surface_nodes);
  body.finalize();
  return body;
}

MatX affineField(const MatX3& X, int columns, unsigned seed) {
  const MatX A = test::randomVector(3 * columns, 1.0, seed).reshaped(3, columns);
  const Eigen::RowVectorXd offset = test::randomVector(columns, 1.0, seed + 1).transpose();
  return (X * A).rowwise() + offset;
}

TEST(CotangentLaplacian, SymmetricRowsSumToZeroAndIntegratesGradients) {
  const TetMesh& mesh = box();
  const SpMat K = cotangentLaplacian(mesh);
  ASSERT_EQ(K.rows(), mesh.numNodes());
  const MatX dense = MatX(K);
  const double scale = dense.diagonal().maxCoeff();
  ASSERT_GT(scale, 0.0);
  EXPECT_LE((dense - dense.transpose()).cwiseAbs().maxCoeff(), 1e-15 * scale);
  EXPECT_LE(dense.rowwise().sum().cwiseAbs().maxCoeff(), 1e-13 * scale);
  // Dirichlet energy of an affine field a·x is |a|² × volume exactly; random fields are ≥ 0.
  const Vec3 a(0.3, -1.2, 0.7);
  const VecX linear = mesh.nodes * a;
  const double volume = kBoxSize.prod();
  EXPECT_NEAR(linear.dot(K * linear), a.squaredNorm() * volume, 1e-12);
  for (unsigned seed = 1; seed <= 5; ++seed) {
    const VecX x = test::randomVector(mesh.numNodes(), 1.0, seed);
    EXPECT_GT(x.dot(K * x), 0.0);
  }
}

TEST(HarmonicExtension, LinearPrecisionAndSurfaceRows) {
  const TetMesh& mesh = box();
  const HarmonicExtension harmonic(mesh);
  EXPECT_EQ(harmonic.numNodes(), mesh.numNodes());
  EXPECT_EQ(harmonic.numSurfaceNodes(), mesh.num_surface_nodes);
  const int V = mesh.num_surface_nodes;
  // 300 columns: more than one solve block.
  const MatX exact = affineField(mesh.nodes, 300, 11);
  const MatX extended = harmonic.extend(exact.topRows(V));
  ASSERT_EQ(extended.rows(), mesh.numNodes());
  ASSERT_EQ(extended.cols(), 300);
  EXPECT_TRUE((extended.topRows(V).array() == exact.topRows(V).array()).all());
  ASSERT_GT(mesh.numNodes() - V, 0);
  EXPECT_LE((extended - exact).bottomRows(mesh.numNodes() - V).cwiseAbs().maxCoeff(), 1e-10);
}

TEST(HarmonicExtension, SolvesTheDirichletProblemAndKeepsTheMaximumPrinciple) {
  const TetMesh& mesh = box();
  const HarmonicExtension harmonic(mesh);
  const int V = mesh.num_surface_nodes, N = mesh.numNodes();
  MatX surface(V, 1);
  for (int i = 0; i < V; ++i)
    surface(i, 0) = std::sin(7 * mesh.nodes(i, 0)) + mesh.nodes(i, 1) * mesh.nodes(i, 2) * 20;
  const MatX x = harmonic.extend(surface);
  // Interior rows of K x vanish (harmonic), the field is not affine (the test is not trivial).
  const VecX residual = cotangentLaplacian(mesh) * x.col(0);
  EXPECT_LE(residual.tail(N - V).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_GT(residual.head(V).cwiseAbs().maxCoeff(), 1e-6);
  // Kuhn tets have no obtuse dihedral angles: the discrete maximum principle holds.
  EXPECT_LE(x.col(0).tail(N - V).maxCoeff(), surface.maxCoeff());
  EXPECT_GE(x.col(0).tail(N - V).minCoeff(), surface.minCoeff());
}

TEST(HarmonicExtension, RejectsBadInput) {
  const TetMesh& mesh = box();
  const HarmonicExtension harmonic(mesh);
  std::string message = messageOf<InputError>([&] { harmonic.extend(MatX::Zero(5, 2)); });
  EXPECT_NE(message.find("surface_values"), std::string::npos) << message;
  EXPECT_NE(message.find(std::to_string(mesh.num_surface_nodes)), std::string::npos) << message;
  MatX bad = MatX::Zero(mesh.num_surface_nodes, 1);
  bad(3, 0) = std::nan("");
  message = messageOf<InputError>([&] { harmonic.extend(bad); });
  EXPECT_NE(message.find("NaN"), std::string::npos) << message;

  TetMesh inverted = mesh;
  std::swap(inverted.tets(7, 2), inverted.tets(7, 3));
  message = messageOf<InputError>([&] { HarmonicExtension{inverted}; });
  EXPECT_NE(message.find("tet 7"), std::string::npos) << message;
  EXPECT_NE(message.find("volume"), std::string::npos) << message;

  TetMesh unused = mesh;
  unused.nodes.conservativeResize(mesh.numNodes() + 1, 3);
  unused.nodes.row(mesh.numNodes()) = Vec3(0, 0, 0).transpose();
  message = messageOf<InputError>([&] { cotangentLaplacian(unused); });
  EXPECT_NE(message.find("node " + std::to_string(mesh.numNodes())), std::string::npos) << message;

  TetMesh out_of_range = mesh;
  out_of_range.tets(0, 1) = mesh.numNodes() + 4;
  message = messageOf<InputError>([&] { cotangentLaplacian(out_of_range); });
  EXPECT_NE(message.find("tet 0"), std::string::npos) << message;
}

TEST(InteriorFields, BodyFieldsOnAllNodes) {
  const TetMesh& mesh = box();
  const BodyModel body = bodyOnSurface(mesh);
  const HarmonicExtension harmonic(mesh);
  const InteriorFields f = extendBodyFields(mesh, body, harmonic);
  const int V = mesh.num_surface_nodes, N = mesh.numNodes(), K = body.numBetas();
  ASSERT_EQ(f.weights.rows(), N);
  ASSERT_EQ(f.weights.cols(), 24);
  ASSERT_EQ(f.shapedirs.rows(), 3 * N);
  ASSERT_EQ(f.shapedirs.cols(), K);
  ASSERT_EQ(f.posedirs.rows(), 3 * N);
  ASSERT_EQ(f.posedirs.cols(), 207);
  // Surface rows are the body's, bit for bit.
  EXPECT_TRUE((f.weights.topRows(V).array() == body.weights.array()).all());
  EXPECT_TRUE((f.shapedirs.topRows(3 * V).array() == body.shapedirs.array()).all());
  EXPECT_TRUE((f.posedirs.topRows(3 * V).array() == body.posedirs.array()).all());
  // Weights are a partition of unity everywhere.
  EXPECT_GE(f.weights.minCoeff(), 0.0);
  EXPECT_LE((f.weights.rowwise().sum().array() - 1).abs().maxCoeff(), 1e-12);
  EXPECT_GT(f.weights.bottomRows(N - V).maxCoeff(), 0.05);  // interior rows are not empty
  // Row layout: coordinate c of node i at row 3i + c is the harmonic extension of that surface
  // coordinate (checked for one shape and one pose direction).
  for (int c = 0; c < 3; ++c) {
    MatX surface(V, 2);
    for (int i = 0; i < V; ++i) {
      surface(i, 0) = body.shapedirs(3 * i + c, 4);
      surface(i, 1) = body.posedirs(3 * i + c, 100);
    }
    const MatX extended = harmonic.extend(surface);
    for (int i = V; i < N; ++i) {
      EXPECT_NEAR(f.shapedirs(3 * i + c, 4), extended(i, 0), 1e-14);
      EXPECT_NEAR(f.posedirs(3 * i + c, 100), extended(i, 1), 1e-14);
    }
  }
}

TEST(InteriorFields, ShapedNodesAreTheShapedBodyOnTheSurface) {
  const TetMesh& mesh = box();
  const BodyModel body = bodyOnSurface(mesh);
  const InteriorFields f = extendBodyFields(mesh, body, HarmonicExtension(mesh));
  const int V = mesh.num_surface_nodes;
  EXPECT_TRUE(shapedNodes(mesh, f, VecX()) == mesh.nodes);
  for (unsigned seed = 1; seed <= 4; ++seed) {
    const VecX betas = test::randomVector(seed == 4 ? 6 : 10, 2.0, seed);  // one short β
    const MatX3 X = shapedNodes(mesh, f, betas);
    const MatX3 v = shapedVertices(body, betas);
    EXPECT_LE((X.topRows(V) - v).cwiseAbs().maxCoeff(), 1e-12);
    EXPECT_GT((X - mesh.nodes).cwiseAbs().maxCoeff(), 1e-3);  // β moved the nodes
    // Interior rows move with the extended directions: X̄₀ + S β.
    const VecX offsets = f.shapedirs.leftCols(betas.size()) * betas;
    for (int i = V; i < mesh.numNodes(); i += 7)
      for (int c = 0; c < 3; ++c)
        EXPECT_NEAR(X(i, c), mesh.nodes(i, c) + offsets[3 * i + c], 1e-14);
  }
  const std::string message = messageOf<InputError>([&] { shapedNodes(mesh, f, VecX::Zero(11)); });
  EXPECT_NE(message.find("betas has 11"), std::string::npos) << message;
}

TEST(InteriorFields, RejectsAMeshOfAnotherBody) {
  const TetMesh& mesh = box();
  const HarmonicExtension harmonic(mesh);
  const BodyModel other = test::makeRandomModel(mesh.num_surface_nodes + 3, 10, 1);
  std::string message = messageOf<InputError>([&] { extendBodyFields(mesh, other, harmonic); });
  EXPECT_NE(message.find("surface nodes"), std::string::npos) << message;
  BodyModel moved = bodyOnSurface(mesh);
  moved.v_template(5, 1) += 0.01;
  moved.finalize();
  message = messageOf<InputError>([&] { extendBodyFields(mesh, moved, harmonic); });
  EXPECT_NE(message.find("template vertices"), std::string::npos) << message;
  const TetMesh coarser = gridTetMesh({3, 2, 2}, kBoxSize, kBoxOrigin);
  message = messageOf<InputError>(
      [&] { extendBodyFields(mesh, bodyOnSurface(mesh), HarmonicExtension(coarser)); });
  EXPECT_NE(message.find("harmonic extension"), std::string::npos) << message;
}

// -------------------------------------------------------------------------------------------
// Bone nodes

/// Bone flags of the box with a uniform tissue thickness; bone index = largest weight.
VecXi boxBones(const TetMesh& mesh, const MatX3& X, const MatX& weights, double thickness) {
  MatX3 joints(2, 3);
  joints << 0, 0.1, 0.3, 0.1, 0.1, 0.3;
  return selectBoneNodes(mesh, X, weights, joints, {-1, 0},
                         VecX::Constant(mesh.num_surface_nodes, thickness));
}

MatX twoBoneWeights(const MatX3& X) {
  MatX w(X.rows(), 2);
  for (int i = 0; i < X.rows(); ++i) {
    const double s = X(i, 0) > 0.05 ? 0.8 : 0.3;
    w.row(i) << 1 - s, s;
  }
  return w;
}

TEST(BoneNodes, ExactOnABox) {
  const TetMesh mesh = gridTetMesh({8, 6, 7}, kBoxSize, kBoxOrigin);
  const MatX weights = twoBoneWeights(mesh.nodes);
  // Grid depths are multiples of ~0.0333, 0.0357 and 0.0375 m: 0.05 m lies between levels.
  const double thickness = 0.05;
  const VecXi bone = boxBones(mesh, mesh.nodes, weights, thickness);
  // Deep nodes are bone nodes of their dominant bone; of the others, a bone below its anchor
  // quota max(4, ⌈5 %⌉ of the nodes it dominates) takes the ones nearest to its segment
  // (bone 0: the segment to joint 1; bone 1, a leaf: its joint), interior before surface.
  const Vec3 j0(0, 0.1, 0.3), j1(0.1, 0.1, 0.3);
  auto boneDistance = [&](int i, int b) {
    const Vec3 x = mesh.nodes.row(i).transpose();
    if (b == 1) return (x - j1).norm();
    const double t = std::clamp((x - j0).dot(j1 - j0) / (j1 - j0).squaredNorm(), 0.0, 1.0);
    return (x - (j0 + t * (j1 - j0))).norm();
  };
  int deep_count[2] = {0, 0}, dominated[2] = {0, 0}, anchors[2] = {0, 0};
  for (int i = 0; i < mesh.numNodes(); ++i) {
    const int owner = mesh.nodes(i, 0) > 0.05 ? 1 : 0;
    ++dominated[owner];
    const double depth = test::distanceInsideBox(mesh.nodes.row(i), kBoxSize, kBoxOrigin);
    if (i >= mesh.num_surface_nodes && depth > thickness) {
      EXPECT_EQ(bone[i], owner) << "node " << i;
      ++deep_count[owner];
    } else if (bone[i] >= 0) {
      EXPECT_EQ(bone[i], owner) << "node " << i;
      ++anchors[owner];
    }
  }
  for (int b = 0; b < 2; ++b) {
    const int quota = std::max(4, int(std::ceil(0.05 * dominated[b])));
    EXPECT_EQ(anchors[b], std::max(0, quota - deep_count[b])) << "bone " << b;
    // Every anchor is at least as near to the bone as every shallow interior node left soft.
    double farthest_anchor = 0.0, nearest_soft = 1e9;
    for (int i = mesh.num_surface_nodes; i < mesh.numNodes(); ++i) {
      if ((mesh.nodes(i, 0) > 0.05 ? 1 : 0) != b) continue;
      const double depth = test::distanceInsideBox(mesh.nodes.row(i), kBoxSize, kBoxOrigin);
      if (depth > thickness) continue;
      if (bone[i] >= 0) farthest_anchor = std::max(farthest_anchor, boneDistance(i, b));
      else nearest_soft = std::min(nearest_soft, boneDistance(i, b));
    }
    if (anchors[b] > 0) {
      EXPECT_LE(farthest_anchor, nearest_soft) << "bone " << b;
    }
  }
  EXPECT_GT(deep_count[0] + deep_count[1], 10);
  int soft_interior = 0;
  for (int i = mesh.num_surface_nodes; i < mesh.numNodes(); ++i) soft_interior += bone[i] < 0;
  EXPECT_GT(soft_interior, 10);  // some interior nodes stay soft
  // Depths agree with the exact box distance.
  const VecX depth = nodeDepths(mesh, mesh.nodes);
  for (int i = 0; i < mesh.numNodes(); ++i)
    EXPECT_NEAR(depth[i], test::distanceInsideBox(mesh.nodes.row(i), kBoxSize, kBoxOrigin), 1e-14);
}

TEST(BoneNodes, DeterministicAndStableUnderJitter) {
  const TetMesh mesh = gridTetMesh({8, 6, 7}, kBoxSize, kBoxOrigin);
  const MatX weights = twoBoneWeights(mesh.nodes);
  const VecXi bone = boxBones(mesh, mesh.nodes, weights, 0.05);
  EXPECT_TRUE(bone == boxBones(mesh, mesh.nodes, weights, 0.05));
  // Jitter of 0.1 mm (the nearest depth level is > 1 mm away from the threshold): no flips.
  MatX3 jittered = mesh.nodes;
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> uni(-1e-4, 1e-4);
  for (int i = mesh.num_surface_nodes; i < mesh.numNodes(); ++i)
    for (int c = 0; c < 3; ++c) jittered(i, c) += uni(rng);
  EXPECT_TRUE(bone == boxBones(mesh, jittered, weights, 0.05));
}

TEST(BoneNodes, DeeperIsNeverSofterAlongARayIntoTheLimb) {
  const test::Limb limb = test::makeLimb();
  const MaterialModel model = MaterialModel::defaults(10);
  const MatX3 surface = limb.mesh.nodes.topRows(limb.mesh.num_surface_nodes);
  const VecX thickness =
      surfaceTissueThickness(surface, limb.weights.topRows(limb.mesh.num_surface_nodes),
                             limb.joints, limb.parents, model, VecX());
  // Two probes at each place: the grid node and a copy moved a little deeper.
  const VecXi bone = selectBoneNodes(limb.mesh, limb.mesh.nodes, limb.weights, limb.joints,
                                     limb.parents, thickness);
  int bones = 0;
  for (int i = 0; i < limb.mesh.numNodes(); ++i) bones += bone[i] >= 0;
  EXPECT_GT(bones, 0);
  EXPECT_LT(bones, limb.mesh.numNodes() - limb.mesh.num_surface_nodes);
  // Along the ray y = 0 from the side face x = −0.06 to the axis, at mid-height of each bone:
  // once a node is bone, every deeper node is bone.
  for (double z : {0.1, 0.3}) {
    std::vector<std::pair<double, int>> ray;  // (depth, bone flag)
    for (int i = limb.mesh.num_surface_nodes; i < limb.mesh.numNodes(); ++i)
      if (std::abs(limb.mesh.nodes(i, 1)) < 1e-9 && std::abs(limb.mesh.nodes(i, 2) - z) < 1e-9 &&
          limb.mesh.nodes(i, 0) <= 0)
        ray.emplace_back(limb.mesh.nodes(i, 0) + 0.06, bone[i]);
    ASSERT_GE(ray.size(), 3u);
    std::sort(ray.begin(), ray.end());
    bool seen_bone = false;
    for (const auto& [depth, b] : ray) {
      if (seen_bone) {
        EXPECT_GE(b, 0) << "depth " << depth << " at z = " << z;
      }
      seen_bone = seen_bone || b >= 0;
    }
    EXPECT_TRUE(seen_bone) << "z = " << z;
    EXPECT_LT(ray.front().second, 0) << "the shallowest node is soft";
  }
}

TEST(BoneNodes, StableUnderASmallShapeChange) {
  const test::Limb limb = test::makeLimb();
  const MaterialModel model = MaterialModel::defaults(10);
  const int V = limb.mesh.num_surface_nodes;
  auto bonesAt = [&](const VecX& betas) {
    const VecX thickness =
        surfaceTissueThickness(limb.mesh.nodes.topRows(V), limb.weights.topRows(V), limb.joints,
                               limb.parents, model, betas);
    return selectBoneNodes(limb.mesh, limb.mesh.nodes, limb.weights, limb.joints, limb.parents,
                           thickness);
  };
  VecX betas = VecX::Zero(10);
  const VecXi before = bonesAt(betas);
  betas[1] = 0.02;  // 0.1 % thicker tissue
  const VecXi after = bonesAt(betas);
  int flips = 0;
  for (int i = 0; i < limb.mesh.numNodes(); ++i) flips += (before[i] >= 0) != (after[i] >= 0);
  EXPECT_LE(flips, (limb.mesh.numNodes() - V) / 50) << "flips of " << limb.mesh.numNodes() - V;
  // A large change does move the boundary (the test can fail): thinner tissue, more bone
  // nodes. (Thicker tissue would soon hit the anchor quota of each bone instead.)
  betas[1] = -3.0;
  const VecXi lean = bonesAt(betas);
  int lean_bones = 0, bones = 0;
  for (int i = 0; i < limb.mesh.numNodes(); ++i)
    lean_bones += lean[i] >= 0, bones += before[i] >= 0;
  EXPECT_GT(lean_bones, bones);
}

TEST(BoneNodes, RejectsBadInput) {
  const TetMesh& mesh = box();
  const MatX weights = twoBoneWeights(mesh.nodes);
  MatX3 joints(2, 3);
  joints.setZero();
  std::string message = messageOf<InputError>([&] {
    selectBoneNodes(mesh, mesh.nodes, weights, joints, {-1, 0},
                    VecX::Constant(mesh.num_surface_nodes - 1, 0.01));
  });
  EXPECT_NE(message.find("surface_tissue_thickness"), std::string::npos) << message;
  message = messageOf<InputError>([&] {
    selectBoneNodes(mesh, mesh.nodes, weights.leftCols(1), joints, {-1, 0},
                    VecX::Constant(mesh.num_surface_nodes, 0.01));
  });
  EXPECT_NE(message.find("weights has shape"), std::string::npos) << message;
  message = messageOf<InputError>([&] {
    selectBoneNodes(mesh, mesh.nodes, weights, joints, {-1, 0},
                    VecX::Constant(mesh.num_surface_nodes, -0.01));
  });
  EXPECT_NE(message.find("negative"), std::string::npos) << message;
  message = messageOf<InputError>([&] {
    selectBoneNodes(mesh, mesh.nodes.topRows(10), weights, joints, {-1, 0},
                    VecX::Constant(mesh.num_surface_nodes, 0.01));
  });
  EXPECT_NE(message.find("nodes have 10 rows"), std::string::npos) << message;
}

}  // namespace
}  // namespace flsh
