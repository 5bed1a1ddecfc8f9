// Triangle meshes on disk: PLY (binary little-endian or ASCII, optional per-vertex colours)
// and OBJ. Writes are atomic.
#pragma once

#include <string>

#include "flsh/core/types.h"

namespace flsh::io {

/// Per-vertex RGB colours in [0, 1], #V × 3 (empty = none).
using Colors = MatX3;

void writePly(const std::string& path, const Eigen::Ref<const MatX3>& V,
              const Eigen::Ref<const MatX3i>& F, const Colors& colors = Colors(),
              bool binary = true);
void writeObj(const std::string& path, const Eigen::Ref<const MatX3>& V,
              const Eigen::Ref<const MatX3i>& F);

/// Reads a triangle mesh written by writePly/writeObj (or any PLY with float/double vertex
/// x,y,z and triangle faces, or OBJ with v/f lines). Throws InputError on malformed input.
void readMesh(const std::string& path, MatX3& V, MatX3i& F);

}  // namespace flsh::io
