// Bindings of include/flsh/io: scene files (a read-only view of the parsed SceneSpec), and
// building and running them (load_scene, run_scene).
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <Eigen/LU>
#include <cstdio>
#include <memory>

#include "bindings.h"
#include "flsh/io/scene_build.h"
#include "flsh/io/scene_file.h"
#include "flsh/io/scene_run.h"

namespace flsh::python {

void bind_io(py::module_& m) {
  m.def(
      "fit_betas",
      [](const py::object& betas, const BodyModel& body, const std::string& origin) {
        const VecX b = to_vector(betas, "betas", -1, "(K,)");
        std::string warning;
        const VecX fitted = io::fitBetas(b, body, origin, &warning);
        if (!warning.empty() &&
            PyErr_WarnEx(PyExc_UserWarning, ("flsh: " + warning).c_str(), 1) != 0)
          throw py::error_already_set();  // warnings turned into errors
        return to_numpy(fitted);
      },
      py::arg("betas"), py::arg("body"), py::arg("origin") = "betas",
      "`betas` for `body`'s K shape components: shorter stays, longer is cut to K with a "
      "UserWarning naming `origin` if a dropped value is nonzero (AMASS clips carry 16).");
  // --- Scene files (read-only views) ---------------------------------------------------------
  py::class_<AvatarSpec>(m, "AvatarSpec", "One avatar of a scene file (read-only).")
      .def_readonly("name", &AvatarSpec::name)
      .def_readonly("model", &AvatarSpec::model, "SMPL .npz path or 'synthetic'")
      .def_readonly("synthetic_vertices", &AvatarSpec::synthetic_vertices)
      .def_property_readonly(
          "betas", [](const AvatarSpec& a) { return to_numpy(a.betas); },
          "(K,) shape; empty = zeros")
      .def_readonly("simulation", &AvatarSpec::simulation, "'skeleton', 'fem' or 'rom'")
      .def_readonly("resolution", &AvatarSpec::resolution, "tet-mesh resolution ('fem', 'rom')")
      .def_readonly("material_file", &AvatarSpec::material_file,
                    "material file, resolved ('fem', 'rom'); '' = built-in")
      .def_property_readonly(
          "basis", [](const AvatarSpec& a) { return std::string(reducedBasisKindName(a.basis)); },
          "the reduced basis ('rom'): 'modes', 'handles' or 'modes+handles'")
      .def_readonly("vibration_modes", &AvatarSpec::vibration_modes,
                    "fixed-interface vibration modes of the modal basis ('rom' with modes)")
      .def_readonly("modal_columns", &AvatarSpec::modal_columns,
                    "columns of the compressed modal basis ('rom' with modes); 0 = all")
      .def_readonly("handles", &AvatarSpec::handles,
                    "point handles ('rom' with the handle basis or modes+handles)")
      .def_readonly("elastic_cubature", &AvatarSpec::elastic_cubature,
                    "elastic cubature tets ('rom'); 0 = off")
      .def_readonly("inertial_cubature", &AvatarSpec::inertial_cubature,
                    "inertial cubature tets ('rom'); 0 = off")
      .def_readonly("motion", &AvatarSpec::motion, "AMASS .npz path or builtin:NAME; '' = none")
      .def_readonly("motion_seconds", &AvatarSpec::motion_seconds, "s; 0 = the duration")
      .def_property_readonly(
          "offset", [](const AvatarSpec& a) { return to_numpy(VecX(a.offset)); },
          "(3,) added to the motion's root translation, m")
      .def_readonly("yaw", &AvatarSpec::yaw, "rotation of the motion about +y, rad")
      .def_readonly("up", &AvatarSpec::up,
                    "up axis of the motion file, 'y' or 'z'; '' = the file's, else 'z'")
      .def_readonly("options", &AvatarSpec::options, "SimulableOptions")
      .def("__repr__", [](const AvatarSpec& a) {
        return "AvatarSpec(name='" + a.name + "', model='" + a.model + "', motion='" + a.motion +
               "')";
      });
  py::class_<OutputSpec>(m, "OutputSpec", "Outputs of a scene file (read-only).")
      .def_readonly("dir", &OutputSpec::dir)
      .def_readonly("ply", &OutputSpec::ply)
      .def_readonly("npz", &OutputSpec::npz)
      .def_readonly("gltf", &OutputSpec::gltf)
      .def_readonly("png", &OutputSpec::png)
      .def_readonly("png_frames", &OutputSpec::png_frames)
      .def_readonly("every", &OutputSpec::every, "write every n-th frame");
  py::class_<SceneSpec>(m, "SceneSpec", "A parsed, validated scene file (read-only).")
      .def_readonly("source", &SceneSpec::source, "file path or 'builtin default scene'")
      .def_readonly("avatars", &SceneSpec::avatars, "list of AvatarSpec")
      .def_readonly("colliders", &SceneSpec::colliders,
                    "list of Collider (without the \"ground\" key's plane)")
      .def_property_readonly(
          "ground",
          [](const SceneSpec& s) -> py::object {
            if (!s.ground.enabled) return py::none();
            if (s.ground.automatic) return py::str("auto");
            return py::float_(s.ground.height);
          },
          "the \"ground\" key: None, 'auto' or a height y (m)")
      .def_readonly("time_step", &SceneSpec::time_step, "s")
      .def_readonly("duration", &SceneSpec::duration, "s")
      .def_readonly("newton", &SceneSpec::newton, "NewtonOptions")
      .def_readonly("soft_tissue_gradient_tolerance", &SceneSpec::soft_tissue_gradient_tolerance,
                    "Newton tolerance of scenes with FEM avatars; <= 0 = the default")
      .def_readonly("reduced_gradient_tolerance", &SceneSpec::reduced_gradient_tolerance,
                    "Newton tolerance of scenes whose soft avatars are all ROM; <= 0 = the default")
      .def_readonly("soft_tissue_lagged", &SceneSpec::soft_tissue_lagged,
                    "LaggedFactorOptions of the FEM's solver (newton.soft_tissue_lagged)")
      .def_readonly("reduced_lagged", &SceneSpec::reduced_lagged,
                    "LaggedFactorOptions of the ROM's solver (newton.reduced_lagged)")
      .def_property_readonly(
          "preset", [](const SceneSpec& s) { return std::string(presetName(s.preset)); },
          "'none' or 'realtime' (the scene key \"preset\")")
      .def_readonly("reduced_iteration_budget", &SceneSpec::reduced_iteration_budget,
                    "Newton iterations per step of the ROM's solver as a budget; 0 = none")
      .def_readonly("avatar_contact", &SceneSpec::avatar_contact)
      .def_readonly("outputs", &SceneSpec::outputs, "OutputSpec")
      .def("__repr__", [](const SceneSpec& s) {
        return "SceneSpec(source='" + s.source + "', avatars=" + std::to_string(s.avatars.size()) +
               ", colliders=" + std::to_string(s.colliders.size()) + ")";
      });
  const auto overrides_of = [](double duration, double time_step, const std::string& out) {
    SceneOverrides o;
    o.duration = duration;
    o.time_step = time_step;
    o.output_dir = out;
    return o;
  };
  m.def(
      "load_scene_file",
      [overrides_of](const std::filesystem::path& path, double duration, double time_step,
                     const std::string& output_dir) {
        const std::string p = path_string(path);
        require_existing_file(p, "load_scene_file");
        const SceneOverrides o = overrides_of(duration, time_step, output_dir);
        py::gil_scoped_release release;
        return loadSceneFile(p, o);
      },
      py::arg("path"), py::kw_only(), py::arg("duration") = 0.0, py::arg("time_step") = 0.0,
      py::arg("output_dir") = "",
      "Parses and validates a scene file (JSON) as a SceneSpec. Overrides (0 / '' = keep): "
      "duration s, time_step s, output_dir. FileNotFoundError / OSError / ValueError.");
  m.def(
      "default_scene",
      [overrides_of](double duration, double time_step, const std::string& output_dir) {
        return defaultScene(overrides_of(duration, time_step, output_dir));
      },
      py::kw_only(), py::arg("duration") = 0.0, py::arg("time_step") = 0.0,
      py::arg("output_dir") = "",
      "The built-in default SceneSpec (a synthetic avatar walking, a ball thrown at it).");

  // A scene file (or None: the built-in default scene) parsed with its overrides.
  const auto scene_spec = [overrides_of](const py::object& path, double duration, double time_step,
                                         const std::string& output_dir, const std::string& fn) {
    const SceneOverrides o = overrides_of(duration, time_step, output_dir);
    if (path.is_none()) return defaultScene(o);
    const std::string p = path_string(path.cast<std::filesystem::path>());
    require_existing_file(p, fn);
    return loadSceneFile(p, o);
  };
  const auto stderr_log = [](const std::string& prefix) {
    return [prefix](const std::string& line) {
      std::fprintf(stderr, "%s%s\n", prefix.c_str(), line.c_str());
    };
  };
  m.def(
      "load_scene",
      [scene_spec, stderr_log](const py::object& path, double duration, double time_step,
                               bool verbose) {
        const SceneSpec spec = scene_spec(path, duration, time_step, "", "load_scene");
        py::gil_scoped_release release;
        return io::buildScene(spec, verbose ? io::SceneBuildLog(stderr_log("load_scene: "))
                                            : io::SceneBuildLog())
            .scene;
      },
      py::arg("path") = py::none(), py::kw_only(), py::arg("duration") = 0.0,
      py::arg("time_step") = 0.0, py::arg("verbose") = true,
      "A scene file (None: the built-in default scene) built into a ready, initialized Scene: "
      "its avatars (Scene.simulables, in the file's order), colliders and \"ground\", solver "
      "settings; step it with Scene.step(). Progress and warnings go to stderr (verbose). "
      "Overrides (0 = keep): duration s, time_step s.");
  m.def(
      "load_scene_avatars",
      [scene_spec, stderr_log](const py::object& path, double duration, double time_step,
                               bool verbose) {
        const SceneSpec spec = scene_spec(path, duration, time_step, "", "load_scene_avatars");
        std::vector<io::SceneAvatar> avatars;
        std::vector<Collider> colliders;
        {
          py::gil_scoped_release release;
          const io::SceneBuildLog log =
              verbose ? io::SceneBuildLog(stderr_log("load_scene_avatars: ")) : io::SceneBuildLog();
          avatars = io::buildSceneAvatars(spec, log);
          colliders = io::sceneColliders(spec, avatars, log);
        }
        py::list parts;
        for (const io::SceneAvatar& a : avatars) {
          py::dict part;
          part["name"] = a.spec->name;
          part["simulation"] = a.spec->simulation;
          // Shared with the simulable: read only (Python's holders are non-const).
          part["body"] = std::const_pointer_cast<BodyModel>(a.body);
          part["avatar"] = a.avatar;
          part["motion"] =
              a.motion ? py::cast(std::const_pointer_cast<Motion>(a.motion)) : py::none();
          part["simulable"] = a.simulable;
          parts.append(part);
        }
        py::dict scene;
        scene["spec"] = spec;
        scene["avatars"] = parts;
        scene["colliders"] = colliders;
        scene["steps"] = io::sceneSteps(spec);
        return scene;
      },
      py::arg("path") = py::none(), py::kw_only(), py::arg("duration") = 0.0,
      py::arg("time_step") = 0.0, py::arg("verbose") = false,
      "The parts of a scene file (None: the built-in default scene) built as load_scene builds "
      "them, without a Scene: a dict with 'spec' (SceneSpec), 'avatars' (per avatar a dict "
      "name, simulation, body, avatar (SoftAvatar, volumetric data ready), motion (Motion or "
      "None), simulable (not initialized)), 'colliders' (the scene's and its \"ground\") and "
      "'steps' (duration / time_step). What flsh.torch.RolloutSimulator.from_scene reads; the "
      "objects are shared: treat them as read only.");
  m.def(
      "run_scene",
      [scene_spec, stderr_log](const py::object& path, const std::string& out_dir, double duration,
                               double time_step, bool progress) {
        const SceneSpec spec = scene_spec(path, duration, time_step, out_dir, "run_scene");
        io::SceneRunOptions options;
        options.log = stderr_log("simulate: ");
        options.progress_bar = progress;
        if (!out_dir.empty()) options.output_dir_origin = "out_dir";
        io::SceneRunReport r;
        {
          py::gil_scoped_release release;
          r = io::runScene(spec, options);
        }
        const std::string warning = r.unconvergedWarning();
        if (!warning.empty()) std::fprintf(stderr, "simulate: warning: %s\n", warning.c_str());
        if (progress) std::fprintf(stderr, "%s", r.summary().c_str());
        py::dict report;
        report["source"] = r.source;
        report["output_dir"] = r.output_dir;
        report["written"] = r.written;
        report["avatars"] = r.avatar_names;
        report["colliders"] = r.colliders;
        report["ground_height"] = r.ground ? py::object(py::float_(r.ground_height)) : py::none();
        report["steps"] = r.steps;
        report["frames"] = r.frames;
        report["time_step"] = r.time_step;
        report["newton_iterations"] = r.newton_iterations;
        report["factorizations"] = r.factorizations;
        report["cg_iterations"] = r.cg_iterations;
        report["unconverged"] = r.unconverged;
        report["iteration_budget"] = r.iteration_budget;
        report["at_budget"] = r.at_budget;
        report["max_contacts"] = r.max_contacts;
        py::dict displacement;
        for (size_t i = 0; i < r.avatar_names.size(); ++i)
          if (r.max_displacement_mm[i] >= 0)
            displacement[py::str(r.avatar_names[i])] = r.max_displacement_mm[i];
        report["max_displacement_mm"] = displacement;
        report["setup_seconds"] = r.setup_seconds;
        report["simulation_seconds"] = r.simulation_seconds;
        report["output_seconds"] = r.output_seconds;
        report["summary"] = r.summary();
        return report;
      },
      py::arg("path") = py::none(), py::arg("out_dir") = "", py::kw_only(),
      py::arg("duration") = 0.0, py::arg("time_step") = 0.0, py::arg("progress") = true,
      "Runs a scene file (None: the built-in default scene) as `flsh simulate` does: the same "
      "outputs (meshes/, states.npz, animation.glb, sheet.png) in out_dir ('' = the file's "
      "outputs.dir), written through a staging folder; progress, warnings and the summary on "
      "stderr (progress=True). Returns a dict of the run's figures (steps, Newton "
      "iterations, unconverged steps, the ROM's iteration_budget of a preset (0: none) and "
      "the steps at_budget, contacts, max_displacement_mm per soft avatar, written files, times, "
      "summary). Overrides (0 = keep): duration s, time_step s.");
}

}  // namespace flsh::python
