// SoftAvatar: the immutable data of one body shape that a simulation needs (ARCHITECTURE.md §3).
//
// Created from a body model and β, configured with the FLSH paper's settings, then built by
// initVolumetricData(). Only what the chosen model needs is built: a skeleton-only avatar
// (soft tissue off, the default) never builds a tetrahedral mesh; its bone masses and inertias
// come from the closed body surface filled with a uniform density.
//
// Bone inertia as a smooth function of β (so that the adjoint can differentiate it exactly):
// the TEMPLATE surface (β = 0) is voxelized once; every voxel piece is lumped to its nearest
// template vertex i, which keeps its mass m_i and its first and second moments f_i, S_i about
// the vertex (computeVertexMassMoments). For a shape β each vertex's pieces move rigidly with
// the vertex, X_i(β) = v_template_i + shapedirs_i β, and all masses scale by
// s(β) = vol(β) / vol(0) (volumes of the closed surfaces, divergence theorem), so the total mass
// is density × shaped volume. Bone b then gets, with o = X_i(β) − J_b(β) and weights w_ib:
//   mass = s Σ w m_i,  first = s Σ w (f_i + m_i o),  second = s Σ w (S_i + f_i oᵀ + o f_iᵀ + m_i o
//   oᵀ)
// (lumpBoneInertia), a polynomial in β. (Voxelizing the shaped surface instead would jump
// whenever a voxel centre crosses the surface or changes its nearest vertex: not
// differentiable.) Avatars of one body model with equal density and voxel size share the
// template data (voxelized once per process while any of them is alive).
#pragma once

#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "flsh/body/body_model.h"
#include "flsh/core/types.h"
#include "flsh/energy/bone_inertia.h"
#include "flsh/volume/reduced_data.h"
#include "flsh/volume/volumetric_data.h"

namespace flsh {

/// A capsule attached to a bone: segment from a to b (rest pose, world) and radius, m.
struct BoneCapsule {
  int bone = 0;
  Vec3 a = Vec3::Zero(), b = Vec3::Zero();
  double radius = 0.0;
};

struct VertexMassMoments;

struct SoftAvatarSettings {
  double density = 1010.0;   ///< uniform body density for the skeleton model, kg/m³
  double voxel_size = 0.01;  ///< voxel edge used to integrate mass properties, m
  /// The volumetric body of the soft-tissue models: tet-mesh resolution, material file, cache.
  VolumetricSettings volumetric;
  /// The reduced model's handles, basis and cubatures (used with enableReducedModel(); cached
  /// in the same directory as the volumetric body, under volumetric.use_cache).
  ReducedSettings reduced;
};

class SoftAvatar {
 public:
  /// β may be shorter than the model's K (zero padded). Throws InputError on bad sizes.
  SoftAvatar(std::shared_ptr<const BodyModel> body, const VecX& betas,
             const SoftAvatarSettings& settings = {});

  // Settings of the FLSH paper. Soft tissue off: the articulated skeleton (no tet mesh is
  // built). On: the FEM soft skeleton, whose volumetric body (tet mesh, interior fields, bone
  // nodes, materials) initVolumetricData() builds or loads from the cache. Soft tissue and the
  // reduced model on: the ROM soft skeleton, which adds the reduced data (handles, basis and the
  // cubatures switched on here) on top of the volumetric body. The reduced model is a
  // soft-tissue model: enabling it without soft tissue makes initVolumetricData() throw
  // InputError. The cubature flags only act on the reduced model and are ignored without it.
  void enableSoftTissue(bool on = true) { soft_tissue_ = on; }
  void enableReducedModel(bool on = true) { reduced_ = on; }
  void enableInertialCubature(bool on = true) { inertial_cubature_ = on; }
  void enableElasticCubature(bool on = true) { elastic_cubature_ = on; }
  bool softTissueEnabled() const { return soft_tissue_; }
  bool reducedModelEnabled() const { return reduced_; }
  bool inertialCubatureEnabled() const { return inertial_cubature_; }
  bool elasticCubatureEnabled() const { return elastic_cubature_; }

  /// Builds what the configured model needs: for every model the rest shape, joints, bone
  /// inertias and capsules; with soft tissue also the volumetric body. Idempotent; the
  /// settings cannot change afterwards (make a new avatar).
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

  /// The volumetric body (soft tissue on); throws Error for a skeleton-only or uninitialized
  /// avatar.
  const VolumetricData& volumetricData() const;
  bool hasVolumetricData() const { return volumetric_ != nullptr; }
  /// The reduced data (soft tissue and reduced model on); throws Error for another model or an
  /// uninitialized avatar.
  const ReducedData& reducedData() const;
  bool hasReducedData() const { return reduced_data_ != nullptr; }
  /// Replaces the reduced data by the caller's (a basis or cubature of one's own; e.g. every tet
  /// with weight 1 for exact integration), after initVolumetricData() with the reduced model on
  /// and before any Simulable reads this avatar. Checked against the volumetric body: InputError
  /// (naming the field) for a basis that is not #nodes × #handles, with entries outside [0, 1]
  /// or on bone nodes, handles out of range, repeated, or on bone nodes, or cubature tets out of
  /// range / weights not finite and > 0 / lengths that differ.
  void setReducedData(std::shared_ptr<const ReducedData> data);
  /// This avatar with other soft-tissue materials, for fitting them (the adjoint's Material
  /// group): the same β and discretization — tet mesh, rest nodes, bone nodes (their selection
  /// by tissue_fraction and the regions' tissue_scale is kept), orthotropy frames, and for the
  /// ROM the basis, cubature samples, weights and rest-split floors — with every tet's
  /// materials re-evaluated from `model` (tet_material_map.h) and, for the ROM, the subspace's
  /// rest stiffness K recomputed. Cheap next to a build (no meshing, basis or cubature
  /// training; nothing is cached). Error on an avatar without an initialized volumetric body;
  /// InputError on a model for another number of shape components or not physical at β.
  std::shared_ptr<SoftAvatar> withMaterial(const MaterialModel& model) const;
  /// This avatar at another shape β′, for fitting β (the adjoint's Shape group): the same
  /// discretization — tet mesh, bone nodes (selected at this avatar's β), orthotropy frames, and
  /// for the ROM the basis, cubature samples, weights and rest-split floors — with the rest data
  /// of β′: surface, joints, areas, bone inertias and capsules as a new avatar would have them,
  /// rest nodes X̄(β′) = X̄₀ + S β′, every tet's materials from the material model at β′ on the
  /// tets' areas and volumes at X̄(β′) (tet_material_map.h) and, for the ROM, K recomputed. The
  /// soft models' Shape gradient is exact for this model. Cheap next to a build (nothing is
  /// meshed, trained or cached). β′ as the constructor's (zero padded; InputError on a bad size
  /// or value, or a material model not physical at β′); Error on an uninitialized avatar.
  std::shared_ptr<SoftAvatar> withShape(const VecX& betas) const;
  /// Cache hit, warnings and seconds per stage of the reduced build (all zero without it).
  const ReducedBuildReport& reducedBuildReport() const { return reduced_report_; }
  /// Cache hits, warnings and seconds per stage of the volumetric build (all zero without it);
  /// `skeletonSeconds()` is the time of the skeleton part (inertia, capsules).
  const VolumetricBuildReport& volumetricBuildReport() const { return build_report_; }
  double skeletonSeconds() const { return skeleton_seconds_; }

  // Derivatives with respect to β (K = body().numBetas() columns), for the adjoint. Available
  // after initVolumetricData(); exact (the data are polynomials in β).
  /// d restJoints / dβ: 72 × K, row 3b + c = coordinate c of J_b (J_regressor · shapedirs).
  const MatX& restJointsShapeJacobian() const { return joints_shape_jacobian_; }
  /// d boneInertia / dβ: (24·10) × K in the layout of SimParameter::BoneInertia (per bone: mass,
  /// first moment (3), second moment xx, yy, zz, xy, xz, yz).
  const MatX& boneInertiaShapeJacobian() const { return inertia_shape_jacobian_; }
  /// d vertexAreas / dβ: #V × K, m² per unit β.
  const MatX& vertexAreasShapeJacobian() const { return areas_shape_jacobian_; }
  /// d volume / dβ: K, m³ per unit β.
  const VecX& volumeShapeGradient() const { return volume_shape_gradient_; }
  /// The voxelized template (β = 0) lumped to the template vertices (see the top of this file).
  const VertexMassMoments& templateMassMoments() const { return *template_moments_; }
  double templateVolume() const { return template_volume_; }  ///< vol(0), m³

  /// Data a higher layer derives from this avatar alone (e.g. the reduced elasticity's table of
  /// every tet in the subspace), built by `make` on the first call with `key` and shared by
  /// every later caller — every Simulable of this avatar. Thread-safe (make runs under a lock).
  /// A copy of the avatar (withShape, withMaterial) starts with none, and initVolumetricData()
  /// and setReducedData() forget them.
  template <class T, class Make>
  std::shared_ptr<const T> derived(const std::string& key, Make&& make) const {
    std::lock_guard<std::mutex> lock(derived_.mutex);
    std::shared_ptr<const void>& slot = derived_.entries[key];
    if (!slot) slot = std::shared_ptr<const T>(make());
    return std::static_pointer_cast<const T>(slot);
  }

 private:
  // derived()'s entries; copying an avatar does not copy them.
  struct DerivedData {
    std::mutex mutex;
    std::map<std::string, std::shared_ptr<const void>> entries;
    DerivedData() = default;
    DerivedData(const DerivedData&) {}
    DerivedData& operator=(const DerivedData&) {
      forget();
      return *this;
    }
    void forget() {
      std::lock_guard<std::mutex> lock(mutex);
      entries.clear();
    }
  };

  void buildRestShape();
  void buildShapeJacobians(const MatX3& X, const MatX3& J, double mass_scale);
  /// The ROM data for new volumetric data of the same discretization (K recomputed).
  std::shared_ptr<const ReducedData> reducedDataFor(const VolumetricData& data) const;

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
  std::shared_ptr<const VertexMassMoments> template_moments_;
  double template_volume_ = 0.0;
  MatX joints_shape_jacobian_, inertia_shape_jacobian_, areas_shape_jacobian_;
  VecX volume_shape_gradient_;
  std::shared_ptr<const VolumetricData> volumetric_;
  VolumetricBuildReport build_report_;
  std::shared_ptr<const ReducedData> reduced_data_;
  ReducedBuildReport reduced_report_;
  double skeleton_seconds_ = 0.0;
  mutable DerivedData derived_;
};

/// Mass, first and second moments of a voxelized solid lumped to surface vertices, each about
/// its vertex (see the top of this file).
struct VertexMassMoments {
  VecX mass;                        ///< #V, kg
  MatX3 first_moment;               ///< #V × 3, Σ m (x − X_i), kg·m
  std::vector<Mat3> second_moment;  ///< #V, Σ m (x − X_i)(x − X_i)ᵀ (with each voxel's own), kg·m²
};

/// Voxelizes the closed surface (V, F) filled with `density` (voxel edge `voxel_size`, m) and
/// lumps every voxel piece to its nearest vertex (ties: smaller index). Deterministic.
VertexMassMoments computeVertexMassMoments(const MatX3& V, const MatX3i& F, double density,
                                           double voxel_size);

/// Bone mass properties from vertex moments carried rigidly by vertices at positions V (#V × 3)
/// and spread over bones by the skinning weights (#V × bones), about the joints J (bones × 3);
/// every mass scaled by `mass_scale`.
std::vector<BoneInertia> lumpBoneInertia(const VertexMassMoments& moments, const MatX3& V,
                                         const MatX& weights, const MatX3& J,
                                         double mass_scale = 1.0);

/// Mass properties of a closed surface (V, F) filled with `density`, split over 24 bones by the
/// skinning weights of the nearest surface vertex, integrated on voxels of edge `voxel_size`.
/// Joints J (24 × 3) are the bone origins. lumpBoneInertia(computeVertexMassMoments(V, F, …),
/// V, weights, J): what SoftAvatar computes at β = 0 (for β ≠ 0 it moves the template's moments).
std::vector<BoneInertia> computeBoneInertia(const MatX3& V, const MatX3i& F, const MatX& weights,
                                            const MatX3& J, double density, double voxel_size);

/// One capsule per bone fitted to the vertices the bone dominates (rest pose): axis from the
/// joint to its child (or along the principal direction for leaves), radius a robust
/// percentile of the distances. Bones dominating no vertex get a zero-radius capsule.
std::vector<BoneCapsule> fitBoneCapsules(const MatX3& V, const MatX& weights, const MatX3& J,
                                         const std::vector<int>& parents);

}  // namespace flsh
