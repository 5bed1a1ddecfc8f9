// Bindings of include/flsh/body: the SMPL skeleton tables, BodyModel (read-only numpy views of
// its arrays), the synthetic body, the forward pass with its Jacobians, and motions.
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <Eigen/LU>
#include <cmath>
#include <memory>

#include "bindings.h"
#include "flsh/body/body_forward.h"
#include "flsh/body/body_model.h"
#include "flsh/body/motion.h"
#include "flsh/body/motion_frame.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/body/synthetic_body.h"

namespace flsh::python {

namespace {

/// One posed frame as numpy arrays; the Jacobians are None unless they were requested.
struct PyPosedBody {
  py::array vertices, joints, rest_joints, transforms;
  py::object vertices_betas = py::none(), vertices_pose = py::none(),
             vertices_trans = py::none(), joints_betas = py::none(), joints_pose = py::none(),
             joints_trans = py::none();
};

/// T posed frames as numpy arrays.
struct PyPosedBatch {
  py::array vertices, joints;
};

// A 3N × M column-major Jacobian (row 3i + c) as an (N, 3, M) array that takes over its
// storage: a strided view instead of a copy (the pose Jacobian of SMPL is 12 MB).
py::array jacobian_to_numpy(MatX&& jacobian) {
  const py::ssize_t rows = jacobian.rows(), cols = jacobian.cols(), d = sizeof(double);
  auto* owned = new MatX(std::move(jacobian));
  py::capsule free_when_done(owned, [](void* p) { delete static_cast<MatX*>(p); });
  return py::array_t<double>({rows / 3, py::ssize_t(3), cols}, {3 * d, d, rows * d},
                             owned->data(), free_when_done);
}

VecX checked_betas(const BodyModel& model, const py::object& betas) {
  const VecX b = to_vector(betas, "betas", -1, "(K,)");
  if (b.size() > model.numBetas())
    throw py::value_error("betas: expected at most " + std::to_string(model.numBetas()) +
                          " values (the model's shape components), got shape " +
                          shape_text({long(b.size())}));
  return b;
}

RowMatX checked_poses(const py::object& poses) {
  auto a = as_float64(poses, "poses");
  if (a.ndim() != 2 || (a.shape(1) != kSmplPoseSize && a.shape(1) != kSmplhPoseSize))
    check_shape(a, "poses", {-1, kSmplPoseSize}, "(T, 72) or (T, 156)");
  return Eigen::Map<const RowMatX>(a.data(), a.shape(0), a.shape(1));
}

const BodyModel& model_of(const py::object& self) { return self.cast<const BodyModel&>(); }

// An `rows × cols` column-major Eigen matrix whose rows are 3i + c, viewed as (rows/3, 3, cols).
py::array blend_shapes_view(const MatX& m, const py::object& owner) {
  const py::ssize_t d = sizeof(double);
  return readonly_view(m.data(), {m.rows() / 3, 3, m.cols()}, {3 * d, d, m.rows() * d}, owner);
}

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
  motion.trans =
      trans.is_none() ? RowMatX(RowMatX::Zero(frames, 3)) : to_matrix(trans, "trans", frames, 3);
  if (!betas.is_none()) motion.betas = to_vector(betas, "betas", -1, "(K,)");
  motion.fps = fps;
  motion.gender = gender;
  motion.source = source;
  motion.up = up;
  if (up != "y") rotateMotion(motion, world);
  return motion;
}

// Motion: plain data beside the body (include/flsh/body/motion.h, motion_frame.h).
void bind_motion(py::module_& m) {
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
  m.def("upright_warning", &uprightWarning, py::arg("motion"),
        "A warning sentence if the body leans more than 60 degrees from +y at frame 0 (the usual "
        "sign of a wrong up axis), else ''.");
  m.def(
      "make_builtin_motion",
      [](const std::string& name, double seconds, double fps) {
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
}

}  // namespace

void bind_body(py::module_& m) {
  // --- Skeleton tables -----------------------------------------------------------------------
  py::tuple names(kNumJoints), parents(kNumJoints);
  for (int j = 0; j < kNumJoints; ++j) {
    names[j] = py::str(kSmplJointNames[j]);
    parents[j] = py::int_(kSmplParents[j]);
  }
  m.attr("SMPL_JOINT_NAMES") = names;
  m.attr("SMPL_PARENTS") = parents;
  m.attr("NUM_JOINTS") = kNumJoints;
  m.def("smpl_joint_index", &smplJointIndex, py::arg("name"),
        "Index (0..23) of an SMPL joint by name, e.g. 'left_knee'; ValueError if unknown.");
  m.def("to_smpl_pose",
        [](const py::object& pose) { return to_numpy(toSmplPose(to_pose(pose, "pose"))); },
        py::arg("pose"),
        "A (72,) or SMPL-H (156,) pose, rad, as SMPL's (72,): body joints 0–21 kept, hands 0.");

  // --- BodyModel -----------------------------------------------------------------------------
  const py::ssize_t d = sizeof(double);
  py::class_<BodyModel, std::shared_ptr<BodyModel>>(
      m, "BodyModel",
      "Immutable SMPL-format body model. Array properties are read-only numpy views, m.")
      .def_property_readonly(
          "v_template",
          [d](py::object self) {
            const BodyModel& b = model_of(self);
            return readonly_view(b.v_template.data(), {b.v_template.rows(), 3}, {3 * d, d}, self);
          },
          "(V, 3) template vertices (T-pose, mean shape), m.")
      .def_property_readonly(
          "shapedirs",
          [](py::object self) { return blend_shapes_view(model_of(self).shapedirs, self); },
          "(V, 3, K) shape directions, m per unit β.")
      .def_property_readonly(
          "posedirs",
          [](py::object self) { return blend_shapes_view(model_of(self).posedirs, self); },
          "(V, 3, 207) pose blend shapes, m per unit entry of R_j − I (j = 1..23, row-major).")
      .def_property_readonly(
          "J_regressor",
          [](py::object self) { return to_numpy(RowMatX(model_of(self).J_regressor)); },
          "(24, V) joint regressor as a dense copy: J = J_regressor @ v_shaped.")
      .def_property_readonly(
          "weights",
          [d](py::object self) {
            const MatX& w = model_of(self).weights;
            return readonly_view(w.data(), {w.rows(), w.cols()}, {d, w.rows() * d}, self);
          },
          "(V, 24) skinning weights; rows sum to 1.")
      .def_property_readonly(
          "parents",
          [](py::object self) {
            const auto& p = model_of(self).parents;
            py::array_t<int> a(py::ssize_t(p.size()));
            std::copy(p.begin(), p.end(), a.mutable_data());
            return a;
          },
          "(24,) int parent of each joint; parents[0] = -1.")
      .def_property_readonly(
          "faces",
          [](py::object self) {
            const MatX3i& f = model_of(self).faces;
            return readonly_view(f.data(), {f.rows(), 3},
                                 {3 * py::ssize_t(sizeof(int)), py::ssize_t(sizeof(int))}, self);
          },
          "(F, 3) int32 triangles, counter-clockwise seen from outside.")
      .def_property_readonly(
          "source", [](const BodyModel& b) { return b.source; },
          "File path or 'synthetic(...)' the model came from.")
      .def_property_readonly(
          "family", [](const BodyModel& b) { return b.family; },
          "'SMPL', or 'SMPL-H' for an SMPL-H / SMPL+H file converted to "
          "SMPL's 24 joints (finger joints merged into the hands).")
      .def_property_readonly("num_vertices", &BodyModel::numVertices, "V")
      .def_property_readonly("num_faces", &BodyModel::numFaces, "F")
      .def_property_readonly("num_betas", &BodyModel::numBetas, "K, number of shape components")
      .def_property_readonly("num_joints", &BodyModel::numJoints, "24")
      .def("__repr__", [](const BodyModel& b) {
        return "BodyModel(source='" + b.source + "', family='" + b.family +
               "', vertices=" + std::to_string(b.numVertices()) +
               ", faces=" + std::to_string(b.numFaces()) +
               ", betas=" + std::to_string(b.numBetas()) +
               ", joints=" + std::to_string(b.numJoints()) + ")";
      });

  m.def("load_body_model", [](const std::filesystem::path& path) {
          const std::string p = path_string(path);
          require_existing_file(p, "load_body_model");
          py::gil_scoped_release release;
          return std::make_shared<BodyModel>(loadBodyModel(p));
        },
        py::arg("path"),
        "Loads an SMPL-format .npz (v_template, shapedirs, posedirs, J_regressor, weights, "
        "kintree_table, f; float32 or float64). FileNotFoundError / OSError / ValueError.");
  m.def("save_body_model", [](const BodyModel& model, const std::filesystem::path& path) {
          const std::string p = path_string(path);
          py::gil_scoped_release release;
          saveBodyModel(model, p);
        },
        py::arg("model"), py::arg("path"),
        "Writes the model as an SMPL-format .npz (float64 arrays, int64 kintree_table and f), "
        "atomically; load_body_model reads it back exactly.");

  // --- Synthetic body ------------------------------------------------------------------------
  py::class_<SyntheticBodyOptions>(m, "SyntheticBodyOptions", "Options of make_synthetic_body.")
      .def(py::init([](int vertices, double height) {
             SyntheticBodyOptions o;
             o.vertices = vertices;
             o.height = height;
             return o;
           }),
           py::kw_only(), py::arg("vertices") = SyntheticBodyOptions{}.vertices,
           py::arg("height") = SyntheticBodyOptions{}.height)
      .def_readwrite("vertices", &SyntheticBodyOptions::vertices,
                     "Number of surface vertices (exact, ≥ 200); 2V − 4 triangles.")
      .def_readwrite("height", &SyntheticBodyOptions::height,
                     "Height of the mean shape in T-pose, m.")
      .def("__repr__", [](const SyntheticBodyOptions& o) {
        return "SyntheticBodyOptions(vertices=" + std::to_string(o.vertices) +
               ", height=" + py::repr(py::float_(o.height)).cast<std::string>() + ")";
      });
  py::tuple shape_names(kSyntheticShapeNames.size());
  for (size_t k = 0; k < kSyntheticShapeNames.size(); ++k)
    shape_names[k] = py::str(kSyntheticShapeNames[k]);
  m.attr("SYNTHETIC_SHAPE_NAMES") = shape_names;

  m.def("make_synthetic_body", [](const SyntheticBodyOptions& options) {
          py::gil_scoped_release release;
          return std::make_shared<BodyModel>(makeSyntheticBody(options));
        },
        py::arg("options"),
        "Generates the synthetic SMPL-format body (deterministic; ValueError if vertices < 200).");
  m.def("make_synthetic_body", [](int vertices, double height) {
          SyntheticBodyOptions options;
          options.vertices = vertices;
          options.height = height;
          py::gil_scoped_release release;
          return std::make_shared<BodyModel>(makeSyntheticBody(options));
        },
        py::arg("vertices") = SyntheticBodyOptions{}.vertices,
        py::arg("height") = SyntheticBodyOptions{}.height,
        "Generates the synthetic SMPL-format body with `vertices` surface vertices and a "
        "T-pose `height` in m.");

  // --- Forward pass --------------------------------------------------------------------------
  py::class_<PyPosedBody>(m, "PosedBody", "One posed frame (pose_body). Lengths in m.")
      .def_readonly("vertices", &PyPosedBody::vertices, "(V, 3) world vertices, m (with trans).")
      .def_readonly("joints", &PyPosedBody::joints, "(24, 3) posed joint centres, m (with trans).")
      .def_readonly("rest_joints", &PyPosedBody::rest_joints,
                    "(24, 3) joint centres of the shaped T-pose, m.")
      .def_readonly("transforms", &PyPosedBody::transforms,
                    "(24, 4, 4) global bone transforms G_j (translation = posed joint, no trans).")
      .def_readonly("vertices_betas", &PyPosedBody::vertices_betas,
                    "(V, 3, K) d vertices / d betas, or None without jacobians=True.")
      .def_readonly("vertices_pose", &PyPosedBody::vertices_pose,
                    "(V, 3, 72) d vertices / d pose (SMPL layout), m/rad, or None.")
      .def_readonly("vertices_trans", &PyPosedBody::vertices_trans,
                    "(V, 3, 3) d vertices / d trans (identity blocks), or None.")
      .def_readonly("joints_betas", &PyPosedBody::joints_betas,
                    "(24, 3, K) d joints / d betas, or None.")
      .def_readonly("joints_pose", &PyPosedBody::joints_pose,
                    "(24, 3, 72) d joints / d pose, m/rad, or None.")
      .def_readonly("joints_trans", &PyPosedBody::joints_trans,
                    "(24, 3, 3) d joints / d trans (identity blocks), or None.")
      .def("__repr__", [](const PyPosedBody& b) {
        return "PosedBody(vertices=" + std::to_string(b.vertices.shape(0)) +
               ", jacobians=" + (b.vertices_pose.is_none() ? "False" : "True") + ")";
      });

  m.def("pose_body",
        [](const BodyModel& model, const py::object& betas, const py::object& pose,
           const py::object& trans, bool jacobians) {
          const VecX b = checked_betas(model, betas);
          const VecX p = to_pose(pose, "pose");
          const Vec3 t = trans.is_none() ? Vec3::Zero() : to_vec3(trans, "trans");
          PosedBody body;
          PosedBodyJacobians jac;
          {
            py::gil_scoped_release release;
            body = poseBody(model, b, p, t, jacobians ? &jac : nullptr);
          }
          PyPosedBody out;
          const py::ssize_t J = py::ssize_t(body.joints.rows());
          out.vertices = take_numpy(std::move(body.vertices), {model.numVertices(), 3});
          out.joints = take_numpy(std::move(body.joints), {J, 3});
          out.rest_joints = take_numpy(std::move(body.rest_joints), {J, 3});
          py::array_t<double> transforms({py::ssize_t(body.transforms.size()), py::ssize_t(4),
                                          py::ssize_t(4)});
          auto G = transforms.mutable_unchecked<3>();
          for (size_t j = 0; j < body.transforms.size(); ++j)
            for (int r = 0; r < 4; ++r)
              for (int c = 0; c < 4; ++c) G(j, r, c) = body.transforms[j](r, c);
          out.transforms = transforms;
          if (jacobians) {
            out.vertices_betas = jacobian_to_numpy(std::move(jac.vertices_betas));
            out.vertices_pose = jacobian_to_numpy(std::move(jac.vertices_pose));
            out.vertices_trans = jacobian_to_numpy(std::move(jac.vertices_trans));
            out.joints_betas = jacobian_to_numpy(std::move(jac.joints_betas));
            out.joints_pose = jacobian_to_numpy(std::move(jac.joints_pose));
            out.joints_trans = jacobian_to_numpy(std::move(jac.joints_trans));
          }
          return out;
        },
        py::arg("model"), py::arg("betas"), py::arg("pose"), py::arg("trans") = py::none(),
        py::arg("jacobians") = false,
        "Poses one frame. betas (≤K,) zero padded; pose (72,) or SMPL-H (156,) axis-angle, rad; "
        "trans (3,) m or None. Returns PosedBody; with jacobians=True also d/d(betas, pose, "
        "trans) as (N, 3, K|72|3) arrays.");

  py::class_<PyPosedBatch>(m, "PosedBatch", "T posed frames (pose_body_batch), m.")
      .def_readonly("vertices", &PyPosedBatch::vertices, "(T, V, 3) world vertices, m.")
      .def_readonly("joints", &PyPosedBatch::joints, "(T, 24, 3) posed joint centres, m.")
      .def("__repr__", [](const PyPosedBatch& b) {
        return "PosedBatch(frames=" + std::to_string(b.vertices.shape(0)) +
               ", vertices=" + std::to_string(b.vertices.shape(1)) + ")";
      });

  m.def("pose_body_batch",
        [](const BodyModel& model, const py::object& betas, const py::object& poses,
           const py::object& trans) {
          const VecX b = checked_betas(model, betas);
          const RowMatX P = checked_poses(poses);
          const RowMatX T = trans.is_none() ? RowMatX(RowMatX::Zero(P.rows(), 3))
                                            : to_matrix(trans, "trans", P.rows(), 3);
          PosedBatch batch;
          {
            py::gil_scoped_release release;
            batch = poseBodyBatch(model, b, P, T);
          }
          PyPosedBatch out;
          const py::ssize_t frames = P.rows();
          out.vertices = take_numpy(std::move(batch.vertices), {frames, model.numVertices(), 3});
          out.joints = take_numpy(std::move(batch.joints), {frames, py::ssize_t(kNumJoints), 3});
          return out;
        },
        py::arg("model"), py::arg("betas"), py::arg("poses"), py::arg("trans") = py::none(),
        "Poses T frames in parallel (GIL released). betas (≤K,); poses (T, 72) or (T, 156), rad; "
        "trans (T, 3) m or None. Returns PosedBatch with vertices (T, V, 3), joints (T, 24, 3).");

  m.def("shaped_vertices",
        [](const BodyModel& model, const py::object& betas) {
          return to_numpy(shapedVertices(model, checked_betas(model, betas)));
        },
        py::arg("model"), py::arg("betas"),
        "Shaped T-pose vertices v_template + shapedirs·β, (V, 3), m.");
  bind_motion(m);
}

}  // namespace flsh::python
