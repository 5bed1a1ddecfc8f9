#include "flsh/body/skinned_surface.h"

#include <algorithm>
#include <string>
#include <utility>

#include "flsh/core/error.h"

namespace flsh {

SparseSkinWeights SparseSkinWeights::fromDense(const MatX& weights) {
  SparseSkinWeights s;
  const int nv = int(weights.rows());
  s.start.assign(size_t(nv) + 1, 0);
  for (int i = 0; i < nv; ++i) {
    for (int b = 0; b < int(weights.cols()); ++b)
      if (weights(i, b) != 0.0) s.entries.push_back({b, weights(i, b)});
    s.start[size_t(i) + 1] = int(s.entries.size());
  }
  return s;
}

namespace {

// The bound of the vertices [first, last) on bone b.
SurfaceBound restBound(const SparseSkinWeights& w, const MatX3& X, const MatX3& J, int b,
                       const int* first, const int* last) {
  SurfaceBound bound;
  if (first == last) return bound;
  const auto offset = [&](int i) -> Vec3 { return (X.row(i) - J.row(b)).transpose(); };
  Vec3 lo = Vec3::Constant(1e300), hi = Vec3::Constant(-1e300);
  for (const int* i = first; i != last; ++i) {
    lo = lo.cwiseMin(offset(*i));
    hi = hi.cwiseMax(offset(*i));
  }
  bound.center = 0.5 * (lo + hi);
  const int bones = int(J.rows());
  std::vector<double> coweight(size_t(bones), 0.0);
  for (const int* i = first; i != last; ++i) {
    bound.radius = std::max(bound.radius, (offset(*i) - bound.center).norm());
    bound.extent = std::max(bound.extent, offset(*i).norm());
    for (int k = w.start[*i]; k < w.start[*i + 1]; ++k) {
      const SparseSkinWeights::Influence& in = w.entries[size_t(k)];
      if (in.bone != b) coweight[size_t(in.bone)] = std::max(coweight[size_t(in.bone)], in.weight);
    }
  }
  for (int c = 0; c < bones; ++c) {
    if (!(coweight[size_t(c)] > 0.0)) continue;
    double extent = 0.0;
    for (const int* i = first; i != last; ++i)
      extent = std::max(extent, (X.row(*i) - J.row(c)).norm());
    bound.co.push_back({c, coweight[size_t(c)], extent});
  }
  return bound;
}

}  // namespace

SkinnedSurface SkinnedSurface::build(const MatX& weights, const MatX3& X, const MatX3& J,
                                     int cluster_vertices) {
  const int nv = int(weights.rows()), bones = int(weights.cols());
  if (X.rows() != nv || J.rows() != bones)
    throw InputError("SkinnedSurface::build: weights are " + shapeString({long(nv), long(bones)}) +
                     " but the rest vertices are " + shapeString({long(X.rows()), 3}) +
                     " and the rest joints " + shapeString({long(J.rows()), 3}) +
                     " (expected #V × 3 and #bones × 3)");
  if (cluster_vertices < 1)
    throw InputError("SkinnedSurface::build: cluster_vertices = " +
                     std::to_string(cluster_vertices) + ", expected >= 1");
  SkinnedSurface s;
  s.weights = SparseSkinWeights::fromDense(weights);
  s.dominated.assign(size_t(bones), {});
  for (int i = 0; i < nv; ++i) {
    int best = 0;
    for (int b = 1; b < bones; ++b)
      if (weights(i, b) > weights(i, best)) best = b;
    s.dominated[size_t(best)].push_back(i);
  }
  s.bone_bound.reserve(size_t(bones));
  s.bone_clusters.assign(1, 0);
  for (int b = 0; b < bones; ++b) {
    std::vector<int>& verts = s.dominated[size_t(b)];
    s.bone_bound.push_back(
        restBound(s.weights, X, J, b, verts.data(), verts.data() + verts.size()));
    // Pieces are split (median along the longest side of their rest box) until small; the
    // leaves are the clusters, in the order they come off the stack.
    std::vector<std::pair<int, int>> pending;
    if (!verts.empty()) pending.emplace_back(0, int(verts.size()));
    while (!pending.empty()) {
      const auto [begin, end] = pending.back();
      pending.pop_back();
      if (end - begin <= cluster_vertices) {
        s.clusters.push_back(
            {b, begin, end,
             restBound(s.weights, X, J, b, verts.data() + begin, verts.data() + end)});
        continue;
      }
      Vec3 lo = Vec3::Constant(1e300), hi = Vec3::Constant(-1e300);
      for (int k = begin; k < end; ++k) {
        const Vec3 p = (X.row(verts[size_t(k)]) - J.row(b)).transpose();
        lo = lo.cwiseMin(p);
        hi = hi.cwiseMax(p);
      }
      int axis = 0;
      (hi - lo).maxCoeff(&axis);
      const int mid = (begin + end) / 2;
      std::nth_element(verts.begin() + begin, verts.begin() + mid, verts.begin() + end,
                       [&](int i, int j) { return X(i, axis) < X(j, axis); });
      pending.emplace_back(begin, mid);
      pending.emplace_back(mid, end);
    }
    s.bone_clusters.push_back(int(s.clusters.size()));
  }
  return s;
}

}  // namespace flsh
