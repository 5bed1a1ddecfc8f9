#include "flsh/io/presets.h"

#include <gtest/gtest.h>

#include "flsh/core/error.h"
#include "support/test_support.h"

namespace flsh {
namespace {

TEST(Presets, NamesRoundTripAndUnknownNamesAreNamed) {
  for (Preset preset : {Preset::None, Preset::Realtime})
    EXPECT_EQ(parsePreset(presetName(preset), "test"), preset);
  const std::string message =
      test::messageOf<InputError>([] { parsePreset("real-time", "--preset"); });
  EXPECT_EQ(message, "--preset: unknown preset 'real-time', expected 'none' or 'realtime'");
}

TEST(Presets, NoneIsTheLibraryDefaultAndRealtimeTheSmallModalRom) {
  const ReducedSettings none = presetReducedSettings(Preset::None);
  const ReducedSettings defaults;
  EXPECT_EQ(none.basis_kind, defaults.basis_kind);
  EXPECT_EQ(none.modes.vibration_modes, defaults.modes.vibration_modes);
  EXPECT_EQ(none.modes.columns, defaults.modes.columns);
  EXPECT_EQ(none.elastic_cubature_points, defaults.elastic_cubature_points);
  EXPECT_EQ(none.inertial_cubature_points, defaults.inertial_cubature_points);
  EXPECT_EQ(presetReducedIterationBudget(Preset::None), 0);

  // The configuration measured in docs/benchmarks.md ("The real-time preset").
  const ReducedSettings realtime = presetReducedSettings(Preset::Realtime);
  EXPECT_EQ(realtime.basis_kind, ReducedBasisKind::Modes);
  EXPECT_EQ(realtime.modes.vibration_modes, 12);
  EXPECT_EQ(realtime.modes.columns, 24);
  EXPECT_EQ(realtime.elastic_cubature_points, 100);
  EXPECT_EQ(realtime.inertial_cubature_points, 100);
  EXPECT_EQ(realtime.training_samples, 400);
  EXPECT_EQ(realtime.modes.rotation_weight, 1.0);
  EXPECT_EQ(presetReducedIterationBudget(Preset::Realtime), 3);
}

}  // namespace
}  // namespace flsh
