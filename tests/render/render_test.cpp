// Tests of the software renderer and PNG files: framing, shading, z-buffer, floor, sheets,
// PNG round trips and error handling.
#include "flsh/render/render.h"

#include <gtest/gtest.h>
#include <png.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <map>
#include <random>

#include "flsh/core/error.h"
#include "support/test_support.h"

namespace flsh::render {
namespace {

namespace fs = std::filesystem;

// Unit icosphere: 12 vertices refined `levels` times (4^levels · 20 triangles), outward faces.
void icosphere(int levels, MatX3& V, MatX3i& F) {
  const double t = (1 + std::sqrt(5.0)) / 2;
  std::vector<Vec3> points = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0},
                              {0, -1, t}, {0, 1, t}, {0, -1, -t}, {0, 1, -t},
                              {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
  std::vector<Eigen::Vector3i> faces = {
      {0, 11, 5},  {0, 5, 1},  {0, 1, 7},  {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
      {11, 10, 2}, {10, 7, 6}, {7, 1, 8},  {3, 9, 4},  {3, 4, 2},   {3, 2, 6}, {3, 6, 8},
      {3, 8, 9},   {4, 9, 5},  {2, 4, 11}, {6, 2, 10}, {8, 6, 7},   {9, 8, 1}};
  for (Vec3& p : points) p.normalize();
  for (int level = 0; level < levels; ++level) {
    std::map<std::pair<int, int>, int> midpoints;
    auto midpoint = [&](int a, int b) {
      const auto key = std::minmax(a, b);
      const auto found = midpoints.find(key);
      if (found != midpoints.end()) return found->second;
      points.push_back((points[a] + points[b]).normalized());
      return midpoints[key] = int(points.size()) - 1;
    };
    std::vector<Eigen::Vector3i> refined;
    for (const Eigen::Vector3i& f : faces) {
      const int a = midpoint(f[0], f[1]), b = midpoint(f[1], f[2]), c = midpoint(f[2], f[0]);
      refined.push_back({f[0], a, c});
      refined.push_back({f[1], b, a});
      refined.push_back({f[2], c, b});
      refined.push_back({a, b, c});
    }
    faces = refined;
  }
  V.resize(points.size(), 3);
  for (size_t i = 0; i < points.size(); ++i) V.row(i) = points[i].transpose();
  F.resize(faces.size(), 3);
  for (size_t f = 0; f < faces.size(); ++f) F.row(f) = faces[f].transpose();
}

// The camera frame the renderer uses for `options` (right, up, forward).
struct Basis {
  Vec3 right, up, forward;
};
Basis cameraBasis(const RenderOptions& options) {
  Basis basis;
  basis.forward = options.view_direction.normalized();
  basis.up = (options.up - options.up.dot(basis.forward) * basis.forward).normalized();
  basis.right = basis.forward.cross(basis.up);
  return basis;
}

// A square (two triangles) centred at `center`, spanned by unit axes a and b, half size h.
void square(const Vec3& center, const Vec3& a, const Vec3& b, double h, MatX3& V, MatX3i& F) {
  V.resize(4, 3);
  V.row(0) = (center - h * a - h * b).transpose();
  V.row(1) = (center + h * a - h * b).transpose();
  V.row(2) = (center + h * a + h * b).transpose();
  V.row(3) = (center - h * a + h * b).transpose();
  F.resize(2, 3);
  F << 0, 1, 2,  //
      0, 2, 3;
}

bool isColor(const Image& image, int x, int y, int r, int g, int b) {
  const uint8_t* p = image.pixel(x, y);
  return p[0] == r && p[1] == g && p[2] == b;
}
int brightness(const Image& image, int x, int y) {
  const uint8_t* p = image.pixel(x, y);
  return p[0] + p[1] + p[2];
}

RenderOptions smallOptions(bool ground = false) {
  RenderOptions options;
  options.width = 64;
  options.height = 48;
  options.draw_ground = ground;
  return options;
}

TEST(Render, SphereHasBackgroundCornersAndShadedCentre) {
  MatX3 V;
  MatX3i F;
  icosphere(3, V, F);
  const RenderOptions options = smallOptions();
  const Image image = renderMesh(V, F, options);
  ASSERT_EQ(image.width, 64);
  ASSERT_EQ(image.height, 48);
  ASSERT_EQ(image.rgb.size(), size_t(64 * 48 * 3));
  for (auto [x, y] : {std::pair{0, 0}, {63, 0}, {0, 47}, {63, 47}}) {
    EXPECT_TRUE(isColor(image, x, y, 255, 255, 255)) << x << ", " << y;
  }
  const uint8_t* centre = image.pixel(32, 24);
  // Skin-like base colour: red > green > blue, neither white nor black.
  EXPECT_GT(centre[0], centre[1]);
  EXPECT_GT(centre[1], centre[2]);
  EXPECT_GT(centre[2], 20);
  EXPECT_LT(centre[0], 255);
  // Smooth shading varies across the sphere.
  EXPECT_NE(brightness(image, 26, 20), brightness(image, 38, 28));
  // The framing keeps the aspect ratio: the sphere is round (same extent in x and y).
  int min_x = 64, max_x = -1, min_y = 48, max_y = -1;
  for (int y = 0; y < 48; ++y) {
    for (int x = 0; x < 64; ++x) {
      if (isColor(image, x, y, 255, 255, 255)) continue;
      min_x = std::min(min_x, x), max_x = std::max(max_x, x);
      min_y = std::min(min_y, y), max_y = std::max(max_y, y);
    }
  }
  EXPECT_NEAR(max_x - min_x, max_y - min_y, 2);
  EXPECT_GT(max_y - min_y, 30);  // fills most of the height (margin only)
}

TEST(Render, FaceTowardsTheViewerIsBrighterThanGrazingFaces) {
  const RenderOptions options = smallOptions();
  const Basis basis = cameraBasis(options);
  MatX3 V;
  MatX3i F;
  square(Vec3::Zero(), basis.right, basis.up, 1.0, V, F);
  const int frontal = brightness(renderMesh(V, F, options), 32, 24);
  EXPECT_GT(frontal, 300);
  for (double sign : {-1.0, 1.0}) {
    // Turned 80° about the camera's vertical axis: the face is seen nearly edge-on.
    const double angle = sign * 80.0 * M_PI / 180.0;
    const Vec3 a = std::cos(angle) * basis.right + std::sin(angle) * basis.forward;
    square(Vec3::Zero(), a, basis.up, 1.0, V, F);
    const Image image = renderMesh(V, F, options);
    ASSERT_FALSE(isColor(image, 32, 24, 255, 255, 255));
    EXPECT_LT(brightness(image, 32, 24), frontal - 60) << "angle " << sign * 80;
  }
}

TEST(Render, BackFacesAreShadedLikeFrontFaces) {
  const RenderOptions options = smallOptions();
  const Basis basis = cameraBasis(options);
  MatX3 V;
  MatX3i F;
  square(Vec3::Zero(), basis.right, basis.up, 1.0, V, F);
  const Image front = renderMesh(V, F, options);
  const MatX3i flipped = F.rowwise().reverse();
  const Image back = renderMesh(V, flipped, options);
  EXPECT_EQ(front.rgb, back.rgb);
}

TEST(Render, ZBufferShowsTheNearerTriangle) {
  const RenderOptions options = smallOptions();
  const Basis basis = cameraBasis(options);
  MatX3 near_V, far_V;
  MatX3i near_F, far_F;
  square(-0.5 * basis.forward, basis.right, basis.up, 0.5, near_V, near_F);  // red, in front
  square(+0.5 * basis.forward, basis.right, basis.up, 1.0, far_V, far_F);    // blue, larger
  MatX3 V(8, 3), colors(8, 3);
  V << near_V, far_V;
  colors.topRows(4).rowwise() = Eigen::RowVector3d(1, 0, 0);
  colors.bottomRows(4).rowwise() = Eigen::RowVector3d(0, 0, 1);
  for (bool near_first : {true, false}) {
    MatX3i F(4, 3);
    if (near_first)
      F << near_F, (far_F.array() + 4).matrix();
    else
      F << (far_F.array() + 4).matrix(), near_F;
    const Image image = renderMesh(V, F, options, colors);
    const uint8_t* centre = image.pixel(32, 24);  // overlap: the red square wins
    EXPECT_GT(centre[0], 100) << "near first: " << near_first;
    EXPECT_EQ(centre[2], 0) << "near first: " << near_first;
    const uint8_t* side = image.pixel(32 + 14, 24);  // only the blue square
    EXPECT_EQ(side[0], 0);
    EXPECT_GT(side[2], 100);
  }
}

TEST(Render, PerVertexColorsAreInterpolated) {
  const RenderOptions options = smallOptions();
  const Basis basis = cameraBasis(options);
  MatX3 V;
  MatX3i F;
  square(Vec3::Zero(), basis.right, basis.up, 1.0, V, F);
  MatX3 colors(4, 3);
  colors << 1, 0, 0,  // left
      0, 0, 1,        // right
      0, 0, 1,        //
      1, 0, 0;
  const Image image = renderMesh(V, F, options, colors);
  const uint8_t* left = image.pixel(14, 24);
  const uint8_t* middle = image.pixel(32, 24);
  const uint8_t* right = image.pixel(50, 24);
  EXPECT_GT(left[0], left[2]);
  EXPECT_GT(right[2], right[0]);
  EXPECT_GT(middle[0], 0);
  EXPECT_GT(middle[2], 0);
}

TEST(Render, GroundIsDrawnBelowTheBodyWithAContactShadow) {
  MatX3 V;
  MatX3i F;
  icosphere(3, V, F);
  RenderOptions options = smallOptions(/*ground=*/true);
  options.width = 120;
  options.height = 120;
  options.view_direction = Vec3(0, -1, -1);  // from above, so the floor is well visible
  const Image with_ground = renderMesh(V, F, options);
  options.draw_ground = false;
  const Image without_ground = renderMesh(V, F, options);
  // Below the sphere the floor is grey, a contact shadow darkens it right under the sphere
  // (seen just in front of the sphere's lowest visible point).
  int lowest_body_row = -1;
  for (int y = 0; y < 120; ++y) {
    if (!isColor(without_ground, 60, y, 255, 255, 255)) lowest_body_row = y;
  }
  ASSERT_GT(lowest_body_row, 60);
  ASSERT_LT(lowest_body_row, 115);
  const int shadow_row = lowest_body_row + 2;
  const uint8_t* floor_pixel = with_ground.pixel(60, shadow_row);
  EXPECT_EQ(floor_pixel[0], floor_pixel[1]);  // grey
  EXPECT_EQ(floor_pixel[1], floor_pixel[2]);
  EXPECT_LT(floor_pixel[0], 230);
  EXPECT_TRUE(isColor(without_ground, 60, shadow_row, 255, 255, 255));
  // Further out on the floor, at the same row, it is lighter (the shadow is local).
  const uint8_t* open_floor = with_ground.pixel(8, shadow_row);
  EXPECT_EQ(open_floor[0], open_floor[2]);
  EXPECT_GT(open_floor[0], floor_pixel[0] + 20);
  EXPECT_LT(open_floor[0], 255);
}

TEST(Render, SheetPlacesFramesLeftToRightWithCommonFraming) {
  MatX3 V;
  MatX3i F;
  icosphere(2, V, F);
  std::vector<MatX3> frames;
  for (int k = 0; k < 5; ++k) {
    MatX3 moved = V;
    moved.col(0).array() += 0.5 * k;  // moves right frame by frame
    frames.push_back(moved);
  }
  RenderOptions options = smallOptions();
  options.width = 40;
  options.height = 30;
  const Image sheet = renderSheet(frames, F, options, /*columns=*/2);
  EXPECT_EQ(sheet.width, 2 * 40);
  EXPECT_EQ(sheet.height, 3 * 30);
  const Image row = renderSheet(frames, F, options);
  EXPECT_EQ(row.width, 5 * 40);
  EXPECT_EQ(row.height, 30);

  // Mean x of body pixels inside each panel of the single row grows from frame to frame.
  double previous = -1;
  for (int k = 0; k < 5; ++k) {
    double sum = 0;
    int count = 0;
    for (int y = 0; y < 30; ++y) {
      for (int x = 0; x < 40; ++x) {
        if (!isColor(row, 40 * k + x, y, 255, 255, 255)) sum += x, ++count;
      }
    }
    ASSERT_GT(count, 20) << "panel " << k;
    EXPECT_GT(sum / count, previous + 1) << "panel " << k;
    previous = sum / count;
  }
  // The empty sixth cell of the 2-column sheet is background.
  for (int y = 60; y < 90; ++y) {
    for (int x = 40; x < 80; ++x) ASSERT_TRUE(isColor(sheet, x, y, 255, 255, 255));
  }
  // A panel of the sheet equals the single-row panel of the same frame.
  for (int y = 0; y < 30; ++y) {
    for (int x = 0; x < 40; ++x) {
      ASSERT_TRUE(
          std::equal(sheet.pixel(40 + x, y), sheet.pixel(40 + x, y) + 3, row.pixel(40 + x, y)));
    }
  }
}

TEST(Render, DegenerateInputsThrowOrRenderSafely) {
  MatX3 V;
  MatX3i F;
  icosphere(1, V, F);
  const RenderOptions options = smallOptions(/*ground=*/true);
  EXPECT_THROW(renderMesh(MatX3(0, 3), MatX3i(0, 3), options), InputError);
  EXPECT_THROW(renderMesh(V, MatX3i(0, 3), options), InputError);
  MatX3 nan_V = V;
  nan_V(3, 1) = std::numeric_limits<double>::quiet_NaN();
  try {
    renderMesh(nan_V, F, options);
    ADD_FAILURE() << "NaN accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("non-finite"), std::string::npos) << e.what();
  }
  MatX3i bad_F = F;
  bad_F(0, 1) = int(V.rows());
  EXPECT_THROW(renderMesh(V, bad_F, options), InputError);
  try {
    renderMesh(V, F, options, MatX3::Zero(3, 3));
    ADD_FAILURE() << "wrong colour shape accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("(3, 3)"), std::string::npos) << e.what();
  }
  RenderOptions bad = options;
  bad.view_direction = Vec3::Zero();
  EXPECT_THROW(renderMesh(V, F, bad), InputError);
  bad = options;
  bad.up = options.view_direction;
  EXPECT_THROW(renderMesh(V, F, bad), InputError);
  bad = options;
  bad.width = 0;
  EXPECT_THROW(renderMesh(V, F, bad), InputError);
  EXPECT_THROW(renderSheet({}, F, options), InputError);
  EXPECT_THROW(renderSheet({V, V}, F, options, 0, {MatX3()}), InputError);

  // All vertices at one point: framed with a minimum extent, nothing to rasterize.
  const MatX3 point = MatX3::Constant(V.rows(), 3, 0.25);
  RenderOptions plain = options;
  plain.draw_ground = false;
  const Image empty = renderMesh(point, F, plain);
  for (uint8_t value : empty.rgb) ASSERT_EQ(value, 255);
  const Image with_ground = renderMesh(point, F, options);
  EXPECT_EQ(with_ground.rgb.size(), size_t(64 * 48 * 3));

  // A flat mesh seen edge-on (zero height in the image) still renders.
  RenderOptions side = plain;
  side.view_direction = Vec3(0, 0, -1);
  MatX3 flat = V;
  flat.col(1).setZero();
  EXPECT_NO_THROW(renderMesh(flat, F, side));
}

TEST(Render, ExplicitFrameIsRespected) {
  MatX3 V;
  MatX3i F;
  icosphere(2, V, F);
  RenderOptions options = smallOptions();
  const Image fitted = renderMesh(V, F, options);
  options.frame = Eigen::AlignedBox3d(Vec3::Constant(-4), Vec3::Constant(4));
  const Image framed = renderMesh(V, F, options);
  auto coverage = [](const Image& image) {
    int count = 0;
    for (int y = 0; y < image.height; ++y) {
      for (int x = 0; x < image.width; ++x) count += !isColor(image, x, y, 255, 255, 255);
    }
    return count;
  };
  EXPECT_LT(coverage(framed) * 4, coverage(fitted));  // a bigger frame makes the sphere small
  EXPECT_GT(coverage(framed), 0);
}

TEST(Png, WriteReadRoundTripIsExact) {
  const std::string dir = test::freshTempDir("render_png_round_trip");
  Image image;
  image.width = 37;
  image.height = 23;
  image.rgb.resize(37 * 23 * 3);
  std::mt19937 rng(7);
  for (uint8_t& value : image.rgb) value = uint8_t(rng() & 0xff);
  const std::string path = dir + "/noise.png";
  writePng(path, image);
  const Image read = readPng(path);
  EXPECT_EQ(read.width, 37);
  EXPECT_EQ(read.height, 23);
  EXPECT_EQ(read.rgb, image.rgb);
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 1);

  // A rendered picture too.
  MatX3 V;
  MatX3i F;
  icosphere(2, V, F);
  const Image rendered = renderMesh(V, F, smallOptions(true));
  writePng(dir + "/sphere.png", rendered);
  EXPECT_EQ(readPng(dir + "/sphere.png").rgb, rendered.rgb);
}

TEST(Png, ReadsRgbaAsRgb) {
  const std::string dir = test::freshTempDir("render_png_rgba");
  const int width = 5, height = 3;
  std::vector<uint8_t> rgba(width * height * 4);
  for (size_t k = 0; k < rgba.size(); ++k) rgba[k] = uint8_t(17 * k + 3);
  png_image description;
  std::memset(&description, 0, sizeof(description));
  description.version = PNG_IMAGE_VERSION;
  description.width = width;
  description.height = height;
  description.format = PNG_FORMAT_RGBA;
  const std::string path = dir + "/rgba.png";
  ASSERT_TRUE(png_image_write_to_file(&description, path.c_str(), 0, rgba.data(), 0, nullptr));
  const Image image = readPng(path);
  ASSERT_EQ(image.width, width);
  ASSERT_EQ(image.height, height);
  for (int p = 0; p < width * height; ++p) {
    for (int c = 0; c < 3; ++c) EXPECT_EQ(image.rgb[3 * p + c], rgba[4 * p + c]);
  }
}

TEST(Png, ErrorsNameThePath) {
  const std::string dir = test::freshTempDir("render_png_errors");
  Image image;
  image.width = 2;
  image.height = 2;
  image.rgb.assign(12, 128);
  { std::ofstream(dir + "/a_file") << "not a png"; }
  try {
    writePng(dir + "/a_file/picture.png", image);  // parent is a regular file
    ADD_FAILURE() << "no FileError";
  } catch (const FileError& e) {
    EXPECT_NE(std::string(e.what()).find("a_file"), std::string::npos) << e.what();
  }
  fs::create_directory(dir + "/a_dir");
  EXPECT_THROW(writePng(dir + "/a_dir", image), FileError);  // target is a directory
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 2);
  EXPECT_TRUE(fs::is_empty(dir + "/a_dir"));

  Image wrong = image;
  wrong.rgb.resize(11);
  EXPECT_THROW(writePng(dir + "/wrong.png", wrong), InputError);
  EXPECT_FALSE(fs::exists(dir + "/wrong.png"));

  EXPECT_THROW(readPng(dir + "/missing.png"), FileError);
  try {
    readPng(dir + "/a_file");
    ADD_FAILURE() << "no InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("a_file"), std::string::npos) << e.what();
  }
  // A PNG cut short is malformed, not a crash.
  writePng(dir + "/whole.png", image);
  std::ifstream in(dir + "/whole.png", std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::ofstream(dir + "/cut.png", std::ios::binary) << bytes.substr(0, bytes.size() / 2);
  EXPECT_THROW(readPng(dir + "/cut.png"), InputError);
}

}  // namespace
}  // namespace flsh::render
