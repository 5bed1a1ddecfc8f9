// Software rasterizer: orthographic camera, per-pixel z-buffer, smooth Lambert shading from
// interpolated vertex normals, 3 × 3 supersampling, and an optional floor with a soft contact
// shadow. Passes: floor → triangles (depth, triangle id, barycentrics) → shading → downsample.
#include "flsh/render/render.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "flsh/core/error.h"
#include "flsh/render/plot.h"

namespace flsh::render {
namespace {

constexpr int kSupersample = 3;       // samples per pixel along each axis
constexpr double kMargin = 0.06;      // empty border around the framed box, fraction per side
constexpr double kMinExtent = 1e-3;   // m; framing of a point-like mesh
constexpr int kMaxImageSide = 16384;  // pixels; guards against absurd allocations
constexpr double kGamma = 2.2;        // colours are sRGB-like; lighting is done in linear

double toLinear(double c) { return std::pow(std::clamp(c, 0.0, 1.0), kGamma); }
double toDisplay(double c) { return std::pow(std::clamp(c, 0.0, 1.0), 1.0 / kGamma); }
double smoothstep(double edge0, double edge1, double x) {
  const double t = std::clamp((x - edge0) / (edge1 - edge0), 0.0, 1.0);
  return t * t * (3.0 - 2.0 * t);
}

// ---------------------------------------------------------------------------------------
// Input checks.

void checkOptions(const char* function, const RenderOptions& options) {
  auto fail = [&](const std::string& what) {
    throw InputError(std::string(function) + ": " + what);
  };
  if (options.width < 1 || options.width > kMaxImageSide || options.height < 1 ||
      options.height > kMaxImageSide) {
    fail("options.width × options.height is " + std::to_string(options.width) + " × " +
         std::to_string(options.height) + ", expected each in [1, " +
         std::to_string(kMaxImageSide) + "] pixels");
  }
  if (!options.view_direction.allFinite() || options.view_direction.norm() < 1e-12) {
    std::ostringstream msg;
    msg << "options.view_direction is (" << options.view_direction.transpose()
        << "), expected a finite nonzero vector";
    fail(msg.str());
  }
  if (!options.up.allFinite() || options.up.norm() < 1e-12 ||
      options.up.normalized().cross(options.view_direction.normalized()).norm() < 1e-6) {
    std::ostringstream msg;
    msg << "options.up is (" << options.up.transpose()
        << "), expected a finite vector not parallel to options.view_direction ("
        << options.view_direction.transpose() << ")";
    fail(msg.str());
  }
  if (!options.frame.isEmpty() &&
      !(options.frame.min().allFinite() && options.frame.max().allFinite())) {
    fail("options.frame has non-finite corners");
  }
  if (!options.base_color.allFinite() || !options.background.allFinite()) {
    fail("options.base_color and options.background must be finite RGB values in [0, 1]");
  }
}

void checkMesh(const char* function, const Eigen::Ref<const MatX3>& V,
               const Eigen::Ref<const MatX3i>& F, const MatX3& colors) {
  if (V.rows() == 0 || F.rows() == 0) {
    throw InputError(std::string(function) + ": empty mesh: argument V has shape " +
                     shapeString({long(V.rows()), 3}) + " and F has shape " +
                     shapeString({long(F.rows()), 3}) + ", expected at least one of each");
  }
  for (Eigen::Index i = 0; i < V.rows(); ++i) {
    if (!V.row(i).allFinite()) {
      throw InputError(std::string(function) + ": argument V (shape " +
                       shapeString({long(V.rows()), 3}) + ") has a non-finite value in row " +
                       std::to_string(i));
    }
  }
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      if (F(f, k) < 0 || F(f, k) >= V.rows()) {
        throw InputError(std::string(function) + ": argument F (shape " +
                         shapeString({long(F.rows()), 3}) + ") row " + std::to_string(f) +
                         " has vertex index " + std::to_string(F(f, k)) +
                         ", expected an index in [0, " + std::to_string(V.rows()) + ")");
      }
    }
  }
  if (colors.rows() != 0) {
    if (colors.rows() != V.rows()) {
      throw InputError(std::string(function) + ": argument colors has shape " +
                       shapeString({long(colors.rows()), 3}) + ", expected " +
                       shapeString({long(V.rows()), 3}) + " (one RGB row per vertex) or empty");
    }
    if (!colors.allFinite()) {
      throw InputError(std::string(function) + ": argument colors " +
                       shapeString({long(colors.rows()), 3}) + " has a non-finite value");
    }
  }
}

Eigen::AlignedBox3d boundingBox(const Eigen::Ref<const MatX3>& V) {
  Eigen::AlignedBox3d box;
  for (Eigen::Index i = 0; i < V.rows(); ++i) box.extend(V.row(i).transpose());
  return box;
}

// ---------------------------------------------------------------------------------------
// Camera and floor, shared by every panel of a sheet.

struct Camera {
  Vec3 right, up, forward;            // orthonormal; forward = viewing direction
  double center_x = 0, center_y = 0;  // framed centre in (right, up) coordinates, m
  double pixels_per_meter = 1;        // at the supersampled resolution
  int width = 0, height = 0;          // supersampled pixels

  // Pixel coordinates (x right, y down, pixel centres at +0.5) and depth along forward.
  Vec3 project(const Vec3& p) const {
    return Vec3((p.dot(right) - center_x) * pixels_per_meter + 0.5 * width,
                0.5 * height - (p.dot(up) - center_y) * pixels_per_meter, p.dot(forward));
  }
  // The point on the plane depth = 0 that projects to pixel (x, y).
  Vec3 rayOrigin(double x, double y) const {
    return (center_x + (x - 0.5 * width) / pixels_per_meter) * right +
           (center_y + (0.5 * height - y) / pixels_per_meter) * up;
  }
};

// A soft-edged rounded floor mat on the plane normal·p = level, centred under the framed box,
// with a contact-shadow map sampled on a grid over the mat.
struct Floor {
  bool visible = false;
  Vec3 normal;                  // world up (unit)
  double level = 0;             // normal·p of the floor plane, m
  Vec3 center, axis1, axis2;    // mat centre on the plane and its in-plane axes (unit)
  double half1 = 0, half2 = 0;  // mat half sizes along the axes, m
  double depth_offset = 0;      // pushes the floor back so soles touching it win the z-test
  int grid1 = 0, grid2 = 0;     // shadow grid cells
  std::vector<float> shadow;    // darkening in [0, 1], grid2 rows × grid1 columns

  double alpha(double u, double v) const {
    // Superellipse |u|⁴ + |v|⁴: a rounded rectangle whose border fades into the background.
    const double a = u / half1, b = v / half2;
    const double rho = std::sqrt(std::sqrt(a * a * a * a + b * b * b * b));
    return 1.0 - smoothstep(0.7, 1.0, rho);
  }
  double shadowAt(double u, double v) const {
    const double gx = (u + half1) / (2 * half1) * grid1 - 0.5;
    const double gy = (v + half2) / (2 * half2) * grid2 - 0.5;
    const int x0 = int(std::floor(gx)), y0 = int(std::floor(gy));
    const double fx = gx - x0, fy = gy - y0;
    auto cell = [&](int x, int y) -> double {
      if (x < 0 || y < 0 || x >= grid1 || y >= grid2) return 0.0;
      return shadow[size_t(y) * grid1 + x];
    };
    return (1 - fy) * ((1 - fx) * cell(x0, y0) + fx * cell(x0 + 1, y0)) +
           fy * ((1 - fx) * cell(x0, y0 + 1) + fx * cell(x0 + 1, y0 + 1));
  }
};

struct Setup {
  Camera camera;
  Floor floor;
};

Setup makeSetup(const Eigen::AlignedBox3d& frame, const RenderOptions& options) {
  Setup setup;
  Camera& camera = setup.camera;
  camera.forward = options.view_direction.normalized();
  camera.up = (options.up - options.up.dot(camera.forward) * camera.forward).normalized();
  camera.right = camera.forward.cross(camera.up);
  camera.width = options.width * kSupersample;
  camera.height = options.height * kSupersample;

  std::vector<Vec3> corners;
  for (int k = 0; k < 8; ++k) {
    corners.push_back(frame.corner(Eigen::AlignedBox3d::CornerType(k)));
  }
  double min_x = std::numeric_limits<double>::infinity(), max_x = -min_x;
  double min_y = min_x, max_y = -min_x;
  for (const Vec3& p : corners) {
    min_x = std::min(min_x, p.dot(camera.right));
    max_x = std::max(max_x, p.dot(camera.right));
    min_y = std::min(min_y, p.dot(camera.up));
    max_y = std::max(max_y, p.dot(camera.up));
  }

  Floor& floor = setup.floor;
  floor.normal = options.up.normalized();
  // Only a floor seen from above is drawn; seen edge-on or from below it would hide the body.
  floor.visible = options.draw_ground && camera.forward.dot(floor.normal) < -1e-3;
  if (floor.visible) {
    double level = std::numeric_limits<double>::infinity(), top = -level;
    for (const Vec3& p : corners) {
      level = std::min(level, p.dot(floor.normal));
      top = std::max(top, p.dot(floor.normal));
    }
    floor.level = level;
    Vec3 axis1 = camera.right - camera.right.dot(floor.normal) * floor.normal;
    if (axis1.norm() < 1e-6) axis1 = floor.normal.unitOrthogonal();
    floor.axis1 = axis1.normalized();
    floor.axis2 = floor.normal.cross(floor.axis1);
    double min1 = std::numeric_limits<double>::infinity(), max1 = -min1, min2 = min1, max2 = -min1;
    for (const Vec3& p : corners) {
      min1 = std::min(min1, p.dot(floor.axis1));
      max1 = std::max(max1, p.dot(floor.axis1));
      min2 = std::min(min2, p.dot(floor.axis2));
      max2 = std::max(max2, p.dot(floor.axis2));
    }
    const double size = std::max({max1 - min1, max2 - min2, top - level, kMinExtent});
    const double pad = 0.3 * size;
    floor.center = 0.5 * (min1 + max1) * floor.axis1 + 0.5 * (min2 + max2) * floor.axis2 +
                   level * floor.normal;
    // The mat's fading border starts at 70% of its half size: keep the footprint inside it.
    floor.half1 = (0.5 * (max1 - min1) + pad) / 0.85;
    floor.half2 = (0.5 * (max2 - min2) + pad) / 0.85;
    floor.depth_offset = 1e-4 * size;
    // The visible floor extends the framing downwards (front edge) and upwards (back edge),
    // not sideways: a wide mat may run off the sides of the picture.
    for (int su = -1; su <= 1; su += 2) {
      for (int sv = -1; sv <= 1; sv += 2) {
        const Vec3 p =
            floor.center + 0.7 * (su * floor.half1 * floor.axis1 + sv * floor.half2 * floor.axis2);
        min_y = std::min(min_y, p.dot(camera.up));
        max_y = std::max(max_y, p.dot(camera.up));
      }
    }
  }

  const double extent_x = std::max(max_x - min_x, kMinExtent);
  const double extent_y = std::max(max_y - min_y, kMinExtent);
  camera.center_x = 0.5 * (min_x + max_x);
  camera.center_y = 0.5 * (min_y + max_y);
  camera.pixels_per_meter = std::min(camera.width / (extent_x * (1 + 2 * kMargin)),
                                     camera.height / (extent_y * (1 + 2 * kMargin)));
  return setup;
}

// Separable box blur, applied three times (close to a Gaussian of σ ≈ radius).
void blur(std::vector<float>& values, int nx, int ny, int radius) {
  if (radius < 1) return;
  std::vector<float> scratch(values.size());
  for (int pass = 0; pass < 3; ++pass) {
    for (int y = 0; y < ny; ++y) {
      for (int x = 0; x < nx; ++x) {
        double sum = 0;
        for (int k = -radius; k <= radius; ++k) {
          const int xx = x + k;
          if (xx >= 0 && xx < nx) sum += values[size_t(y) * nx + xx];
        }
        scratch[size_t(y) * nx + x] = float(sum / (2 * radius + 1));
      }
    }
    for (int y = 0; y < ny; ++y) {
      for (int x = 0; x < nx; ++x) {
        double sum = 0;
        for (int k = -radius; k <= radius; ++k) {
          const int yy = y + k;
          if (yy >= 0 && yy < ny) sum += scratch[size_t(yy) * nx + x];
        }
        values[size_t(y) * nx + x] = float(sum / (2 * radius + 1));
      }
    }
  }
}

// Contact shadow: the mesh is projected straight down onto a grid over the mat, keeping
// the lowest height per cell; low parts (feet) give a dark, tight shadow and the whole body
// a faint, wide one.
void computeShadow(Floor& floor, const Eigen::Ref<const MatX3>& V,
                   const Eigen::Ref<const MatX3i>& F) {
  constexpr int kCells = 256;  // along the longer mat axis
  const double cell = 2 * std::max(floor.half1, floor.half2) / kCells;
  floor.grid1 = std::max(4, int(std::ceil(2 * floor.half1 / cell)));
  floor.grid2 = std::max(4, int(std::ceil(2 * floor.half2 / cell)));
  const size_t cells = size_t(floor.grid1) * floor.grid2;
  std::vector<float> lowest(cells, std::numeric_limits<float>::infinity());

  double top = -std::numeric_limits<double>::infinity();
  std::vector<Vec3> grid_points(V.rows());  // (cell x, cell y, height above floor)
  for (Eigen::Index i = 0; i < V.rows(); ++i) {
    const Vec3 p = V.row(i).transpose() - floor.center;
    grid_points[i] = Vec3((p.dot(floor.axis1) + floor.half1) / (2 * floor.half1) * floor.grid1,
                          (p.dot(floor.axis2) + floor.half2) / (2 * floor.half2) * floor.grid2,
                          std::max(0.0, p.dot(floor.normal)));
    top = std::max(top, grid_points[i].z());
  }
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    const Vec3& a = grid_points[F(f, 0)];
    const Vec3& b = grid_points[F(f, 1)];
    const Vec3& c = grid_points[F(f, 2)];
    const double area = (b.x() - a.x()) * (c.y() - a.y()) - (c.x() - a.x()) * (b.y() - a.y());
    if (std::abs(area) < 1e-12) continue;  // vertical faces are covered by their neighbours
    const int x0 = std::max(0, int(std::floor(std::min({a.x(), b.x(), c.x()}))));
    const int x1 = std::min(floor.grid1 - 1, int(std::ceil(std::max({a.x(), b.x(), c.x()}))));
    const int y0 = std::max(0, int(std::floor(std::min({a.y(), b.y(), c.y()}))));
    const int y1 = std::min(floor.grid2 - 1, int(std::ceil(std::max({a.y(), b.y(), c.y()}))));
    for (int y = y0; y <= y1; ++y) {
      for (int x = x0; x <= x1; ++x) {
        const double px = x + 0.5, py = y + 0.5;
        const double wa = ((b.x() - px) * (c.y() - py) - (c.x() - px) * (b.y() - py)) / area;
        const double wb = ((c.x() - px) * (a.y() - py) - (a.x() - px) * (c.y() - py)) / area;
        const double wc = 1.0 - wa - wb;
        if (wa < 0 || wb < 0 || wc < 0) continue;
        float& cell_height = lowest[size_t(y) * floor.grid1 + x];
        cell_height = std::min(cell_height, float(wa * a.z() + wb * b.z() + wc * c.z()));
      }
    }
  }

  const double height = std::max(top, kMinExtent);
  std::vector<float> contact(cells, 0.0f), soft(cells, 0.0f);
  for (size_t k = 0; k < cells; ++k) {
    if (!std::isfinite(lowest[k])) continue;
    contact[k] = float(std::exp(-lowest[k] / (0.06 * height)));
    soft[k] = float(std::exp(-lowest[k] / (0.8 * height)));
  }
  blur(contact, floor.grid1, floor.grid2, std::max(1, int(std::lround(0.04 * height / cell))));
  blur(soft, floor.grid1, floor.grid2, std::max(1, int(std::lround(0.1 * height / cell))));
  floor.shadow.resize(cells);
  for (size_t k = 0; k < cells; ++k) {
    floor.shadow[k] = float(std::min(0.8, 1.6 * contact[k] + 0.6 * soft[k]));
  }
}

// Area-weighted vertex normals (unnormalized face normals summed), #V × 3, unit or zero.
MatX3 vertexNormals(const Eigen::Ref<const MatX3>& V, const Eigen::Ref<const MatX3i>& F) {
  MatX3 normals = MatX3::Zero(V.rows(), 3);
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    const Vec3 a = V.row(F(f, 0)), b = V.row(F(f, 1)), c = V.row(F(f, 2));
    const Vec3 n = (b - a).cross(c - a);
    for (int k = 0; k < 3; ++k) normals.row(F(f, k)) += n.transpose();
  }
  for (Eigen::Index i = 0; i < V.rows(); ++i) {
    const double length = normals.row(i).norm();
    if (length > 0) normals.row(i) /= length;
  }
  return normals;
}

Image renderWithSetup(const Eigen::Ref<const MatX3>& V, const Eigen::Ref<const MatX3i>& F,
                      const RenderOptions& options, const MatX3& colors, Setup setup) {
  const Camera& camera = setup.camera;
  Floor& floor = setup.floor;
  const int W = camera.width, H = camera.height;
  const size_t samples = size_t(W) * H;

  const Vec3 background(toLinear(options.background.x()), toLinear(options.background.y()),
                        toLinear(options.background.z()));
  std::vector<Vec3> color(samples, background);  // linear RGB per sample
  std::vector<double> depth(samples, std::numeric_limits<double>::infinity());
  std::vector<int> triangle(samples, -1);
  std::vector<float> bary_b(samples, 0.0f), bary_c(samples, 0.0f);

  // Floor pass: intersect each sample's ray with the floor plane.
  if (floor.visible) {
    computeShadow(floor, V, F);
    const double floor_grey = toLinear(0.90);
    const double denominator = camera.forward.dot(floor.normal);
#pragma omp parallel for schedule(static)
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        const Vec3 origin = camera.rayOrigin(x + 0.5, y + 0.5);
        const double t = (floor.level - origin.dot(floor.normal)) / denominator;
        const Vec3 p = origin + t * camera.forward - floor.center;
        const double u = p.dot(floor.axis1), v = p.dot(floor.axis2);
        const double alpha = floor.alpha(u, v);
        if (alpha <= 0) continue;
        const double lit = floor_grey * (1.0 - floor.shadowAt(u, v));
        const size_t s = size_t(y) * W + x;
        color[s] = (1 - alpha) * background + alpha * Vec3::Constant(lit);
        depth[s] = t + floor.depth_offset;
      }
    }
  }

  // Triangle pass: nearest triangle and its barycentrics per sample.
  std::vector<Vec3> screen(V.rows());
  for (Eigen::Index i = 0; i < V.rows(); ++i) screen[i] = camera.project(V.row(i).transpose());
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    const Vec3& a = screen[F(f, 0)];
    const Vec3& b = screen[F(f, 1)];
    const Vec3& c = screen[F(f, 2)];
    const double area = (b.x() - a.x()) * (c.y() - a.y()) - (c.x() - a.x()) * (b.y() - a.y());
    if (std::abs(area) < 1e-12) continue;  // edge-on or degenerate: covers no sample
    const int x0 = std::max(0, int(std::floor(std::min({a.x(), b.x(), c.x()}))));
    const int x1 = std::min(W - 1, int(std::ceil(std::max({a.x(), b.x(), c.x()}))));
    const int y0 = std::max(0, int(std::floor(std::min({a.y(), b.y(), c.y()}))));
    const int y1 = std::min(H - 1, int(std::ceil(std::max({a.y(), b.y(), c.y()}))));
    for (int y = y0; y <= y1; ++y) {
      const double py = y + 0.5;
      for (int x = x0; x <= x1; ++x) {
        const double px = x + 0.5;
        const double wa = ((b.x() - px) * (c.y() - py) - (c.x() - px) * (b.y() - py)) / area;
        const double wb = ((c.x() - px) * (a.y() - py) - (a.x() - px) * (c.y() - py)) / area;
        const double wc = 1.0 - wa - wb;
        // A small tolerance closes cracks along shared edges; the z-test settles overlaps.
        if (wa < -1e-9 || wb < -1e-9 || wc < -1e-9) continue;
        const double z = wa * a.z() + wb * b.z() + wc * c.z();
        const size_t s = size_t(y) * W + x;
        if (z < depth[s]) {
          depth[s] = z;
          triangle[s] = int(f);
          bary_b[s] = float(wb);
          bary_c[s] = float(wc);
        }
      }
    }
  }

  // Shading pass. Lights are fixed to the camera so the visible side is always lit: a key
  // light from the upper left (≈ 38° off the view axis), a weaker fill from the right, and a
  // sky/ground ambient term.
  const MatX3 normals = vertexNormals(V, F);
  const Vec3 key_light = (-camera.forward + 0.6 * camera.up - 0.5 * camera.right).normalized();
  const Vec3 fill_light = (-camera.forward + 0.1 * camera.up + 0.9 * camera.right).normalized();
  const Vec3 world_up = options.up.normalized();
  const bool per_vertex = colors.rows() > 0;
  const Vec3 base(toLinear(options.base_color.x()), toLinear(options.base_color.y()),
                  toLinear(options.base_color.z()));
#pragma omp parallel for schedule(static)
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const size_t s = size_t(y) * W + x;
      const int f = triangle[s];
      if (f < 0) continue;
      const double wb = bary_b[s], wc = bary_c[s], wa = 1.0 - wb - wc;
      const int ia = F(f, 0), ib = F(f, 1), ic = F(f, 2);
      Vec3 n = wa * normals.row(ia) + wb * normals.row(ib) + wc * normals.row(ic);
      if (n.norm() < 1e-12) {
        n = (V.row(ib) - V.row(ia)).cross(V.row(ic) - V.row(ia)).transpose();
        if (n.norm() < 1e-300) n = -camera.forward;
      }
      n.normalize();
      if (n.dot(camera.forward) > 0) n = -n;  // two-sided: shade the side facing the viewer
      const double ambient = 0.14 + 0.08 * n.dot(world_up);
      const double intensity = ambient + 0.85 * std::max(0.0, n.dot(key_light)) +
                               0.22 * std::max(0.0, n.dot(fill_light));
      Vec3 albedo = base;
      if (per_vertex) {
        const Vec3 display = wa * colors.row(ia) + wb * colors.row(ib) + wc * colors.row(ic);
        albedo = Vec3(toLinear(display.x()), toLinear(display.y()), toLinear(display.z()));
      }
      color[s] = intensity * albedo;
    }
  }

  // Downsample: average each kSupersample × kSupersample block, then encode for display.
  Image image;
  image.width = options.width;
  image.height = options.height;
  image.rgb.resize(size_t(image.width) * image.height * 3);
  const double weight = 1.0 / (kSupersample * kSupersample);
#pragma omp parallel for schedule(static)
  for (int y = 0; y < image.height; ++y) {
    for (int x = 0; x < image.width; ++x) {
      Vec3 sum = Vec3::Zero();
      for (int dy = 0; dy < kSupersample; ++dy) {
        for (int dx = 0; dx < kSupersample; ++dx) {
          sum += color[size_t(y * kSupersample + dy) * W + (x * kSupersample + dx)];
        }
      }
      uint8_t* out = image.pixel(x, y);
      for (int c = 0; c < 3; ++c) {
        out[c] = uint8_t(std::lround(255.0 * toDisplay(weight * sum[c])));
      }
    }
  }
  return image;
}

}  // namespace

Image renderMesh(const Eigen::Ref<const MatX3>& V, const Eigen::Ref<const MatX3i>& F,
                 const RenderOptions& options, const MatX3& colors) {
  checkOptions("renderMesh", options);
  checkMesh("renderMesh", V, F, colors);
  const Eigen::AlignedBox3d frame = options.frame.isEmpty() ? boundingBox(V) : options.frame;
  return renderWithSetup(V, F, options, colors, makeSetup(frame, options));
}

Image renderSheet(const std::vector<MatX3>& frames, const Eigen::Ref<const MatX3i>& F,
                  const RenderOptions& options, int columns, const std::vector<MatX3>& colors) {
  checkOptions("renderSheet", options);
  if (frames.empty()) throw InputError("renderSheet: argument frames is empty, expected ≥ 1 mesh");
  if (columns < 0) {
    throw InputError("renderSheet: argument columns is " + std::to_string(columns) +
                     ", expected ≥ 0 (0 = all frames in one row)");
  }
  if (!colors.empty() && colors.size() != frames.size()) {
    throw InputError("renderSheet: argument colors has " + std::to_string(colors.size()) +
                     " entries, expected " + std::to_string(frames.size()) +
                     " (one per frame) or none");
  }
  const MatX3 no_colors;
  Eigen::AlignedBox3d frame = options.frame;
  for (size_t k = 0; k < frames.size(); ++k) {
    const std::string function = "renderSheet (frame " + std::to_string(k) + ")";
    checkMesh(function.c_str(), frames[k], F, colors.empty() ? no_colors : colors[k]);
    if (frames[k].rows() != frames[0].rows()) {
      throw InputError("renderSheet: frame " + std::to_string(k) + " has shape " +
                       shapeString({long(frames[k].rows()), 3}) + ", expected " +
                       shapeString({long(frames[0].rows()), 3}) + " like frame 0");
    }
    if (options.frame.isEmpty()) frame.extend(boundingBox(frames[k]));
  }
  const Setup setup = makeSetup(frame, options);

  const int count = int(frames.size());
  const int per_row = columns == 0 ? count : std::min(columns, count);
  const int rows = (count + per_row - 1) / per_row;
  if (int64_t(per_row) * options.width > kMaxImageSide * 4 ||
      int64_t(rows) * options.height > kMaxImageSide * 4) {
    throw InputError("renderSheet: the sheet would be " + std::to_string(per_row) + " × " +
                     std::to_string(options.width) + " by " + std::to_string(rows) + " × " +
                     std::to_string(options.height) + " pixels, too large");
  }
  Image sheet;
  sheet.width = per_row * options.width;
  sheet.height = rows * options.height;
  sheet.rgb.resize(size_t(sheet.width) * sheet.height * 3);
  const uint8_t background[3] = {
      uint8_t(std::lround(255.0 * std::clamp(options.background.x(), 0.0, 1.0))),
      uint8_t(std::lround(255.0 * std::clamp(options.background.y(), 0.0, 1.0))),
      uint8_t(std::lround(255.0 * std::clamp(options.background.z(), 0.0, 1.0)))};
  for (size_t p = 0; p < sheet.rgb.size(); p += 3) {
    std::copy(background, background + 3, sheet.rgb.begin() + p);
  }
  for (int k = 0; k < count; ++k) {
    const Image panel =
        renderWithSetup(frames[k], F, options, colors.empty() ? no_colors : colors[k], setup);
    const int x0 = (k % per_row) * options.width, y0 = (k / per_row) * options.height;
    for (int y = 0; y < panel.height; ++y) {
      std::copy(panel.pixel(0, y), panel.pixel(0, y) + 3 * panel.width, sheet.pixel(x0, y0 + y));
    }
  }
  return sheet;
}

MatX3 displacementColors(const VecX& magnitudes, double max_value) {
  // viridis at t = k/6 (sRGB, 0-255): perceptually uniform and readable in grey scale.
  static constexpr int kStops = 7;
  static constexpr unsigned char kViridis[kStops][3] = {
      {0x44, 0x01, 0x54}, {0x44, 0x3a, 0x83}, {0x31, 0x68, 0x8e}, {0x21, 0x90, 0x8c},
      {0x35, 0xb7, 0x79}, {0x8f, 0xd7, 0x44}, {0xfd, 0xe7, 0x25}};
  if (!std::isfinite(max_value) || max_value < 0.0) {
    std::ostringstream msg;
    msg << "displacementColors: argument max_value is " << max_value
        << ", expected a finite value ≥ 0 (the value shown in the top colour)";
    throw InputError(msg.str());
  }
  MatX3 colors(magnitudes.size(), 3);
  for (Eigen::Index i = 0; i < magnitudes.size(); ++i) {
    if (!std::isfinite(magnitudes[i])) {
      std::ostringstream msg;
      msg << "displacementColors: argument magnitudes (shape "
          << shapeString({long(magnitudes.size())}) << ") has the non-finite value "
          << magnitudes[i] << " at index " << i;
      throw InputError(msg.str());
    }
    const double t = max_value > 0.0 ? std::clamp(magnitudes[i] / max_value, 0.0, 1.0) : 0.0;
    const double s = t * (kStops - 1);
    const int k = std::min(int(s), kStops - 2);
    const double f = s - k;
    for (int c = 0; c < 3; ++c)
      colors(i, c) = ((1.0 - f) * kViridis[k][c] + f * kViridis[k + 1][c]) / 255.0;
  }
  return colors;
}

double quantileOf(const std::vector<VecX>& values, double q) {
  if (!(q >= 0.0 && q <= 1.0)) {
    std::ostringstream msg;
    msg << "quantileOf: argument q is " << q << ", expected a quantile in [0, 1]";
    throw InputError(msg.str());
  }
  std::vector<double> all;
  for (size_t k = 0; k < values.size(); ++k) {
    for (Eigen::Index i = 0; i < values[k].size(); ++i) {
      if (!std::isfinite(values[k][i])) {
        std::ostringstream msg;
        msg << "quantileOf: values[" << k << "] has the non-finite value " << values[k][i]
            << " at index " << i;
        throw InputError(msg.str());
      }
      all.push_back(values[k][i]);
    }
  }
  if (all.empty()) return 0.0;
  const double position = q * double(all.size() - 1);
  const size_t below = size_t(std::floor(position));
  std::nth_element(all.begin(), all.begin() + long(below), all.end());
  const double lo = all[below];
  if (below + 1 >= all.size()) return lo;
  const double hi = *std::min_element(all.begin() + long(below) + 1, all.end());
  return lo + (position - double(below)) * (hi - lo);
}

std::vector<double> colorBarTicks(double max_value, int max_ticks) {
  if (!std::isfinite(max_value) || max_value < 0.0) {
    std::ostringstream msg;
    msg << "colorBarTicks: argument max_value is " << max_value << ", expected a finite value ≥ 0";
    throw InputError(msg.str());
  }
  if (max_ticks < 2)
    throw InputError("colorBarTicks: argument max_ticks is " + std::to_string(max_ticks) +
                     ", expected ≥ 2");
  if (max_value == 0.0) return {0.0};
  // The smallest step 1, 2 or 5 × 10^k that leaves at most max_ticks ticks (0 included).
  double step = std::pow(10.0, std::floor(std::log10(max_value / (max_ticks - 1))));
  for (int k = 0; max_value / step > max_ticks - 1 + 1e-9; ++k) {
    const double mantissa[3] = {2.0, 2.5, 2.0};  // 1 → 2 → 5 → 10 → 20 …
    step *= mantissa[k % 3];
  }
  std::vector<double> ticks;
  for (int k = 0; k * step <= max_value * (1 + 1e-12); ++k) ticks.push_back(k * step);
  return ticks;
}

namespace {
std::string tickText(double value) {
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), "%.3g", value);
  return buffer;
}
}  // namespace

Image withColorBar(const Image& image, double max_value, const std::string& unit,
                   const std::string& caption) {
  if (image.width < 64 || image.height <= 0)
    throw InputError("withColorBar: the image is " + std::to_string(image.width) + " × " +
                     std::to_string(image.height) + " pixels, expected at least 64 wide");
  const std::vector<double> ticks = colorBarTicks(max_value);  // checks max_value
  constexpr int kStrip = 64, kLeft = 16, kBarTop = 22, kBarHeight = 14, kMaxBar = 480;
  const int right_room = labelWidth(tickText(max_value) + "+ " + unit) + 12;
  const int bar_width = std::max(8, std::min(kMaxBar, image.width - kLeft - right_room));
  Image out;
  out.width = image.width;
  out.height = image.height + kStrip;
  out.rgb.assign(size_t(out.width) * out.height * 3, 255);
  std::copy(image.rgb.begin(), image.rgb.end(), out.rgb.begin());
  const int top = image.height;
  const Vec3 text_color(0.1, 0.1, 0.1);
  drawLabel(out, kLeft, top + 8, caption, text_color);
  const VecX positions = VecX::LinSpaced(bar_width, 0.0, 1.0);
  const MatX3 colors = displacementColors(positions, 1.0);
  for (int x = 0; x < bar_width; ++x)
    for (int y = 0; y < kBarHeight; ++y) {
      uint8_t* p = out.pixel(kLeft + x, top + kBarTop + y);
      for (int c = 0; c < 3; ++c) p[c] = uint8_t(std::lround(255.0 * colors(x, c)));
    }
  auto xOf = [&](double value) {
    return kLeft + int(std::lround((bar_width - 1) * (max_value > 0 ? value / max_value : 0.0)));
  };
  auto tick = [&](double value, const std::string& label) {
    const int x = xOf(value);
    for (int y = top + kBarTop + kBarHeight; y < top + kBarTop + kBarHeight + 4; ++y) {
      uint8_t* p = out.pixel(x, y);
      p[0] = p[1] = p[2] = 25;
    }
    drawLabel(out, std::max(0, x - labelWidth(label) / 2), top + kBarTop + kBarHeight + 6, label,
              text_color);
  };
  // The scale's top at the bar's end ("+": larger values share its colour); ticks whose labels
  // would run into it are left out.
  const std::string top_label = tickText(max_value) + "+ " + unit;
  const int top_label_left = xOf(max_value) - labelWidth(top_label) / 2;
  for (double value : ticks) {
    const std::string label = tickText(value);
    if (value < max_value && xOf(value) + labelWidth(label) / 2 + 8 < top_label_left)
      tick(value, label);
  }
  tick(max_value, top_label);
  return out;
}

}  // namespace flsh::render
