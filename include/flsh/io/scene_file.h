// Scene files (JSON) for `flsh simulate`: avatars, colliders, time step, duration, outputs.
// See docs/scene_format.md for the keys; unknown keys, wrong types and missing files are
// errors naming the key path (e.g. "scene.json: avatars[1].motion: …").
#pragma once

#include <string>
#include <vector>

#include "flsh/contact/collider.h"
#include "flsh/io/presets.h"
#include "flsh/sim/simulable.h"
#include "flsh/solve/newton.h"
#include "flsh/solve/scene.h"
#include "flsh/volume/reduced_data.h"

namespace flsh {

/// Most steps a scene may take, duration / time_step: a bound that catches unit mistakes (ms
/// for s).
constexpr long kMaxSceneSteps = 10'000'000;

/// In a model path, replaced by the gender of the avatar's motion ("female", "male" or
/// "neutral"; a motion without one, or a built-in motion, is "neutral"), e.g.
/// "models/smplh/{gender}/model.npz" for AMASS's body-model layout.
constexpr const char* kGenderPlaceholder = "{gender}";

struct AvatarSpec {
  std::string name;  ///< for outputs; default "avatar<i>"
  /// SMPL or SMPL-H .npz path (resolved; may hold kGenderPlaceholder), or "synthetic".
  std::string model = "synthetic";
  int synthetic_vertices = 6890;  ///< for model = "synthetic"
  VecX betas;                     ///< shape; empty = zeros (or the motion's)
  /// "skeleton" (articulated rigid bones), "fem" (FEM soft skeleton: the avatar is built with
  /// enableSoftTissue() and its volumetric body) or "rom" (ROM soft skeleton: also
  /// enableReducedModel(), the reduced basis and the cubatures below; docs/rom.md).
  std::string simulation = "skeleton";
  /// "fem" / "rom" only: interior node density of the tet mesh relative to the default
  /// (TetMeshOptions).
  double resolution = TetMeshOptions().resolution;
  /// "fem" / "rom" only: material file (JSON, docs/materials.md), resolved; empty = built-in.
  std::string material_file;
  /// "rom" only: point handles of the reduced basis (ReducedSettings::num_handles, ≥ 1).
  int handles = ReducedSettings().num_handles;
  /// "rom" only: sample tets of the elastic / inertial cubature; 0 = that cubature off (the
  /// elastic energy / the inertia integrated exactly over every tet / node).
  int elastic_cubature = ReducedSettings().elastic_cubature_points;
  int inertial_cubature = ReducedSettings().inertial_cubature_points;
  /// "rom" only: ReducedSettings::surface_partition_of_unity (the basis rescaled to sum to 1 on
  /// the soft surface; about half the error against the FEM, docs/rom.md).
  bool surface_partition_of_unity = ReducedSettings().surface_partition_of_unity;
  /// "rom" only: what spans the soft tissue (ReducedSettings::basis_kind, the key "basis":
  /// "handles", "modes" or "modes+handles"; default "modes", but "handles" given without a
  /// "basis" means "handles") and, with modes, the vibration modes and the compressed column
  /// count (ModalBasisSettings::vibration_modes / columns; 0 = every column).
  ReducedBasisKind basis = ReducedSettings().basis_kind;
  int vibration_modes = ReducedSettings().modes.vibration_modes;
  int modal_columns = ReducedSettings().modes.columns;
  std::string motion;           ///< AMASS .npz path or builtin:NAME; empty = none
  double motion_seconds = 0.0;  ///< length of a built-in motion, s; 0 = the duration
  /// Up axis the motion file was recorded in, "y" or "z"; empty = the file's own `up` key,
  /// else "z" (AMASS). loadMotion turns the clip into flsh's y-up world.
  std::string up;
  Vec3 offset = Vec3::Zero();  ///< added to the motion's root translation, m
  double yaw = 0.0;            ///< rotation of the motion about +y, rad
  SimulableOptions options;
};

struct OutputSpec {
  std::string dir = "out/simulate";
  bool ply = true;   ///< per-frame PLY meshes (one folder per avatar)
  bool npz = true;   ///< states.npz: states, vertices, joints per frame per avatar
  bool gltf = true;  ///< animation.glb: skinned mesh + per-frame bone transforms per avatar
  bool png = true;   ///< sheet.png with a few frames
  int png_frames = 5;
  int every = 1;  ///< write every n-th frame
};

/// "ground": a plane with normal +y named "ground", at a given height or under the avatars.
struct GroundSpec {
  bool enabled = false;
  /// At the lowest vertex of every avatar posed by its motion over its first `over_seconds`
  /// (io::automaticGround, scene_build.h), rather than at `height`.
  bool automatic = false;
  double height = 0.0;        ///< m (world y), when not automatic
  double over_seconds = 1.0;  ///< s, when automatic
};

struct SceneSpec {
  std::string source;  ///< file path or "builtin default scene"
  std::vector<AvatarSpec> avatars;
  std::vector<Collider> colliders;
  GroundSpec ground;  ///< the "ground" key; added to the colliders by io::sceneColliders
  double time_step = 1.0 / 60.0;  ///< s
  double duration = 2.0;          ///< s
  NewtonOptions newton;
  /// "newton.soft_tissue_gradient_tolerance": Newton's relative gradient tolerance in scenes
  /// with a "fem" avatar; ≤ 0 (absent) keeps SceneOptions::soft_tissue_newton's default (1e-5).
  double soft_tissue_gradient_tolerance = -1.0;
  /// "newton.reduced_gradient_tolerance": the same for scenes whose soft avatars are all "rom";
  /// ≤ 0 (absent) keeps SceneOptions::reduced_newton's default (reducedNewtonDefaults()).
  double reduced_gradient_tolerance = -1.0;
  /// "newton.soft_tissue_lagged" / "newton.reduced_lagged": the lagged-factor settings of the
  /// FEM's and the ROM's solvers (SceneOptions::soft_tissue_newton.lagged / reduced_newton.lagged);
  /// keys absent from the file keep those solvers' defaults.
  LaggedFactorOptions soft_tissue_lagged = softTissueNewtonDefaults().lagged;
  LaggedFactorOptions reduced_lagged = reducedNewtonDefaults().lagged;
  /// "newton.soft_tissue_presolve" / "newton.reduced_presolve": the bones-first iterations of
  /// the FEM's and the ROM's solvers (SceneOptions::soft_tissue_newton.coarse_presolve /
  /// reduced_newton.coarse_presolve); keys absent keep those solvers' defaults.
  CoarsePresolveOptions soft_tissue_presolve = softTissueNewtonDefaults().coarse_presolve;
  CoarsePresolveOptions reduced_presolve = reducedNewtonDefaults().coarse_presolve;
  /// "preset": a named bundle of defaults (flsh/io/presets.h): its ROM settings for every
  /// "rom" avatar (the avatar's own keys win) and its Newton iteration budget for the ROM's
  /// solver (unless "newton.max_iterations" is given).
  Preset preset = Preset::None;
  /// Newton iterations per step of the ROM's solver as a budget, whose end is not a failure
  /// (presetReducedIterationBudget; 0: none, the solver ends at its tolerance or fails at
  /// newton.max_iterations).
  int reduced_iteration_budget = 0;
  bool avatar_contact = true;
  OutputSpec outputs;
  /// Avatar cache of the "fem" / "rom" avatars' volumetric bodies and reduced data: folder
  /// (resolved; empty = the default, $FLSH_CACHE_DIR or ~/.cache/flsh) and whether it is read
  /// and written.
  std::string cache_dir;
  bool use_cache = true;
};

/// Command-line overrides, applied before validation (so that e.g. collider velocities span
/// the overridden duration). Zero / empty = keep the scene's value.
struct SceneOverrides {
  double duration = 0.0;   ///< s (--duration)
  double time_step = 0.0;  ///< s (--time-step)
  std::string output_dir;  ///< --out
  std::string cache_dir;   ///< --cache (relative to the working directory)
  bool no_cache = false;   ///< --no-cache: neither read nor write the avatar cache
};

/// Parses and validates a scene file; relative paths are relative to the file's folder.
/// Every referenced file must exist. Throws FileError / InputError before any output exists.
SceneSpec loadSceneFile(const std::string& path, const SceneOverrides& overrides = {});
/// Parses JSON text (`origin` names it in messages; `base_dir` resolves relative paths).
SceneSpec parseSceneJson(const std::string& text, const std::string& origin,
                         const std::string& base_dir = ".", const SceneOverrides& overrides = {});
/// The built-in default: a synthetic avatar walking on the ground, a ball thrown at it
/// (the same scene as examples/scenes/default.json).
SceneSpec defaultScene(const SceneOverrides& overrides = {});

}  // namespace flsh
