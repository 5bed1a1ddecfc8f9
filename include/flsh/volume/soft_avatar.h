// SoftAvatar: the immutable data of one body shape that a simulation needs (ARCHITECTURE.md §3).
//
// Created from a body model and β, configured with the FLSH paper's settings, then built by
// initVolumetricData(). Only what the chosen model needs is built: a skeleton-only avatar
// (soft tissue off, the default) never builds a tetrahedral mesh; its bone masses and inertias
// come from the closed body surface filled with a uniform density.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "flsh/body/body_model.h"
#include "flsh/core/types.h"

namespace flsh {

/// Mass properties of one bone in the rest pose, about the bone's joint centre J_b, in the
/// world-aligned rest frame: a material point X of the bone moves as x = R_b (X − J_b) + t_b.
struct BoneInertia {
  double mass = 0.0;                   ///< Σ m, kg
  Vec3 first_moment = Vec3::Zero();    ///< Σ m (X − J_b), kg·m
  Mat3 second_moment = Mat3::Zero();   ///< Σ m (X − J_b)(X − J_b)ᵀ, kg·m²
  Vec3 centerOfMass(const Vec3& joint) const { return joint + first_moment / mass; }
};

/// A capsule attached to a bone: segment from a to b (rest pose, world) and radius, m.
struct BoneCapsule {
  int bone = 0;
  Vec3 a = Vec3::Zero(), b = Vec3::Zero();
  double radius = 0.0;
};

struct SoftAvatarSettings {
  double density = 1010.0;    ///< uniform body density for the skeleton model, kg/m³
  double voxel_size = 0.01;   ///< voxel edge used to integrate mass properties, m
};

class SoftAvatar {
 public:
  /// β may be shorter than the model's K (zero padded). Throws InputError on bad sizes.
  SoftAvatar(std::shared_ptr<const BodyModel> body, const VecX& betas,
             const SoftAvatarSettings& settings = {});

  // Settings of the FLSH paper. The soft-tissue models (FEM, ROM) come with the volumetric
  // issue; until then enableSoftTissue(true) makes initVolumetricData() throw an Error that
  // says so.
  void enableSoftTissue(bool on = true) { soft_tissue_ = on; }
  void enableReducedModel(bool on = true) { reduced_ = on; }
  void enableInertialCubature(bool on = true) { inertial_cubature_ = on; }
  void enableElasticCubature(bool on = true) { elastic_cubature_ = on; }
  bool softTissueEnabled() const { return soft_tissue_; }
  bool reducedModelEnabled() const { return reduced_; }

  /// Builds what the configured model needs (for the skeleton: rest shape, joints, bone
  /// inertias, capsules). Idempotent.
  void initVolumetricData();
  bool initialized() const { return initialized_; }

  const BodyModel& body() const { return *body_; }
  std::shared_ptr<const BodyModel> bodyPtr() const { return body_; }
  const VecX& betas() const { return betas_; }  ///< length K (padded)
  const SoftAvatarSettings& settings() const { return settings_; }

  // Available after initVolumetricData():
  const MatX3& restVertices() const { return rest_vertices_; }  ///< #V × 3, shaped T-pose
  const MatX3& restJoints() const { return rest_joints_; }      ///< 24 × 3, J(β)
  const std::vector<BoneInertia>& boneInertia() const { return bone_inertia_; }  ///< 24
  const std::vector<BoneCapsule>& boneCapsules() const { return capsules_; }     ///< one per bone
  const VecX& vertexAreas() const { return vertex_areas_; }  ///< #V, m² (a third of incident faces)
  double totalMass() const;
  double volume() const { return volume_; }  ///< enclosed volume of the rest surface, m³

 private:
  std::shared_ptr<const BodyModel> body_;
  VecX betas_;
  SoftAvatarSettings settings_;
  bool soft_tissue_ = false, reduced_ = false, inertial_cubature_ = false,
       elastic_cubature_ = false, initialized_ = false;
  MatX3 rest_vertices_, rest_joints_;
  std::vector<BoneInertia> bone_inertia_;
  std::vector<BoneCapsule> capsules_;
  VecX vertex_areas_;
  double volume_ = 0.0;
};

/// Mass properties of a closed surface (V, F) filled with `density`, split over 24 bones by the
/// skinning weights of the nearest surface vertex, integrated on voxels of edge `voxel_size`.
/// Joints J (24 × 3) are the bone origins. Used by SoftAvatar; exposed for tests.
std::vector<BoneInertia> computeBoneInertia(const MatX3& V, const MatX3i& F, const MatX& weights,
                                            const MatX3& J, double density, double voxel_size);

/// One capsule per bone fitted to the vertices the bone dominates (rest pose): axis from the
/// joint to its child (or along the principal direction for leaves), radius a robust
/// percentile of the distances. Bones dominating no vertex get a zero-radius capsule.
std::vector<BoneCapsule> fitBoneCapsules(const MatX3& V, const MatX& weights, const MatX3& J,
                                         const std::vector<int>& parents);

}  // namespace flsh
