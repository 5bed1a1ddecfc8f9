// Named bundles of settings, one switch for a whole trade: the scene key "preset", `flsh avatar
// --preset` and Python's SoftAvatar(preset=...). A preset fills in defaults; settings given
// explicitly next to it win.
#pragma once

#include <string>

#include "flsh/volume/reduced_data.h"

namespace flsh {

enum class Preset {
  None,  ///< the library's defaults
  /// The ROM for real time (issue 26): the static modes and 12 vibration modes compressed to 24
  /// columns (rotation weight 1), 100 sample tets per cubature trained on 400 samples, and a
  /// budget of 3 Newton iterations per step (after the bones' presolve) instead of a tolerance.
  /// Measured on the full-size walk with ground contact: 13.6 % of the FEM's soft-tissue
  /// displacement off (jumping jacks 23 %, ball 16 %), the budget 0.002 mm from a 1e-9 solve;
  /// 570–700 steps/s on the 2-core machine (libgomp's default spinning wait), 300–460 on a
  /// busier one (docs/benchmarks.md "The real-time preset").
  Realtime,
};

/// "none" or "realtime".
const char* presetName(Preset preset);
/// The preset of a presetName; InputError naming `where` and the known names otherwise.
Preset parsePreset(const std::string& name, const std::string& where);

/// The ROM's settings under `preset` (None: ReducedSettings()).
ReducedSettings presetReducedSettings(Preset preset);

/// Newton iterations per step of the ROM's solver under `preset`, a budget whose end is not a
/// failure (NewtonResult::max_iterations_reached; the step keeps its last iterate and is not a
/// minimum, so the adjoint refuses it); 0: none (the solver's max_iterations and tolerance).
int presetReducedIterationBudget(Preset preset);

}  // namespace flsh
