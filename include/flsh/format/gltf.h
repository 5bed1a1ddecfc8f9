// Binary glTF 2.0 (.glb) output of a simulation: per avatar a skinned mesh whose skeleton
// follows the SMPL parent table, and one animation that moves every bone node (translation and
// rotation, sampled per frame, LINEAR), so that any glTF viewer plays the result. Rigid meshes
// (colliders) can be added with a per-frame translation.
#pragma once

#include <string>
#include <vector>

#include "flsh/core/types.h"

namespace flsh::io {

/// One skinned avatar. The bind pose is the rest shape: rest_vertices skinned by `weights` to
/// bones whose rest frames are (I, rest_joints[b]). Frame k places bone b at the world rigid
/// transform x ↦ rotations[k][b] (x − rest_joints[b]) + positions[k].row(b), i.e. linear blend
/// skinning of exactly the transforms a skeleton simulation moves.
struct GltfSkinnedAvatar {
  std::string name;
  MatX3 rest_vertices;                       ///< #V × 3, m
  MatX3i faces;                              ///< #F × 3
  MatX weights;                              ///< #V × #B skinning weights (the 4 largest are kept)
  std::vector<int> parents;                  ///< #B, parents[0] = −1, parents[b] < b
  MatX3 rest_joints;                         ///< #B × 3 joint centres of the rest shape, m
  std::vector<std::string> bone_names;       ///< #B (empty = "bone<b>")
  std::vector<std::vector<Mat3>> rotations;  ///< #frames × #B world rotations
  std::vector<MatX3> positions;              ///< #frames × (#B × 3) world joint positions, m
  Vec3 color = Vec3(0.80, 0.62, 0.52);       ///< base colour, linear RGB in [0, 1]
};

/// A rigid mesh moved by a translation per frame (e.g. a sphere collider).
struct GltfRigidMesh {
  std::string name;
  MatX3 vertices;                  ///< #V × 3 at zero translation, m
  MatX3i faces;                    ///< #F × 3
  std::vector<Vec3> translations;  ///< #frames (or empty: static)
  Vec3 color = Vec3(0.2, 0.4, 0.9);
};

/// Writes a .glb with the avatars, rigid meshes and one animation named "simulation" over
/// `times` (#frames, s, strictly increasing). Atomic. Throws InputError naming the avatar and
/// the array when a shape is inconsistent or a value is not finite, FileError on write errors.
void writeGlb(const std::string& path, const std::vector<double>& times,
              const std::vector<GltfSkinnedAvatar>& avatars,
              const std::vector<GltfRigidMesh>& rigid_meshes = {});

/// Area-weighted vertex normals of a triangle mesh (#V × 3, unit; +y where undefined).
MatX3 vertexNormals(const Eigen::Ref<const MatX3>& V, const Eigen::Ref<const MatX3i>& F);

}  // namespace flsh::io
