// Motions: AMASS-style `.npz` files and built-in procedural motions.
#pragma once

#include <string>
#include <vector>

#include "flsh/core/types.h"

namespace flsh {

/// A motion sequence, always in SMPL's 72-value pose layout and in flsh's world, whose up axis
/// is +y (docs/formats.md, "Motions"): loadMotion turns clips recorded z up (AMASS) upright.
struct Motion {
  RowMatX poses;      ///< T × 72 axis-angle joint rotations, rad
  RowMatX trans;      ///< T × 3 root translation, m
  VecX betas;         ///< shape coefficients stored with the motion (may be empty)
  double fps = 30.0;  ///< frames per second
  std::string gender; ///< as stored in the file ("" if absent)
  std::string source; ///< file path or "builtin:NAME"
  /// Up axis of the frame the source was recorded in, "y" or "z". The poses and translations
  /// above are in flsh's y-up world either way: a "z" clip was turned upright on loading
  /// (rotateMotion with worldFromUpAxis("z"), motion_frame.h).
  std::string up = "y";

  int numFrames() const { return int(poses.rows()); }
  double duration() const { return numFrames() > 1 ? (numFrames() - 1) / fps : 0.0; }
};

/// Reads an AMASS-style `.npz`: `poses` (T × 72 or T × 156), `trans` (T × 3), optional
/// `betas` (any length), `mocap_framerate` (or `mocap_frame_rate`, else 30 fps with a
/// warning on stderr), optional `gender`, optional `up` ("y" or "z").
///
/// The clip's up axis is `up` if given ("y" or "z"), else the file's `up` key, else "z": a
/// file without the key is an AMASS clip, recorded z up. A z-up clip is rotated into flsh's
/// y-up world about its root joint's rest position (rotateMotion). A warning goes to stderr
/// when the body is not upright at frame 0 in the world (uprightWarning), the usual sign of
/// a wrong up axis. Throws InputError naming the file, key and shapes.
Motion loadMotion(const std::string& path, const std::string& up = "");

/// Writes a motion as an AMASS-style `.npz` (poses T × 72) with its `up` key, atomically:
/// with `up` = "y" the motion as it is in flsh's world; with "z" turned into a z-up frame as
/// AMASS stores clips (the inverse of loadMotion's turn, so loadMotion reads it back).
void saveMotion(const Motion& motion, const std::string& path, const std::string& up = "y");

/// Names of the built-in procedural motions ("walk", "jumping_jacks", "arm_swings", …).
std::vector<std::string> builtinMotionNames();

/// A built-in motion, `seconds` long at `fps`. Throws InputError for an unknown name.
Motion makeBuiltinMotion(const std::string& name, double seconds = 2.0, double fps = 30.0);

/// Loads `spec` as a file path if it names an existing file (loadMotion with `up`), else as
/// "builtin:NAME" or NAME of a built-in motion (y up; a non-empty `up` other than "y" is then
/// an InputError).
Motion loadOrMakeMotion(const std::string& spec, double seconds = 2.0, double fps = 30.0,
                        const std::string& up = "");

}  // namespace flsh
