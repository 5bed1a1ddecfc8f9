// A synthetic body in SMPL's format, for tests, examples and the default scene (real SMPL
// files are licensed and never ship with flsh).
//
// The surface is one closed, manifold, genus-0 triangle mesh (a smooth union of body parts:
// head, neck, torso, arms, hands, legs, feet) in a T-pose about 1.7 m tall, with SMPL's 24
// joints, names and parent table, smooth skinning weights, a joint regressor that reproduces
// the joint centres, shape directions with human meaning and corrective pose blend shapes.
// Deterministic: the same options give the same bytes.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "flsh/body/body_model.h"

namespace flsh {

/// Ranges of SyntheticBodyOptions that makeSyntheticBody accepts.
constexpr int kMinSyntheticVertices = 200;
constexpr int kMaxSyntheticVertices = 100000;
constexpr double kMinSyntheticHeight = 0.3;  ///< m
constexpr double kMaxSyntheticHeight = 3.0;  ///< m

struct SyntheticBodyOptions {
  /// Number of surface vertices (exact). SMPL's own count by default; ~1000 for fast tests.
  /// A closed genus-0 mesh with V vertices has 2V − 4 triangles (6890 → 13776).
  int vertices = 6890;
  /// Height of the mean shape standing in T-pose, m.
  double height = 1.70;
};

/// Meaning of the 10 shape directions of the synthetic body, in order (e.g. "height").
extern const std::vector<std::string> kSyntheticShapeNames;

/// Generates the synthetic body (finalized). Throws InputError for vertices outside
/// [kMinSyntheticVertices, kMaxSyntheticVertices] (200 … 100 000) or a height outside
/// [kMinSyntheticHeight, kMaxSyntheticHeight] (0.3 … 3 m).
BodyModel makeSyntheticBody(const SyntheticBodyOptions& options = {});

/// The synthetic body for `options`, generated once per process and shared (immutable): the
/// two most recently asked-for option sets are kept, so that the jobs of a batch worker or the
/// scenes run one after another in one program do not generate the same body again (0.7–0.9 s
/// at full size). Thread-safe; errors as makeSyntheticBody.
std::shared_ptr<const BodyModel> sharedSyntheticBody(const SyntheticBodyOptions& options = {});

}  // namespace flsh
