// Bindings of include/flsh/sim: SimulableOptions and Simulable with the runtime API of the
// FLSH paper under the paper's camelCase names, each also under a snake_case alias. Also the
// scipy.sparse helpers declared in bindings.h.
#include <pybind11/stl.h>

#include <cmath>
#include <memory>

#include "bindings.h"
#include "flsh/sim/simulable.h"

namespace flsh::python {

// ---------------------------------------------------------------------------------------------
// scipy.sparse helpers

py::object to_scipy_csc(const SpMat& A) {
  SpMat c = A;
  c.makeCompressed();
  const py::ssize_t nnz = c.nonZeros();
  py::array_t<double> data(nnz);
  py::array_t<int> indices(nnz), indptr(py::ssize_t(c.cols() + 1));
  std::copy(c.valuePtr(), c.valuePtr() + nnz, data.mutable_data());
  std::copy(c.innerIndexPtr(), c.innerIndexPtr() + nnz, indices.mutable_data());
  std::copy(c.outerIndexPtr(), c.outerIndexPtr() + c.cols() + 1, indptr.mutable_data());
  py::object csc = py::module_::import("scipy.sparse").attr("csc_matrix");
  return csc(py::make_tuple(data, indices, indptr),
             py::arg("shape") = py::make_tuple(c.rows(), c.cols()));
}

py::object triplets_to_scipy_csc(const std::vector<Triplet>& triplets, int rows, int cols) {
  SpMat A(rows, cols);
  A.setFromTriplets(triplets.begin(), triplets.end());
  return to_scipy_csc(A);
}

std::vector<Triplet> to_triplets(const py::handle& obj, const std::string& name, long rows,
                                 long cols) {
  py::module_ sparse = py::module_::import("scipy.sparse");
  std::vector<Triplet> triplets;
  const auto check = [&](long r, long c) {
    if ((rows >= 0 && r != rows) || (cols >= 0 && c != cols))
      throw py::value_error(name + ": expected shape " + shape_text({rows, cols}) + ", got " +
                            shape_text({r, c}));
  };
  if (sparse.attr("issparse")(obj).cast<bool>()) {
    py::object coo = obj.attr("tocoo")();
    const py::tuple shape = coo.attr("shape");
    check(shape[0].cast<long>(), shape[1].cast<long>());
    auto row = as_int32(coo.attr("row"), name + ".row");
    auto col = as_int32(coo.attr("col"), name + ".col");
    auto data = as_float64(coo.attr("data"), name + ".data");
    triplets.reserve(size_t(data.size()));
    for (py::ssize_t k = 0; k < data.size(); ++k)
      triplets.emplace_back(row.data()[k], col.data()[k], data.data()[k]);
    return triplets;
  }
  auto a = as_float64(obj, name);
  if (a.ndim() != 2)
    throw py::value_error(name + ": expected a scipy.sparse matrix or a 2-D array of shape " +
                          shape_text({rows, cols}) + ", got " + std::to_string(a.ndim()) +
                          "-D array");
  check(long(a.shape(0)), long(a.shape(1)));
  for (py::ssize_t r = 0; r < a.shape(0); ++r)
    for (py::ssize_t c = 0; c < a.shape(1); ++c)
      if (const double v = a.data()[r * a.shape(1) + c]; v != 0.0) triplets.emplace_back(r, c, v);
  return triplets;
}

namespace {

// An increment, state or gradient of the simulable: (numDofs,) finite.
VecX dof_vector(const Simulable& s, const py::object& v, const char* name) {
  return to_vector(v, name, s.numDofs());
}

py::array_t<double> rotations_numpy(const std::vector<Mat3>& R) {
  py::array_t<double> a({py::ssize_t(R.size()), py::ssize_t(3), py::ssize_t(3)});
  auto v = a.mutable_unchecked<3>();
  for (size_t b = 0; b < R.size(); ++b)
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) v(b, r, c) = R[b](r, c);
  return a;
}

void check_finite_nonnegative(double value, const char* name) {
  if (!(std::isfinite(value) && value >= 0.0))
    throw py::value_error(std::string(name) + ": expected a finite value ≥ 0, got " +
                          std::to_string(value));
}

std::vector<int> kinematic_list(const py::object& bones) {
  if (bones.is_none()) return {};
  auto a = as_int32(bones, "kinematic_bones");
  check_shape(a, "kinematic_bones", {-1}, "(B,)");
  return std::vector<int>(a.data(), a.data() + a.size());
}

}  // namespace

void bind_sim(py::module_& m) {
  const SimulableOptions defaults;
  py::class_<SimulableOptions>(m, "SimulableOptions",
                               "Stiffnesses and physical settings of a Simulable (SI units).")
      .def(py::init([](double time_step, const py::object& gravity, double joint_stiffness,
                       double tracking_stiffness, double tracking_inertia_floor,
                       double root_stiffness, bool track_mocap, const py::object& kinematic_bones,
                       const py::object& contact) {
             if (!(std::isfinite(time_step) && time_step > 0.0))
               throw py::value_error("time_step: expected a finite value > 0 (s), got " +
                                     std::to_string(time_step));
             check_finite_nonnegative(joint_stiffness, "joint_stiffness");
             check_finite_nonnegative(tracking_stiffness, "tracking_stiffness");
             check_finite_nonnegative(tracking_inertia_floor, "tracking_inertia_floor");
             check_finite_nonnegative(root_stiffness, "root_stiffness");
             SimulableOptions o;
             o.time_step = time_step;
             if (!gravity.is_none()) o.gravity = to_vec3(gravity, "gravity");
             o.joint_stiffness = joint_stiffness;
             o.tracking_stiffness = tracking_stiffness;
             o.tracking_inertia_floor = tracking_inertia_floor;
             o.root_stiffness = root_stiffness;
             o.track_mocap = track_mocap;
             o.kinematic_bones = kinematic_list(kinematic_bones);
             if (!contact.is_none()) o.contact = contact.cast<ContactOptions>();
             return o;
           }),
           py::kw_only(), py::arg("time_step") = defaults.time_step,
           py::arg("gravity") = py::none(), py::arg("joint_stiffness") = defaults.joint_stiffness,
           py::arg("tracking_stiffness") = defaults.tracking_stiffness,
           py::arg("tracking_inertia_floor") = defaults.tracking_inertia_floor,
           py::arg("root_stiffness") = defaults.root_stiffness,
           py::arg("track_mocap") = defaults.track_mocap, py::arg("kinematic_bones") = py::none(),
           py::arg("contact") = py::none(),
           "Keyword arguments; None keeps the default (gravity (0, −9.81, 0) m/s², no kinematic "
           "bones, default ContactOptions).")
      .def_readwrite("time_step", &SimulableOptions::time_step, "h, s")
      .def_property(
          "gravity", [](const SimulableOptions& o) { return to_numpy(VecX(o.gravity)); },
          [](SimulableOptions& o, const py::object& g) { o.gravity = to_vec3(g, "gravity"); },
          "(3,) m/s²")
      .def_readwrite("joint_stiffness", &SimulableOptions::joint_stiffness, "k_J, N/m")
      .def_readwrite("tracking_stiffness", &SimulableOptions::tracking_stiffness,
                     "ω_T², 1/s² (joint springs k_b = ω_T² (I_b + tracking_inertia_floor))")
      .def_readwrite("tracking_inertia_floor", &SimulableOptions::tracking_inertia_floor,
                     "kg·m², added to each non-root bone's subtree inertia I_b in its tracking "
                     "stiffness, so that toes and hands are not nearly free (0 = pure I_b)")
      .def_readwrite("root_stiffness", &SimulableOptions::root_stiffness,
                     "1/s² (root springs scaled by mass and polar inertia)")
      .def_readwrite("track_mocap", &SimulableOptions::track_mocap,
                     "False: no tracking springs (a passive ragdoll)")
      .def_property(
          "kinematic_bones", [](const SimulableOptions& o) { return o.kinematic_bones; },
          [](SimulableOptions& o, const py::object& b) { o.kinematic_bones = kinematic_list(b); },
          "bones prescribed by the mocap, e.g. [0] pins the root")
      .def_readwrite("contact", &SimulableOptions::contact, "ContactOptions (a copy on read)")
      .def("__repr__", [](const SimulableOptions& o) {
        return "SimulableOptions(time_step=" +
               py::repr(py::float_(o.time_step)).cast<std::string>() +
               ", track_mocap=" + (o.track_mocap ? "True" : "False") + ")";
      });

  {
    // The values and their docs come from the parameter registry (flsh/sim/sim_parameter.h).
    py::enum_<SimParameter> parameter(
        m, "SimParameter",
        "Parameter groups the total gradient g = ∇(E_dyn + E_pot) depends on (for the adjoint). "
        "Sizes and layouts: Simulable.parameterSize / getParameter.");
    for (const SimParameterInfo& info : simParameters())
      parameter.value(info.enum_name, info.id, info.doc);
  }

  using S = Simulable;
  py::class_<S, std::shared_ptr<S>> sim(
      m, "Simulable",
      "One avatar's simulation state and energies (articulated skeleton: 24 bones × 6 DoFs "
      "[t_b m, r_b rad]). Methods carry the FLSH paper's names; each has a snake_case alias. "
      "Derivatives are in the increment chart [δt_b, δω_b] at the current state. Keeps its "
      "avatar and mocap alive. Not thread-safe.");
  sim.def(py::init([](std::shared_ptr<SoftAvatar> avatar, std::shared_ptr<Motion> mocap,
                      const py::object& options) {
            const SimulableOptions o =
                options.is_none() ? SimulableOptions() : options.cast<SimulableOptions>();
            return std::make_shared<S>(std::move(avatar), std::move(mocap), o);
          }),
          py::arg("avatar"), py::arg("mocap") = py::none(), py::arg("options") = py::none(),
          "avatar: initialized SoftAvatar; mocap: Motion to track or None (rest pose); "
          "options: SimulableOptions or None.");
  sim.def(py::init([](std::shared_ptr<SoftAvatar> avatar, std::shared_ptr<BodyModel> body,
                      std::shared_ptr<Motion> mocap, const py::object& options) {
            const SimulableOptions o =
                options.is_none() ? SimulableOptions() : options.cast<SimulableOptions>();
            return std::make_shared<S>(std::move(avatar), std::move(body), std::move(mocap), o);
          }),
          py::arg("avatar"), py::arg("body"), py::arg("mocap"), py::arg("options") = py::none(),
          "The paper's form: body must be the avatar's BodyModel.");

  // Registers `camel` and its snake_case alias as the same function object.
  const auto alias = [&sim](const char* camel, const char* snake) {
    sim.attr(snake) = sim.attr(camel);
  };

  sim.def("initialize", &S::initialize,
          "State from the mocap's first frame (or the rest pose) with the mocap's velocity; "
          "time = 0.");
  sim.def("preUpdate", &S::preUpdate,
          "Before a step: time += h, mocap targets, inertial prediction, kinematic bones.");
  alias("preUpdate", "pre_update");
  sim.def("postUpdate", &S::postUpdate, "After a converged step: q_{n−1} ← q_n, q_n ← q.");
  alias("postUpdate", "post_update");

  // ---- state
  sim.def("numDofs", &S::numDofs, "Number of DoFs (144 for the skeleton).");
  sim.def_property_readonly("num_dofs", &S::numDofs, "Number of DoFs (144 for the skeleton).");
  sim.def(
      "getState", [](const S& s) { return to_numpy(s.getState()); },
      "(numDofs,) state: per bone [t_b (m, 3), r_b rotation vector (rad, 3)].");
  alias("getState", "get_state");
  sim.def(
      "setState", [](S& s, const py::object& q) { s.setState(dof_vector(s, q, "q")); },
      py::arg("q"),
      "Sets the state q (numDofs,) in getState's layout. With soft tissue, the pose blend "
      "shapes stay those held at the last preUpdate (the previous converged pose, as during "
      "a step): on a fresh simulable, get_vertices() after set_state differs from the "
      "surface a simulation reached there by its pose blend (mm), while "
      "get_soft_tissue_displacements() does not depend on it (C++ restoreStep puts a "
      "step's held pose blend back too).");
  alias("setState", "set_state");
  sim.def(
      "updateState", [](S& s, const py::object& dq) { s.updateState(dof_vector(s, dq, "dq")); },
      py::arg("dq"),
      "Applies an increment dq (numDofs,): t_b += δt_b (m), R_b ← exp([δω_b]×) R_b (rad).");
  alias("updateState", "update_state");
  sim.def("pushState", &S::pushState, "Saves the state on a stack.");
  alias("pushState", "push_state");
  sim.def("popState", &S::popState,
          "Restores the last pushed state exactly (RuntimeError if the stack is empty).");
  alias("popState", "pop_state");
  sim.def("discardState", &S::discardState,
          "Drops the last pushed state without restoring it (RuntimeError if the stack is empty).");
  alias("discardState", "discard_state");
  sim.def(
      "setVelocity", [](S& s, const py::object& v) { s.setVelocity(dof_vector(s, v, "v")); },
      py::arg("v"),
      "Sets the velocity v (numDofs,), m/s and rad/s (world frame): q_{n−1} = q_n − h v.");
  alias("setVelocity", "set_velocity");
  sim.def(
      "getVelocity", [](const S& s) { return to_numpy(s.getVelocity()); },
      "(numDofs,) velocity (q_n ⊖ q_{n−1}) / h, m/s and rad/s.");
  alias("getVelocity", "get_velocity");
  sim.def_property_readonly("time", &S::time, "Simulated time, s.");

  // ---- outputs
  sim.def(
      "getPose", [](const S& s) { return to_numpy(s.getPose()); },
      "(72,) SMPL pose read off the state, rad.");
  alias("getPose", "get_pose");
  sim.def(
      "getTrans", [](const S& s) { return to_numpy(VecX(s.getTrans())); },
      "(3,) SMPL root translation t_0 − J_0, m.");
  alias("getTrans", "get_trans");
  sim.def(
      "getStateJacobian",
      [](const S& s) {
        RowMatX J;
        {
          py::gil_scoped_release release;
          J = s.getStateJacobian();
        }
        return to_numpy(J);
      },
      "(75, numDofs) d(pose (72), trans (3)) / dq.");
  alias("getStateJacobian", "get_state_jacobian");
  sim.def(
      "getVertices",
      [](const S& s) {
        MatX3 V;
        {
          py::gil_scoped_release release;
          V = s.getVertices();
        }
        return to_numpy(V);
      },
      "(V, 3) mesh vertices, m: SMPL skinning of getPose()/getTrans(); with soft tissue the "
      "simulated surface get_nodes() (held pose blend and displacements included).");
  alias("getVertices", "get_vertices");
  sim.def(
      "getNodes", [](const S& s) { return to_numpy(s.getNodes()); },
      "(V, 3) simulation nodes (linear blend skinning of the bone transforms), m.");
  alias("getNodes", "get_nodes");
  sim.def(
      "getNodesStateJacobian",
      [](const S& s) {
        SpMat J;
        {
          py::gil_scoped_release release;
          J = s.getNodesStateJacobian();
        }
        return to_scipy_csc(J);
      },
      "d nodes / dq as a scipy.sparse.csc_matrix (3V, numDofs), row 3i + c.");
  alias("getNodesStateJacobian", "get_nodes_state_jacobian");
  sim.def_property_readonly(
      "bone_rotations", [](const S& s) { return rotations_numpy(s.boneRotations()); },
      "(24, 3, 3) bone rotations R_b relative to the rest pose.");
  sim.def_property_readonly(
      "bone_positions", [](const S& s) { return to_numpy(s.bonePositions()); },
      "(24, 3) joint centres t_b, m.");

  // ---- soft tissue (FEM and ROM soft skeletons)
  sim.def("hasSoftTissue", &S::hasSoftTissue,
          "True for the soft-tissue models (an avatar with enable_soft_tissue()): the state then "
          "holds, after the 144 bone values, a displacement per soft-tissue node (FEM) or a "
          "z_h per handle of the reduced basis (ROM, enable_reduced_model()).");
  alias("hasSoftTissue", "has_soft_tissue");
  sim.def("hasReducedModel", &S::hasReducedModel,
          "True for the ROM soft skeleton: u_j = Σ_h φ_h(j) z_h with the avatar's reduced basis "
          "(docs/rom.md).");
  alias("hasReducedModel", "has_reduced_model");
  sim.def("numBoneDofs", &S::numBoneDofs, "Number of bone DoFs, 6 · 24 = 144 (the state's head).");
  sim.def_property_readonly("num_bone_dofs", &S::numBoneDofs,
                            "Number of bone DoFs, 6 · 24 = 144 (the state's head).");
  sim.def(
      "softNodes",
      [](const S& s) {
        const VecXi& nodes = s.softNodes();
        py::array_t<int> a(py::ssize_t(nodes.size()));
        std::copy(nodes.data(), nodes.data() + nodes.size(), a.mutable_data());
        return a;
      },
      "(S,) int32 tet node of each 3-value block of the soft state, in state order: block k "
      "is state[numBoneDofs() + 3k : … + 3], the displacement u (m) of node softNodes()[k] "
      "(FEM: every soft-tissue node; ROM: the handles, whose u equals their z_h); empty for "
      "the skeleton.");
  alias("softNodes", "soft_nodes");
  sim.def("nodeSoftDof", &S::nodeSoftDof, py::arg("j"),
          "State index of tet node j's first displacement value when u_j is a state entry of its "
          "own, else −1: bone nodes, every vertex of the skeleton model, and in the ROM every "
          "node but the handles (see nodeDisplacementBasis); ValueError for j outside the nodes.");
  alias("nodeSoftDof", "node_soft_dof");
  sim.def(
      "nodeDisplacementBasis",
      [](const S& s, int j) {
        py::list out;
        for (const auto& [index, block] : s.nodeDisplacementBasis(j))
          out.append(py::make_tuple(index, to_numpy(RowMatX(block))));
        return out;
      },
      py::arg("j"),
      "u_j (m) as a combination of state entries: list of (index, B) pairs, B a (3, 3) "
      "float64 array, with u_j = Σ B @ state[index : index + 3]. FEM: [(nodeSoftDof(j), I)]; "
      "ROM: (index of z_h, φ_h(j) I) for the handles whose φ reaches j, then with modes one "
      "pair per three modal coordinates (the block of Ψ_j's three columns); [] for bone nodes "
      "and the skeleton model. ValueError for j outside the nodes.");
  alias("nodeDisplacementBasis", "node_displacement_basis");
  sim.def(
      "getSoftTissueDisplacements",
      [](const S& s) { return to_numpy(s.getSoftTissueDisplacements()); },
      "(V, 3) float64 soft-tissue displacements u of the surface vertices, m, in the unposed "
      "(rest) space; zero on bone nodes and for the skeleton model.");
  alias("getSoftTissueDisplacements", "get_soft_tissue_displacements");
  sim.def(
      "getUnposedSurface", [](const S& s) { return to_numpy(s.getUnposedSurface()); },
      "(V, 3) float64 unposed surface Y, m: the rest surface X̄(β), plus for the soft-tissue "
      "model the held pose blend offsets and u.");
  alias("getUnposedSurface", "get_unposed_surface");
  sim.def(
      "getVolumeNodes",
      [](const S& s) {
        MatX3 X;
        {
          py::gil_scoped_release release;
          X = s.getVolumeNodes();
        }
        return to_numpy(X);
      },
      "(N, 3) float64 world positions of every tet node, m (surface vertices first); the "
      "skeleton model: the (V, 3) surface nodes.");
  alias("getVolumeNodes", "get_volume_nodes");

  // ---- energies
  sim.def("getDynamicEnergyScalar", &S::getDynamicEnergyScalar,
          "Inertia 1/(2h²) Σ m ‖x(q) − x̂‖², J (0 when static).");
  alias("getDynamicEnergyScalar", "get_dynamic_energy_scalar");
  sim.def("getPotentialEnergyScalar", &S::getPotentialEnergyScalar,
          "Gravity + joint + tracking springs + contact, J.");
  alias("getPotentialEnergyScalar", "get_potential_energy_scalar");
  sim.def(
      "getDynamicGradientVector",
      [](const S& s) {
        VecX g = VecX::Zero(s.numDofs());
        s.getDynamicGradientVector(g);
        return to_numpy(g);
      },
      "(numDofs,) gradient of the dynamic energy (a new vector), J per m or rad.");
  alias("getDynamicGradientVector", "get_dynamic_gradient_vector");
  sim.def(
      "getPotentialGradientVector",
      [](const S& s) {
        VecX g = VecX::Zero(s.numDofs());
        s.getPotentialGradientVector(g);
        return to_numpy(g);
      },
      "(numDofs,) gradient of the potential energy (a new vector), J per m or rad.");
  alias("getPotentialGradientVector", "get_potential_gradient_vector");
  sim.def(
      "getGradientVector",
      [](const S& s) {
        VecX g = VecX::Zero(s.numDofs());
        {
          py::gil_scoped_release release;
          s.getGradientVector(g);
        }
        return to_numpy(g);
      },
      "(numDofs,) gradient of the whole objective (dynamic + potential, a new vector), in one "
      "call as a Scene sums it (the ROM evaluates its node terms beside contact on two "
      "threads). The sum of getDynamicGradientVector and getPotentialGradientVector.");
  alias("getGradientVector", "get_gradient_vector");
  sim.def(
      "getEnergyAndGradientVector",
      [](const S& s) {
        VecX g = VecX::Zero(s.numDofs());
        double energy = 0.0;
        {
          py::gil_scoped_release release;
          energy = s.getEnergyAndGradientVector(g);
        }
        return py::make_tuple(energy, to_numpy(g));
      },
      "(energy, gradient): the whole objective's energy (J) and its (numDofs,) gradient from "
      "the same passes, what a line search needs at a trial state; the energy equals "
      "getDynamicEnergyScalar() + getPotentialEnergyScalar() up to round-off.");
  alias("getEnergyAndGradientVector", "get_energy_and_gradient_vector");
  sim.def(
      "fixVectorKinematic",
      [](const S& s, const py::object& g) {
        VecX v = dof_vector(s, g, "g");
        s.fixVectorKinematic(v);
        return to_numpy(v);
      },
      py::arg("g"), "Copy of g (numDofs,) with the kinematic DoFs zeroed.");
  alias("fixVectorKinematic", "fix_vector_kinematic");
  sim.def(
      "getDynamicHessianTripletVector",
      [](const S& s, bool psd) {
        std::vector<Triplet> H;
        {
          py::gil_scoped_release release;
          s.getDynamicHessianTripletVector(H, 0, psd);
        }
        return triplets_to_scipy_csc(H, s.numDofs(), s.numDofs());
      },
      py::arg("psd") = true,
      "Hessian of the dynamic energy, scipy.sparse.csc_matrix (numDofs, numDofs). psd=True: "
      "Gauss–Newton (what Newton uses); False: exact.");
  alias("getDynamicHessianTripletVector", "get_dynamic_hessian_triplet_vector");
  sim.def(
      "getPotentialHessianTripletVector",
      [](const S& s, bool psd) {
        std::vector<Triplet> H;
        {
          py::gil_scoped_release release;
          s.getPotentialHessianTripletVector(H, 0, psd);
        }
        return triplets_to_scipy_csc(H, s.numDofs(), s.numDofs());
      },
      py::arg("psd") = true,
      "Hessian of the potential energy, scipy.sparse.csc_matrix (numDofs, numDofs). "
      "psd=True: projected positive semidefinite; False: exact.");
  alias("getPotentialHessianTripletVector", "get_potential_hessian_triplet_vector");
  sim.def(
      "getHessianTripletVector",
      [](const S& s, bool psd) {
        std::vector<Triplet> H;
        {
          py::gil_scoped_release release;
          std::vector<FixedHessianBlocks> blocks;
          s.getHessianTripletVector(H, blocks, 0, psd);
          appendBlockTriplets(blocks, H);
        }
        return triplets_to_scipy_csc(H, s.numDofs(), s.numDofs());
      },
      py::arg("psd") = true,
      "Hessian of the whole objective (dynamic + potential), scipy.sparse.csc_matrix "
      "(numDofs, numDofs), in one call as a Scene assembles it (the ROM evaluates its inertia "
      "beside contact, gravity and elasticity on two threads). The sum of "
      "getDynamicHessianTripletVector and getPotentialHessianTripletVector of the same form.");
  alias("getHessianTripletVector", "get_hessian_triplet_vector");
  sim.def(
      "fixMatrixKinematic",
      [](const S& s, const py::object& H) {
        const int n = s.numDofs();
        std::vector<Triplet> t = to_triplets(H, "H", n, n);
        s.fixMatrixKinematic(t);
        return triplets_to_scipy_csc(t, n, n);
      },
      py::arg("H"),
      "H (numDofs, numDofs), scipy.sparse or dense, with kinematic rows/columns made "
      "identity; returns a csc_matrix.");
  alias("fixMatrixKinematic", "fix_matrix_kinematic");

  // ---- scene hooks
  sim.def("setColliders", &S::setColliders, py::arg("colliders"),
          "Replaces the colliders (list of Collider) seen by this avatar.");
  alias("setColliders", "set_colliders");
  sim.def_property_readonly("colliders", &S::colliders, "list of Collider (copies).");
  sim.def("setStatic", &S::setStatic, py::arg("on") = true,
          "True: drops the dynamic term (static equilibrium).");
  alias("setStatic", "set_static");
  sim.def_property_readonly("is_static", &S::isStatic);
  sim.def_property_readonly(
      "avatar", [](const S& s) { return &s.avatar(); }, py::return_value_policy::reference_internal,
      "The SoftAvatar.");
  sim.def_property_readonly("options", &S::options, "SimulableOptions (a copy).");
  sim.def_property_readonly(
      "active_contacts", [](const S& s) { return s.stats().active_contacts; },
      "Vertex–collider contacts at the last energy evaluation.");
  // ---- parameter derivatives (for the adjoint)
  sim.def("parameterSize", &S::parameterSize, py::arg("p"),
          "Number of values of the SimParameter group p (ColliderOffsets: 3 per collider).");
  alias("parameterSize", "parameter_size");
  sim.def(
      "getParameter", [](const S& s, SimParameter p) { return to_numpy(s.getParameter(p)); },
      py::arg("p"),
      "(parameterSize(p),) current values of group p in SimParameter's layout and units.");
  alias("getParameter", "get_parameter");
  sim.def(
      "setParameter",
      [](S& s, SimParameter p, const py::object& value) {
        s.setParameter(p, to_vector(value, "value", s.parameterSize(p)));
      },
      py::arg("p"), py::arg("value"),
      "Overrides group p with value (parameterSize(p),); the state is kept. PoseTargets and "
      "RootTranslationTarget hold until the next preUpdate/initialize. ValueError on size, "
      "non-finite or invalid values (nothing is changed then); Shape is read only.");
  alias("setParameter", "set_parameter");
  sim.def(
      "getGradientParameterJacobian",
      [](const S& s, SimParameter p) {
        MatX J;
        {
          py::gil_scoped_release release;
          J = s.getGradientParameterJacobian(p);
        }
        return to_numpy(RowMatX(J));
      },
      py::arg("p"),
      "(numDofs, parameterSize(p)) ∂g/∂p of the total gradient at the current state (exact, "
      "increment chart, kinematic rows not zeroed); units: gradient units (J per m or rad) "
      "per unit of p. Does not change the state.");
  alias("getGradientParameterJacobian", "get_gradient_parameter_jacobian");
  sim.def(
      "getGradientPreviousStateJacobian",
      [](const S& s, int which) {
        MatX J;
        {
          py::gil_scoped_release release;
          J = s.getGradientPreviousStateJacobian(which);
        }
        return to_numpy(RowMatX(J));
      },
      py::arg("which"),
      "(numDofs, numDofs) ∂g/∂q_n (which=1) or ∂g/∂q_{n−1} (which=2), with respect to "
      "increments [δt_b m, δω_b rad] of that state; zero when static. ValueError for other "
      "`which`. Does not change the state.");
  alias("getGradientPreviousStateJacobian", "get_gradient_previous_state_jacobian");

  sim.def("__repr__", [](const S& s) {
    return "Simulable(dofs=" + std::to_string(s.numDofs()) +
           ", time=" + py::repr(py::float_(s.time())).cast<std::string>() + ")";
  });
}

}  // namespace flsh::python
