// The volumetric body of a SoftAvatar (ARCHITECTURE.md §3), built in two levels:
//  - VolumetricTemplate, shared by every body shape: the tet mesh of the template surface
//    (surface vertices = nodes 0..V−1) and the body's fields extended to all nodes. The costly
//    part (meshing, harmonic solves); it depends on the model arrays and the mesh options only.
//  - VolumetricData at one β: rest nodes X̄(β) = X̄₀ + S β, bone nodes, per-tet materials.
// Both levels are cached on disk (AvatarCache) under keys that hash everything they depend on.
#pragma once

#include <memory>
#include <string>

#include "flsh/body/body_model.h"
#include "flsh/core/types.h"
#include "flsh/volume/avatar_cache.h"
#include "flsh/volume/materials.h"
#include "flsh/volume/tet_mesh.h"
#include "flsh/volume/volume_fields.h"

namespace flsh {

struct VolumetricSettings {
  TetMeshOptions tet_mesh;     ///< resolution of the interior
  /// Material coefficients (JSON, docs/materials.md); empty: MaterialModel::defaults.
  std::string material_file;
  bool use_cache = true;       ///< read and write the on-disk cache
  std::string cache_dir;       ///< empty: AvatarCache::defaultDirectory()
};

struct VolumetricTemplate {
  TetMesh mesh;              ///< template rest nodes (β = 0), m
  InteriorFields fields;     ///< weights #N × 24, shapedirs 3#N × K, posedirs 3#N × 207
  TetMeshQuality quality;
  std::string key;           ///< cache key (hex SHA-256 of the inputs)
};

struct VolumetricData {
  std::shared_ptr<const VolumetricTemplate> templ;
  MatX3 rest_nodes;          ///< #N × 3, X̄(β), m; rows 0..V−1 = the SMPL shaped vertices
  MatX3 rest_joints;         ///< 24 × 3, J(β), m
  VecXi bone_of_node;        ///< #N: bone a node is attached to, −1 for soft-tissue nodes
  VecX tissue_thickness;     ///< V: local soft-tissue thickness at the surface vertices, m
  TetMaterials materials;    ///< per tet at β
  MaterialModel material_model;
  std::string key;           ///< cache key of this level
  int numNodes() const { return int(rest_nodes.rows()); }
  int numTets() const { return templ ? templ->mesh.numTets() : 0; }
  int numBoneNodes() const;
  double totalMass() const;  ///< Σ ρ · volume over tets at X̄(β), kg
};

/// How a build went: cache hits, warnings (a rejected cache file), seconds per stage (0 for a
/// stage skipped because its level came from the cache).
struct VolumetricBuildReport {
  bool template_from_cache = false, data_from_cache = false;
  std::string warnings;             ///< one line per problem (e.g. a corrupted cache file rebuilt)
  TetMeshTimings meshing;           ///< stages of tetrahedralizeSurface
  double seconds_meshing = 0, seconds_harmonic = 0, seconds_quality = 0;
  double seconds_bone_nodes = 0, seconds_materials = 0;
  double seconds_cache_load = 0, seconds_cache_store = 0, seconds_total = 0;
};

/// Cache key of the template level: model arrays, mesh options, cache format version.
std::string volumetricTemplateKey(const BodyModel& body, const TetMeshOptions& options);

/// Builds (or loads from `cache`, when not null) the template level.
std::shared_ptr<const VolumetricTemplate> buildVolumetricTemplate(const BodyModel& body,
                                                                  const TetMeshOptions& options,
                                                                  const AvatarCache* cache,
                                                                  VolumetricBuildReport* report);

/// Builds (or loads) the data at β (zero-padded to K): the template level first, then the
/// shape level. Throws InputError on bad β or material file; cache problems only warn.
VolumetricData buildVolumetricData(const BodyModel& body, const VecX& betas,
                                   const VolumetricSettings& settings,
                                   VolumetricBuildReport* report = nullptr);

}  // namespace flsh
