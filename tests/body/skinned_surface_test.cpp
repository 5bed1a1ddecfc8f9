// The skinned surface's data (body/skinned_surface.h): the sparse weights are the dense
// weights' nonzero entries, the dominated vertices partition the surface, the clusters
// partition each bone's vertices into small contiguous ranges, and every bound contains its
// vertices (what the broad phases rely on to skip only vertices that cannot touch).
#include "flsh/body/skinned_surface.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <vector>

#include "flsh/body/synthetic_body.h"
#include "flsh/core/error.h"
#include "support/test_support.h"

namespace flsh {
namespace {

constexpr int kClusterVertices = 20;

struct Surface {
  BodyModel body;
  MatX3 J;
  SkinnedSurface surface;
};

const Surface& surface() {
  static const Surface s = [] {
    Surface out;
    SyntheticBodyOptions options;
    options.vertices = 600;
    out.body = makeSyntheticBody(options);
    out.J = MatX3(out.body.J_regressor * out.body.v_template);
    out.surface =
        SkinnedSurface::build(out.body.weights, out.body.v_template, out.J, kClusterVertices);
    return out;
  }();
  return s;
}

TEST(SkinnedSurface, SparseWeightsAreTheNonzeroDenseWeights) {
  const Surface& s = surface();
  const MatX& W = s.body.weights;
  const SparseSkinWeights& w = s.surface.weights;
  ASSERT_EQ(w.numVertices(), W.rows());
  ASSERT_GT(w.entries.size(), size_t(W.rows()));  // some vertices have several bones
  MatX rebuilt = MatX::Zero(W.rows(), W.cols());
  for (int i = 0; i < W.rows(); ++i)
    for (int k = w.start[i]; k < w.start[i + 1]; ++k) {
      EXPECT_NE(w.entries[k].weight, 0.0);
      if (k > w.start[i]) {
        EXPECT_LT(w.entries[k - 1].bone, w.entries[k].bone);
      }
      rebuilt(i, w.entries[k].bone) = w.entries[k].weight;
    }
  EXPECT_EQ(rebuilt, W);
}

TEST(SkinnedSurface, ClustersPartitionEachBonesDominatedVertices) {
  const Surface& s = surface();
  const SkinnedSurface& ss = s.surface;
  const MatX& W = s.body.weights;
  ASSERT_EQ(ss.numBones(), W.cols());
  ASSERT_EQ(ss.bone_clusters.size(), size_t(W.cols()) + 1);
  std::vector<int> owner(size_t(W.rows()), -1);
  for (int b = 0; b < ss.numBones(); ++b)
    for (int i : ss.dominated[b]) {
      EXPECT_EQ(owner[i], -1) << "vertex " << i << " in two bones";
      owner[i] = b;
      Eigen::Index best;
      W.row(i).maxCoeff(&best);
      EXPECT_EQ(b, best) << "vertex " << i;
    }
  EXPECT_EQ(std::count(owner.begin(), owner.end(), -1), 0);
  int split_bones = 0;
  for (int b = 0; b < ss.numBones(); ++b) {
    std::vector<char> covered(ss.dominated[b].size(), 0);
    for (int k = ss.bone_clusters[b]; k < ss.bone_clusters[b + 1]; ++k) {
      const SkinnedSurface::Cluster& c = ss.clusters[k];
      EXPECT_EQ(c.bone, b);
      EXPECT_GT(c.end, c.begin);
      EXPECT_LE(c.end - c.begin, kClusterVertices);
      EXPECT_EQ(ss.clusterEnd(k) - ss.clusterBegin(k), c.end - c.begin);
      for (int j = c.begin; j < c.end; ++j) {
        EXPECT_EQ(covered[j], 0);
        covered[j] = 1;
      }
    }
    EXPECT_EQ(std::count(covered.begin(), covered.end(), 0), 0) << "bone " << b;
    split_bones += ss.bone_clusters[b + 1] - ss.bone_clusters[b] > 1;
  }
  EXPECT_GT(split_bones, 0);  // some bones dominate more than kClusterVertices vertices
}

// Every vertex of a set lies within its bound: |X − J_b − centre| ≤ radius, |X − J_b| ≤
// extent, and for each other bone c that moves one of them, w_ic ≤ its weight and |X − J_c| ≤
// its extent over the whole set (checked as equalities with the maxima, so a bound that is
// too small or needlessly large fails).
void expectBoundHolds(const Surface& s, int b, const int* first, const int* last,
                      const SurfaceBound& bound) {
  const MatX3& X = s.body.v_template;
  const SparseSkinWeights& w = s.surface.weights;
  double radius = 0.0, extent = 0.0;
  std::vector<double> weight(size_t(s.J.rows()), 0.0), co_extent(size_t(s.J.rows()), 0.0);
  for (const int* i = first; i != last; ++i) {
    const Vec3 offset = (X.row(*i) - s.J.row(b)).transpose();
    radius = std::max(radius, (offset - bound.center).norm());
    extent = std::max(extent, offset.norm());
    for (int k = w.start[*i]; k < w.start[*i + 1]; ++k)
      if (w.entries[k].bone != b)
        weight[w.entries[k].bone] = std::max(weight[w.entries[k].bone], w.entries[k].weight);
    for (int c = 0; c < int(s.J.rows()); ++c)  // over the whole set (a conservative extent)
      co_extent[c] = std::max(co_extent[c], (X.row(*i) - s.J.row(c)).norm());
  }
  EXPECT_DOUBLE_EQ(bound.radius, radius);
  EXPECT_DOUBLE_EQ(bound.extent, extent);
  size_t expected_co = 0;
  for (double v : weight) expected_co += v > 0.0;
  ASSERT_EQ(bound.co.size(), expected_co);
  for (const SurfaceBound::CoInfluence& co : bound.co) {
    EXPECT_EQ(co.weight, weight[co.bone]);
    EXPECT_DOUBLE_EQ(co.extent, co_extent[co.bone]);
  }
}

TEST(SkinnedSurface, BoundsContainTheirVertices) {
  const Surface& s = surface();
  const SkinnedSurface& ss = s.surface;
  int with_co = 0;
  for (int b = 0; b < ss.numBones(); ++b) {
    const std::vector<int>& v = ss.dominated[b];
    expectBoundHolds(s, b, v.data(), v.data() + v.size(), ss.bone_bound[b]);
    with_co += !ss.bone_bound[b].co.empty();
  }
  EXPECT_GT(with_co, 0);
  for (int k = 0; k < int(ss.clusters.size()); ++k)
    expectBoundHolds(s, ss.clusters[k].bone, ss.clusterBegin(k), ss.clusterEnd(k),
                     ss.clusters[k].bound);
}

TEST(SkinnedSurface, MismatchedSizesAreInputErrors) {
  const Surface& s = surface();
  const std::string msg = test::messageOf<InputError>(
      [&] { SkinnedSurface::build(s.body.weights, MatX3(s.body.v_template.topRows(10)), s.J, 8); });
  EXPECT_NE(msg.find("rest vertices are (10, 3)"), std::string::npos) << msg;
  EXPECT_NE(test::messageOf<InputError>([&] {
              SkinnedSurface::build(s.body.weights, s.body.v_template, s.J, 0);
            }).find("cluster_vertices = 0, expected >= 1"),
            std::string::npos);
}

}  // namespace
}  // namespace flsh
