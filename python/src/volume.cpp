// Bindings of include/flsh/volume: SoftAvatar (rest shape, bone inertias, capsules) with the
// FLSH paper's camelCase settings as aliases of the snake_case names.
#include <pybind11/stl.h>

#include <memory>

#include "bindings.h"
#include "flsh/volume/soft_avatar.h"

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

}  // namespace

void bind_volume(py::module_& m) {
  py::class_<BoneInertia>(m, "BoneInertia",
                          "Mass properties of one bone about its joint centre J_b (rest pose, "
                          "world axes).")
      .def_property_readonly("mass", [](const BoneInertia& b) { return b.mass; }, "Σ m, kg")
      .def_property_readonly("first_moment",
                             [](const BoneInertia& b) { return to_numpy(VecX(b.first_moment)); },
                             "(3,) Σ m (X − J_b), kg·m")
      .def_property_readonly("second_moment",
                             [](const BoneInertia& b) { return mat3_numpy(b.second_moment); },
                             "(3, 3) Σ m (X − J_b)(X − J_b)ᵀ, kg·m²")
      .def("center_of_mass",
           [](const BoneInertia& b, const py::object& joint) {
             return to_numpy(VecX(b.centerOfMass(to_vec3(joint, "joint"))));
           },
           py::arg("joint"), "(3,) centre of mass J_b + first_moment / mass, m; joint (3,) m.")
      .def("__repr__", [](const BoneInertia& b) {
        return "BoneInertia(mass=" + py::repr(py::float_(b.mass)).cast<std::string>() + ")";
      });

  py::class_<BoneCapsule>(m, "BoneCapsule", "A capsule attached to a bone (rest pose), m.")
      .def_property_readonly("bone", [](const BoneCapsule& c) { return c.bone; }, "bone index")
      .def_property_readonly("a", [](const BoneCapsule& c) { return to_numpy(VecX(c.a)); },
                             "(3,) first end of the axis segment, m")
      .def_property_readonly("b", [](const BoneCapsule& c) { return to_numpy(VecX(c.b)); },
                             "(3,) second end of the axis segment, m")
      .def_property_readonly("radius", [](const BoneCapsule& c) { return c.radius; }, "m")
      .def("__repr__", [](const BoneCapsule& c) {
        return "BoneCapsule(bone=" + std::to_string(c.bone) +
               ", radius=" + py::repr(py::float_(c.radius)).cast<std::string>() + ")";
      });

  const SoftAvatarSettings defaults;
  py::class_<SoftAvatar, std::shared_ptr<SoftAvatar>> avatar(
      m, "SoftAvatar",
      "The immutable data of one body shape for simulation. Configure, then call "
      "init_volumetric_data(); the skeleton model (soft tissue off) is the default.");
  avatar
      .def(py::init([](std::shared_ptr<BodyModel> body, const py::object& betas, double density,
                       double voxel_size) {
             if (!body) throw py::value_error("body: expected a BodyModel, got None");
             const VecX b = betas.is_none() ? VecX(VecX::Zero(body->numBetas()))
                                            : to_vector(betas, "betas", -1, "(K,)");
             SoftAvatarSettings settings;
             settings.density = density;
             settings.voxel_size = voxel_size;
             return std::make_shared<SoftAvatar>(std::move(body), b, settings);
           }),
           py::arg("body"), py::arg("betas") = py::none(), py::kw_only(),
           py::arg("density") = defaults.density, py::arg("voxel_size") = defaults.voxel_size,
           "body: BodyModel; betas (≤K,) zero padded, None = zeros; density kg/m³; voxel_size "
           "m (edge of the voxels that integrate the bone inertias).")
      .def("init_volumetric_data",
           [](SoftAvatar& a) {
             py::gil_scoped_release release;
             a.initVolumetricData();
           },
           "Builds what the configured model needs (skeleton: rest shape, joints, bone "
           "inertias, capsules). Idempotent; RuntimeError if soft tissue is enabled (not yet "
           "available).")
      .def_property_readonly("initialized", &SoftAvatar::initialized)
      .def_property_readonly("soft_tissue_enabled", &SoftAvatar::softTissueEnabled)
      .def_property_readonly("reduced_model_enabled", &SoftAvatar::reducedModelEnabled)
      .def_property_readonly("body",
                             [](const SoftAvatar& a) {
                               return std::const_pointer_cast<BodyModel>(a.bodyPtr());
                             },
                             "The BodyModel the avatar was built for.")
      .def_property_readonly("betas", [](const SoftAvatar& a) { return to_numpy(a.betas()); },
                             "(K,) shape coefficients (zero padded).")
      .def_property_readonly("density", [](const SoftAvatar& a) { return a.settings().density; },
                             "kg/m³")
      .def_property_readonly("voxel_size",
                             [](const SoftAvatar& a) { return a.settings().voxel_size; }, "m")
      .def_property_readonly("rest_vertices",
                             [](const SoftAvatar& a) {
                               return to_numpy(initialized(a, "rest_vertices").restVertices());
                             },
                             "(V, 3) shaped T-pose vertices, m.")
      .def_property_readonly("rest_joints",
                             [](const SoftAvatar& a) {
                               return to_numpy(initialized(a, "rest_joints").restJoints());
                             },
                             "(24, 3) joint centres J(β) of the shaped T-pose, m.")
      .def_property_readonly("bone_inertia",
                             [](const SoftAvatar& a) {
                               return initialized(a, "bone_inertia").boneInertia();
                             },
                             "list of 24 BoneInertia (mass kg, first_moment kg·m, "
                             "second_moment kg·m²).")
      .def_property_readonly("bone_capsules",
                             [](const SoftAvatar& a) {
                               return initialized(a, "bone_capsules").boneCapsules();
                             },
                             "list of 24 BoneCapsule, one per bone (rest pose).")
      .def_property_readonly("vertex_areas",
                             [](const SoftAvatar& a) {
                               return to_numpy(initialized(a, "vertex_areas").vertexAreas());
                             },
                             "(V,) a third of the incident faces' areas, m².")
      .def_property_readonly("total_mass",
                             [](const SoftAvatar& a) {
                               return initialized(a, "total_mass").totalMass();
                             },
                             "Σ bone masses, kg.")
      .def_property_readonly("volume",
                             [](const SoftAvatar& a) { return initialized(a, "volume").volume(); },
                             "Enclosed volume of the rest surface, m³.")
      .def("__repr__", [](const SoftAvatar& a) {
        return "SoftAvatar(vertices=" + std::to_string(a.body().numVertices()) +
               ", initialized=" + (a.initialized() ? "True" : "False") +
               ", soft_tissue=" + (a.softTissueEnabled() ? "True" : "False") + ")";
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
       "Reduced (ROM) soft-tissue model instead of full FEM; on = True.",
       &SoftAvatar::enableReducedModel},
      {"enable_inertial_cubature", "enableInertialCubature",
       "Cubature for the inertia of the reduced model; on = True.",
       &SoftAvatar::enableInertialCubature},
      {"enable_elastic_cubature", "enableElasticCubature",
       "Cubature for the elastic energy of the reduced model; on = True.",
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
