// A scene file run from the library, as `flsh simulate` runs it (scene_run.h).
#include "flsh/io/scene_run.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>

#include "core/seconds_since.h"
#include "flsh/core/error.h"
#include "flsh/core/memory_check.h"
#include "flsh/io/output_dir.h"
#include "flsh/io/scene_outputs.h"

namespace flsh::io {

namespace {

using Clock = std::chrono::steady_clock;

using detail::secondsSince;

std::string number(double value) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.6g", value);
  return text;
}

/// One line on stderr that updates in place on a terminal; a line per 10 % otherwise.
class ProgressBar {
 public:
  ProgressBar(int total, bool enabled)
      : total_(std::max(1, total)), enabled_(enabled), tty_(isatty(fileno(stderr)) != 0) {}
  void update(int done, double sim_time) {
    if (!enabled_) return;
    const double elapsed = secondsSince(start_);
    const int percent = int(100.0 * done / total_);
    if (tty_) {
      if (done < total_ && secondsSince(last_) < 0.1) return;
      last_ = Clock::now();
    } else {
      if (percent / 10 == last_decile_ && done < total_) return;
      last_decile_ = percent / 10;
    }
    const double rate = elapsed > 0 ? done / elapsed : 0.0;
    const double eta = rate > 0 ? (total_ - done) / rate : 0.0;
    const int width = 24, filled = width * done / total_;
    std::fprintf(stderr, "%s[%s%s] %3d%%  step %d/%d  t = %.3f s  %.0f steps/s  ETA %.1f s%s",
                 tty_ ? "\r" : "", std::string(filled, '#').c_str(),
                 std::string(width - filled, '.').c_str(), percent, done, total_, sim_time, rate,
                 eta, tty_ ? "\033[K" : "\n");
    std::fflush(stderr);
  }
  void finish() {
    if (enabled_ && tty_) std::fputc('\n', stderr);
  }

 private:
  int total_;
  bool enabled_, tty_;
  int last_decile_ = 0;  // the first line comes at 10 %
  Clock::time_point start_ = Clock::now(), last_ = Clock::time_point();
};

/// What a scene run may find in (and writes to) its output folder.
std::vector<OutputEntry> sceneOutputEntries() {
  return {OutputEntry::folderOf("meshes", ".ply"), OutputEntry::file("states.npz"),
          OutputEntry::file("animation.glb"), OutputEntry::file("sheet.png")};
}

/// Throws InputError unless the frames the enabled outputs keep in memory fit in half of this
/// machine's memory; names the sizes and what to change.
void checkRecordingMemory(const SceneSpec& scene, const std::vector<RecordedAvatar>& avatars,
                          size_t colliders, int frames) {
  const double per_frame = SceneRecorder::bytesPerFrame(scene.outputs, avatars, colliders);
  checkMemory(scene.source + ": outputs (states.npz and animation.glb keep " +
                  std::to_string(frames) + " saved frames of " +
                  std::to_string(int(std::ceil(per_frame / 1e3))) + " kB)",
              per_frame * frames,
              "save fewer frames (outputs.every), shorten duration, or switch npz and gltf off");
}

}  // namespace

BuiltScene buildScene(const SceneSpec& spec, const SceneBuildLog& log) {
  BuiltScene built;
  built.avatars = buildSceneAvatars(spec, log);
  built.colliders = sceneColliders(spec, built.avatars, log);
  built.scene = std::make_shared<Scene>(sceneOptionsOf(spec));
  for (const SceneAvatar& run : built.avatars) built.scene->addSimulable(run.simulable);
  for (const Collider& collider : built.colliders) built.scene->addCollider(collider);
  built.scene->initialize();
  // An avatar starting deep inside the ground or far above it is usually a wrong ground
  // height or up axis: say so.
  built.warnings = startWarnings(built.avatars, built.colliders);
  if (log)
    for (const std::string& warning : built.warnings) log("warning: " + warning);
  return built;
}

int sceneSteps(const SceneSpec& scene) {
  const double steps = std::round(scene.duration / scene.time_step);
  if (!(steps <= double(kMaxSceneSteps)))
    throw InputError(scene.source + ": duration / time_step = " + number(steps) +
                     " steps, expected at most " + number(double(kMaxSceneSteps)) +
                     " (shorten duration or raise time_step)");
  return std::max(1, int(steps));
}

SceneRunReport runScene(const SceneSpec& spec, const SceneRunOptions& options) {
  const auto t_setup = Clock::now();
  const SceneBuildLog log = options.log ? options.log : [](const std::string&) {};
  const OutputSpec& wanted = spec.outputs;
  const bool any_output = wanted.ply || wanted.npz || wanted.gltf || wanted.png;
  SceneRunReport report;
  report.source = spec.source;
  report.steps = sceneSteps(spec);
  report.frames = 1 + report.steps / wanted.every;
  report.time_step = spec.time_step;
  report.output_dir = wanted.dir;
  // The outputs go to a staging folder beside outputs.dir, which replaces it at the end.
  std::unique_ptr<StagedOutputDir> out_dir;
  if (any_output)
    out_dir = std::make_unique<StagedOutputDir>(wanted.dir, sceneOutputEntries(),
                                                options.output_dir_origin.empty()
                                                    ? spec.source + ": outputs.dir"
                                                    : options.output_dir_origin);
  BuiltScene built = buildScene(spec, log);
  std::vector<RecordedAvatar> recorded;
  for (const SceneAvatar& run : built.avatars)
    recorded.push_back({run.spec->name, run.simulable, run.soft});
  checkRecordingMemory(spec, recorded, built.colliders.size(), report.frames);
  // The budget is the ROM solver's: it counts when that solver runs the scene
  // (Scene::newtonOptions: soft tissue, none of it FEM).
  if (built.scene->hasSoftTissue() && !built.scene->hasFemSoftTissue())
    report.iteration_budget = spec.reduced_iteration_budget;
  report.avatars = int(built.avatars.size());
  report.colliders = int(built.colliders.size());
  report.ground = spec.ground.enabled;
  report.ground_automatic = spec.ground.automatic;
  if (report.ground) report.ground_height = built.colliders.back().p0().y();
  report.setup_seconds = secondsSince(t_setup);

  // ---- simulation: PLY meshes go to the staging folder as they come, the rest is kept ----
  const double h = spec.time_step;
  SceneRecorder recorder(wanted, out_dir ? out_dir->staging() : std::string(), recorded,
                         built.colliders, h, report.frames);
  // Recording (PLY frames are written as they come) counts as output time, not simulation.
  double record_seconds = 0.0;
  const auto record = [&](double t) {
    const auto t0 = Clock::now();
    recorder.record(t);
    record_seconds += secondsSince(t0);
  };
  record(0.0);
  const double first_record_seconds = record_seconds;  // before t_sim
  const auto t_sim = Clock::now();
  ProgressBar progress(report.steps, options.progress_bar);
  Scene& scene = *built.scene;
  for (int s = 1; s <= report.steps; ++s) {
    StepStats stats;
    try {
      stats = scene.step();
    } catch (const Error& e) {
      std::string names;  // Scene numbers its simulables in the scene's avatar order
      for (const SceneAvatar& run : built.avatars)
        names += (names.empty() ? "" : ", ") + run.spec->name;
      throw Error("simulation failed at step " + std::to_string(s) + " (t = " + number(s * h) +
                  " s): " + e.what() + " (simulables 0, 1, ... are the avatars " + names +
                  "); nothing was written");
    }
    report.newton_iterations += stats.newton.iterations;
    report.factorizations += stats.newton.factorizations;
    report.cg_iterations += stats.newton.cg_iterations;
    report.max_contacts = std::max(report.max_contacts, stats.active_contacts);
    if (report.iteration_budget > 0 && stats.newton.max_iterations_reached)
      ++report.at_budget;
    else if (!stats.newton.converged && report.unconverged++ == 0)
      report.first_unconverged = "step " + std::to_string(s) + ": " + stats.newton.message;
    if (s % wanted.every == 0) record(s * h);
    progress.update(s, s * h);
  }
  progress.finish();
  report.simulation_seconds = secondsSince(t_sim) - (record_seconds - first_record_seconds);

  // ---- outputs: each file atomic in the staging folder, which then replaces outputs.dir ----
  const auto t_out = Clock::now();
  report.written = recorder.finish();
  if (out_dir) out_dir->commit();
  report.output_seconds = secondsSince(t_out) + record_seconds;
  for (size_t i = 0; i < built.avatars.size(); ++i) {
    const SceneAvatar& run = built.avatars[i];
    report.avatar_names.push_back(run.spec->name);
    report.avatar_models.push_back(run.spec->simulation);
    report.max_displacement_mm.push_back(run.soft ? recorder.maxDisplacementMm(i) : -1.0);
  }
  report.sheet = wanted.png;
  report.sheet_max_displacement_mm = recorder.sheetMaxDisplacementMm();
  return report;
}

std::string SceneRunReport::summary() const {
  std::string text;
  char line[8192];  // the summary line names the scene file and the output folder
  bool any_soft = false;
  for (size_t i = 0; i < avatar_names.size(); ++i) {
    if (max_displacement_mm[i] < 0) continue;
    any_soft = true;
    std::snprintf(line, sizeof(line),
                  "simulate: avatar '%s' (%s): max soft-tissue displacement |u| %.3f mm over the "
                  "saved frames\n",
                  avatar_names[i].c_str(), avatar_models[i].c_str(), max_displacement_mm[i]);
    text += line;
  }
  if (sheet && any_soft) {
    std::snprintf(line, sizeof(line),
                  "simulate: sheet.png colours soft avatars by |u| (viridis): 0 mm dark purple to "
                  "%.3f mm yellow\n",
                  sheet_max_displacement_mm);
    text += line;
  }
  std::string outputs;
  for (const std::string& w : written) outputs += (outputs.empty() ? "" : ", ") + w;
  const std::string ground_note = ground ? " (ground at y = " + number(ground_height) + " m" +
                                               (ground_automatic ? ", auto)" : ")")
                                         : "";
  const double per_step = 1.0 / std::max(1, steps);
  const std::string budget_note = iteration_budget > 0
                                      ? ", " + std::to_string(at_budget) + " at the budget of " +
                                            std::to_string(iteration_budget) + " iterations"
                                      : "";
  std::snprintf(line, sizeof(line),
                "simulate: %s: %d avatar(s), %d collider(s)%s, %d steps of %.4g s (%.3g s), "
                "%d frames; %.0f steps/s, %.2f Newton iterations/step (%.2f factorizations, "
                "%.1f PCG iterations), %d unconverged%s, "
                "max %d contacts; wall time: set-up %.2f s, simulation %.2f s, output %.2f s; "
                "wrote %s in %s\n",
                source.c_str(), avatars, colliders, ground_note.c_str(), steps, time_step,
                steps * time_step, frames, steps / std::max(simulation_seconds, 1e-9),
                newton_iterations * per_step, factorizations * per_step, cg_iterations * per_step,
                unconverged, budget_note.c_str(), max_contacts, setup_seconds, simulation_seconds,
                output_seconds, outputs.empty() ? "nothing" : outputs.c_str(), output_dir.c_str());
  return text + line;
}

std::string SceneRunReport::unconvergedWarning() const {
  if (unconverged == 0) return "";
  return std::to_string(unconverged) + " of " + std::to_string(steps) +
         " steps did not converge (first: " + first_unconverged + ")";
}

}  // namespace flsh::io
