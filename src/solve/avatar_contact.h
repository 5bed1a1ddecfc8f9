// Avatar–avatar contact data of a Scene (private to src/solve): each simulable's skinning data,
// broad-phase clusters and posed capsules (Scene::AvatarContactData), and the 6 × 6 block
// accumulator of the contact Hessian (Scene::BlockAccumulator). Scene::avatarContactEnergy and
// its helpers are in avatar_contact.cpp.
#pragma once

#include <vector>

#include "flsh/body/skinned_surface.h"
#include "flsh/core/types.h"
#include "flsh/solve/scene.h"

namespace flsh {

/// Skinning data of one simulable and its posed capsules and (lazily) nodes at the last state
/// seen. Nodes are x_i = Σ_b w_ib (R_b (Y_i − J_b) + t_b), the formula of
/// Simulable::getNodes, computed only for the vertex groups the broad phase keeps. Y is the
/// unposed surface: the rest vertices X for the skeleton, getUnposedSurface() (moving with the
/// soft-tissue displacements) for the soft-tissue model. The rest bounds below are taken on X;
/// a soft vertex is further off by at most |Σ_b w_ib R_b (Y_i − X_i)| ≤ Σ_b |w_ib| |Y_i − X_i|.
struct Scene::AvatarContactData {
  int bones = 0;
  // Soft tissue: each vertex's u as state entries of the simulable, u_i = Σ B q.segment<3>(index)
  // over soft_basis[soft_start[i] .. soft_start[i + 1]) (one entry per soft node in the FEM,
  // the handles reaching it and the modal groups in the ROM, none on bone nodes), and the unposed
  // surface Y (#V × 3, m) of the cached posed data; with it the displacement margins of each
  // cluster and bone group (m).
  bool soft = false;
  std::vector<int> soft_start;
  std::vector<std::pair<int, Mat3>> soft_basis;
  MatX3 surface;
  std::vector<double> cluster_shift, group_shift;
  // The skinned surface (body/skinned_surface.h): nonzero weights per vertex, vertices grouped
  // by their dominant bone and split into clusters of at most kClusterSize, with rest bounds.
  SkinnedSurface skinned;

  // Cache key: the bone transforms (and for soft tissue the surface Y) the posed data below
  // belong to; `version` counts changes.
  bool valid = false;
  long version = 0;
  std::vector<Mat3> key_rotations;
  MatX3 key_positions;

  // Posed bounds: a vertex x_i = x_ib + Σ_{c≠b} w_ic (x_ic − x_ib) (x_ib: its rigid position on
  // its dominant bone b) lies within `bound` of `center`, since
  // |x_ic − x_ib| ≤ ‖R_c − R_b‖₂ |X − J_b| + |R_c (J_b − J_c) + t_c − t_b| and equally
  // ≤ ‖R_c − R_b‖₂ |X − J_c| + |R_b (J_b − J_c) + t_c − t_b|; the smaller is used (for a
  // vertex near the joint of b and c one of the two joint terms is the small joint-spring gap).
  // joint_gap_c holds the second joint term.
  std::vector<Vec3> group_center, cluster_center;
  std::vector<double> group_bound, cluster_bound;
  std::vector<double> rotation_gap, joint_gap, joint_gap_c;  // per bone pair b·bones + c
  std::vector<char> cluster_posed;  // nodes of the cluster computed for this state
  MatX3 nodes;                      // #V × 3, valid for posed clusters only
  struct PosedCapsule {
    int bone = 0;
    Vec3 a_rotated, b_rotated;  // R_b (a − J_b), R_b (b − J_b): a' = a_rotated + t_b
    Vec3 a, b;                  // posed end points, m
    double radius = 0.0;
    Vec3 center;  // bounding sphere of the capsule
    double bound = 0.0;
  };
  std::vector<PosedCapsule> capsules;
};

/// 6 × 6 Hessian blocks between the bones of two simulables, accumulated per vertex–capsule
/// contact and flushed as triplets once per ordered pair (so each bone pair emits 36 entries,
/// not 36 per contact).
struct Scene::BlockAccumulator {
  int size = 0;  // bones of A followed by bones of B
  std::vector<Mat6> blocks;
  std::vector<char> touched;
  std::vector<int> touched_list;

  void reset(int bones) {
    if (bones != size) {
      size = bones;
      blocks.assign(size_t(size) * size, Mat6::Zero());
      touched.assign(size_t(size) * size, 0);
    }
    touched_list.clear();
  }
  Mat6& at(int i, int j) {
    const int index = i * size + j;
    if (!touched[index]) {
      touched[index] = 1;
      blocks[index].setZero();
      touched_list.push_back(index);
    }
    return blocks[index];
  }
  /// Appends the touched blocks; local bone l maps to merged DoF dof(l) + 0..5.
  template <class DofOf>
  void flush(const DofOf& dof, std::vector<Triplet>& H) {
    for (int index : touched_list) {
      const int row = dof(index / size), col = dof(index % size);
      const Mat6& B = blocks[index];
      for (int c = 0; c < 6; ++c)
        for (int r = 0; r < 6; ++r) H.emplace_back(row + r, col + c, B(r, c));
      touched[index] = 0;
    }
    touched_list.clear();
  }
};

}  // namespace flsh
