// Motions: AMASS-style `.npz` files and built-in procedural motions.
#pragma once

#include <string>
#include <vector>

#include "flsh/core/types.h"

namespace flsh {

/// A motion sequence, always in SMPL's 72-value pose layout.
struct Motion {
  RowMatX poses;      ///< T × 72 axis-angle joint rotations, rad
  RowMatX trans;      ///< T × 3 root translation, m
  VecX betas;         ///< shape coefficients stored with the motion (may be empty)
  double fps = 30.0;  ///< frames per second
  std::string gender; ///< as stored in the file ("" if absent)
  std::string source; ///< file path or "builtin:NAME"

  int numFrames() const { return int(poses.rows()); }
  double duration() const { return numFrames() > 1 ? (numFrames() - 1) / fps : 0.0; }
};

/// Reads an AMASS-style `.npz`: `poses` (T × 72 or T × 156), `trans` (T × 3), optional
/// `betas` (any length), `mocap_framerate` (or `mocap_frame_rate`, else 30 fps with a
/// warning on stderr), optional `gender`. Throws InputError naming the file, key and shapes.
Motion loadMotion(const std::string& path);

/// Writes a motion as an AMASS-style `.npz` (poses T × 72), atomically.
void saveMotion(const Motion& motion, const std::string& path);

/// Names of the built-in procedural motions ("walk", "jumping_jacks", "arm_swings", …).
std::vector<std::string> builtinMotionNames();

/// A built-in motion, `seconds` long at `fps`. Throws InputError for an unknown name.
Motion makeBuiltinMotion(const std::string& name, double seconds = 2.0, double fps = 30.0);

/// Loads `spec` as a file path if it names an existing file, else as "builtin:NAME" or NAME
/// of a built-in motion.
Motion loadOrMakeMotion(const std::string& spec, double seconds = 2.0, double fps = 30.0);

}  // namespace flsh
