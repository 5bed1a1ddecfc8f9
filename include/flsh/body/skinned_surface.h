// The skinned surface's fixed data, built once by one function for every part that skins or
// searches the surface: the nonzero skinning weights per vertex, each bone's dominated vertices
// (those whose largest weight is the bone's) split into spatial clusters, and rest-frame bounds
// of every such set for a broad phase. The body skins with the weights; the simulable's
// collider contact and the scene's avatar–avatar contact prune with the bounds.
//
// The bounds are taken in each bone's rest frame about its joint (offsets X_i − J_b). A broad
// phase poses them: a vertex x_i = x_ib + Σ_{c≠b} w_ic (x_ic − x_ib) (x_ib its rigid position
// on its dominant bone b) is off its rigid position by at most Σ_c W_bc (‖R_c − R_b‖₂ e_b +
// |R_c (J_b − J_c) + t_c − t_b|), with W_bc the largest w_ic over the set and e_b its extent
// (or the same with the set's extent about J_c and R_b, whichever is smaller).
#pragma once

#include <vector>

#include "flsh/core/types.h"

namespace flsh {

/// Skinning weights as (bone, weight) lists per vertex, the nonzero entries only.
struct SparseSkinWeights {
  struct Influence {
    int bone;
    double weight;
  };
  std::vector<int> start;  ///< #V + 1: vertex i's influences are [start[i], start[i + 1])
  std::vector<Influence> entries;

  /// The nonzero entries of a dense #V × #bones weight matrix, bones ascending per vertex.
  static SparseSkinWeights fromDense(const MatX& weights);
  int numVertices() const { return start.empty() ? 0 : int(start.size()) - 1; }
};

/// A vertex set's rest bound in bone b's frame: within `radius` of `center` (offsets X − J_b)
/// and within `extent` of J_b; for each other bone c that moves a vertex of the set, the
/// largest weight w_ic and the set's extent about J_c, max |X − J_c| (bones ascending).
struct SurfaceBound {
  Vec3 center = Vec3::Zero();
  double radius = 0.0, extent = 0.0;
  struct CoInfluence {
    int bone;
    double weight, extent;
  };
  std::vector<CoInfluence> co;
};

struct SkinnedSurface {
  SparseSkinWeights weights;
  /// Per bone, the vertices it dominates (largest weight; ties to the lower bone), ordered so
  /// that each of its clusters is a contiguous range.
  std::vector<std::vector<int>> dominated;
  std::vector<SurfaceBound> bone_bound;  ///< per bone, of all its dominated vertices
  struct Cluster {
    int bone, begin, end;  ///< the vertices dominated[bone][begin, end)
    SurfaceBound bound;
  };
  /// Bone b's clusters are clusters[bone_clusters[b] .. bone_clusters[b + 1]): median splits
  /// along the longest side of the rest box until a piece has at most `cluster_vertices`.
  std::vector<Cluster> clusters;
  std::vector<int> bone_clusters;  ///< #bones + 1

  /// From the dense weights (#V × #bones), rest vertices X (#V × 3) and rest joints J (#bones ×
  /// 3). Throws InputError on mismatched sizes or cluster_vertices < 1.
  static SkinnedSurface build(const MatX& weights, const MatX3& X, const MatX3& J,
                              int cluster_vertices);
  int numBones() const { return int(dominated.size()); }
  /// Cluster k's vertices [clusterBegin(k), clusterEnd(k)).
  const int* clusterBegin(int k) const {
    return dominated[size_t(clusters[size_t(k)].bone)].data() + clusters[size_t(k)].begin;
  }
  const int* clusterEnd(int k) const {
    return dominated[size_t(clusters[size_t(k)].bone)].data() + clusters[size_t(k)].end;
  }
};

}  // namespace flsh
