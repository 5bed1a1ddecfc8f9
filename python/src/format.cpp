// Bindings of include/flsh/format: meshes (PLY / OBJ).
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include "bindings.h"
#include "flsh/format/mesh_io.h"

namespace flsh::python {

void bind_format(py::module_& m) {
  // --- Meshes --------------------------------------------------------------------------------
  m.def(
      "write_ply",
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
  m.def(
      "write_obj",
      [](const std::filesystem::path& path, const py::object& vertices, const py::object& faces) {
        const MatX3 V = to_points(vertices, "vertices");
        const MatX3i F = to_triangles(faces, "faces");
        const std::string p = path_string(path);
        py::gil_scoped_release release;
        io::writeObj(p, V, F);
      },
      py::arg("path"), py::arg("vertices"), py::arg("faces"),
      "Writes an OBJ atomically: vertices (V, 3) m, faces (F, 3) int.");
  m.def(
      "read_mesh",
      [](const std::filesystem::path& path) {
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
      py::arg("path"),
      "Reads a PLY or OBJ triangle mesh: (vertices (V, 3) float64, faces (F, 3) int32).");
}

}  // namespace flsh::python
