// Bindings of include/flsh/contact: colliders (plane, sphere, capsule), their scripted paths,
// and the contact options.
#include <pybind11/stl.h>

#include <cmath>

#include "bindings.h"
#include "flsh/contact/collider.h"
#include "flsh/contact/contact_energy.h"

namespace flsh::python {

namespace {

ColliderPath make_path(const py::object& times, const py::object& offsets) {
  const VecX t = to_vector(times, "times", -1, "(K,)");
  const MatX3 o = to_points(offsets, "offsets", t.size());
  ColliderPath path;
  path.times.assign(t.data(), t.data() + t.size());
  for (long k = 0; k < o.rows(); ++k) path.offsets.push_back(o.row(k).transpose());
  path.validate("ColliderPath");
  return path;
}

py::array_t<double> path_offsets(const ColliderPath& p) {
  MatX3 o(long(p.offsets.size()), 3);
  for (size_t k = 0; k < p.offsets.size(); ++k) o.row(long(k)) = p.offsets[k].transpose();
  return to_numpy(o);
}

void check_positive(double value, const char* name) {
  if (!(std::isfinite(value) && value > 0.0))
    throw py::value_error(std::string(name) + ": expected a finite value > 0, got " +
                          std::to_string(value));
}

const char* shape_name(ColliderShape s) {
  switch (s) {
    case ColliderShape::Plane: return "plane";
    case ColliderShape::Sphere: return "sphere";
    case ColliderShape::Capsule: return "capsule";
  }
  return "unknown";
}

}  // namespace

void bind_contact(py::module_& m) {
  py::enum_<ColliderShape>(m, "ColliderShape", "Shape of a Collider.")
      .value("Plane", ColliderShape::Plane)
      .value("Sphere", ColliderShape::Sphere)
      .value("Capsule", ColliderShape::Capsule);

  py::class_<ColliderPath>(m, "ColliderPath",
                           "Piecewise-linear keyframed translation of a collider; empty = static. "
                           "Held constant before the first and after the last key.")
      .def(py::init([](const py::object& times, const py::object& offsets) {
             return (times.is_none() && offsets.is_none()) ? ColliderPath()
                                                           : make_path(times, offsets);
           }),
           py::arg("times") = py::none(), py::arg("offsets") = py::none(),
           "times (K,) strictly increasing, s; offsets (K, 3) translations, m. No arguments: "
           "static.")
      .def_property_readonly("times",
                             [](const ColliderPath& p) {
                               return to_numpy(p.times.data(), {py::ssize_t(p.times.size())});
                             },
                             "(K,) key times, s")
      .def_property_readonly("offsets", &path_offsets, "(K, 3) translations at the keys, m")
      .def("offset_at",
           [](const ColliderPath& p, double t) { return to_numpy(VecX(p.offsetAt(t))); },
           py::arg("t"), "(3,) translation at time t (s), m.")
      .def("velocity_at",
           [](const ColliderPath& p, double t) { return to_numpy(VecX(p.velocityAt(t))); },
           py::arg("t"), "(3,) velocity at time t (s), m/s (right derivative at keys).")
      .def_static("constant_velocity",
                  [](const py::object& velocity, double duration) {
                    check_positive(duration, "duration");
                    return ColliderPath::constantVelocity(to_vec3(velocity, "velocity"), duration);
                  },
                  py::arg("velocity"), py::arg("duration"),
                  "Straight path from offset 0 at t = 0 with velocity (3,) m/s for duration s.")
      .def("__len__", [](const ColliderPath& p) { return p.times.size(); })
      .def("__repr__", [](const ColliderPath& p) {
        return "ColliderPath(keys=" + std::to_string(p.times.size()) + ")";
      });

  py::class_<Collider>(m, "Collider",
                       "Analytic collider; signed distance positive outside, negative inside. "
                       "Make one with Collider.plane / sphere / capsule.")
      .def_static("plane",
                  [](const py::object& point, const py::object& normal) {
                    const Vec3 n = to_vec3(normal, "normal");
                    if (!(n.norm() > 0.0))
                      throw py::value_error("normal: expected a nonzero vector, got (0, 0, 0)");
                    return Collider::plane(to_vec3(point, "point"), n);
                  },
                  py::arg("point") = to_numpy(VecX(Vec3::Zero())),
                  py::arg("normal") = to_numpy(VecX(Vec3::UnitY())),
                  "Half-space below the plane through point (3,) m with outward normal (3,) "
                  "(normalized); default: the ground y = 0.")
      .def_static("sphere",
                  [](const py::object& center, double radius) {
                    check_positive(radius, "radius");
                    return Collider::sphere(to_vec3(center, "center"), radius);
                  },
                  py::arg("center"), py::arg("radius"), "Sphere: center (3,) m, radius m.")
      .def_static("capsule",
                  [](const py::object& a, const py::object& b, double radius) {
                    check_positive(radius, "radius");
                    return Collider::capsule(to_vec3(a, "a"), to_vec3(b, "b"), radius);
                  },
                  py::arg("a"), py::arg("b"), py::arg("radius"),
                  "Capsule around the segment a (3,) – b (3,) m with radius m.")
      .def_property_readonly("shape", &Collider::shape)
      .def_property_readonly("p0", [](const Collider& c) { return to_numpy(VecX(c.p0())); },
                             "(3,) plane point, sphere centre or capsule end a, m")
      .def_property_readonly("p1", [](const Collider& c) { return to_numpy(VecX(c.p1())); },
                             "(3,) plane normal or capsule end b (unused for spheres)")
      .def_property_readonly("radius", &Collider::radius, "m (0 for planes)")
      .def_property("path", [](const Collider& c) { return c.path; },
                    [](Collider& c, const ColliderPath& p) {
                      p.validate("Collider.path");
                      c.path = p;
                    },
                    "ColliderPath moving the collider (a copy; assign to change it).")
      .def_readwrite("name", &Collider::name, "for messages and outputs")
      .def("signed_distance",
           [](const Collider& c, const py::object& x, double t, bool derivatives) -> py::object {
             auto a = as_float64(x, "x");
             if (a.ndim() == 1) {
               const Vec3 p = to_vec3(a, "x");
               Vec3 g;
               Mat3 H;
               const double d = c.signedDistance(p, t, derivatives ? &g : nullptr,
                                                 derivatives ? &H : nullptr);
               if (!derivatives) return py::float_(d);
               const Eigen::Matrix<double, 3, 3, Eigen::RowMajor> Hr = H;
               return py::make_tuple(d, to_numpy(VecX(g)), to_numpy(Hr.data(), {3, 3}));
             }
             const MatX3 P = to_points(a, "x");
             const py::ssize_t n = P.rows();
             VecX d(n);
             MatX3 G(n, 3);
             py::array_t<double> H({n, py::ssize_t(3), py::ssize_t(3)});
             auto Hv = H.mutable_unchecked<3>();
             for (py::ssize_t i = 0; i < n; ++i) {
               Vec3 g;
               Mat3 h;
               d[i] = c.signedDistance(P.row(i).transpose(), t, derivatives ? &g : nullptr,
                                       derivatives ? &h : nullptr);
               if (!derivatives) continue;
               G.row(i) = g.transpose();
               for (int r = 0; r < 3; ++r)
                 for (int s = 0; s < 3; ++s) Hv(i, r, s) = h(r, s);
             }
             if (!derivatives) return to_numpy(d);
             return py::make_tuple(to_numpy(d), to_numpy(G), H);
           },
           py::arg("x"), py::arg("t") = 0.0, py::arg("derivatives") = false,
           "Signed distance (m) of x (3,) or points (N, 3) at time t (s): a float or (N,). With "
           "derivatives=True a tuple (d, ∂d/∂x (3,)|(N, 3), ∂²d/∂x² (3, 3)|(N, 3, 3)).")
      .def("__repr__", [](const Collider& c) {
        return std::string("Collider(") + shape_name(c.shape()) +
               (c.name.empty() ? "" : ", name='" + c.name + "'") +
               (c.path.times.empty() ? "" : ", moving") + ")";
      });

  const ContactOptions contact_defaults;
  py::class_<ContactOptions>(m, "ContactOptions",
                             "Penalty contact k_c/2 Σ a_i max(0, −d(x_i))² on surface vertices.")
      .def(py::init([](double stiffness, bool exact_hessian) {
             if (!(std::isfinite(stiffness) && stiffness >= 0.0))
               throw py::value_error("stiffness: expected a finite value ≥ 0, got " +
                                     std::to_string(stiffness));
             ContactOptions o;
             o.stiffness = stiffness;
             o.exact_hessian = exact_hessian;
             return o;
           }),
           py::kw_only(), py::arg("stiffness") = contact_defaults.stiffness,
           py::arg("exact_hessian") = contact_defaults.exact_hessian)
      .def_readwrite("stiffness", &ContactOptions::stiffness, "k_c, N/m³")
      .def_readwrite("exact_hessian", &ContactOptions::exact_hessian,
                     "keep the curvature term (exact, may be indefinite); off = Gauss–Newton")
      .def("__repr__", [](const ContactOptions& o) {
        return "ContactOptions(stiffness=" + py::repr(py::float_(o.stiffness)).cast<std::string>() +
               ", exact_hessian=" + (o.exact_hessian ? "True" : "False") + ")";
      });
}

}  // namespace flsh::python
