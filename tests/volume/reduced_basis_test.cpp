// Farthest-point handles and bounded biharmonic weights (reduced_basis.h).
#include "flsh/volume/reduced_basis.h"

#include <gtest/gtest.h>

#include <Eigen/SparseCholesky>
#include <algorithm>
#include <memory>
#include <set>

#include "flsh/body/synthetic_body.h"
#include "flsh/core/error.h"
#include "flsh/volume/volume_fields.h"
#include "flsh/volume/volumetric_data.h"
#include "support/test_support.h"

namespace flsh {
namespace {

/// The 600-vertex synthetic body's volumetric data at β = 0 (built once per binary).
const VolumetricData& smallVolume() {
  static const VolumetricData data = [] {
    const BodyModel body = makeSyntheticBody({600, 1.70});
    VolumetricSettings settings;
    settings.cache_dir = test::freshTempDir("reduced_basis_cache");
    return buildVolumetricData(body, VecX::Zero(10), settings);
  }();
  return data;
}

const BodyModel& smallBody() {
  static const BodyModel body = makeSyntheticBody({600, 1.70});
  return body;
}

constexpr int kHandles = 12;
constexpr double kTightTolerance = 1e-10;

struct SmallBasis {
  VecXi handles;
  BoundedBiharmonicWeights result;
};

const SmallBasis& smallBasis() {
  static const SmallBasis basis = [] {
    const VolumetricData& data = smallVolume();
    SmallBasis b;
    const int V = smallBody().numVertices();
    b.handles = farthestPointSurfaceHandles(data.rest_nodes.topRows(V), smallBody().faces, kHandles,
                                            0, data.bone_of_node.head(V));
    BoundedBiharmonicOptions options;
    options.kkt_tolerance = kTightTolerance;
    b.result = computeBoundedBiharmonicWeights(data.templ->mesh, data.rest_nodes, b.handles,
                                               data.bone_of_node, options);
    return b;
  }();
  return basis;
}

/// Q = L M⁻¹ L built here from the stiffness matrix and tet volumes, independently of the library's
/// biharmonicEnergyMatrix.
SpMat independentBiharmonic(const TetMesh& mesh, const MatX3& nodes) {
  TetMesh at = mesh;
  at.nodes = nodes;
  const SpMat L = cotangentLaplacian(at);
  const VecX volumes = tetVolumes(at);
  VecX mass = VecX::Zero(at.numNodes());
  for (int t = 0; t < at.numTets(); ++t)
    for (int k = 0; k < 4; ++k) mass[at.tets(t, k)] += volumes[t] / 4;
  SpMat Minv(at.numNodes(), at.numNodes());
  Minv.reserve(VecXi::Ones(at.numNodes()));
  for (int i = 0; i < at.numNodes(); ++i) Minv.insert(i, i) = 1 / mass[i];
  return SpMat(L * Minv * L);
}

double energy(const SpMat& Q, const VecX& phi) { return phi.dot(Q * phi); }

// ---------------------------------------------------------------------------------------------
// Farthest-point sampling

TEST(FarthestPointHandles, EuclideanPicksTheFarthestVertexEachTime) {
  MatX3 points(6, 3);
  points << 0, 0, 0,  //
      1, 0, 0,        //
      5, 0, 0,        //
      2, 0, 0,        //
      5, 4, 0,        //
      0.5, 0, 0;
  const VecXi handles = farthestPointSurfaceHandles(points, 4, 0);
  // From the origin the farthest is (5,4) (√41); then (5,0) at min(5, 4) = 4, ahead of (2,0) at
  // min(2, 5) = 2; then (2,0) at min(2, 3, 5) = 2.
  EXPECT_EQ(handles, (VecXi(4) << 0, 4, 2, 3).finished());
}

TEST(FarthestPointHandles, CoveringRadiusNeverGrowsAndHandlesAreDistinct) {
  const BodyModel& body = smallBody();
  for (bool geodesic : {false, true}) {
    const VecXi handles = geodesic ? farthestPointSurfaceHandles(body.v_template, body.faces, 40, 7)
                                   : farthestPointSurfaceHandles(body.v_template, 40, 7);
    ASSERT_EQ(handles.size(), 40);
    EXPECT_EQ(handles[0], 7);
    const std::set<int> distinct(handles.data(), handles.data() + handles.size());
    EXPECT_EQ(distinct.size(), 40u);
    // Euclidean check of the sampling's defining property on the Euclidean variant: the k-th
    // pick's distance to the previous picks is the largest such distance and does not grow.
    if (geodesic) continue;
    double previous = std::numeric_limits<double>::infinity();
    for (int k = 1; k < 40; ++k) {
      auto distanceToChosen = [&](int v) {
        double d = std::numeric_limits<double>::infinity();
        for (int j = 0; j < k; ++j)
          d = std::min(d, (body.v_template.row(v) - body.v_template.row(handles[j])).norm());
        return d;
      };
      const double picked = distanceToChosen(handles[k]);
      for (int v = 0; v < body.v_template.rows(); ++v) ASSERT_LE(distanceToChosen(v), picked);
      EXPECT_LE(picked, previous);
      previous = picked;
    }
  }
}

TEST(FarthestPointHandles, GeodesicDiffersFromEuclideanAcrossCloseSheets) {
  // Two parallel chains 0.1 apart joined near one end: along the graph the start of the second
  // chain is the farthest point from the start of the first, not the straight-line farthest.
  MatX3 V(8, 3);
  V << 0, 0, 0, 1, 0, 0, 2, 0, 0, 3, 0, 0,  //
      0, 0.1, 0, 1, 0.1, 0, 2, 0.1, 0, 3, 0.1, 0;
  MatX3i F(2, 3);
  F << 3, 7, 2, 2, 7, 6;  // joins the strips at x = 3 (and x = 2)
  MatX3i edges(6, 3);     // degenerate "faces" along each strip give the chain edges
  edges << 0, 1, 1, 1, 2, 2, 2, 3, 3, 4, 5, 5, 5, 6, 6, 6, 7, 7;
  MatX3i all(F.rows() + edges.rows(), 3);
  all << F, edges;
  const VecXi euclidean = farthestPointSurfaceHandles(V, 2, 0);
  const VecXi geodesic = farthestPointSurfaceHandles(V, all, 2, 0);
  EXPECT_EQ(euclidean[1], 7);  // (3, 0.1): straight-line farthest
  EXPECT_EQ(geodesic[1], 4);   // (0, 0.1): 2 + 0.1 + 2 along the strips
}

TEST(FarthestPointHandles, BoneAttachedVerticesAreNeverChosen) {
  const VolumetricData& data = smallVolume();
  const int V = smallBody().numVertices();
  const VecXi bones = data.bone_of_node.head(V);
  const int attached = int((bones.array() >= 0).count());
  ASSERT_GT(attached, 0) << "the small body anchors some surface nodes (hands) to bones";
  for (bool geodesic : {false, true}) {
    const int count = V - attached;  // every eligible vertex
    const VecXi handles =
        geodesic ? farthestPointSurfaceHandles(data.rest_nodes.topRows(V), smallBody().faces, count,
                                               0, bones)
                 : farthestPointSurfaceHandles(data.rest_nodes.topRows(V), count, 0, bones);
    for (int k = 0; k < count; ++k) ASSERT_LT(bones[handles[k]], 0) << "handle " << k;
    EXPECT_NE(test::messageOf<InputError>([&] {
                farthestPointSurfaceHandles(data.rest_nodes.topRows(V), count + 1, 0, bones);
              }).find("count = " + std::to_string(count + 1)),
              std::string::npos);
  }
  int attached_vertex = 0;
  while (bones[attached_vertex] < 0) ++attached_vertex;
  EXPECT_NE(test::messageOf<InputError>([&] {
              farthestPointSurfaceHandles(data.rest_nodes.topRows(V), 3, attached_vertex, bones);
            }).find("is attached to a bone"),
            std::string::npos);
  EXPECT_NE(test::messageOf<InputError>([&] {
              farthestPointSurfaceHandles(data.rest_nodes.topRows(V), 3, 0, bones.head(7));
            }).find("bone_of_vertex has 7 entries"),
            std::string::npos);
}

TEST(FarthestPointHandles, RejectsBadArguments) {
  const BodyModel& body = smallBody();
  const int V = int(body.v_template.rows());
  EXPECT_NE(test::messageOf<InputError>([&] {
              farthestPointSurfaceHandles(body.v_template, 0);
            }).find("count = 0"),
            std::string::npos);
  EXPECT_NE(test::messageOf<InputError>([&] {
              farthestPointSurfaceHandles(body.v_template, V + 1);
            }).find("count = " + std::to_string(V + 1)),
            std::string::npos);
  EXPECT_NE(test::messageOf<InputError>([&] {
              farthestPointSurfaceHandles(body.v_template, 3, V);
            }).find("first"),
            std::string::npos);
  MatX3i bad = body.faces;
  bad(4, 1) = V;
  EXPECT_NE(test::messageOf<InputError>([&] {
              farthestPointSurfaceHandles(body.v_template, bad, 3, 0);
            }).find("surface_faces row 4"),
            std::string::npos);
  MatX3 two_islands(4, 3);
  two_islands << 0, 0, 0, 1, 0, 0, 0, 1, 0, 5, 5, 5;
  MatX3i one_face(1, 3);
  one_face << 0, 1, 2;
  EXPECT_NE(test::messageOf<InputError>([&] {
              farthestPointSurfaceHandles(two_islands, one_face, 2, 0);
            }).find("vertex 3 is not connected"),
            std::string::npos);
}

// ---------------------------------------------------------------------------------------------
// Bounded biharmonic weights

TEST(BoundedBiharmonicWeights, ConstraintsHoldExactly) {
  const VolumetricData& data = smallVolume();
  const SmallBasis& basis = smallBasis();
  const MatX& W = basis.result.weights;
  ASSERT_GT(data.numBoneNodes(), 0);
  ASSERT_EQ(W.rows(), data.numNodes());
  ASSERT_EQ(W.cols(), kHandles);
  for (int h = 0; h < kHandles; ++h) {
    for (int k = 0; k < kHandles; ++k) EXPECT_EQ(W(basis.handles[k], h), k == h ? 1.0 : 0.0);
    for (int i = 0; i < data.numNodes(); ++i) {
      if (data.bone_of_node[i] >= 0) {
        ASSERT_EQ(W(i, h), 0.0) << "bone node " << i;
      }
    }
  }
  EXPECT_EQ(basis.result.report.max_constraint_error, 0.0);
}

TEST(BoundedBiharmonicWeights, BoundsHoldAndTheReportSaysSo) {
  const SmallBasis& basis = smallBasis();
  const BoundedBiharmonicReport& report = basis.result.report;
  EXPECT_GE(basis.result.weights.minCoeff(), -1e-8);
  EXPECT_LE(basis.result.weights.maxCoeff(), 1 + 1e-8);
  EXPECT_LE(report.max_bound_violation, 1e-8);
  EXPECT_TRUE(report.converged);
  EXPECT_LE(report.max_kkt_residual, kTightTolerance);
  ASSERT_EQ(report.iterations.size(), kHandles);
  EXPECT_GE(report.iterations.minCoeff(), 1);
  for (int h = 0; h < kHandles; ++h) EXPECT_GT(report.support_size[h], 0);
  // No renormalization: with zero data on bone nodes the interior weights fade below 1.
  const VecX sums = basis.result.weights.rowwise().sum();
  EXPECT_LT(sums.minCoeff(), 0.5);
}

TEST(BoundedBiharmonicWeights, KktConditionsHoldForAnIndependentlyBuiltEnergy) {
  const VolumetricData& data = smallVolume();
  const SmallBasis& basis = smallBasis();
  const SpMat Q = independentBiharmonic(data.templ->mesh, data.rest_nodes);
  for (int h : {0, kHandles / 2, kHandles - 1}) {
    const VecX phi = basis.result.weights.col(h);
    const VecX g = Q * phi;  // gradient of ½ φᵀQφ
    double scale = 0;
    for (SpMat::InnerIterator it(Q, basis.handles[h]); it; ++it)
      scale = std::max(scale, std::abs(it.value()));
    const double tol = 1e-8 * scale;  // the solve's tolerance plus rounding of the check
    std::set<int> fixed(basis.handles.data(), basis.handles.data() + kHandles);
    int free_count = 0, lower_count = 0, strictly_positive_multipliers = 0;
    for (int i = 0; i < data.numNodes(); ++i) {
      if (fixed.count(i) || data.bone_of_node[i] >= 0) continue;
      if (phi[i] > 0 && phi[i] < 1) {
        ++free_count;
        ASSERT_LE(std::abs(g[i]), tol) << "free node " << i << " of handle " << h;
      } else if (phi[i] == 0) {
        ++lower_count;
        ASSERT_GE(g[i], -tol) << "multiplier of the bound 0 at node " << i;
        if (g[i] > 100 * tol) ++strictly_positive_multipliers;
      } else {
        ASSERT_EQ(phi[i], 1.0);
        ASSERT_LE(g[i], tol) << "multiplier of the bound 1 at node " << i;
      }
    }
    // The bounds matter: many free nodes and many bounds held by a strictly positive multiplier.
    EXPECT_GT(free_count, 10);
    EXPECT_GT(lower_count, 10);
    EXPECT_GT(strictly_positive_multipliers, 0);
  }
}

TEST(BoundedBiharmonicWeights, NoFeasiblePerturbationHasLowerEnergy) {
  const VolumetricData& data = smallVolume();
  const SmallBasis& basis = smallBasis();
  const SpMat Q = independentBiharmonic(data.templ->mesh, data.rest_nodes);
  const int n = data.numNodes();
  std::vector<char> fixed(n, 0);
  for (int i = 0; i < n; ++i) fixed[i] = data.bone_of_node[i] >= 0;
  for (int k = 0; k < kHandles; ++k) fixed[basis.handles[k]] = 1;
  std::vector<int> free_nodes;
  for (int i = 0; i < n; ++i)
    if (!fixed[i]) free_nodes.push_back(i);
  const int m = int(free_nodes.size());
  std::vector<int> position(n, -1);
  for (int k = 0; k < m; ++k) position[free_nodes[k]] = k;
  std::vector<Triplet> triplets;
  for (int j = 0; j < Q.outerSize(); ++j)
    for (SpMat::InnerIterator it(Q, j); it; ++it)
      if (position[it.row()] >= 0 && position[j] >= 0)
        triplets.emplace_back(position[it.row()], position[j], it.value());
  SpMat Qff(m, m);
  Qff.setFromTriplets(triplets.begin(), triplets.end());
  const Eigen::SimplicialLDLT<SpMat> unconstrained_solver(Qff);
  ASSERT_EQ(unconstrained_solver.info(), Eigen::Success);

  for (int h : {0, 5}) {
    const VecX phi = basis.result.weights.col(h);
    const double optimum = energy(Q, phi);
    ASSERT_GT(optimum, 0);
    // The unconstrained (equality-only) minimizer violates the bounds; clamped, it is feasible
    // but has a higher energy.
    VecX e_h = VecX::Zero(n);
    e_h[basis.handles[h]] = 1;
    const VecX coupling = Q * e_h;
    VecX rhs(m);
    for (int k = 0; k < m; ++k) rhs[k] = -coupling[free_nodes[k]];
    const VecX free_values = unconstrained_solver.solve(rhs);
    VecX unconstrained = e_h;
    for (int k = 0; k < m; ++k) unconstrained[free_nodes[k]] = free_values[k];
    EXPECT_LT(unconstrained.minCoeff(), -1e-3) << "the bounds are active";
    EXPECT_LT(energy(Q, unconstrained), optimum);  // the bounds cost energy
    const VecX clamped = unconstrained.cwiseMax(0.0).cwiseMin(1.0);
    EXPECT_GT(energy(Q, clamped), optimum * (1 + 1e-6));
    // Random feasible perturbations (projected onto the box, constraints kept) never go lower.
    for (unsigned seed = 1; seed <= 6; ++seed) {
      const double size = seed <= 3 ? 1e-2 : 1e-5;
      const VecX noise = test::randomVector(n, size, seed);
      VecX perturbed = phi;
      for (int i : free_nodes) perturbed[i] = std::clamp(phi[i] + noise[i], 0.0, 1.0);
      EXPECT_GE(energy(Q, perturbed), optimum * (1 - 1e-12)) << "seed " << seed;
    }
  }
}

TEST(BoundedBiharmonicWeights, DeterministicAcrossThreadCounts) {
  const VolumetricData& data = smallVolume();
  const SmallBasis& basis = smallBasis();
  for (int threads : {1, 2}) {
    BoundedBiharmonicOptions options;
    options.kkt_tolerance = kTightTolerance;
    options.threads = threads;
    const BoundedBiharmonicWeights again = computeBoundedBiharmonicWeights(
        data.templ->mesh, data.rest_nodes, basis.handles, data.bone_of_node, options);
    EXPECT_EQ(again.weights, basis.result.weights) << threads << " threads";
    EXPECT_EQ(again.report.iterations, basis.result.report.iterations);
  }
}

TEST(BoundedBiharmonicWeights, LooserToleranceStaysCloseAndFeasible) {
  const VolumetricData& data = smallVolume();
  const SmallBasis& basis = smallBasis();
  const BoundedBiharmonicWeights loose = computeBoundedBiharmonicWeights(
      data.templ->mesh, data.rest_nodes, basis.handles, data.bone_of_node);
  EXPECT_TRUE(loose.report.converged);
  EXPECT_EQ(loose.report.max_bound_violation, 0.0);
  EXPECT_LE((loose.weights - basis.result.weights).cwiseAbs().maxCoeff(), 1e-3);
}

TEST(BoundedBiharmonicWeights, BiharmonicEnergyMatrixMatchesIndependentBuild) {
  const VolumetricData& data = smallVolume();
  const SpMat Q = biharmonicEnergyMatrix(data.templ->mesh, data.rest_nodes);
  const SpMat reference = independentBiharmonic(data.templ->mesh, data.rest_nodes);
  ASSERT_GT(reference.norm(), 0);
  EXPECT_LE((Q - reference).norm(), 1e-12 * reference.norm());
  EXPECT_EQ((Q - SpMat(Q.transpose())).norm(), 0.0);
  // Constants are in the kernel (L has zero row sums).
  EXPECT_LE((Q * VecX::Ones(Q.rows())).cwiseAbs().maxCoeff(), 1e-9 * reference.norm());
}

TEST(BoundedBiharmonicWeights, RejectsBadArguments) {
  const VolumetricData& data = smallVolume();
  const TetMesh& mesh = data.templ->mesh;
  const VecXi& bones = data.bone_of_node;
  int bone_node = -1;
  for (int i = 0; i < bones.size() && bone_node < 0; ++i)
    if (bones[i] >= 0) bone_node = i;
  ASSERT_GE(bone_node, 0);
  auto message = [&](const VecXi& handles, const VecXi& bone_of_node, const MatX3& nodes) {
    return test::messageOf<InputError>(
        [&] { computeBoundedBiharmonicWeights(mesh, nodes, handles, bone_of_node); });
  };
  const MatX3& X = data.rest_nodes;
  EXPECT_NE(message((VecXi(2) << 3, 3).finished(), bones, X).find("is repeated"),
            std::string::npos);
  EXPECT_NE(message((VecXi(1) << bone_node).finished(), bones, X).find("is a bone node"),
            std::string::npos);
  EXPECT_NE(message((VecXi(1) << data.numNodes()).finished(), bones, X).find("handles[0]"),
            std::string::npos);
  EXPECT_NE(message(VecXi(0), bones, X).find("handles is empty"), std::string::npos);
  EXPECT_NE(message((VecXi(1) << 3).finished(), bones.head(5), X).find("bone_of_node has 5"),
            std::string::npos);
  VecXi bad_bones = bones;
  bad_bones[2] = -4;
  EXPECT_NE(message((VecXi(1) << 3).finished(), bad_bones, X).find("bone_of_node[2] = -4"),
            std::string::npos);
  EXPECT_NE(message((VecXi(1) << 3).finished(), bones, X.topRows(10)).find("rows"),
            std::string::npos);
}

}  // namespace
}  // namespace flsh
