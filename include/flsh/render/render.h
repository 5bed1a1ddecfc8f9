// A small headless software renderer: shaded triangle meshes into RGB images, and PNG output.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "flsh/core/types.h"

namespace flsh::render {

/// 8-bit RGB image, row-major, top row first.
struct Image {
  int width = 0, height = 0;
  std::vector<uint8_t> rgb;  ///< width · height · 3
  uint8_t* pixel(int x, int y) { return &rgb[3 * (size_t(y) * width + x)]; }
  const uint8_t* pixel(int x, int y) const { return &rgb[3 * (size_t(y) * width + x)]; }
};

struct RenderOptions {
  int width = 480;   ///< pixels
  int height = 640;  ///< pixels
  /// Direction the camera looks along (world), default: from the front (+z) towards −z,
  /// slightly from above and from the body's right.
  Vec3 view_direction = Vec3(-0.25, -0.2, -1.0);
  Vec3 up = Vec3::UnitY();
  /// Orthographic framing: the view fits this world box (min, max); empty box = fit the mesh.
  Eigen::AlignedBox3d frame;
  Vec3 base_color = Vec3(0.80, 0.62, 0.52);  ///< used when no per-vertex colours
  Vec3 background = Vec3(1.0, 1.0, 1.0);
  bool draw_ground = true;  ///< a shaded floor at the lowest point of the frame box
};

/// Renders one mesh (#V × 3, #F × 3) with Lambert + ambient shading and a z-buffer.
/// `colors` (#V × 3 in [0, 1]) overrides base_color when given.
Image renderMesh(const Eigen::Ref<const MatX3>& V, const Eigen::Ref<const MatX3i>& F,
                 const RenderOptions& options = {}, const MatX3& colors = MatX3());

/// Renders several frames of one animated mesh side by side with a common framing
/// (`columns` per row; 0 = all in one row).
Image renderSheet(const std::vector<MatX3>& frames, const Eigen::Ref<const MatX3i>& F,
                  const RenderOptions& options = {}, int columns = 0,
                  const std::vector<MatX3>& colors = {});

/// Colours (#V × 3 in [0, 1], sRGB) of the perceptual sequential map viridis for values
/// (#V, e.g. displacement magnitudes in any unit) over [0, max_value] (same unit): 0 is dark
/// purple (0.267, 0.004, 0.329), max_value is yellow (0.993, 0.906, 0.144). The map
/// interpolates linearly in sRGB between 7 stops at t = k/6 (viridis #440154, #443a83, #31688e,
/// #21908c, #35b779, #8fd744, #fde725); its relative luminance increases with t. Values are
/// clamped to [0, max_value]; max_value = 0 maps everything to the 0 colour. Throws InputError
/// for a non-finite value (naming its index) or a negative or non-finite max_value.
MatX3 displacementColors(const VecX& magnitudes, double max_value);

/// The q-quantile of all entries of `values` pooled (linear interpolation between the order
/// statistics, as numpy.quantile's default): the robust top of a colour scale, which ignores the
/// largest (1 − q) of the entries, e.g. a few flopping vertices. 0 when there are no entries.
/// Throws InputError for q outside [0, 1] or a non-finite entry (naming its vector and index).
double quantileOf(const std::vector<VecX>& values, double q);

/// Tick values of a colour bar over [0, max_value]: 0 and the multiples of a step of 1, 2 or
/// 5 × 10^k up to max_value, at most `max_ticks` (≥ 2) of them. {0} for max_value = 0. Throws
/// InputError for a negative or non-finite max_value or max_ticks < 2.
std::vector<double> colorBarTicks(double max_value, int max_ticks = 6);

/// `image` with a white strip appended below it holding a horizontal colour bar of
/// displacementColors over [0, max_value] (left to right), tick marks labelled with
/// colorBarTicks' values, max_value labelled at the right end with "+" (larger values share its
/// colour), `unit` after the labels and `caption` above the bar (printable ASCII, the plots'
/// font). The bar is at most 480 pixels wide and fits the image's width. Throws InputError for
/// an image narrower than 64 pixels or a negative or non-finite max_value.
Image withColorBar(const Image& image, double max_value, const std::string& unit,
                   const std::string& caption);

/// Writes an 8-bit RGB PNG atomically. Throws FileError on failure.
void writePng(const std::string& path, const Image& image);

/// Reads an 8-bit RGB/RGBA PNG (for tests and tools). Throws FileError when `path` is missing or
/// unreadable; InputError naming it when it is not a regular file (a FIFO, a directory: never
/// opened), not a PNG, malformed, or announces more pixels than its size can hold.
Image readPng(const std::string& path);

}  // namespace flsh::render
