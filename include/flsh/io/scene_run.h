// Running a scene file as `flsh simulate` does, from the library (C++ and Python): the scene
// built into a ready Scene (avatars, colliders with the ground, initialized), then stepped over
// its duration with its outputs recorded into a staging folder that replaces outputs.dir at the
// end (output_dir.h), and a report of what happened. The CLI prints this report.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "flsh/contact/collider.h"
#include "flsh/io/scene_build.h"
#include "flsh/io/scene_file.h"
#include "flsh/solve/scene.h"

namespace flsh::io {

/// A scene file built and initialized, ready to step.
struct BuiltScene {
  std::vector<SceneAvatar> avatars;   ///< in the scene file's order (Scene's simulables 0, 1, …)
  std::vector<Collider> colliders;    ///< the scene's, then its "ground" (sceneColliders)
  std::shared_ptr<Scene> scene;       ///< initialized: time 0, every avatar at its first frame
  std::vector<std::string> warnings;  ///< startWarnings, also sent to the log
};

/// Builds the avatars (buildSceneAvatars), the colliders and the Scene (sceneOptionsOf) and
/// initializes it; progress and warning lines go to `log`. Nothing is written but the cache.
/// `scene` must outlive the result's avatars' `spec` pointers (used while building only).
BuiltScene buildScene(const SceneSpec& scene, const SceneBuildLog& log = {});

/// The number of steps of the scene, round(duration / time_step) ≥ 1; throws InputError
/// naming the allowed range above kMaxSceneSteps (scene_file.h).
int sceneSteps(const SceneSpec& scene);

struct SceneRunOptions {
  SceneBuildLog log;          ///< progress and warning lines (no newline); empty = silent
  bool progress_bar = false;  ///< a progress bar on stderr (in place on a terminal)
  /// Names what set outputs.dir in messages (e.g. "--out"); empty = "SCENE: outputs.dir".
  std::string output_dir_origin;
};

/// What a run did: the figures of `flsh simulate`'s summary.
struct SceneRunReport {
  std::string source;  ///< the scene file
  int avatars = 0;
  int colliders = 0;  ///< with the ground
  bool ground = false, ground_automatic = false;
  double ground_height = 0.0;  ///< m, when `ground`
  int steps = 0, frames = 0;
  double time_step = 0.0;
  long newton_iterations = 0, factorizations = 0, cg_iterations = 0;
  int unconverged = 0, max_contacts = 0;
  std::string first_unconverged;  ///< "step N: message" of the first unconverged step
  /// With an iteration budget (SceneSpec::reduced_iteration_budget, the realtime preset): the
  /// budget, and the steps that used all of it (not counted as unconverged: the budget is the
  /// trade asked for); 0 without one.
  int iteration_budget = 0, at_budget = 0;
  double setup_seconds = 0.0, simulation_seconds = 0.0, output_seconds = 0.0;
  std::string output_dir;            ///< outputs.dir
  std::vector<std::string> written;  ///< what was written there ("states.npz", …)
  /// Per avatar (scene order): name, model and, for "fem"/"rom", the largest soft-tissue
  /// displacement over the saved frames (mm; −1 for the skeleton).
  std::vector<std::string> avatar_names, avatar_models;
  std::vector<double> max_displacement_mm;
  double sheet_max_displacement_mm = 0.0;  ///< sheet.png's colour scale, when soft avatars
  bool sheet = false;                      ///< sheet.png written

  /// The lines `flsh simulate` prints on stdout (the soft avatars' displacements, the sheet's
  /// colour scale, the summary line), each ending in a newline.
  std::string summary() const;
  /// The warning line about unconverged steps, or "".
  std::string unconvergedWarning() const;
};

/// Runs `scene` as `flsh simulate` does: checks the outputs and the memory they need, builds
/// the scene (buildScene), steps it over its duration recording outputs into a staging folder
/// beside outputs.dir, which replaces it once everything is written. Throws before writing
/// anything on bad input; a failed step throws naming the step, the time and the avatars, and
/// leaves outputs.dir as it was.
SceneRunReport runScene(const SceneSpec& scene, const SceneRunOptions& options = {});

}  // namespace flsh::io
