// Bindings of include/flsh/core: error translation, rotation helpers, and the shared
// numpy ⇄ Eigen helpers declared in bindings.h.
#include <pybind11/stl/filesystem.h>

#include <cerrno>
#include <cmath>
#include <cstdint>
#include <limits>
#include <sstream>

#include <Eigen/LU>  // determinant()

#include "bindings.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"

namespace flsh::python {

// ---------------------------------------------------------------------------------------------
// Helpers

std::string shape_text(const std::vector<long>& shape) {
  std::ostringstream s;
  s << "(";
  for (size_t i = 0; i < shape.size(); ++i) {
    if (i) s << ", ";
    if (shape[i] < 0)
      s << (shape.size() == 2 && i == 0 ? "N" : "*");  // "any extent"
    else
      s << shape[i];
  }
  if (shape.size() == 1) s << ",";
  s << ")";
  return s.str();
}

namespace {

std::vector<long> shape_of(const py::array& a) {
  std::vector<long> shape(a.ndim());
  for (py::ssize_t d = 0; d < a.ndim(); ++d) shape[d] = long(a.shape(d));
  return shape;
}

std::string dtype_name(const py::array& a) { return py::str(a.dtype()).cast<std::string>(); }

// Any Python object (array, list, scalar) as a numpy array; refuses what numpy cannot convert.
py::array as_array(const py::handle& obj, const std::string& name) {
  py::array a = py::array::ensure(obj);
  if (!a) throw py::value_error(name + ": expected an array, got " +
                                py::str(py::type::of(obj)).cast<std::string>());
  return a;
}

}  // namespace

void check_shape(const py::array& a, const std::string& name, const std::vector<long>& expected,
                 const std::string& expected_text) {
  bool ok = a.ndim() == py::ssize_t(expected.size());
  for (size_t d = 0; ok && d < expected.size(); ++d)
    ok = expected[d] < 0 || a.shape(d) == expected[d];
  if (!ok)
    throw py::value_error(name + ": expected shape " +
                          (expected_text.empty() ? shape_text(expected) : expected_text) +
                          ", got " + shape_text(shape_of(a)));
}

py::array_t<double, py::array::c_style> as_float64(const py::handle& obj, const std::string& name,
                                                   bool require_finite) {
  py::array a = as_array(obj, name);
  const char kind = a.dtype().kind();
  if (kind != 'f' && kind != 'i' && kind != 'u')
    throw py::value_error(name + ": expected a float or integer array, got dtype " +
                          dtype_name(a));
  auto d = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(a);
  if (!d) throw py::error_already_set();
  if (require_finite) {
    const double* p = d.data();
    for (py::ssize_t i = 0; i < d.size(); ++i)
      if (!std::isfinite(p[i]))
        throw py::value_error(name + ": contains NaN or Inf (first at flat index " +
                              std::to_string(i) + ")");
  }
  return d;
}

py::array_t<int, py::array::c_style> as_int32(const py::handle& obj, const std::string& name) {
  py::array a = as_array(obj, name);
  const char kind = a.dtype().kind();
  if (kind != 'i' && kind != 'u')
    throw py::value_error(name + ": expected an integer array, got dtype " + dtype_name(a));
  py::array_t<int, py::array::c_style> out(std::vector<py::ssize_t>(a.shape(), a.shape() + a.ndim()));
  int* q = out.mutable_data();
  auto too_large = [&](const std::string& value, py::ssize_t i) {
    return py::value_error(name + ": value " + value + " at flat index " + std::to_string(i) +
                           " does not fit in int32");
  };
  if (kind == 'u') {
    auto u = py::array_t<uint64_t, py::array::c_style | py::array::forcecast>::ensure(a);
    for (py::ssize_t i = 0; i < u.size(); ++i) {
      if (u.data()[i] > uint64_t(std::numeric_limits<int>::max()))
        throw too_large(std::to_string(u.data()[i]), i);
      q[i] = int(u.data()[i]);
    }
  } else {
    auto s = py::array_t<int64_t, py::array::c_style | py::array::forcecast>::ensure(a);
    for (py::ssize_t i = 0; i < s.size(); ++i) {
      if (s.data()[i] > std::numeric_limits<int>::max() ||
          s.data()[i] < std::numeric_limits<int>::min())
        throw too_large(std::to_string(s.data()[i]), i);
      q[i] = int(s.data()[i]);
    }
  }
  return out;
}

VecX to_vector(const py::handle& obj, const std::string& name, long size,
               const std::string& expected_text) {
  auto a = as_float64(obj, name);
  check_shape(a, name, {size}, expected_text);
  return Eigen::Map<const VecX>(a.data(), a.shape(0));
}

Vec3 to_vec3(const py::handle& obj, const std::string& name) { return to_vector(obj, name, 3); }

RowMatX to_matrix(const py::handle& obj, const std::string& name, long rows, long cols) {
  auto a = as_float64(obj, name);
  check_shape(a, name, {rows, cols});
  return Eigen::Map<const RowMatX>(a.data(), a.shape(0), a.shape(1));
}

MatX3 to_points(const py::handle& obj, const std::string& name, long rows) {
  auto a = as_float64(obj, name);
  check_shape(a, name, {rows, 3});
  return Eigen::Map<const MatX3>(a.data(), a.shape(0), 3);
}

MatX3i to_triangles(const py::handle& obj, const std::string& name) {
  auto a = as_int32(obj, name);
  check_shape(a, name, {-1, 3}, "(F, 3)");
  return Eigen::Map<const MatX3i>(a.data(), a.shape(0), 3);
}

VecX to_pose(const py::handle& obj, const std::string& name) {
  auto a = as_float64(obj, name);
  if (a.ndim() != 1 || (a.shape(0) != 72 && a.shape(0) != 156))
    check_shape(a, name, {72}, "(72,) or (156,)");  // throws with the actual shape
  return Eigen::Map<const VecX>(a.data(), a.shape(0));
}

std::string path_string(const std::filesystem::path& path) { return path.string(); }

void require_existing_file(const std::string& path, const std::string& what) {
  std::error_code ec;
  if (std::filesystem::exists(path, ec)) return;
  const std::string message = what + ": no such file";  // Python appends ": 'PATH'"
  py::object error = py::module_::import("builtins")
                         .attr("FileNotFoundError")(ENOENT, message, path);
  PyErr_SetObject(PyExc_FileNotFoundError, error.ptr());
  throw py::error_already_set();
}

py::array_t<double> to_numpy(const double* data, const std::vector<py::ssize_t>& shape) {
  py::array_t<double> a(shape);
  std::copy(data, data + a.size(), a.mutable_data());
  return a;
}
py::array_t<double> to_numpy(const MatX3& m) { return to_numpy(m.data(), {m.rows(), 3}); }
py::array_t<double> to_numpy(const RowMatX& m) { return to_numpy(m.data(), {m.rows(), m.cols()}); }
py::array_t<double> to_numpy(const VecX& v) { return to_numpy(v.data(), {v.size()}); }
py::array_t<int> to_numpy(const MatX3i& m) {
  py::array_t<int> a({py::ssize_t(m.rows()), py::ssize_t(3)});
  std::copy(m.data(), m.data() + m.size(), a.mutable_data());
  return a;
}

// ---------------------------------------------------------------------------------------------
// Bindings

namespace {

py::array_t<double> mat3_to_numpy(const Mat3& R) {
  const Eigen::Matrix<double, 3, 3, Eigen::RowMajor> rm = R;
  return to_numpy(rm.data(), {3, 3});
}

Mat3 to_rotation(const py::handle& obj, const std::string& name) {
  const Mat3 R = to_matrix(obj, name, 3, 3);
  // logSO3 assumes a rotation; anything else would give a meaningless answer.
  const double orthogonality = (R.transpose() * R - Mat3::Identity()).cwiseAbs().maxCoeff();
  if (orthogonality > 1e-6 || R.determinant() < 0)
    throw py::value_error(name + ": expected a rotation matrix (RᵀR = I, det R = 1), got "
                          "max |RᵀR − I| = " + std::to_string(orthogonality) +
                          ", det R = " + std::to_string(R.determinant()));
  return R;
}

}  // namespace

void bind_core(py::module_& m) {
  // flsh's exceptions as the Python exceptions a caller expects (error.h).
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const flsh::InputError& e) {
      PyErr_SetString(PyExc_ValueError, e.what());
    } catch (const flsh::FileError& e) {
      PyErr_SetString(PyExc_OSError, e.what());
    } catch (const flsh::Error& e) {
      PyErr_SetString(PyExc_RuntimeError, e.what());
    }
  });

  m.def("skew", [](const py::object& v) { return mat3_to_numpy(skew(to_vec3(v, "v"))); },
        py::arg("v"), "Cross-product matrix [v]× (3, 3) of a 3-vector v: skew(v) @ w = v × w.");
  m.def("rodrigues", [](const py::object& theta) {
          return mat3_to_numpy(rodrigues(to_vec3(theta, "theta")));
        },
        py::arg("theta"),
        "Rotation matrix (3, 3) R = exp([θ]×) of a rotation vector θ (3,), rad (axis × angle).");
  m.def("log_so3", [](const py::object& R) {
          return to_numpy(VecX(logSO3(to_rotation(R, "R"))));
        },
        py::arg("R"), "Rotation vector θ (3,), |θ| ≤ π rad, of a rotation matrix R (3, 3).");
  m.def("left_jacobian_so3", [](const py::object& theta) {
          return mat3_to_numpy(leftJacobianSO3(to_vec3(theta, "theta")));
        },
        py::arg("theta"),
        "Left Jacobian J_l(θ) (3, 3) of SO(3): d exp([θ+ε]×) = [J_l(θ) ε]× exp([θ]×).");
  m.def("left_jacobian_inverse_so3", [](const py::object& theta) {
          return mat3_to_numpy(leftJacobianInverseSO3(to_vec3(theta, "theta")));
        },
        py::arg("theta"), "Inverse (3, 3) of the left Jacobian of SO(3), for |θ| < 2π.");
  m.def("slerp_rotation_vector",
        [](const py::object& a, const py::object& b, double t) {
          if (!(t >= 0.0 && t <= 1.0))
            throw py::value_error("t: expected a value in [0, 1], got " + std::to_string(t));
          return to_numpy(VecX(slerpRotationVector(to_vec3(a, "a"), to_vec3(b, "b"), t)));
        },
        py::arg("a"), py::arg("b"), py::arg("t"),
        "Rotation vector (3,) on the shortest arc from rotation vector a to b, t in [0, 1].");
}

}  // namespace flsh::python
