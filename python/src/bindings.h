// Shared declarations of the flsh._flsh binding files (one per C++ folder) and the helpers
// that turn numpy inputs into checked Eigen data and Eigen results into numpy arrays.
//
// Inputs go through the checks here, not through pybind11's Eigen casters, so that a wrong
// dtype or shape gives a ValueError naming the argument, the expected and the actual shape
// instead of pybind11's generic "incompatible function arguments".
#pragma once

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <filesystem>
#include <string>
#include <type_traits>
#include <vector>

#include "flsh/core/types.h"

namespace py = pybind11;

namespace flsh::python {

void bind_core(py::module_& m);
void bind_body(py::module_& m);
void bind_format(py::module_& m);
void bind_io(py::module_& m);
void bind_render(py::module_& m);
void bind_volume(py::module_& m);
void bind_contact(py::module_& m);
void bind_sim(py::module_& m);
void bind_solve(py::module_& m);
void bind_diff(py::module_& m);

/// "(72,)", "(800, 3)": numpy's way of writing a shape, for messages.
std::string shape_text(const std::vector<long>& shape);

/// `obj` as a C-contiguous float64 array after checking its dtype (float or integer; bool,
/// complex, object and strings are refused) and that every value is finite. Throws
/// ValueError naming `name`.
py::array_t<double, py::array::c_style> as_float64(const py::handle& obj, const std::string& name,
                                                   bool require_finite = true);

/// `obj` as a C-contiguous int32 array after checking it holds integers (float arrays are
/// refused, so that 1.5 never becomes a vertex index 1) that fit in int32.
py::array_t<int, py::array::c_style> as_int32(const py::handle& obj, const std::string& name);

/// Checks `a.shape` against `expected` (−1 = any extent), else throws ValueError
/// "NAME: expected shape (…), got (…)". `expected_text` overrides the text of the expectation.
void check_shape(const py::array& a, const std::string& name, const std::vector<long>& expected,
                 const std::string& expected_text = "");

/// Converters with shape checks; `size`/`rows`/`cols` of −1 mean any.
VecX to_vector(const py::handle& obj, const std::string& name, long size = -1,
               const std::string& expected_text = "");
Vec3 to_vec3(const py::handle& obj, const std::string& name);
RowMatX to_matrix(const py::handle& obj, const std::string& name, long rows = -1, long cols = -1);
MatX3 to_points(const py::handle& obj, const std::string& name, long rows = -1);  ///< (N, 3)
MatX3i to_triangles(const py::handle& obj, const std::string& name);              ///< (F, 3)
/// A pose of 72 or 156 values, as given (conversion to 72 is the C++ side's job).
VecX to_pose(const py::handle& obj, const std::string& name);

/// A filesystem path argument (str or os.PathLike) as a std::string.
std::string path_string(const std::filesystem::path& path);
/// Raises FileNotFoundError (errno ENOENT) naming `what` and the path when it does not exist;
/// readers call it so that a missing file is the specific OSError Python code expects.
void require_existing_file(const std::string& path, const std::string& what);

/// numpy arrays that own a copy of Eigen data, in C order with the given shape.
py::array_t<double> to_numpy(const double* data, const std::vector<py::ssize_t>& shape);
py::array_t<double> to_numpy(const MatX3& m);
py::array_t<double> to_numpy(const RowMatX& m);
py::array_t<double> to_numpy(const VecX& v);
py::array_t<int> to_numpy(const MatX3i& m);

/// A sparse matrix as a scipy.sparse.csc_matrix (copies; duplicates already summed).
py::object to_scipy_csc(const SpMat& A);
/// A sparse matrix from Python: a scipy.sparse matrix (any format) or a dense 2-D array,
/// checked to be rows × cols (−1 = any) with finite values; ValueError naming `name`.
std::vector<Triplet> to_triplets(const py::handle& obj, const std::string& name, long rows,
                                 long cols);
/// Triplets (duplicates summed) as a rows × cols csc_matrix.
py::object triplets_to_scipy_csc(const std::vector<Triplet>& triplets, int rows, int cols);

/// A numpy array that takes over an Eigen matrix's storage (no copy), viewed in C order
/// with `shape`; the matrix must be row-major (or a vector) with shape's element count.
template <class M>
py::array_t<typename std::decay_t<M>::Scalar> take_numpy(M&& m, const std::vector<py::ssize_t>& shape) {
  using Plain = std::decay_t<M>;
  static_assert(Plain::IsRowMajor || Plain::ColsAtCompileTime == 1, "C order needed");
  auto* owned = new Plain(std::forward<M>(m));
  py::capsule free_when_done(owned, [](void* p) { delete static_cast<Plain*>(p); });
  return py::array_t<typename Plain::Scalar>(shape, owned->data(), free_when_done);
}

/// A read-only numpy view of memory owned by `owner` (kept alive by the view), with byte
/// strides. Used for the arrays of immutable objects such as BodyModel.
template <class T>
py::array readonly_view(const T* data, const std::vector<py::ssize_t>& shape,
                        const std::vector<py::ssize_t>& strides, const py::handle& owner) {
  py::array a(py::dtype::of<T>(), shape, strides, data, owner);
  py::detail::array_proxy(a.ptr())->flags &= ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
  return a;
}

}  // namespace flsh::python
