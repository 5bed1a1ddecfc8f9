// sheet.png of a recorded scene (issue 29, "A picture people can read"): one robust colour scale
// over the shown frames of the soft avatars (the 99th percentile of their surface |u|, not the
// maximum), a colour bar strip below the frames and each frame labelled with its time.
#include <gtest/gtest.h>

#include <filesystem>
#include <memory>

#include "flsh/body/motion.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/io/scene_outputs.h"
#include "flsh/render/render.h"
#include "flsh/solve/scene.h"
#include "support/test_support.h"

namespace flsh::io {
namespace {

int darkPixels(const render::Image& image, int x0, int y0, int x1, int y1) {
  int n = 0;
  for (int y = y0; y < y1; ++y)
    for (int x = x0; x < x1; ++x) {
      const uint8_t* p = image.pixel(x, y);
      n += p[0] < 60 && p[1] < 60 && p[2] < 60;
    }
  return n;
}

TEST(SceneSheet, SoftAvatarsShareARobustScaleWithAColourBarAndTimeLabels) {
  SyntheticBodyOptions body_options;
  body_options.vertices = 800;
  auto body = std::make_shared<BodyModel>(makeSyntheticBody(body_options));
  auto avatar = std::make_shared<SoftAvatar>(
      body, VecX(), test::smallSoftAvatarSettings(test::freshTempDir("scene_sheet_cache")));
  avatar->enableSoftTissue();
  avatar->initVolumetricData();
  auto motion = std::make_shared<Motion>(makeBuiltinMotion("jumping_jacks", 1.0, 30.0));
  SimulableOptions options;
  options.time_step = 1.0 / 30.0;
  auto sim = std::make_shared<Simulable>(avatar, motion, options);
  Scene scene;
  scene.addSimulable(sim);
  scene.initialize();

  OutputSpec outputs;
  outputs.ply = outputs.npz = outputs.gltf = false;
  outputs.png_frames = 3;
  const std::string dir = test::freshTempDir("scene_sheet_out");
  const int frames = 7;  // shown: 0, 3, 6
  SceneRecorder recorder(outputs, dir, {{"soft", sim, true}}, {}, options.time_step, frames);
  std::vector<VecX> shown_mm;
  double largest = 0.0;
  for (int k = 0; k < frames; ++k) {
    if (k > 0) scene.step();
    recorder.record(k * options.time_step);
    const VecX mm = 1000.0 * sim->getSoftTissueDisplacements().rowwise().norm();
    if (k % 3 == 0) {
      shown_mm.push_back(mm);
      largest = std::max(largest, mm.maxCoeff());
    }
  }
  recorder.finish();
  const double scale = recorder.sheetMaxDisplacementMm();
  EXPECT_DOUBLE_EQ(scale, render::quantileOf(shown_mm, 0.99));
  EXPECT_GT(scale, 0.0);
  EXPECT_LT(scale, largest);  // not the maximum: the top 1 % are clamped to the top colour

  const render::Image sheet = render::readPng(dir + "/sheet.png");
  EXPECT_EQ(sheet.width, 3 * 320);
  EXPECT_GT(sheet.height, 480);  // the colour bar's strip
  // Time labels in the top-left corner of each panel (dark text on the white background).
  for (int j = 0; j < 3; ++j)
    EXPECT_GT(darkPixels(sheet, 320 * j, 0, 320 * j + 140, 30), 40) << "panel " << j;
  EXPECT_GT(darkPixels(sheet, 0, 480, sheet.width, sheet.height), 100);  // bar labels
}

}  // namespace
}  // namespace flsh::io
