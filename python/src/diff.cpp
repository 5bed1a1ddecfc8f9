// Bindings of include/flsh/diff: Rollout (a differentiable simulation of one Simulable over T
// steps), its inputs (RolloutInputs), gradients/directions (RolloutVariables), options and the
// per-step tape diagnostics. Arrays are numpy float64 with shape checks; run, backward and
// forward_sensitivities release the GIL (a Rollout is still not thread-safe: one call at a time).
#include <pybind11/stl.h>

#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "bindings.h"
#include "flsh/diff/rollout.h"

namespace flsh::python {

namespace {

// One member of RolloutInputs/RolloutVariables: numpy in (None = empty), numpy out (empty = None).
py::object vector_or_none(const VecX& v) {
  if (v.size() == 0) return py::none();
  return to_numpy(v);
}
py::object matrix_or_none(const RowMatX& m) {
  if (m.size() == 0) return py::none();
  return to_numpy(m);
}
VecX optional_vector(const py::object& obj, const std::string& name, long size = -1,
                     const std::string& expected = "") {
  if (obj.is_none()) return VecX();
  return to_vector(obj, name, size, expected);
}
RowMatX optional_matrix(const py::object& obj, const std::string& name, long cols) {
  if (obj.is_none()) return RowMatX();
  return to_matrix(obj, name, -1, cols);
}

// The members shared by RolloutInputs and RolloutVariables, with their shapes and units, in
// one place so that the two classes document them identically.
struct MemberDoc {
  const char* name;
  const char* doc;
};
constexpr const char* kPoseDoc =
    "(T, 72) tracking target rotation vectors per step, rad (SMPL layout: "
    "bone b ≥ 1 relative to its parent, the root global)";
constexpr const char* kRootDoc =
    "(T, 3) SMPL trans per step, m (the root joint's target is J_0(β) + trans)";
constexpr const char* kStateDoc =
    "(numDofs,) state vector q_0 (Simulable.getState layout: per bone [t_b m, r_b rad])";
constexpr const char* kVelocityDoc =
    "(numDofs,) initial velocity per DoF, m/s and world-frame rad/s (Simulable.setVelocity)";
constexpr const char* kStiffnessDoc =
    "(4,) joint (N/m), tracking (1/s²), root (1/s²), contact (N/m³) stiffness";
constexpr const char* kColliderDoc = "(3·#colliders,) translation of each collider's whole path, m";

RolloutVariables make_variables(const py::object& shape, const py::object& rest_joints,
                                const py::object& bone_inertia, const py::object& pose_targets,
                                const py::object& root_targets, const py::object& stiffnesses,
                                const py::object& collider_offsets, const py::object& initial_state,
                                const py::object& initial_velocity) {
  RolloutVariables v;
  v.shape = optional_vector(shape, "shape", -1, "(K,)");
  v.rest_joints = optional_vector(rest_joints, "rest_joints", 72);
  v.bone_inertia = optional_vector(bone_inertia, "bone_inertia", 240);
  v.pose_targets = optional_matrix(pose_targets, "pose_targets", 72);
  v.root_targets = optional_matrix(root_targets, "root_targets", 3);
  v.stiffnesses = optional_vector(stiffnesses, "stiffnesses", 4);
  v.collider_offsets = optional_vector(collider_offsets, "collider_offsets", -1, "(3·#colliders,)");
  v.initial_state = optional_vector(initial_state, "initial_state", -1, "(numDofs,)");
  v.initial_velocity = optional_vector(initial_velocity, "initial_velocity", -1, "(numDofs,)");
  return v;
}

// Checks a cotangent of one step's joints: (24, 3).
MatX3 joints_argument(const py::handle& obj, const std::string& name) {
  return to_points(obj, name, 24);
}

// A (T, rows, 3) float64 array checked against the rollout's T and `rows`.
py::array_t<double, py::array::c_style> trajectory_argument(const py::handle& obj,
                                                            const std::string& name, long steps,
                                                            long rows, const char* rows_name) {
  auto a = as_float64(obj, name);
  check_shape(a, name, {steps, rows, 3},
              "(T, " + std::string(rows_name) + ", 3) = " + shape_text({steps, rows, 3}));
  return a;
}

}  // namespace

void bind_diff(py::module_& m) {
  const RolloutOptions rollout_defaults;
  py::class_<TapeSolveOptions>(
      m, "TapeSolveOptions",
      "How the sweeps over a tape of snapshots (the FEM's) solve with each step's exact Hessian: "
      "by PCG preconditioned by a nearby step's factor (a float copy) and the bones' exact "
      "coarse level, or by a factor of every step. Systems under 2000 unknowns always factor.")
      .def(py::init<>())
      .def_readwrite("iterative", &TapeSolveOptions::iterative,
                     "PCG with a nearby step's factor (default True); False: every step "
                     "factors its exact Hessian")
      .def_readwrite("relative_tolerance", &TapeSolveOptions::relative_tolerance,
                     "PCG stops when |b - H x| <= relative_tolerance |b| (in (0, 1); default "
                     "1e-12)")
      .def_readwrite("max_iterations", &TapeSolveOptions::max_iterations,
                     "PCG iterations (>= 1) before the step factors its own Hessian instead "
                     "(default 60)")
      .def_readwrite("refactor_after_iterations", &TapeSolveOptions::refactor_after_iterations,
                     "a solve that needed more iterations (>= 0) makes the next step factor "
                     "(default 25)")
      .def_readwrite("max_right_hand_sides", &TapeSolveOptions::max_right_hand_sides,
                     "sweeps with more solves per step (>= 1; forward sensitivities' directions) "
                     "factor every step (default 3)")
      .def("__repr__", [](const TapeSolveOptions& o) {
        return std::string("TapeSolveOptions(iterative=") + (o.iterative ? "True" : "False") +
               ", relative_tolerance=" +
               py::repr(py::float_(o.relative_tolerance)).cast<std::string>() +
               ", max_iterations=" + std::to_string(o.max_iterations) +
               ", refactor_after_iterations=" + std::to_string(o.refactor_after_iterations) +
               ", max_right_hand_sides=" + std::to_string(o.max_right_hand_sides) + ")";
      });
  py::class_<RolloutOptions>(m, "RolloutOptions", "Options of a Rollout.")
      .def(py::init([](const py::object& newton, const py::object& soft_tissue_newton,
                       const py::object& reduced_newton) {
             RolloutOptions o;
             if (!newton.is_none()) o.newton = newton.cast<NewtonOptions>();
             if (!soft_tissue_newton.is_none())
               o.soft_tissue_newton = soft_tissue_newton.cast<NewtonOptions>();
             if (!reduced_newton.is_none()) o.reduced_newton = reduced_newton.cast<NewtonOptions>();
             return o;
           }),
           py::kw_only(), py::arg("newton") = py::none(),
           py::arg("soft_tissue_newton") = py::none(), py::arg("reduced_newton") = py::none(),
           "NewtonOptions of every step, or None (defaults), per model as SceneOptions has them: "
           "newton (the skeleton), soft_tissue_newton (FEM; default: the scene's with "
           "gradient_tolerance 1e-8), reduced_newton (ROM; likewise). The gradients are as "
           "accurate as Newton's convergence: use gradient_tolerance ≈ 1e-10 or tighter when "
           "comparing with finite differences.")
      .def_readwrite("newton", &RolloutOptions::newton, "NewtonOptions (a copy on read)")
      .def_readwrite("soft_tissue_newton", &RolloutOptions::soft_tissue_newton,
                     "NewtonOptions of the FEM (a copy on read)")
      .def_readwrite("reduced_newton", &RolloutOptions::reduced_newton,
                     "NewtonOptions of the ROM (a copy on read)")
      .def_property(
          "tape_storage",
          [](const RolloutOptions& o) {
            switch (o.tape_storage) {
              case RolloutOptions::TapeStorage::Factors:
                return std::string("factors");
              case RolloutOptions::TapeStorage::Snapshots:
                return std::string("snapshots");
              default:
                return std::string("auto");
            }
          },
          [](RolloutOptions& o, const std::string& value) {
            if (value == "auto")
              o.tape_storage = RolloutOptions::TapeStorage::Auto;
            else if (value == "factors")
              o.tape_storage = RolloutOptions::TapeStorage::Factors;
            else if (value == "snapshots")
              o.tape_storage = RolloutOptions::TapeStorage::Snapshots;
            else
              throw py::value_error(
                  "tape_storage: expected 'auto', 'factors' or 'snapshots', got '" + value + "'");
          },
          "What the tape keeps: 'factors' (each step's factor), 'snapshots' (only each step's "
          "converged state; every sweep solves with the steps' exact Hessians again, as "
          "tape_solve says: memory grows with the state) or 'auto' (snapshots for the FEM, "
          "factors otherwise; the default).")
      .def_readwrite("tape_solve", &RolloutOptions::tape_solve,
                     "TapeSolveOptions of a tape of snapshots (a copy on read; checked when a "
                     "Rollout is made)")
      .def("__repr__", [](const RolloutOptions& o) {
        return "RolloutOptions(newton=" + py::repr(py::cast(o.newton)).cast<std::string>() + ")";
      });

  py::class_<RolloutInputs>(
      m, "RolloutInputs",
      "Inputs of a Rollout.run; every member None means the simulable's own (mocap targets, "
      "what initialize() sets, the stiffnesses of its options, colliders where they are).")
      .def(py::init([](const py::object& pose_targets, const py::object& root_targets,
                       const py::object& initial_state, const py::object& initial_velocity,
                       const py::object& stiffnesses, const py::object& collider_offsets) {
             RolloutInputs in;
             in.pose_targets = optional_matrix(pose_targets, "pose_targets", 72);
             in.root_targets = optional_matrix(root_targets, "root_targets", 3);
             in.initial_state = optional_vector(initial_state, "initial_state", -1, "(numDofs,)");
             in.initial_velocity =
                 optional_vector(initial_velocity, "initial_velocity", -1, "(numDofs,)");
             in.stiffnesses = optional_vector(stiffnesses, "stiffnesses", 4);
             in.collider_offsets =
                 optional_vector(collider_offsets, "collider_offsets", -1, "(3·#colliders,)");
             return in;
           }),
           py::kw_only(), py::arg("pose_targets") = py::none(),
           py::arg("root_targets") = py::none(), py::arg("initial_state") = py::none(),
           py::arg("initial_velocity") = py::none(), py::arg("stiffnesses") = py::none(),
           py::arg("collider_offsets") = py::none(),
           "Keyword arguments, each a float64 array or None. Shapes are checked here "
           "(columns) and by Rollout.run (against T, numDofs and the colliders).")
      .def_property(
          "pose_targets", [](const RolloutInputs& in) { return matrix_or_none(in.pose_targets); },
          [](RolloutInputs& in, const py::object& v) {
            in.pose_targets = optional_matrix(v, "pose_targets", 72);
          },
          kPoseDoc)
      .def_property(
          "root_targets", [](const RolloutInputs& in) { return matrix_or_none(in.root_targets); },
          [](RolloutInputs& in, const py::object& v) {
            in.root_targets = optional_matrix(v, "root_targets", 3);
          },
          kRootDoc)
      .def_property(
          "initial_state", [](const RolloutInputs& in) { return vector_or_none(in.initial_state); },
          [](RolloutInputs& in, const py::object& v) {
            in.initial_state = optional_vector(v, "initial_state", -1, "(numDofs,)");
          },
          kStateDoc)
      .def_property(
          "initial_velocity",
          [](const RolloutInputs& in) { return vector_or_none(in.initial_velocity); },
          [](RolloutInputs& in, const py::object& v) {
            in.initial_velocity = optional_vector(v, "initial_velocity", -1, "(numDofs,)");
          },
          kVelocityDoc)
      .def_property(
          "stiffnesses", [](const RolloutInputs& in) { return vector_or_none(in.stiffnesses); },
          [](RolloutInputs& in, const py::object& v) {
            in.stiffnesses = optional_vector(v, "stiffnesses", 4);
          },
          kStiffnessDoc)
      .def_property(
          "collider_offsets",
          [](const RolloutInputs& in) { return vector_or_none(in.collider_offsets); },
          [](RolloutInputs& in, const py::object& v) {
            in.collider_offsets = optional_vector(v, "collider_offsets", -1, "(3·#colliders,)");
          },
          kColliderDoc);

  py::class_<RolloutVariables> variables(
      m, "RolloutVariables",
      "One value per rollout input group: the gradients of Rollout.backward, or a direction of "
      "Rollout.forward_sensitivities (None members are zero). Each gradient is with respect to "
      "the raw numbers a user passes (see docs/adjoint.md).");
  variables.def(py::init(&make_variables), py::kw_only(), py::arg("shape") = py::none(),
                py::arg("rest_joints") = py::none(), py::arg("bone_inertia") = py::none(),
                py::arg("pose_targets") = py::none(), py::arg("root_targets") = py::none(),
                py::arg("stiffnesses") = py::none(), py::arg("collider_offsets") = py::none(),
                py::arg("initial_state") = py::none(), py::arg("initial_velocity") = py::none(),
                "Keyword arguments, each a float64 array or None (zero).");
  const auto vector_member = [&variables](const char* name, VecX RolloutVariables::*member,
                                          long size, const char* doc) {
    const std::string n = name;
    variables.def_property(
        name, [member](const RolloutVariables& v) { return vector_or_none(v.*member); },
        [member, n, size](RolloutVariables& v, const py::object& value) {
          v.*member = optional_vector(value, n, size);
        },
        doc);
  };
  const auto matrix_member = [&variables](const char* name, RowMatX RolloutVariables::*member,
                                          long cols, const char* doc) {
    const std::string n = name;
    variables.def_property(
        name, [member](const RolloutVariables& v) { return matrix_or_none(v.*member); },
        [member, n, cols](RolloutVariables& v, const py::object& value) {
          v.*member = optional_matrix(value, n, cols);
        },
        doc);
  };
  // One property per registry group (flsh/sim/sim_parameter.h).
  for (const SimParameterInfo& info : simParameters()) {
    const SimParameter id = info.id;
    const std::string name = info.name;
    const long size = info.fixed_size;
    if (info.per_step)
      variables.def_property(
          info.name, [id](const RolloutVariables& v) { return matrix_or_none(*v.perStep(id)); },
          [id, name, size](RolloutVariables& v, const py::object& value) {
            *v.perStep(id) = optional_matrix(value, name, size);
          },
          (std::string("(T, ") + std::to_string(size) + ") one row per step: " + info.doc).c_str());
    else
      variables.def_property(
          info.name, [id](const RolloutVariables& v) { return vector_or_none(*v.global(id)); },
          [id, name, size](RolloutVariables& v, const py::object& value) {
            *v.global(id) = optional_vector(value, name, size);
          },
          info.doc);
  }
  vector_member("initial_state", &RolloutVariables::initial_state, -1, kStateDoc);
  vector_member("initial_velocity", &RolloutVariables::initial_velocity, -1, kVelocityDoc);
  variables.def(
      "dot", [](const RolloutVariables& a, const RolloutVariables& b) { return dot(a, b); },
      py::arg("other"),
      "Σ over groups of the element-wise products (None members count as zero): vᵀ(dL/dp).");
  variables.def(
      "accumulate",
      [](RolloutVariables& into, const RolloutVariables& add) { accumulate(into, add); },
      py::arg("other"),
      "self += other, group by group (None counts as zero); ValueError when two members "
      "differ in shape.");
  variables.def("__repr__", [](const RolloutVariables& v) {
    std::string s = "RolloutVariables(";
    const auto add = [&s](const char* name, long rows, long cols) {
      if (rows * cols == 0) return;
      if (s.back() != '(') s += ", ";
      s += std::string(name) + "=" + (cols < 0 ? shape_text({rows}) : shape_text({rows, cols}));
    };
    for (const SimParameterInfo& info : simParameters()) {
      if (info.per_step)
        add(info.name, v.perStep(info.id)->rows(), v.perStep(info.id)->cols());
      else
        add(info.name, v.global(info.id)->size(), -1);
    }
    add("initial_state", v.initial_state.size(), -1);
    add("initial_velocity", v.initial_velocity.size(), -1);
    return s + ")";
  });

  py::class_<TapeStepInfo>(m, "TapeStepInfo", "Diagnostics of one recorded rollout step.")
      .def_readonly("converged", &TapeStepInfo::converged, "Newton met its tolerance")
      .def_readonly("newton_iterations", &TapeStepInfo::newton_iterations)
      .def_readonly("line_search_steps", &TapeStepInfo::line_search_steps,
                    "backtracking halvings Newton needed")
      .def_readonly("psd_fallbacks", &TapeStepInfo::psd_fallbacks,
                    "iterations whose direction came from the PSD form")
      .def_readonly("gradient_norm", &TapeStepInfo::gradient_norm, "‖g‖∞ at the recorded state")
      .def_readonly("factorization", &TapeStepInfo::factorization,
                    "how the exact Hessian was factored: 'llt', 'ldlt', 'lu' or 'singular'; "
                    "'deferred' before a sweep has reached it, 'pcg' where the last sweep solved "
                    "by PCG with a nearby step's factor (a tape of snapshots, TapeSolveOptions)")
      .def_readonly("cg_iterations", &TapeStepInfo::cg_iterations,
                    "PCG iterations of the last sweep's solves at this step (0 where it used "
                    "the step's own factor)")
      .def("__repr__", [](const TapeStepInfo& i) {
        return "TapeStepInfo(converged=" + std::string(i.converged ? "True" : "False") +
               ", newton_iterations=" + std::to_string(i.newton_iterations) + ", factorization='" +
               i.factorization + "')";
      });

  py::class_<Rollout, std::shared_ptr<Rollout>> rollout(
      m, "Rollout",
      "A differentiable simulation of one Simulable (articulated skeleton) over T steps: run() "
      "simulates and records a tape, backward() gives dL/d(every input) for dL/d(states), "
      "forward_sensitivities() the state changes along input directions. Keeps (and steps) the "
      "simulable; backward and forward_sensitivities leave it bitwise as run() left it. Not "
      "thread-safe.");
  rollout.def(py::init([](std::shared_ptr<Simulable> simulable, const py::object& options) {
                if (!simulable) throw py::value_error("simulable: expected a Simulable, got None");
                const RolloutOptions o =
                    options.is_none() ? RolloutOptions() : options.cast<RolloutOptions>();
                return std::make_shared<Rollout>(std::move(simulable), o);
              }),
              py::arg("simulable"), py::arg("options") = py::none(),
              "simulable: Simulable without kinematic bones (RuntimeError otherwise); its "
              "stiffnesses and colliders are the defaults of later runs. options: "
              "RolloutOptions or None.");
  rollout.def(
      "run",
      [](Rollout& r, int steps, const py::object& inputs) {
        const RolloutInputs in = inputs.is_none() ? RolloutInputs() : inputs.cast<RolloutInputs>();
        py::gil_scoped_release release;
        r.run(steps, in);
      },
      py::arg("steps"), py::arg("inputs") = py::none(),
      "Simulates `steps` steps (h = the simulable's time_step) from `inputs` (RolloutInputs or "
      "None) and records the tape. ValueError on wrong sizes or non-finite inputs (before "
      "anything changes).");
  rollout.def_property_readonly("num_steps", &Rollout::numSteps, "T of the last run (0 before)");
  rollout.def_property_readonly("num_dofs", &Rollout::numDofs, "numDofs of the simulable (144)");
  rollout.def_property_readonly(
      "states", [](const Rollout& r) { return to_numpy(r.states()); },
      "(T, numDofs) states after steps 1..T (getState layout: per bone [t_b m, r_b rad]).");
  rollout.def_property_readonly(
      "initial_state", [](const Rollout& r) { return to_numpy(r.initialState()); },
      "(numDofs,) q_0, the state before step 1.");
  rollout.def(
      "joints",
      [](const Rollout& r) {
        RowMatX J = r.joints();
        const py::ssize_t T = J.rows();
        return take_numpy(std::move(J), {T, 24, 3});
      },
      "(T, 24, 3) joint (bone) positions t_b after steps 1..T, m.");
  rollout.def(
      "vertices",
      [](const Rollout& r, int t) {
        MatX3 V;
        {
          py::gil_scoped_release release;
          V = r.vertices(t);
        }
        return to_numpy(V);
      },
      py::arg("t"), "(V, 3) SMPL vertices (Simulable.getVertices) at step t (0 = q_0), m.");
  rollout.def(
      "vertex_trajectory",
      [](const Rollout& r) {
        const py::ssize_t T = r.numSteps();
        const py::ssize_t V = r.simulable().avatar().body().numVertices();
        RowMatX all;
        {
          py::gil_scoped_release release;
          all = r.vertexTrajectory();
        }
        return take_numpy(std::move(all), {T, V, 3});
      },
      "(T, V, 3) SMPL vertices after steps 1..T, m.");
  rollout.def(
      "step_info",
      [](const Rollout& r, int t) {
        if (t < 1 || t > r.numSteps())
          throw py::value_error("t: expected a step in 1.." + std::to_string(r.numSteps()) +
                                ", got " + std::to_string(t));
        return r.tape().stepInfo(t);
      },
      py::arg("t"), "TapeStepInfo of step t (1..T): convergence and factorization.");
  rollout.def_property_readonly(
      "simulable", [](const Rollout& r) { return &r.simulable(); },
      py::return_value_policy::reference_internal,
      "The Simulable (left after the last step of the last run).");

  rollout.def(
      "joints_cotangent",
      [](const Rollout& r, const py::object& dL_djoints) {
        return to_numpy(r.jointsCotangent(joints_argument(dL_djoints, "dL_djoints")));
      },
      py::arg("dL_djoints"),
      "dL/d(state vector) (numDofs,) from dL/d(joint positions) (24, 3) of one step.");
  rollout.def(
      "vertices_cotangent",
      [](const Rollout& r, int t, const py::object& dL_dvertices) {
        const MatX3 g =
            to_points(dL_dvertices, "dL_dvertices", r.simulable().avatar().body().numVertices());
        Rollout::VerticesCotangent c;
        {
          py::gil_scoped_release release;
          c = r.verticesCotangent(t, g);
        }
        return py::make_tuple(to_numpy(c.state), c.direct,
                              c.previous_state.size() ? py::object(to_numpy(c.previous_state))
                                                      : py::object(py::none()));
      },
      py::arg("t"), py::arg("dL_dvertices"),
      "dL/d(vertices at step t) (V, 3) pulled back through getVertices: returns (state "
      "(numDofs,), direct RolloutVariables with the β and J_0 parts that do not go through "
      "the state, previous_state: soft tissue's (numDofs,) for the state of step t − 1, whose "
      "held pose blend moves the surface, else None). trajectory_cotangent sums them for a "
      "whole trajectory.");
  rollout.def(
      "trajectory_cotangent",
      [](const Rollout& r, const py::object& dL_djoints, const py::object& dL_dvertices) {
        const long T = r.numSteps();
        if (T == 0) throw py::value_error("trajectory_cotangent: call run() first");
        RowMatX joints, vertices;
        if (!dL_djoints.is_none()) {
          auto a = trajectory_argument(dL_djoints, "dL_djoints", T, 24, "24");
          joints = Eigen::Map<const RowMatX>(a.data(), T, 72);
        }
        if (!dL_dvertices.is_none()) {
          const long V = r.simulable().avatar().body().numVertices();
          auto a = trajectory_argument(dL_dvertices, "dL_dvertices", T, V, "V");
          vertices = Eigen::Map<const RowMatX>(a.data(), T, 3 * V);
        }
        Rollout::TrajectoryCotangent c;
        {
          py::gil_scoped_release release;
          c = r.trajectoryCotangent(joints, vertices);
        }
        return py::make_tuple(to_numpy(c.states), c.direct);
      },
      py::arg("dL_djoints") = py::none(), py::arg("dL_dvertices") = py::none(),
      "Cotangent of a loss on the whole trajectory: dL/d(joints) (T, 24, 3) and/or dL/d(SMPL "
      "vertices) (T, V, 3) after steps 1..T (None = zero) → (dL/d(states) (T, numDofs), direct "
      "RolloutVariables), the arguments of backward.");
  rollout.def(
      "backward",
      [](Rollout& r, const py::object& dL_dstates, const py::object& direct,
         const py::object& groups) {
        const RowMatX a = to_matrix(dL_dstates, "dL_dstates", r.numSteps(), r.numDofs());
        const RolloutVariables d =
            direct.is_none() ? RolloutVariables() : direct.cast<RolloutVariables>();
        std::vector<SimParameter> wanted;
        if (!groups.is_none())
          for (const py::handle& name : groups) {
            const std::string text = py::str(name);
            bool found = false;
            for (const SimParameterInfo& info : simParameters())
              if (text == info.name) {
                wanted.push_back(info.id);
                found = true;
              }
            if (!found) {
              std::string names;
              for (const SimParameterInfo& info : simParameters())
                names += std::string(names.empty() ? "" : ", ") + info.name;
              throw py::value_error("Rollout.backward: groups: unknown group '" + text +
                                    "', expected some of " + names);
            }
          }
        RolloutVariables grad;
        {
          py::gil_scoped_release release;
          grad = r.backward(a, d, wanted);
        }
        return grad;
      },
      py::arg("dL_dstates"), py::arg("direct") = py::none(), py::arg("groups") = py::none(),
      "Reverse pass: RolloutVariables of dL/d(every input) for dL/d(states) (T, numDofs, "
      "getState layout) plus the loss's direct dependence on inputs (`direct`, e.g. from "
      "vertices_cotangent), added to the result. groups: names of the registry groups to "
      "compute (e.g. ['pose_targets', 'material']; None: all); the others come back None and "
      "cost nothing. Leaves the simulable bitwise unchanged; RuntimeError before run().");
  rollout.def(
      "forward_sensitivities",
      [](Rollout& r, const std::vector<RolloutVariables>& directions) {
        std::vector<RowMatX> out;
        {
          py::gil_scoped_release release;
          out = r.forwardSensitivities(directions);
        }
        py::list result;
        for (RowMatX& dq : out) result.append(to_numpy(dq));
        return result;
      },
      py::arg("directions"),
      "For each direction (list of RolloutVariables; None members are zero) the (T, numDofs) "
      "changes of the states dq_t/dp · v.");
  rollout.def("__repr__", [](const Rollout& r) {
    return "Rollout(steps=" + std::to_string(r.numSteps()) +
           ", dofs=" + std::to_string(r.numDofs()) + ")";
  });
}

}  // namespace flsh::python
