// Bindings of include/flsh/render: the software renderer and PNG files.
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <cstring>

#include "bindings.h"
#include "flsh/render/render.h"

namespace flsh::python {

namespace {

using render::Image;
using render::RenderOptions;

// An (H, W, 3) uint8 array as an Image (other dtypes are refused: no silent rescaling).
Image image_from_array(const py::object& obj, const std::string& name) {
  py::array a = py::array::ensure(obj);
  if (!a || a.dtype().kind() != 'u' || a.dtype().itemsize() != 1)
    throw py::value_error(name + ": expected a uint8 array of shape (H, W, 3), got " +
                          (a ? "dtype " + py::str(a.dtype()).cast<std::string>()
                             : py::str(py::type::of(obj)).cast<std::string>()));
  check_shape(a, name, {-1, -1, 3}, "(H, W, 3)");
  auto c = py::array_t<uint8_t, py::array::c_style | py::array::forcecast>::ensure(a);
  Image image;
  image.height = int(c.shape(0));
  image.width = int(c.shape(1));
  image.rgb.assign(c.data(), c.data() + c.size());
  return image;
}

py::object frame_to_numpy(const Eigen::AlignedBox3d& box) {
  if (box.isEmpty()) return py::none();
  RowMatX corners(2, 3);
  corners.row(0) = box.min().transpose();
  corners.row(1) = box.max().transpose();
  return to_numpy(corners);
}

Eigen::AlignedBox3d frame_from_object(const py::object& obj) {
  if (obj.is_none()) return Eigen::AlignedBox3d();
  const RowMatX corners = to_matrix(obj, "frame", 2, 3);
  if ((corners.row(0).array() > corners.row(1).array()).any())
    throw py::value_error("frame: expected rows (min, max) with min ≤ max, got min " +
                          py::repr(to_numpy(VecX(corners.row(0).transpose()))).cast<std::string>() +
                          ", max " +
                          py::repr(to_numpy(VecX(corners.row(1).transpose()))).cast<std::string>());
  return Eigen::AlignedBox3d(Vec3(corners.row(0).transpose()), Vec3(corners.row(1).transpose()));
}

Vec3 unit_color(const py::object& obj, const std::string& name) {
  const Vec3 c = to_vec3(obj, name);
  if ((c.array() < 0).any() || (c.array() > 1).any())
    throw py::value_error(name + ": expected RGB values in [0, 1]");
  return c;
}

void check_size(int pixels, const char* name) {
  if (pixels < 1 || pixels > 16384)
    throw py::value_error(std::string(name) + ": expected 1..16384 pixels, got " +
                          std::to_string(pixels));
}

const RenderOptions& options_or_default(const py::object& options, RenderOptions& fallback) {
  return options.is_none() ? fallback : options.cast<const RenderOptions&>();
}

}  // namespace

void bind_render(py::module_& m) {
  py::class_<Image>(m, "Image", "8-bit RGB image, top row first.")
      .def(py::init([](const py::object& array) { return image_from_array(array, "array"); }),
           py::arg("array"), "From an (H, W, 3) uint8 array (copied).")
      .def_readonly("width", &Image::width, "pixels")
      .def_readonly("height", &Image::height, "pixels")
      .def_property_readonly("array", [](py::object self) {
          const Image& im = self.cast<const Image&>();
          return readonly_view(im.rgb.data(), {im.height, im.width, 3},
                               {py::ssize_t(im.width) * 3, 3, 1}, self);
        }, "(H, W, 3) uint8 read-only view of the pixels.")
      .def("__repr__", [](const Image& im) {
        return "Image(width=" + std::to_string(im.width) + ", height=" +
               std::to_string(im.height) + ")";
      });

  py::class_<RenderOptions>(m, "RenderOptions", "Camera and shading of render_mesh/render_sheet.")
      .def(py::init([](int width, int height, const py::object& view_direction,
                       const py::object& up, const py::object& frame,
                       const py::object& base_color, const py::object& background,
                       bool draw_ground) {
             RenderOptions o;
             check_size(width, "width");
             check_size(height, "height");
             o.width = width;
             o.height = height;
             if (!view_direction.is_none()) o.view_direction = to_vec3(view_direction, "view_direction");
             if (!up.is_none()) o.up = to_vec3(up, "up");
             o.frame = frame_from_object(frame);
             if (!base_color.is_none()) o.base_color = unit_color(base_color, "base_color");
             if (!background.is_none()) o.background = unit_color(background, "background");
             o.draw_ground = draw_ground;
             return o;
           }),
           py::kw_only(), py::arg("width") = RenderOptions{}.width,
           py::arg("height") = RenderOptions{}.height, py::arg("view_direction") = py::none(),
           py::arg("up") = py::none(), py::arg("frame") = py::none(),
           py::arg("base_color") = py::none(), py::arg("background") = py::none(),
           py::arg("draw_ground") = RenderOptions{}.draw_ground,
           "Keyword arguments; None keeps the default of a vector field.")
      .def_property("width", [](const RenderOptions& o) { return o.width; },
                    [](RenderOptions& o, int w) { check_size(w, "width"); o.width = w; }, "pixels")
      .def_property("height", [](const RenderOptions& o) { return o.height; },
                    [](RenderOptions& o, int h) { check_size(h, "height"); o.height = h; }, "pixels")
      .def_property("view_direction",
                    [](const RenderOptions& o) { return to_numpy(VecX(o.view_direction)); },
                    [](RenderOptions& o, const py::object& v) {
                      o.view_direction = to_vec3(v, "view_direction");
                    },
                    "(3,) world direction the camera looks along.")
      .def_property("up", [](const RenderOptions& o) { return to_numpy(VecX(o.up)); },
                    [](RenderOptions& o, const py::object& v) { o.up = to_vec3(v, "up"); },
                    "(3,) world up direction of the image.")
      .def_property("frame", [](const RenderOptions& o) { return frame_to_numpy(o.frame); },
                    [](RenderOptions& o, const py::object& f) { o.frame = frame_from_object(f); },
                    "(2, 3) world box (min, max) the view fits, m; None = fit the mesh.")
      .def_property("base_color", [](const RenderOptions& o) { return to_numpy(VecX(o.base_color)); },
                    [](RenderOptions& o, const py::object& c) {
                      o.base_color = unit_color(c, "base_color");
                    },
                    "(3,) RGB in [0, 1] used without per-vertex colours.")
      .def_property("background", [](const RenderOptions& o) { return to_numpy(VecX(o.background)); },
                    [](RenderOptions& o, const py::object& c) {
                      o.background = unit_color(c, "background");
                    },
                    "(3,) RGB in [0, 1].")
      .def_readwrite("draw_ground", &RenderOptions::draw_ground,
                     "Shaded floor at the lowest point of the frame box.")
      .def("__repr__", [](const RenderOptions& o) {
        return "RenderOptions(width=" + std::to_string(o.width) + ", height=" +
               std::to_string(o.height) + ")";
      });

  m.def("render_mesh",
        [](const py::object& vertices, const py::object& faces, const py::object& options,
           const py::object& colors) {
          const MatX3 V = to_points(vertices, "vertices");
          const MatX3i F = to_triangles(faces, "faces");
          const MatX3 C = colors.is_none() ? MatX3() : to_points(colors, "colors", V.rows());
          RenderOptions fallback;
          const RenderOptions& o = options_or_default(options, fallback);
          py::gil_scoped_release release;
          return render::renderMesh(V, F, o, C);
        },
        py::arg("vertices"), py::arg("faces"), py::arg("options") = py::none(),
        py::arg("colors") = py::none(),
        "Renders vertices (V, 3) m, faces (F, 3) int into an Image; colors (V, 3) RGB in [0, 1] "
        "or None.");
  m.def("render_sheet",
        [](const py::object& frames, const py::object& faces, const py::object& options,
           int columns, const py::object& colors) {
          auto a = as_float64(frames, "frames");
          check_shape(a, "frames", {-1, -1, 3}, "(N, V, 3)");
          const long N = long(a.shape(0)), V = long(a.shape(1));
          if (N < 1) throw py::value_error("frames: expected at least one frame, got shape (0, " +
                                           std::to_string(V) + ", 3)");
          if (columns < 0)
            throw py::value_error("columns: expected ≥ 0, got " + std::to_string(columns));
          std::vector<MatX3> frame_list(N);
          for (long n = 0; n < N; ++n)
            frame_list[n] = Eigen::Map<const MatX3>(a.data() + n * V * 3, V, 3);
          std::vector<MatX3> color_list;
          if (!colors.is_none()) {
            auto c = as_float64(colors, "colors");
            if (c.ndim() == 2) {  // one colouring for every frame
              color_list.assign(N, to_points(c, "colors", V));
            } else {
              check_shape(c, "colors", {N, V, 3});
              for (long n = 0; n < N; ++n)
                color_list.push_back(Eigen::Map<const MatX3>(c.data() + n * V * 3, V, 3));
            }
          }
          const MatX3i F = to_triangles(faces, "faces");
          RenderOptions fallback;
          const RenderOptions& o = options_or_default(options, fallback);
          py::gil_scoped_release release;
          return render::renderSheet(frame_list, F, o, columns, color_list);
        },
        py::arg("frames"), py::arg("faces"), py::arg("options") = py::none(),
        py::arg("columns") = 0, py::arg("colors") = py::none(),
        "Renders frames (N, V, 3) m of one mesh side by side with a common framing, `columns` "
        "per row (0 = one row); options.width × height is the size of each tile. colors (V, 3) or "
        "(N, V, 3) RGB in [0, 1], or None.");
  m.def("displacement_colors",
        [](const py::object& magnitudes, double max_value) {
          return to_numpy(render::displacementColors(to_vector(magnitudes, "magnitudes"), max_value));
        },
        py::arg("magnitudes"), py::arg("max_value"),
        "Colours (V, 3) in [0, 1] of per-vertex magnitudes (V,) on a viridis map: 0 dark purple, "
        "max_value and above yellow (e.g. soft-tissue displacements |u| in m). ValueError on NaN "
        "or a negative max_value.");
  m.def("write_png",
        [](const std::filesystem::path& path, const py::object& image) {
          const Image im = py::isinstance<Image>(image) ? image.cast<Image>()
                                                         : image_from_array(image, "image");
          const std::string p = path_string(path);
          py::gil_scoped_release release;
          render::writePng(p, im);
        },
        py::arg("path"), py::arg("image"),
        "Writes an Image or (H, W, 3) uint8 array as an 8-bit RGB PNG, atomically.");
  m.def("read_png", [](const std::filesystem::path& path) {
          const std::string p = path_string(path);
          require_existing_file(p, "read_png");
          py::gil_scoped_release release;
          return render::readPng(p);
        },
        py::arg("path"), "Reads an 8-bit RGB or RGBA PNG as an RGB Image.");
}

}  // namespace flsh::python
