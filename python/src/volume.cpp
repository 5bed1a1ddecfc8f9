// Bindings of include/flsh/volume: SoftAvatar (rest shape, bone inertias, capsules) with the
// FLSH paper's camelCase settings as aliases of the snake_case names, the volumetric body of the
// soft-tissue models and the reduced data (handles, basis, cubatures) of the ROM.
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <cmath>
#include <cstdint>
#include <memory>

#include "bindings.h"
#include "flsh/io/presets.h"
#include "flsh/volume/closest_surface_points.h"
#include "flsh/volume/modal_basis.h"
#include "flsh/volume/reduced_data.h"
#include "flsh/volume/soft_avatar.h"
#include "flsh/volume/tet_mesh.h"

namespace flsh::python {

namespace {

py::array_t<double> mat3_numpy(const Mat3& M) {
  const Eigen::Matrix<double, 3, 3, Eigen::RowMajor> rm = M;
  return to_numpy(rm.data(), {3, 3});
}

// Arrays that only exist after initVolumetricData(): a clear error instead of an empty array.
const SoftAvatar& initialized(const SoftAvatar& a, const char* what) {
  if (!a.initialized())
    throw py::value_error(std::string("SoftAvatar.") + what +
                          ": the avatar is not initialized (call init_volumetric_data() first)");
  return a;
}

py::array_t<double> to_numpy_col(const MatX& M) { return to_numpy(RowMatX(M)); }

py::array_t<int> ints_numpy(const MatX4i& tets) {
  return take_numpy(MatX4i(tets), {py::ssize_t(tets.rows()), 4});
}

py::array_t<int> indices_numpy(const VecXi& v) {
  return take_numpy(VecXi(v), {py::ssize_t(v.size())});
}

// A ReducedSettings count from a keyword argument: ValueError naming it when below `lo`.
int checked_count(int value, const char* name, int lo, const char* meaning) {
  if (value < lo)
    throw py::value_error(std::string(name) + ": expected an integer ≥ " + std::to_string(lo) +
                          " (" + meaning + "), got " + std::to_string(value));
  return value;
}

py::dict quality_dict(const TetMeshQuality& q) {
  py::dict d;
  d["min_dihedral_deg"] = q.min_dihedral_deg;
  d["max_dihedral_deg"] = q.max_dihedral_deg;
  d["max_radius_edge_ratio"] = q.max_radius_edge_ratio;
  d["mean_radius_edge_ratio"] = q.mean_radius_edge_ratio;
  d["min_volume"] = q.min_volume;
  return d;
}

}  // namespace

void bind_volume(py::module_& m) {
  m.def(
      "tetrahedralize_surface",
      [](const py::object& V, const py::object& F, double resolution, bool improve_quality) {
        const MatX3 vertices = to_points(V, "vertices");
        const MatX3i faces = to_triangles(F, "faces");
        TetMeshOptions options;
        options.resolution = resolution;
        options.improve_quality = improve_quality;
        TetMesh mesh;
        {
          py::gil_scoped_release release;
          mesh = tetrahedralizeSurface(vertices, faces, options);
        }
        return py::make_tuple(to_numpy(mesh.nodes), ints_numpy(mesh.tets),
                              quality_dict(tetMeshQuality(mesh)));
      },
      py::arg("vertices"), py::arg("faces"), py::kw_only(), py::arg("resolution") = 1.0,
      py::arg("improve_quality") = true,
      "Tet mesh of a closed, outward-oriented surface (vertices (V, 3) m, faces (F, 3)) keeping "
      "the surface: returns (nodes (N, 3) m with nodes[:V] == vertices, tets (T, 4) int32 "
      "positively oriented, quality dict). resolution scales the interior node count; "
      "improve_quality runs the flip/smoothing pass on the worst tets (surface untouched).");

  m.def(
      "closest_surface_points",
      [](const py::object& V, const py::object& F, const py::object& P) {
        const MatX3 vertices = to_points(V, "vertices");
        const MatX3i faces = to_triangles(F, "faces");
        const MatX3 points = to_points(P, "points");
        ClosestSurfacePoints hits;
        {
          py::gil_scoped_release release;
          hits = closestSurfacePoints(vertices, faces, points);
        }
        return py::make_tuple(indices_numpy(hits.faces), to_numpy(hits.barycentric),
                              to_numpy(hits.distances));
      },
      py::arg("vertices"), py::arg("faces"), py::arg("points"),
      "The closest point of a triangle surface (vertices (V, 3), faces (F, 3)) to each query "
      "point (points (P, 3)), exact (bounding-box tree): returns (face (P,) int32, barycentric "
      "(P, 3) weights on the face's vertices, distance (P,) m). ValueError on a bad shape, index "
      "or value.");

  m.def(
      "soft_tissue_rest_operators",
      [](const SoftAvatar& avatar) {
        SoftTissueRestOperators ops;
        {
          py::gil_scoped_release release;
          ops = softTissueRestOperators(
              initialized(avatar, "soft_tissue_rest_operators").volumetricData());
        }
        py::dict d;
        d["soft_nodes"] = indices_numpy(ops.soft_nodes);
        d["stiffness"] = to_scipy_csc(ops.stiffness);
        d["masses"] = to_numpy(ops.masses);
        d["coupling"] = to_numpy_col(ops.coupling);
        return d;
      },
      py::arg("avatar"),
      "The soft tissue of an initialized soft avatar linearized at rest with its bone nodes fixed "
      "(docs/rom.md, 'A basis from the physics'): a dict with soft_nodes (S,) node indices, "
      "stiffness K_uu (scipy.sparse, 3S × 3S, N/m; DoF 3i + a is coordinate a of soft_nodes[i]), "
      "masses (3S,) the lumped M_uu diagonal (kg) and coupling M_ub (3S, 144): the inertial "
      "coupling to each bone's (δt, δω).");

  m.def(
      "modal_basis",
      [](const SoftAvatar& avatar, bool static_modes, int vibration_modes, int columns,
         double eigen_tolerance, std::uint64_t seed, double rotation_weight) {
        ModalBasisSettings settings;
        settings.static_modes = static_modes;
        settings.vibration_modes = vibration_modes;
        settings.columns = columns;
        settings.rotation_weight = rotation_weight;
        settings.eigen_tolerance = eigen_tolerance;
        settings.seed = seed;
        ModalBasis basis;
        {
          py::gil_scoped_release release;
          basis = computeModalBasis(initialized(avatar, "modal_basis").volumetricData(), settings);
        }
        const ModalBasisReport& r = basis.report;
        py::dict report;
        report["static_columns"] = r.static_columns;
        report["vibration_columns"] = r.vibration_columns;
        report["dropped_columns"] = r.dropped_columns;
        report["frequencies"] = to_numpy(r.frequencies);
        report["max_eigen_residual"] = r.max_eigen_residual;
        report["eigen_iterations"] = r.eigen_iterations;
        report["factor_solves"] = r.factor_solves;
        report["seconds"] = r.seconds_total;
        const py::ssize_t n = basis.basis.rows() / 3, k = basis.basis.cols();
        // (N, 3, r): row 3j + a of Ψ is [j, a].
        return py::make_tuple(take_numpy(RowMatX(basis.basis), {n, 3, k}), report);
      },
      py::arg("avatar"), py::kw_only(), py::arg("static_modes") = true,
      py::arg("vibration_modes") = 50, py::arg("columns") = 0, py::arg("eigen_tolerance") = 1e-5,
      py::arg("seed") = 1, py::arg("rotation_weight") = ModalBasisSettings().rotation_weight,
      "The skeleton-aware soft-tissue basis of an initialized soft avatar (issue 26; docs/rom.md, "
      "'A basis from the physics'): one static-correction mode per bone DoF (static_modes) plus "
      "the lowest fixed-interface vibration modes, mass-orthonormal, dependent columns dropped, "
      "compressed to `columns` when > 0 (mass-PCA of the columns weighted by the load each "
      "answers; rotation_weight: a rotation's static mode against a translation's, m/s² per "
      "rad/s², > 0). Returns (basis (N, 3, r): displacement of node j in "
      "column k is basis[j, :, k], zero on bone nodes; report dict with the column counts, the "
      "vibration frequencies in Hz and the eigensolver's residual, Lanczos steps and solves). "
      "ValueError for settings out of range.");

  py::class_<VolumetricData>(
      m, "VolumetricData",
      "The volumetric body of a soft avatar (read-only; arrays are copies): the template tet "
      "mesh, fields extended to all nodes, rest nodes at β, bone nodes and per-tet materials.")
      .def_property_readonly("num_nodes", &VolumetricData::numNodes)
      .def_property_readonly("num_tets", &VolumetricData::numTets)
      .def_property_readonly(
          "num_surface_nodes",
          [](const VolumetricData& d) { return d.templ->mesh.num_surface_nodes; },
          "V: nodes 0..V−1 are the SMPL surface vertices in order")
      .def_property_readonly("num_bone_nodes", &VolumetricData::numBoneNodes)
      .def_property_readonly(
          "template_nodes", [](const VolumetricData& d) { return to_numpy(d.templ->mesh.nodes); },
          "(N, 3) rest nodes of the template (β = 0), m")
      .def_property_readonly(
          "rest_nodes", [](const VolumetricData& d) { return to_numpy(d.rest_nodes); },
          "(N, 3) rest nodes X̄(β) = X̄₀ + S β, m")
      .def_property_readonly(
          "rest_joints", [](const VolumetricData& d) { return to_numpy(d.rest_joints); },
          "(24, 3) J(β), m")
      .def_property_readonly(
          "tets", [](const VolumetricData& d) { return ints_numpy(d.templ->mesh.tets); },
          "(T, 4) node indices, positively oriented")
      .def_property_readonly(
          "weights", [](const VolumetricData& d) { return to_numpy_col(d.templ->fields.weights); },
          "(N, 24) skinning weights on all nodes (rows sum to 1)")
      .def_property_readonly(
          "shapedirs",
          [](const VolumetricData& d) { return to_numpy_col(d.templ->fields.shapedirs); },
          "(3N, K) shape directions, row 3i + c, m per unit β")
      .def_property_readonly(
          "posedirs",
          [](const VolumetricData& d) { return to_numpy_col(d.templ->fields.posedirs); },
          "(3N, 207) pose blend shapes, row 3i + c, m")
      .def_property_readonly(
          "bone_of_node",
          [](const VolumetricData& d) {
            return take_numpy(VecXi(d.bone_of_node), {py::ssize_t(d.bone_of_node.size())});
          },
          "(N,) int32: bone a node is attached to, −1 for soft tissue")
      .def_property_readonly(
          "tissue_thickness", [](const VolumetricData& d) { return to_numpy(d.tissue_thickness); },
          "(V,) local soft-tissue thickness at the surface vertices, m")
      .def_property_readonly(
          "density", [](const VolumetricData& d) { return to_numpy(d.materials.density); },
          "(T,) kg/m³")
      .def_property_readonly(
          "young", [](const VolumetricData& d) { return to_numpy(RowMatX(d.materials.young)); },
          "(T, 3) Young's moduli E1, E2, E3 along the frame axes a1, a2, a3, Pa")
      .def_property_readonly(
          "poisson", [](const VolumetricData& d) { return to_numpy(RowMatX(d.materials.poisson)); },
          "(T, 3) Poisson ratios ν12, ν13, ν23")
      .def_property_readonly(
          "shear", [](const VolumetricData& d) { return to_numpy(RowMatX(d.materials.shear)); },
          "(T, 3) shear moduli G12, G13, G23, Pa")
      .def_property_readonly(
          "fung", [](const VolumetricData& d) { return to_numpy(d.materials.fung); },
          "(T,) Fung exponent γ (dimensionless)")
      .def_property_readonly(
          "skin_fraction",
          [](const VolumetricData& d) { return to_numpy(d.materials.skin_fraction); },
          "(T,) fraction of the tet's volume that is skin")
      .def_property_readonly(
          "frames",
          [](const VolumetricData& d) {
            RowMatX f(long(d.materials.frame.size()), 9);
            for (size_t t = 0; t < d.materials.frame.size(); ++t)
              Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(f.row(long(t)).data()) =
                  d.materials.frame[t];
            return take_numpy(std::move(f), {py::ssize_t(d.materials.frame.size()), 3, 3});
          },
          "(T, 3, 3) material frames; columns a1 (bone axis on the tangent plane), "
          "a2 = a3 × a1, a3 (inward normal)")
      .def_property_readonly(
          "quality", [](const VolumetricData& d) { return quality_dict(d.templ->quality); },
          "dict: min/max dihedral angle (deg), max/mean radius–edge ratio, min volume (m³)")
      .def_property_readonly("total_mass", &VolumetricData::totalMass,
                             "Σ ρ · volume over tets at X̄(β), kg");

  py::class_<Cubature>(
      m, "Cubature",
      "Sample tets and non-negative weights replacing a sum over all tets (read-only copies).")
      .def_property_readonly(
          "elements", [](const Cubature& c) { return indices_numpy(c.elements); },
          "(S,) int32 tet indices into the template mesh, ascending")
      .def_property_readonly(
          "weights", [](const Cubature& c) { return to_numpy(c.weights); },
          "(S,) float64 weights > 0 (dimensionless: 1 = the tet itself)")
      .def_property_readonly(
          "training_error", [](const Cubature& c) { return c.training_error; },
          "relative error ‖A_S w − A·1‖ / ‖A·1‖ on the training samples")
      .def_property_readonly(
          "rounds", [](const Cubature& c) { return c.rounds; }, "greedy rounds of the selection")
      .def("__len__", [](const Cubature& c) { return c.elements.size(); })
      .def("__repr__", [](const Cubature& c) {
        return "Cubature(tets=" + std::to_string(c.elements.size()) +
               ", training_error=" + py::repr(py::float_(c.training_error)).cast<std::string>() +
               ")";
      });

  py::class_<ReducedData>(
      m, "ReducedData",
      "The reduced data of a ROM avatar (read-only; arrays are copies): surface handles, the "
      "bounded biharmonic basis φ (u_j = Σ_h φ_h(j) z_h) and the elastic / inertial cubatures "
      "with their held-out errors (docs/rom.md).")
      .def_property_readonly("num_handles", &ReducedData::numHandles, "H")
      .def_property_readonly(
          "basis_kind",
          [](const ReducedData& d) { return std::string(reducedBasisKindName(d.basis_kind)); },
          "'handles', 'modes' or 'modes+handles'")
      .def_property_readonly("num_modes", &ReducedData::numModes, "r (0 without modes)")
      .def_property_readonly(
          "modes",
          [](const ReducedData& d) {
            return take_numpy(RowMatX(d.modes), {py::ssize_t(d.modes.rows() / 3), py::ssize_t(3),
                                                 py::ssize_t(d.modes.cols())});
          },
          "(N, 3, r) float64 modal columns Ψ (u_j = Ψ[j] @ z_modes; mass-orthonormal, zero on "
          "bone nodes; (N, 3, 0) without modes)")
      .def_property_readonly(
          "handles", [](const ReducedData& d) { return indices_numpy(d.handles); },
          "(H,) int32 tet-node (= surface vertex) indices, farthest-point order")
      .def_property_readonly(
          "basis", [](const ReducedData& d) { return to_scipy_csc(d.basis); },
          "scipy.sparse.csc_matrix (N, H): entry (j, h) = φ_h at tet node j, "
          "in [0, 1]; bone-node rows empty, handle rows unit vectors")
      .def_property_readonly(
          "basis_max_bound_violation",
          [](const ReducedData& d) { return d.basis_max_bound_violation; },
          "max over free nodes of max(−φ, φ − 1, 0) of the QP solve")
      .def_property_readonly(
          "basis_max_constraint_error",
          [](const ReducedData& d) { return d.basis_max_constraint_error; },
          "max |φ_h − δ| at the handles and |φ_h| on bone nodes")
      .def_property_readonly(
          "basis_converged", [](const ReducedData& d) { return d.basis_converged; },
          "every handle's QP met its KKT tolerance")
      .def_property_readonly(
          "elastic_cubature", [](const ReducedData& d) { return d.elastic; },
          "Cubature of the elastic energy (empty when switched off)")
      .def_property_readonly(
          "elastic_test_error", [](const ReducedData& d) { return d.elastic_test_error; },
          "held-out relative error of the elastic energy (0 when off)")
      .def_property_readonly(
          "elastic_rest_stiffness",
          [](const ReducedData& d) { return to_numpy(RowMatX(d.elastic_rest_stiffness)); },
          "(m, m) exact rest stiffness of the subspace (m = 3H + r), N/m: the quadratic "
          "the elastic cubature's sample tets add their excess to (docs/rom.md; "
          "empty when the elastic cubature is off)")
      .def_property_readonly(
          "inertial_cubature", [](const ReducedData& d) { return d.inertial; },
          "Cubature of the kinetic energy (empty when switched off)")
      .def_property_readonly(
          "inertial_test_error", [](const ReducedData& d) { return d.inertial_test_error; },
          "held-out relative error of the kinetic energy (0 when off)")
      .def_property_readonly(
          "inertial_rigid_error", [](const ReducedData& d) { return d.inertial_rigid_error; },
          "largest relative error of the kinetic energy over the skeleton's "
          "rigid motions (each bone turning about its joint; 0 when off)")
      .def_property_readonly(
          "key", [](const ReducedData& d) { return d.key; }, "cache key of this level")
      .def("__repr__", [](const ReducedData& d) {
        return "ReducedData(basis='" + std::string(reducedBasisKindName(d.basis_kind)) +
               "', handles=" + std::to_string(d.numHandles()) +
               ", modes=" + std::to_string(d.numModes()) +
               ", elastic_tets=" + std::to_string(d.elastic.elements.size()) +
               ", inertial_tets=" + std::to_string(d.inertial.elements.size()) + ")";
      });

  py::class_<BoneInertia>(m, "BoneInertia",
                          "Mass properties of one bone about its joint centre J_b (rest pose, "
                          "world axes).")
      .def_property_readonly(
          "mass", [](const BoneInertia& b) { return b.mass; }, "Σ m, kg")
      .def_property_readonly(
          "first_moment", [](const BoneInertia& b) { return to_numpy(VecX(b.first_moment)); },
          "(3,) Σ m (X − J_b), kg·m")
      .def_property_readonly(
          "second_moment", [](const BoneInertia& b) { return mat3_numpy(b.second_moment); },
          "(3, 3) Σ m (X − J_b)(X − J_b)ᵀ, kg·m²")
      .def(
          "center_of_mass",
          [](const BoneInertia& b, const py::object& joint) {
            return to_numpy(VecX(b.centerOfMass(to_vec3(joint, "joint"))));
          },
          py::arg("joint"), "(3,) centre of mass J_b + first_moment / mass, m; joint (3,) m.")
      .def("__repr__", [](const BoneInertia& b) {
        return "BoneInertia(mass=" + py::repr(py::float_(b.mass)).cast<std::string>() + ")";
      });

  py::class_<BoneCapsule>(m, "BoneCapsule", "A capsule attached to a bone (rest pose), m.")
      .def_property_readonly(
          "bone", [](const BoneCapsule& c) { return c.bone; }, "bone index")
      .def_property_readonly(
          "a", [](const BoneCapsule& c) { return to_numpy(VecX(c.a)); },
          "(3,) first end of the axis segment, m")
      .def_property_readonly(
          "b", [](const BoneCapsule& c) { return to_numpy(VecX(c.b)); },
          "(3,) second end of the axis segment, m")
      .def_property_readonly(
          "radius", [](const BoneCapsule& c) { return c.radius; }, "m")
      .def("__repr__", [](const BoneCapsule& c) {
        return "BoneCapsule(bone=" + std::to_string(c.bone) +
               ", radius=" + py::repr(py::float_(c.radius)).cast<std::string>() + ")";
      });

  const SoftAvatarSettings defaults;
  const ReducedSettings& rd = defaults.reduced;
  py::class_<SoftAvatar, std::shared_ptr<SoftAvatar>> avatar(
      m, "SoftAvatar",
      "The immutable data of one body shape for simulation. Configure, then call "
      "init_volumetric_data(); the skeleton model (soft tissue off) is the default.");
  avatar
      .def(
          py::init([](std::shared_ptr<BodyModel> body, const py::object& betas, double density,
                      double voxel_size, double resolution, const std::string& material_file,
                      const py::object& cache_dir, bool use_cache, const py::object& handles,
                      const py::object& elastic_cubature_points,
                      const py::object& inertial_cubature_points,
                      const py::object& cubature_training_samples,
                      double cubature_training_amplitude, std::uint64_t cubature_seed,
                      double basis_drop_below, bool surface_partition_of_unity,
                      const py::object& basis, const py::object& vibration_modes,
                      const py::object& modal_columns, const py::object& preset) {
            if (!body) throw py::value_error("body: expected a BodyModel, got None");
            const VecX b = betas.is_none() ? VecX(VecX::Zero(body->numBetas()))
                                           : to_vector(betas, "betas", -1, "(K,)");
            SoftAvatarSettings settings;
            settings.density = density;
            settings.voxel_size = voxel_size;
            settings.volumetric.tet_mesh.resolution = resolution;
            settings.volumetric.material_file = material_file;
            if (!cache_dir.is_none())
              settings.volumetric.cache_dir =
                  py::module_::import("os").attr("fspath")(cache_dir).cast<std::string>();
            settings.volumetric.use_cache = use_cache;
            // An optional argument: false for None, TypeError naming it for another type than
            // T (`what` describes the values expected).
            const auto given = [](const py::object& value, const char* name, auto type,
                                  const char* what) {
              if (!value.is_none() && !py::isinstance<decltype(type)>(value))
                throw py::type_error(std::string(name) + ": expected " + what + " or None, got " +
                                     py::str(py::type::of(value)).cast<std::string>());
              return !value.is_none();
            };
            // The preset's settings first, then the arguments given (None: the preset's).
            ReducedSettings& r = settings.reduced;
            r = presetReducedSettings(
                given(preset, "preset", py::str(), "'none', 'realtime'")
                    ? parsePreset(preset.cast<std::string>(), "SoftAvatar: preset")
                    : Preset::None);
            const auto given_int = [&](const py::object& value, const char* name) {
              return given(value, name, py::int_(), "an int");
            };
            if (given_int(handles, "handles"))
              r.num_handles =
                  checked_count(handles.cast<int>(), "handles", 1, "point handles of the ROM");
            if (given_int(elastic_cubature_points, "elastic_cubature_points"))
              r.elastic_cubature_points =
                  checked_count(elastic_cubature_points.cast<int>(), "elastic_cubature_points", 1,
                                "sample tets; enable_elastic_cubature(False) switches it off");
            if (given_int(inertial_cubature_points, "inertial_cubature_points"))
              r.inertial_cubature_points =
                  checked_count(inertial_cubature_points.cast<int>(), "inertial_cubature_points", 1,
                                "sample tets; enable_inertial_cubature(False) switches it off");
            if (given_int(cubature_training_samples, "cubature_training_samples"))
              r.training_samples =
                  checked_count(cubature_training_samples.cast<int>(), "cubature_training_samples",
                                1, "random training samples per cubature");
            if (!(cubature_training_amplitude > 0) || !std::isfinite(cubature_training_amplitude))
              throw py::value_error(
                  "cubature_training_amplitude: expected a finite value > 0 (m), got " +
                  std::to_string(cubature_training_amplitude));
            r.training_amplitude = cubature_training_amplitude;
            r.seed = cubature_seed;
            if (!(basis_drop_below >= 0.0 && basis_drop_below <= 0.01))
              throw py::value_error("basis_drop_below: expected a value in [0, 0.01], got " +
                                    std::to_string(basis_drop_below));
            r.basis_drop_below = basis_drop_below;
            r.surface_partition_of_unity = surface_partition_of_unity;
            // As in scene files: handles without a basis choose the handle basis (the modal
            // basis, the default, has none).
            if (given(basis, "basis", py::str(), "'modes', 'handles', 'modes+handles'"))
              r.basis_kind = parseReducedBasisKind(basis.cast<std::string>(), "SoftAvatar: basis");
            else if (!handles.is_none())
              r.basis_kind = ReducedBasisKind::Handles;
            if (!handles.is_none() && r.basis_kind == ReducedBasisKind::Modes)
              throw py::value_error(
                  "handles: not used by basis='modes' (handles belong to basis='handles' or "
                  "'modes+handles')");
            if (given_int(vibration_modes, "vibration_modes")) {
              r.modes.vibration_modes = vibration_modes.cast<int>();
              if (r.modes.vibration_modes < 0)
                throw py::value_error("vibration_modes: expected ≥ 0, got " +
                                      std::to_string(r.modes.vibration_modes));
            }
            if (given_int(modal_columns, "modal_columns")) {
              r.modes.columns = modal_columns.cast<int>();
              if (r.modes.columns < 0)
                throw py::value_error("modal_columns: expected ≥ 0 (0: every column), got " +
                                      std::to_string(r.modes.columns));
            }
            return std::make_shared<SoftAvatar>(std::move(body), b, settings);
          }),
          py::arg("body"), py::arg("betas") = py::none(), py::kw_only(),
          py::arg("density") = defaults.density, py::arg("voxel_size") = defaults.voxel_size,
          py::arg("resolution") = 1.0, py::arg("material_file") = std::string(),
          py::arg("cache_dir") = py::none(), py::arg("use_cache") = true,
          py::arg("handles") = py::none(), py::arg("elastic_cubature_points") = py::none(),
          py::arg("inertial_cubature_points") = py::none(),
          py::arg("cubature_training_samples") = py::none(),
          py::arg("cubature_training_amplitude") = rd.training_amplitude,
          py::arg("cubature_seed") = rd.seed, py::arg("basis_drop_below") = rd.basis_drop_below,
          py::arg("surface_partition_of_unity") = rd.surface_partition_of_unity,
          py::arg("basis") = py::none(), py::arg("vibration_modes") = py::none(),
          py::arg("modal_columns") = py::none(), py::arg("preset") = py::none(),
          "body: BodyModel; betas (≤K,) zero padded, None = zeros; density kg/m³ and voxel_size "
          "m (the skeleton's bone inertias). Soft tissue: resolution (interior node density of the "
          "tet mesh, 1 ≈ 10 000 nodes for SMPL), material_file (JSON, '' = built-in defaults), "
          "cache_dir (None = $FLSH_CACHE_DIR or ~/.cache/flsh), use_cache. Reduced model (ROM, "
          "enable_reduced_model(); docs/rom.md): basis: 'modes' (the default: the avatar's "
          "static-correction and vibration modes), 'handles' (the FLSH paper's surface handles) "
          "or 'modes+handles'; None = 'modes', or 'handles' when handles is given. With modes, "
          "vibration_modes (≥ 0; None = 24) and modal_columns (compressed to this many, 0 = all; "
          "cut to a multiple of 3; None = 72). handles (point handles on the surface, ≥ 1; None "
          "= 87), elastic_cubature_points / inertial_cubature_points (sample tets of each "
          "cubature when enabled, ≥ 1; None = 500), preset (None or 'none': the defaults above; "
          "'realtime': modes 12:24 (rotation weight 1) and 100-tet cubatures trained on 400 "
          "samples, the arguments given win; a scene's "
          "Newton budget is the scene key \"preset\", or SceneOptions.reduced_newton."
          "max_iterations = 3), cubature_training_samples (random training samples per cubature; "
          "None = 600, the preset's under a preset), "
          "cubature_training_amplitude (largest handle displacement of a training sample, m), "
          "cubature_seed, basis_drop_below (handle weights below it are dropped, in [0, 0.01]), "
          "surface_partition_of_unity (the handle weights rescaled to sum to 1 on the soft "
          "surface: about half the error against the FEM, slower; docs/rom.md).")
      .def(
          "init_volumetric_data",
          [](SoftAvatar& a) {
            py::gil_scoped_release release;
            a.initVolumetricData();
          },
          "Builds what the configured model needs (every model: rest shape, joints, bone "
          "inertias, capsules; soft tissue: the volumetric body; the reduced model also its "
          "handles, basis and the enabled cubatures; each level from the cache when there). "
          "Idempotent; ValueError for the reduced model without soft tissue or for more handles "
          "than soft-tissue surface nodes.")
      .def_property_readonly(
          "volumetric_data",
          [](const SoftAvatar& a) -> const VolumetricData& { return a.volumetricData(); },
          py::return_value_policy::reference_internal,
          "VolumetricData of a soft avatar (RuntimeError for the skeleton model).")
      .def_property_readonly("has_volumetric_data", &SoftAvatar::hasVolumetricData)
      .def_property_readonly(
          "material_parameters",
          [](const SoftAvatar& a) {
            return to_numpy(a.volumetricData().material_model.parameters());
          },
          "(P,) the material file's coefficients of a soft avatar (MaterialModel.parameters: per "
          "coefficient a = log c₀ then its K log-slopes; P = 40·(1 + K)); what the adjoint's "
          "'material' group differentiates. RuntimeError for the skeleton model.")
      .def_property_readonly(
          "material_parameter_names",
          [](const SoftAvatar& a) { return a.volumetricData().material_model.parameterNames(); },
          "Names of material_parameters' entries: '<key>.log_value' and '<key>.log_slopes[k]' "
          "with <key> the material file's key path (e.g. 'layers.soft_tissue.E1').")
      .def(
          "save_material_file",
          [](const SoftAvatar& a, const std::filesystem::path& path) {
            a.volumetricData().material_model.save(path_string(path));
          },
          py::arg("path"),
          "Writes this soft avatar's material coefficients (material_parameters) as a material "
          "file (docs/materials.md), atomically: a fitted material (with_material) a scene can "
          "name in \"materials\". OSError on failure; RuntimeError for the skeleton model.")
      .def(
          "with_material",
          [](const SoftAvatar& a, const py::object& parameters) {
            MaterialModel model = a.volumetricData().material_model;
            model.setParameters(to_vector(parameters, "parameters", model.numParameters()));
            py::gil_scoped_release release;
            return a.withMaterial(model);
          },
          py::arg("parameters"),
          "This soft avatar with other material coefficients (parameters: (P,) as "
          "material_parameters): the same β and discretization (tet mesh, bone nodes, frames; "
          "the ROM's basis, cubatures and rest-split floors), every tet's materials "
          "re-evaluated. Cheap next to a build. ValueError on a wrong size or a material that "
          "is not physical.")
      .def(
          "with_shape",
          [](const SoftAvatar& a, const py::object& betas) {
            const VecX b = to_vector(betas, "betas", -1);
            py::gil_scoped_release release;
            return a.withShape(b);
          },
          py::arg("betas"),
          "This avatar at another shape β′ ((K',), K' ≤ K, zero padded), for fitting β: the "
          "same discretization (tet mesh, bone nodes, frames; the ROM's basis, cubatures and "
          "rest-split floors) with the rest data of β′ (surface, joints, inertias, rest nodes "
          "X̄(β′), every tet's materials; the ROM's K). The soft models' β gradient is exact for "
          "this model. Cheap next to a build. ValueError on a bad β.")
      .def_property_readonly(
          "reduced_data", [](const SoftAvatar& a) -> const ReducedData& { return a.reducedData(); },
          py::return_value_policy::reference_internal,
          "ReducedData of a ROM avatar (RuntimeError for the other models).")
      .def_property_readonly("has_reduced_data", &SoftAvatar::hasReducedData)
      .def_property_readonly(
          "reduced_build_report",
          [](const SoftAvatar& a) {
            const ReducedBuildReport& r = a.reducedBuildReport();
            py::dict d;
            d["from_cache"] = r.from_cache;
            d["warnings"] = r.warnings;
            d["seconds_handles"] = r.seconds_handles;
            d["seconds_basis"] = r.seconds_basis;
            d["seconds_training"] = r.seconds_training;
            d["seconds_cubature"] = r.seconds_cubature;
            d["seconds_cache_load"] = r.seconds_cache_load;
            d["seconds_cache_store"] = r.seconds_cache_store;
            d["seconds_total"] = r.seconds_total;
            return d;
          },
          "dict: cache hit, warnings and seconds per stage of the reduced "
          "build (all zero without the reduced model).")
      .def_property_readonly(
          "build_report",
          [](const SoftAvatar& a) {
            const VolumetricBuildReport& r = a.volumetricBuildReport();
            py::dict d;
            d["template_from_cache"] = r.template_from_cache;
            d["data_from_cache"] = r.data_from_cache;
            d["warnings"] = r.warnings;
            d["seconds_skeleton"] = a.skeletonSeconds();
            d["seconds_meshing"] = r.seconds_meshing;
            d["seconds_harmonic"] = r.seconds_harmonic;
            d["seconds_bone_nodes"] = r.seconds_bone_nodes;
            d["seconds_materials"] = r.seconds_materials;
            d["seconds_cache_load"] = r.seconds_cache_load;
            d["seconds_cache_store"] = r.seconds_cache_store;
            d["seconds_volumetric_total"] = r.seconds_total;
            return d;
          },
          "dict: cache hits, warnings and seconds per stage of the build.")
      .def_property_readonly("initialized", &SoftAvatar::initialized)
      .def_property_readonly("soft_tissue_enabled", &SoftAvatar::softTissueEnabled)
      .def_property_readonly("reduced_model_enabled", &SoftAvatar::reducedModelEnabled)
      .def_property_readonly("elastic_cubature_enabled", &SoftAvatar::elasticCubatureEnabled)
      .def_property_readonly("inertial_cubature_enabled", &SoftAvatar::inertialCubatureEnabled)
      .def_property_readonly(
          "basis",
          [](const SoftAvatar& a) {
            return std::string(reducedBasisKindName(a.settings().reduced.basis_kind));
          },
          "the reduced model's basis: 'modes', 'handles' or 'modes+handles' (setting)")
      .def_property_readonly(
          "vibration_modes",
          [](const SoftAvatar& a) { return a.settings().reduced.modes.vibration_modes; },
          "fixed-interface vibration modes of a basis with modes (setting)")
      .def_property_readonly(
          "modal_columns", [](const SoftAvatar& a) { return a.settings().reduced.modes.columns; },
          "columns of the compressed modal basis, 0 = all (setting)")
      .def_property_readonly(
          "handles", [](const SoftAvatar& a) { return a.settings().reduced.num_handles; },
          "point handles of a basis with handles (setting)")
      .def_property_readonly(
          "cubature_training_samples",
          [](const SoftAvatar& a) { return a.settings().reduced.training_samples; },
          "random training samples per cubature (setting)")
      .def_property_readonly(
          "elastic_cubature_points",
          [](const SoftAvatar& a) { return a.settings().reduced.elastic_cubature_points; },
          "sample tets of the elastic cubature when enabled (setting)")
      .def_property_readonly(
          "inertial_cubature_points",
          [](const SoftAvatar& a) { return a.settings().reduced.inertial_cubature_points; },
          "sample tets of the inertial cubature when enabled (setting)")
      .def_property_readonly(
          "body",
          [](const SoftAvatar& a) { return std::const_pointer_cast<BodyModel>(a.bodyPtr()); },
          "The BodyModel the avatar was built for.")
      .def_property_readonly(
          "betas", [](const SoftAvatar& a) { return to_numpy(a.betas()); },
          "(K,) shape coefficients (zero padded).")
      .def_property_readonly(
          "density", [](const SoftAvatar& a) { return a.settings().density; }, "kg/m³")
      .def_property_readonly(
          "voxel_size", [](const SoftAvatar& a) { return a.settings().voxel_size; }, "m")
      .def_property_readonly(
          "rest_vertices",
          [](const SoftAvatar& a) {
            return to_numpy(initialized(a, "rest_vertices").restVertices());
          },
          "(V, 3) shaped T-pose vertices, m.")
      .def_property_readonly(
          "rest_joints",
          [](const SoftAvatar& a) { return to_numpy(initialized(a, "rest_joints").restJoints()); },
          "(24, 3) joint centres J(β) of the shaped T-pose, m.")
      .def_property_readonly(
          "bone_inertia",
          [](const SoftAvatar& a) { return initialized(a, "bone_inertia").boneInertia(); },
          "list of 24 BoneInertia (mass kg, first_moment kg·m, "
          "second_moment kg·m²).")
      .def_property_readonly(
          "bone_capsules",
          [](const SoftAvatar& a) { return initialized(a, "bone_capsules").boneCapsules(); },
          "list of 24 BoneCapsule, one per bone (rest pose).")
      .def_property_readonly(
          "vertex_areas",
          [](const SoftAvatar& a) {
            return to_numpy(initialized(a, "vertex_areas").vertexAreas());
          },
          "(V,) a third of the incident faces' areas, m².")
      .def_property_readonly(
          "total_mass",
          [](const SoftAvatar& a) { return initialized(a, "total_mass").totalMass(); },
          "Σ bone masses, kg.")
      .def_property_readonly(
          "volume", [](const SoftAvatar& a) { return initialized(a, "volume").volume(); },
          "Enclosed volume of the rest surface, m³.")
      .def("__repr__", [](const SoftAvatar& a) {
        return "SoftAvatar(vertices=" + std::to_string(a.body().numVertices()) +
               ", initialized=" + (a.initialized() ? "True" : "False") +
               ", soft_tissue=" + (a.softTissueEnabled() ? "True" : "False") +
               ", reduced=" + (a.reducedModelEnabled() ? "True" : "False") + ")";
      });

  // The settings under both spellings: snake_case (Python) and the paper's camelCase.
  struct Setting {
    const char *snake, *camel, *doc;
    void (SoftAvatar::*set)(bool);
  };
  const Setting settings[] = {
      {"enable_soft_tissue", "enableSoftTissue",
       "Soft-tissue model (FEM or ROM) instead of the skeleton; on = True.",
       &SoftAvatar::enableSoftTissue},
      {"enable_reduced_model", "enableReducedModel",
       "Reduced (ROM) soft-tissue model instead of full FEM (with enable_soft_tissue()); "
       "on = True.",
       &SoftAvatar::enableReducedModel},
      {"enable_inertial_cubature", "enableInertialCubature",
       "Cubature for the inertia of the reduced model (off: exact over all nodes); on = True.",
       &SoftAvatar::enableInertialCubature},
      {"enable_elastic_cubature", "enableElasticCubature",
       "Cubature for the elastic energy of the reduced model (off: exact over all tets); "
       "on = True.",
       &SoftAvatar::enableElasticCubature},
  };
  for (const Setting& s : settings) {
    auto set = s.set;
    auto call = [set](SoftAvatar& a, bool on) { (a.*set)(on); };
    avatar.def(s.snake, call, py::arg("on") = true, s.doc);
    avatar.def(s.camel, call, py::arg("on") = true, s.doc);
  }
  avatar.attr("initVolumetricData") = avatar.attr("init_volumetric_data");
}

}  // namespace flsh::python
