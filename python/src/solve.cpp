// Bindings of include/flsh/solve: Newton's options and result, linear-solver choice, and Scene
// (several simulables and colliders stepped together; also the Objective Newton minimizes).
#include <pybind11/stl.h>

#include <cmath>
#include <memory>

#include "bindings.h"
#include "flsh/solve/newton.h"
#include "flsh/solve/scene.h"

namespace flsh::python {

namespace {

const char* solver_name(LinearSolverType t) {
  switch (t) {
    case LinearSolverType::Auto:
      return "Auto";
    case LinearSolverType::Dense:
      return "Dense";
    case LinearSolverType::Cholmod:
      return "Cholmod";
    case LinearSolverType::SparseLLT:
      return "SparseLLT";
  }
  return "unknown";
}

}  // namespace

void bind_solve(py::module_& m) {
  py::enum_<LinearSolverType>(m, "LinearSolverType", "Linear solver of Newton's steps.")
      .value(
          "Auto", LinearSolverType::Auto,
          "scenes: simplicial sparse Cholesky; elsewhere dense up to 600 unknowns, CHOLMOD above")
      .value("Dense", LinearSolverType::Dense, "Eigen's dense Cholesky")
      .value("Cholmod", LinearSolverType::Cholmod, "CHOLMOD supernodal Cholesky")
      .value("SparseLLT", LinearSolverType::SparseLLT,
             "Eigen's simplicial Cholesky (AMD ordering), analysis reused while the pattern holds");

  const LaggedFactorOptions ld;
  py::class_<LaggedFactorOptions>(
      m, "LaggedFactorOptions",
      "Newton directions by conjugate gradients preconditioned with the factor of an earlier "
      "Hessian, refactoring only when that stops paying off (NewtonOptions.lagged).")
      .def(py::init([](bool enabled, double cg_relative_tolerance, bool adaptive_forcing,
                       int max_cg_iterations, int refactor_after_cg_iterations,
                       bool fast_preconditioner, double reuse_hessian_below,
                       bool coarse_correction) {
             LaggedFactorOptions o;
             o.enabled = enabled;
             o.cg_relative_tolerance = cg_relative_tolerance;
             o.adaptive_forcing = adaptive_forcing;
             o.max_cg_iterations = max_cg_iterations;
             o.refactor_after_cg_iterations = refactor_after_cg_iterations;
             o.fast_preconditioner = fast_preconditioner;
             o.reuse_hessian_below = reuse_hessian_below;
             o.coarse_correction = coarse_correction;
             return o;
           }),
           py::kw_only(), py::arg("enabled") = ld.enabled,
           py::arg("cg_relative_tolerance") = ld.cg_relative_tolerance,
           py::arg("adaptive_forcing") = ld.adaptive_forcing,
           py::arg("max_cg_iterations") = ld.max_cg_iterations,
           py::arg("refactor_after_cg_iterations") = ld.refactor_after_cg_iterations,
           py::arg("fast_preconditioner") = ld.fast_preconditioner,
           py::arg("reuse_hessian_below") = ld.reuse_hessian_below,
           py::arg("coarse_correction") = ld.coarse_correction,
           "Keyword arguments; values are checked when a solve starts (ValueError).")
      .def_readwrite("enabled", &LaggedFactorOptions::enabled,
                     "False: every Newton iteration factors its Hessian")
      .def_readwrite("cg_relative_tolerance", &LaggedFactorOptions::cg_relative_tolerance,
                     "forcing term in (0, 1): CG stops at ‖H d + g‖₂ ≤ η ‖g‖₂")
      .def_readwrite("adaptive_forcing", &LaggedFactorOptions::adaptive_forcing,
                     "η_k = min(η, ‖g_k‖₂/‖g_k−1‖₂): tighter as Newton converges")
      .def_readwrite("max_cg_iterations", &LaggedFactorOptions::max_cg_iterations,
                     "CG iterations (≥ 1) per direction before factoring instead")
      .def_readwrite("refactor_after_cg_iterations",
                     &LaggedFactorOptions::refactor_after_cg_iterations,
                     "a solve needing more CG iterations than this (≥ 0) marks the factor stale")
      .def_readwrite("fast_preconditioner", &LaggedFactorOptions::fast_preconditioner,
                     "apply the factor in single precision (CHOLMOD: split over the threads)")
      .def_readwrite("reuse_hessian_below", &LaggedFactorOptions::reuse_hessian_below,
                     "≥ 0: once ‖g‖∞ ≤ this · max(1, ‖g₀‖∞), PCG may run on the previous "
                     "iterate's Hessian (a chord step, at most one in a row); 0: never")
      .def_readwrite("coarse_correction", &LaggedFactorOptions::coarse_correction,
                     "PCG's preconditioner gets an exact solve on every avatar's bone DoFs with "
                     "their block of the current Hessian (a two-level preconditioner; on in the "
                     "soft-tissue and ROM defaults)")
      .def("__repr__", [](const LaggedFactorOptions& o) {
        return "LaggedFactorOptions(enabled=" + std::string(o.enabled ? "True" : "False") +
               ", cg_relative_tolerance=" +
               py::repr(py::float_(o.cg_relative_tolerance)).cast<std::string>() +
               ", max_cg_iterations=" + std::to_string(o.max_cg_iterations) + ")";
      });

  const CoarsePresolveOptions pd;
  py::class_<CoarsePresolveOptions>(
      m, "CoarsePresolveOptions",
      "Newton iterations on the coarse DoFs alone (a scene's: every avatar's bones, the soft "
      "tissue held) before those on every DoF (NewtonOptions.coarse_presolve).")
      .def(py::init([](int max_iterations, double relative_tolerance) {
             CoarsePresolveOptions o;
             o.max_iterations = max_iterations;
             o.relative_tolerance = relative_tolerance;
             return o;
           }),
           py::kw_only(), py::arg("max_iterations") = pd.max_iterations,
           py::arg("relative_tolerance") = pd.relative_tolerance,
           "Keyword arguments; values are checked when a solve starts (ValueError).")
      .def_readwrite("max_iterations", &CoarsePresolveOptions::max_iterations,
                     "at most this many (≥ 0; 0: none; the soft-tissue and ROM defaults: 8)")
      .def_readwrite("relative_tolerance", &CoarsePresolveOptions::relative_tolerance,
                     "they stop at ‖g_c‖∞ ≤ this · max(1, ‖g_c,0‖∞), in (0, 1)")
      .def("__repr__", [](const CoarsePresolveOptions& o) {
        return "CoarsePresolveOptions(max_iterations=" + std::to_string(o.max_iterations) +
               ", relative_tolerance=" +
               py::repr(py::float_(o.relative_tolerance)).cast<std::string>() + ")";
      });

  const NewtonOptions nd;
  py::class_<NewtonOptions>(m, "NewtonOptions", "Newton's method with backtracking line search.")
      .def(py::init([](int max_iterations, double gradient_tolerance, double step_tolerance,
                       int max_line_search_steps, double armijo, double initial_regularization,
                       LinearSolverType linear_solver, bool exact_hessian, const py::object& lagged,
                       bool approximate_hessian, double approximate_max_ratio) {
             NewtonOptions o;
             if (!lagged.is_none()) o.lagged = lagged.cast<LaggedFactorOptions>();
             o.max_iterations = max_iterations;
             o.gradient_tolerance = gradient_tolerance;
             o.step_tolerance = step_tolerance;
             o.max_line_search_steps = max_line_search_steps;
             o.armijo = armijo;
             o.initial_regularization = initial_regularization;
             o.linear_solver = linear_solver;
             o.exact_hessian = exact_hessian;
             o.approximate_hessian = approximate_hessian;
             o.approximate_max_ratio = approximate_max_ratio;
             return o;
           }),
           py::kw_only(), py::arg("max_iterations") = nd.max_iterations,
           py::arg("gradient_tolerance") = nd.gradient_tolerance,
           py::arg("step_tolerance") = nd.step_tolerance,
           py::arg("max_line_search_steps") = nd.max_line_search_steps,
           py::arg("armijo") = nd.armijo,
           py::arg("initial_regularization") = nd.initial_regularization,
           py::arg("linear_solver") = nd.linear_solver, py::arg("exact_hessian") = nd.exact_hessian,
           py::arg("lagged") = py::none(), py::arg("approximate_hessian") = nd.approximate_hessian,
           py::arg("approximate_max_ratio") = nd.approximate_max_ratio,
           "Keyword arguments (lagged: LaggedFactorOptions, or None: off); values are checked "
           "when a solve starts (ValueError).")
      .def_readwrite("max_iterations", &NewtonOptions::max_iterations)
      .def_readwrite("gradient_tolerance", &NewtonOptions::gradient_tolerance,
                     "converged when ‖g‖∞ ≤ tol · max(1, ‖g₀‖∞)")
      .def_readwrite("step_tolerance", &NewtonOptions::step_tolerance,
                     "… or when the accepted step ‖dq‖∞ ≤ tol (m or rad)")
      .def_readwrite("max_line_search_steps", &NewtonOptions::max_line_search_steps)
      .def_readwrite("armijo", &NewtonOptions::armijo, "sufficient-decrease constant in (0, 1)")
      .def_readwrite("initial_regularization", &NewtonOptions::initial_regularization,
                     "first diagonal shift (relative to the mean diagonal) when H is not PD")
      .def_readwrite("linear_solver", &NewtonOptions::linear_solver)
      .def_readwrite("exact_hessian", &NewtonOptions::exact_hessian,
                     "try the exact Hessian first (falls back to the PSD form if not PD)")
      .def_readwrite("approximate_hessian", &NewtonOptions::approximate_hessian,
                     "directions from the objective's approximate Hessian (the ROM with modes: "
                     "a constant soft–soft block) while they shrink ‖g‖ fast, then the exact "
                     "ones (default False; SceneOptions.reduced_newton: True)")
      .def_readwrite("approximate_max_ratio", &NewtonOptions::approximate_max_ratio,
                     "largest ‖g_{k+1}‖₂ / ‖g_k‖₂ in (0, 1) that keeps the approximation")
      .def_readwrite("approximate_reuse", &NewtonOptions::approximate_reuse,
                     "solve with an earlier iteration's factor of the approximation while it "
                     "works (default True)")
      .def_readwrite("lagged", &NewtonOptions::lagged,
                     "LaggedFactorOptions (edit in place: options.lagged.enabled = False)")
      .def_readwrite("coarse_presolve", &NewtonOptions::coarse_presolve,
                     "CoarsePresolveOptions: iterations on the bones first (edit in place)")
      .def("__repr__", [](const NewtonOptions& o) {
        return "NewtonOptions(max_iterations=" + std::to_string(o.max_iterations) +
               ", gradient_tolerance=" +
               py::repr(py::float_(o.gradient_tolerance)).cast<std::string>() +
               ", linear_solver=" + solver_name(o.linear_solver) + ")";
      });

  py::class_<NewtonResult>(m, "NewtonResult", "Outcome of one Newton solve.")
      .def_readonly("converged", &NewtonResult::converged)
      .def_readonly("iterations", &NewtonResult::iterations)
      .def_readonly("energy", &NewtonResult::energy, "final energy, J")
      .def_readonly("gradient_norm", &NewtonResult::gradient_norm, "‖g‖∞ at the end")
      .def_readonly("line_search_steps", &NewtonResult::line_search_steps,
                    "backtracking halvings in total")
      .def_readonly("regularizations", &NewtonResult::regularizations, "Hessian shifts needed")
      .def_readonly("psd_fallbacks", &NewtonResult::psd_fallbacks,
                    "iterations whose direction came from the PSD form although the exact one was "
                    "asked (not positive definite, or a refresh of the lagged factor)")
      .def_readonly("hessian_evaluations", &NewtonResult::hessian_evaluations,
                    "Hessian assemblies (either form)")
      .def_readonly("approximate_directions", &NewtonResult::approximate_directions,
                    "iterations whose direction came from the approximate Hessian "
                    "(NewtonOptions.approximate_hessian)")
      .def_readonly("approximate_reuses", &NewtonResult::approximate_reuses,
                    "of those, the ones solved with an earlier iteration's factor")
      .def_readonly("hessian_reuses", &NewtonResult::hessian_reuses,
                    "iterations whose PCG ran on the previous iterate's Hessian "
                    "(LaggedFactorOptions.reuse_hessian_below)")
      .def_readonly("factorizations", &NewtonResult::factorizations,
                    "numeric factorizations (regularization retries included)")
      .def_readonly("cg_iterations", &NewtonResult::cg_iterations,
                    "preconditioned CG iterations (lagged factor only)")
      .def_readonly("coarse_iterations", &NewtonResult::coarse_iterations,
                    "iterations on the coarse DoFs alone (NewtonOptions.coarse_presolve; not in "
                    "iterations)")
      .def_readonly("message", &NewtonResult::message)
      .def("__repr__", [](const NewtonResult& r) {
        return "NewtonResult(converged=" + std::string(r.converged ? "True" : "False") +
               ", iterations=" + std::to_string(r.iterations) + ", message='" + r.message + "')";
      });

  const SceneOptions sd;
  py::class_<SceneOptions>(m, "SceneOptions", "Options of a Scene.")
      .def(py::init([](const py::object& newton, bool avatar_contact,
                       const py::object& avatar_contact_options,
                       const py::object& soft_tissue_newton, const py::object& reduced_newton) {
             SceneOptions o;
             if (!newton.is_none()) o.newton = newton.cast<NewtonOptions>();
             if (!soft_tissue_newton.is_none())
               o.soft_tissue_newton = soft_tissue_newton.cast<NewtonOptions>();
             if (!reduced_newton.is_none()) o.reduced_newton = reduced_newton.cast<NewtonOptions>();
             o.avatar_contact = avatar_contact;
             if (!avatar_contact_options.is_none())
               o.avatar_contact_options = avatar_contact_options.cast<ContactOptions>();
             return o;
           }),
           py::kw_only(), py::arg("newton") = py::none(),
           py::arg("avatar_contact") = sd.avatar_contact,
           py::arg("avatar_contact_options") = py::none(),
           py::arg("soft_tissue_newton") = py::none(), py::arg("reduced_newton") = py::none(),
           "newton: NewtonOptions or None; avatar_contact: vertices against the other avatars' "
           "bone capsules; avatar_contact_options: ContactOptions or None; soft_tissue_newton / "
           "reduced_newton: NewtonOptions of scenes with FEM soft tissue / with ROM soft tissue "
           "only, or None (their defaults).")
      .def_readwrite("newton", &SceneOptions::newton,
                     "NewtonOptions of skeleton-only scenes (a copy on read)")
      .def_readwrite("soft_tissue_newton", &SceneOptions::soft_tissue_newton,
                     "NewtonOptions of scenes with an FEM soft-tissue simulable (a copy on read; "
                     "default: PSD Hessian, CHOLMOD with a lagged factor, gradient_tolerance 1e-5)")
      .def_readwrite("reduced_newton", &SceneOptions::reduced_newton,
                     "NewtonOptions of scenes whose soft-tissue simulables all use the reduced "
                     "model (a copy on read; default: exact Hessian with PSD fallback, lagged "
                     "factor, gradient_tolerance 1e-6, linear_solver Auto = dense up to 1500 "
                     "DoFs, CHOLMOD above, approximate_hessian True)")
      .def_readwrite("avatar_contact", &SceneOptions::avatar_contact)
      .def_readwrite("lower_energy_start", &SceneOptions::lower_energy_start,
                     "With soft tissue: start each step's Newton from the lower-energy of the "
                     "inertial prediction and the previous state (default True)")
      .def_readwrite("avatar_contact_options", &SceneOptions::avatar_contact_options,
                     "ContactOptions (a copy on read)");

  py::class_<StepStats>(m, "StepStats", "Diagnostics of one Scene.step().")
      .def_readonly("newton", &StepStats::newton, "NewtonResult")
      .def_readonly("active_contacts", &StepStats::active_contacts,
                    "vertex–collider and vertex–capsule pairs in contact")
      .def_readonly("seconds", &StepStats::seconds, "wall time of the step, s")
      .def("__repr__", [](const StepStats& s) {
        return "StepStats(converged=" + std::string(s.newton.converged ? "True" : "False") +
               ", iterations=" + std::to_string(s.newton.iterations) +
               ", active_contacts=" + std::to_string(s.active_contacts) + ")";
      });

  py::class_<Scene, std::shared_ptr<Scene>>(
      m, "Scene",
      "Several simulables and colliders stepped together; states merged into one vector "
      "(simulable i at offset(i)). Keeps its simulables alive. Not thread-safe.")
      .def(py::init([](const py::object& options) {
             return std::make_shared<Scene>(options.is_none() ? SceneOptions()
                                                              : options.cast<SceneOptions>());
           }),
           py::arg("options") = py::none(), "options: SceneOptions or None.")
      .def("add_simulable", &Scene::addSimulable, py::arg("simulable"),
           "Adds a Simulable (all must share one time step).")
      .def("add_collider", &Scene::addCollider, py::arg("collider"),
           "Adds a Collider seen by every avatar (a copy).")
      .def("initialize", &Scene::initialize, "Calls initialize() on every simulable.")
      .def("step", py::overload_cast<>(&Scene::step), py::call_guard<py::gil_scoped_release>(),
           "One backward-Euler step of every simulable (preUpdate, Newton, postUpdate); "
           "returns StepStats. Releases the GIL.")
      .def_property_readonly("time", &Scene::time, "s")
      .def("has_soft_tissue", &Scene::hasSoftTissue,
           "True when some simulable has soft-tissue DoFs (FEM or ROM).")
      .def("has_fem_soft_tissue", &Scene::hasFemSoftTissue,
           "True when some simulable has FEM soft tissue (not the reduced model).")
      .def_property_readonly(
          "newton_options", [](const Scene& s) { return NewtonOptions(s.newtonOptions()); },
          "The NewtonOptions step() uses (a copy): options.newton for "
          "skeletons only, else soft_tissue_newton with FEM soft tissue, else "
          "reduced_newton.")
      .def("set_static", &Scene::setStatic, py::arg("on") = true,
           "True: drops the dynamic terms (static equilibrium).")
      .def_property_readonly("simulables", &Scene::simulables, "list of Simulable")
      .def_property_readonly("colliders", &Scene::colliders, "list of Collider (copies)")
      .def(
          "offset",
          [](const Scene& s, int i) {
            if (i < 0 || i >= int(s.simulables().size()))
              throw py::index_error("offset: simulable index " + std::to_string(i) +
                                    " out of range [0, " + std::to_string(s.simulables().size()) +
                                    ")");
            return s.offset(i);
          },
          py::arg("i"), "Index of simulable i's first DoF in the merged vector.")
      .def_property_readonly("num_dofs", &Scene::numDofs, "Merged number of DoFs.")
      .def_property_readonly("options", &Scene::options, "SceneOptions (a copy).")
      .def("energy", &Scene::energy, "Merged backward-Euler energy at the current states, J.")
      .def(
          "gradient",
          [](Scene& s) {
            VecX g;
            s.gradient(g);
            return to_numpy(g);
          },
          "(num_dofs,) merged gradient (kinematic DoFs not zeroed).")
      .def(
          "hessian",
          [](Scene& s, bool psd) {
            SpMat H;
            {
              py::gil_scoped_release release;
              s.hessian(H, psd);
            }
            return to_scipy_csc(H);
          },
          py::arg("psd") = true,
          "Merged Hessian as scipy.sparse.csc_matrix (num_dofs, num_dofs); psd=False: exact.")
      .def(
          "apply_increment",
          [](Scene& s, const py::object& dq) { s.step(to_vector(dq, "dq", s.numDofs())); },
          py::arg("dq"), "Applies a merged increment dq (num_dofs,) to every simulable.")
      .def("push", &Scene::push, "Saves every simulable's state.")
      .def("pop", &Scene::pop, "Restores the last pushed states (RuntimeError if none).")
      .def(
          "fix_kinematic",
          [](Scene& s, const py::object& g, const py::object& H) -> py::object {
            VecX v = to_vector(g, "g", s.numDofs());
            if (H.is_none()) {
              s.fixKinematic(v, nullptr);
              return to_numpy(v);
            }
            const std::vector<Triplet> t = to_triplets(H, "H", s.numDofs(), s.numDofs());
            SpMat A(s.numDofs(), s.numDofs());
            A.setFromTriplets(t.begin(), t.end());
            s.fixKinematic(v, &A);
            return py::make_tuple(to_numpy(v), to_scipy_csc(A));
          },
          py::arg("g"), py::arg("H") = py::none(),
          "g (num_dofs,) with kinematic DoFs zeroed; with H also H with their rows/columns "
          "made identity: returns g or (g, H as csc_matrix).")
      .def("__repr__", [](const Scene& s) {
        return "Scene(simulables=" + std::to_string(s.simulables().size()) +
               ", colliders=" + std::to_string(s.colliders().size()) +
               ", dofs=" + std::to_string(s.numDofs()) + ")";
      });

  m.def(
      "newton_solve",
      [](Scene& scene, const py::object& options) {
        const NewtonOptions o =
            options.is_none() ? scene.options().newton : options.cast<NewtonOptions>();
        py::gil_scoped_release release;
        return newtonSolve(scene, o);  // own solver: the scene's may be sized for other DoFs
      },
      py::arg("scene"), py::arg("options") = py::none(),
      "Minimizes the scene's merged energy from its current states (no preUpdate / "
      "postUpdate); options: NewtonOptions or None (the scene's). Releases the GIL.");
}

}  // namespace flsh::python
