// Bindings of include/flsh/io: motions (AMASS-style .npz, built-in motions), meshes (PLY / OBJ)
// and scene files (a read-only view of the parsed SceneSpec).
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <Eigen/LU>
#include <cmath>
#include <cstdio>
#include <memory>

#include "bindings.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/io/mesh_io.h"
#include "flsh/io/motion.h"
#include "flsh/io/motion_frame.h"
#include "flsh/io/scene_build.h"
#include "flsh/io/scene_file.h"
#include "flsh/io/scene_run.h"

namespace flsh::python {

namespace {

const Motion& motion_of(const py::object& self) { return self.cast<const Motion&>(); }

Motion make_motion(const py::object& poses, const py::object& trans, const py::object& betas,
                   double fps, const std::string& gender, const std::string& source,
                   const std::string& up) {
  const Mat3 world = worldFromUpAxis(up, "up");
  auto a = as_float64(poses, "poses");
  if (a.ndim() != 2 || (a.shape(1) != kSmplPoseSize && a.shape(1) != kSmplhPoseSize))
    check_shape(a, "poses", {-1, kSmplPoseSize}, "(T, 72) or (T, 156)");
  if (!(std::isfinite(fps) && fps > 0))
    throw py::value_error("fps: expected a positive frame rate, got " + std::to_string(fps));
  Motion motion;
  motion.poses = toSmplPoses(Eigen::Map<const RowMatX>(a.data(), a.shape(0), a.shape(1)));
  const long frames = long(a.shape(0));
  motion.trans = trans.is_none() ? RowMatX(RowMatX::Zero(frames, 3))
                                 : to_matrix(trans, "trans", frames, 3);
  if (!betas.is_none()) motion.betas = to_vector(betas, "betas", -1, "(K,)");
  motion.fps = fps;
  motion.gender = gender;
  motion.source = source;
  motion.up = up;
  if (up != "y") rotateMotion(motion, world);
  return motion;
}

}  // namespace

void bind_io(py::module_& m) {
  // --- Motion --------------------------------------------------------------------------------
  const py::ssize_t d = sizeof(double);
  py::class_<Motion, std::shared_ptr<Motion>>(
      m, "Motion", "A motion in SMPL's 72-value pose layout. Array properties are read-only.")
      .def(py::init(&make_motion), py::arg("poses"), py::arg("trans") = py::none(),
           py::arg("betas") = py::none(), py::arg("fps") = 30.0, py::arg("gender") = "",
           py::arg("source") = "", py::arg("up") = "y",
           "poses (T, 72) or SMPL-H (T, 156) axis-angle, rad (stored as (T, 72)); trans (T, 3) "
           "m or None (zeros); betas (K,) or None; fps > 0; up: the up axis the arrays were "
           "recorded in, 'y' (flsh's world) or 'z' (AMASS: the motion is turned upright, "
           "rotate_motion).")
      .def_property_readonly(
          "poses",
          [d](py::object self) {
            const RowMatX& p = motion_of(self).poses;
            return readonly_view(p.data(), {p.rows(), p.cols()}, {p.cols() * d, d}, self);
          },
          "(T, 72) axis-angle joint rotations, rad.")
      .def_property_readonly(
          "trans",
          [d](py::object self) {
            const RowMatX& t = motion_of(self).trans;
            return readonly_view(t.data(), {t.rows(), t.cols()}, {t.cols() * d, d}, self);
          },
          "(T, 3) root translation, m.")
      .def_property_readonly(
          "betas",
          [d](py::object self) {
            const VecX& b = motion_of(self).betas;
            return readonly_view(b.data(), {b.size()}, {d}, self);
          },
          "(K,) shape coefficients stored with the motion (may be empty).")
      .def_property_readonly(
          "fps", [](const Motion& mo) { return mo.fps; }, "Frames per second.")
      .def_property_readonly("gender", [](const Motion& mo) { return mo.gender; })
      .def_property_readonly(
          "up", [](const Motion& mo) { return mo.up; },
          "Up axis the source was recorded in, 'y' or 'z'; poses and trans "
          "are in flsh's y-up world either way.")
      .def_property_readonly(
          "source", [](const Motion& mo) { return mo.source; }, "File path or 'builtin:NAME'.")
      .def_property_readonly("num_frames", &Motion::numFrames, "T")
      .def_property_readonly("duration", &Motion::duration, "(T − 1) / fps, s.")
      .def("__len__", &Motion::numFrames)
      .def("__repr__", [](const Motion& mo) {
        return "Motion(source='" + mo.source + "', frames=" + std::to_string(mo.numFrames()) +
               ", fps=" + py::repr(py::float_(mo.fps)).cast<std::string>() + ")";
      });

  m.def(
      "load_motion",
      [](const std::filesystem::path& path, const py::object& up) {
        const std::string p = path_string(path);
        require_existing_file(p, "load_motion");
        const std::string axis = up.is_none() ? std::string() : up.cast<std::string>();
        py::gil_scoped_release release;
        return loadMotion(p, axis);
      },
      py::arg("path"), py::arg("up") = py::none(),
      "Reads an AMASS-style .npz (poses (T, 72|156), trans (T, 3), optional betas, "
      "mocap_framerate, gender, up) as a Motion with (T, 72) poses in flsh's y-up world. "
      "up: 'y' or 'z', the axis the clip was recorded with; None = the file's 'up' key, "
      "else 'z' (AMASS). Warns on stderr if the body is not upright at frame 0.");
  m.def(
      "save_motion",
      [](const Motion& motion, const std::filesystem::path& path, const std::string& up) {
        const std::string p = path_string(path);
        py::gil_scoped_release release;
        saveMotion(motion, p, up);
      },
      py::arg("motion"), py::arg("path"), py::arg("up") = "y",
      "Writes an AMASS-style .npz (poses (T, 72), trans, betas, mocap_framerate, gender, up), "
      "atomically: up='y' as the motion is in flsh's world, 'z' turned z up as AMASS stores "
      "clips (load_motion reads either back).");
  m.def("builtin_motion_names", &builtinMotionNames, "Names of the built-in motions.");
  m.def(
      "world_from_up_axis",
      [](const std::string& up) { return to_numpy(RowMatX(worldFromUpAxis(up))); }, py::arg("up"),
      "(3, 3) rotation from a frame whose up axis is 'y' or 'z' to flsh's y-up world "
      "('z': (x, y, z) -> (x, z, -y)).");
  m.def(
      "rotate_motion",
      [](const Motion& motion, const py::object& rotation) {
        const Mat3 R = to_matrix(rotation, "rotation", 3, 3);
        if (!((R.transpose() * R - Mat3::Identity()).norm() < 1e-9 && R.determinant() > 0))
          throw py::value_error(
              "rotation: expected a (3, 3) rotation matrix (orthonormal, "
              "determinant +1)");
        Motion turned = motion;
        rotateMotion(turned, R);
        return turned;
      },
      py::arg("motion"), py::arg("rotation"),
      "A copy of `motion` turned by the (3, 3) rotation about the root joint's rest position "
      "(trans <- R trans, root <- R root): every posed vertex v -> J0 + R (v - J0).");
  m.def(
      "placed_motion",
      [](const Motion& motion, double yaw, const py::object& offset) {
        return placedMotion(motion, yaw, to_vec3(offset, "offset"));
      },
      py::arg("motion"), py::arg("yaw") = 0.0, py::arg("offset") = py::make_tuple(0.0, 0.0, 0.0),
      "A copy of `motion` turned by `yaw` rad about +y through the root's rest position, then "
      "moved by `offset` (3,) m, as a scene file's yaw_degrees and offset do.");
  m.def(
      "lowest_point_height",
      [](const BodyModel& body, const py::object& betas, const Motion& motion, double seconds) {
        const VecX b =
            betas.is_none() ? VecX::Zero(body.numBetas()) : to_vector(betas, "betas", -1, "(K,)");
        py::gil_scoped_release release;
        return lowestPointHeight(body, b, motion, seconds);
      },
      py::arg("body"), py::arg("betas"), py::arg("motion"), py::arg("seconds") = 1.0,
      "World height y (m) of the body's lowest vertex posed by `motion` over its first "
      "`seconds`: where to put the ground under a clip (a scene file's \"ground\": \"auto\").");
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
  m.def("upright_warning", &uprightWarning, py::arg("motion"),
        "A warning sentence if the body leans more than 60 degrees from +y at frame 0 (the usual "
        "sign of a wrong up axis), else ''.");
  m.def("make_builtin_motion", [](const std::string& name, double seconds, double fps) {
          py::gil_scoped_release release;
          return makeBuiltinMotion(name, seconds, fps);
        },
        py::arg("name"), py::arg("seconds") = 2.0, py::arg("fps") = 30.0,
        "A built-in procedural motion `seconds` long (s) at `fps`; ValueError for unknown names.");
  m.def(
      "load_or_make_motion",
      [](const std::string& spec, double seconds, double fps, const py::object& up) {
        const std::string axis = up.is_none() ? std::string() : up.cast<std::string>();
        py::gil_scoped_release release;
        return loadOrMakeMotion(spec, seconds, fps, axis);
      },
      py::arg("spec"), py::arg("seconds") = 2.0, py::arg("fps") = 30.0, py::arg("up") = py::none(),
      "A motion file path if it exists, else 'builtin:NAME' or NAME of a built-in motion.");

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
      .def_readonly("handles", &AvatarSpec::handles, "reduced-basis handles ('rom')")
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
  m.def("load_scene_file",
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
  m.def("default_scene",
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
      "iterations, contacts, max_displacement_mm per soft avatar, written files, times, "
      "summary). Overrides (0 = keep): duration s, time_step s.");

  // --- Meshes --------------------------------------------------------------------------------
  m.def("write_ply",
        [](const std::filesystem::path& path, const py::object& vertices, const py::object& faces,
           const py::object& colors, bool binary) {
          const MatX3 V = to_points(vertices, "vertices");
          const MatX3i F = to_triangles(faces, "faces");
          const io::Colors C =
              colors.is_none() ? io::Colors() : to_points(colors, "colors", V.rows());
          const std::string p = path_string(path);
          py::gil_scoped_release release;
          io::writePly(p, V, F, C, binary);
        },
        py::arg("path"), py::arg("vertices"), py::arg("faces"), py::arg("colors") = py::none(),
        py::arg("binary") = true,
        "Writes a PLY (binary little-endian or ASCII) atomically: vertices (V, 3) m, faces (F, 3) "
        "int, colors (V, 3) RGB in [0, 1] or None.");
  m.def("write_obj",
        [](const std::filesystem::path& path, const py::object& vertices, const py::object& faces) {
          const MatX3 V = to_points(vertices, "vertices");
          const MatX3i F = to_triangles(faces, "faces");
          const std::string p = path_string(path);
          py::gil_scoped_release release;
          io::writeObj(p, V, F);
        },
        py::arg("path"), py::arg("vertices"), py::arg("faces"),
        "Writes an OBJ atomically: vertices (V, 3) m, faces (F, 3) int.");
  m.def("read_mesh", [](const std::filesystem::path& path) {
          const std::string p = path_string(path);
          require_existing_file(p, "read_mesh");
          MatX3 V;
          MatX3i F;
          {
            py::gil_scoped_release release;
            io::readMesh(p, V, F);
          }
          return py::make_tuple(to_numpy(V), to_numpy(F));
        },
        py::arg("path"), "Reads a PLY or OBJ triangle mesh: (vertices (V, 3) float64, faces (F, 3) int32).");
}

}  // namespace flsh::python
