// From a scene file (SceneSpec, docs/scene_format.md) to simulables ready for a Scene: body
// models (loaded once per file, or the synthetic body), motions placed by their offset and yaw,
// betas, soft-tissue and reduced-model settings, and the avatars' volumetric data (built or
// read from the cache). What `flsh simulate` runs; the input checks name the scene file and
// the key.
#pragma once

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "flsh/body/motion.h"
#include "flsh/io/scene_file.h"
#include "flsh/sim/simulable.h"
#include "flsh/solve/scene.h"
#include "flsh/volume/soft_avatar.h"

namespace flsh::io {

/// One avatar of a scene, built.
struct SceneAvatar {
  const AvatarSpec* spec = nullptr;  ///< in the SceneSpec it was built from (must outlive this)
  std::string where;                 ///< "SCENE: avatars[i]", for messages
  std::shared_ptr<const BodyModel> body;
  std::shared_ptr<SoftAvatar> avatar;
  std::shared_ptr<const Motion> motion;  ///< null without a motion
  std::shared_ptr<Simulable> simulable;
  bool soft = false;  ///< "simulation": "fem" or "rom" (soft-tissue displacements)
  bool rom = false;   ///< "simulation": "rom"
};

/// Progress and warning lines ("generating the synthetic body (600 vertices)...",
/// "warning: …"), one per call, without a trailing newline. May be empty (silent).
using SceneBuildLog = std::function<void(const std::string&)>;

/// Builds every avatar of `scene` in order (nothing is written but the avatar cache). Throws
/// InputError naming the scene file and the avatar's key on bad input, e.g. a model that is not
/// SMPL's 24 joints, betas longer than the model's, motion values out of range
/// (checkMotionValues), or a ROM asking for more handles than the body has.
std::vector<SceneAvatar> buildSceneAvatars(const SceneSpec& scene, const SceneBuildLog& log = {});

/// The colliders of `scene` and its "ground" (GroundSpec), a plane with normal +y named
/// "ground": at its height, or with "ground": "auto" at the lowest vertex of every avatar
/// posed by its motion over its first `over_seconds` (lowestPointHeight, motion_frame.h; an
/// avatar without a motion: its start), which is reported through `log`.
std::vector<Collider> sceneColliders(const SceneSpec& scene,
                                     const std::vector<SceneAvatar>& avatars,
                                     const SceneBuildLog& log = {});

/// Thresholds of startWarnings (m): an avatar deeper than this in a plane, or whose lowest point
/// is higher than this above the nearest floor (a plane facing up, normal y > 0.7).
constexpr double kStartDepthWarning = 0.02;
constexpr double kStartHeightWarning = 0.10;

/// One sentence per avatar that starts deeper than kStartDepthWarning in a plane collider or
/// higher than kStartHeightWarning above every floor: usually a ground at the wrong height or a
/// clip read with the wrong up axis. The surface at t = 0 is the body posed by the motion's
/// first frame (else the rest pose), where Simulable::initialize() puts it.
std::vector<std::string> startWarnings(const std::vector<SceneAvatar>& avatars,
                                       const std::vector<Collider>& colliders);

/// The solver settings of a scene file. Soft-tissue scenes keep their own solver choices
/// (SceneOptions::soft_tissue_newton with an FEM avatar, else reduced_newton for ROM avatars:
/// Hessian form, linear solver, lagged factor, tolerance) and take the scene's iteration limit
/// and step tolerance; their gradient tolerances and lagged-factor settings come from the scene
/// file when it sets them.
SceneOptions sceneOptionsOf(const SceneSpec& scene);

/// The ROM's settings as the scene keys handles / elastic_cubature / inertial_cubature /
/// surface_partition_of_unity / basis / vibration_modes / modal_columns and the `flsh avatar`
/// flags give them: 0 sample tets switches that cubature off (exact integration), and its count
/// then keeps the (unused) default.
void setReducedSettings(ReducedSettings& reduced, int handles, int elastic, int inertial,
                        bool partition_of_unity, ReducedBasisKind basis, int vibration_modes,
                        int modal_columns);

/// Soft tissue, the reduced model and the cubatures that are on (as setReducedSettings).
void enableReducedModel(SoftAvatar& avatar, int elastic, int inertial);

/// `betas` fitted to the model's K shape components: shorter stays (the forward pass zero
/// pads); longer is cut to K, and if a dropped coefficient is nonzero `warning` (if not null)
/// gets a sentence naming `origin`.
VecX fitBetas(const VecX& betas, const BodyModel& model, const std::string& origin,
              std::string* warning = nullptr);

/// Throws InputError naming the motion (`what`) unless its poses are rotation vectors the
/// forward pass accepts (checkPoseAngles: finite, |θ| ≤ kMaxRotationAngle) and its
/// translations are finite and within ±kMaxStatePosition m, by frame.
void checkMotionValues(const Motion& motion, const std::string& what);

}  // namespace flsh::io
