// Internal view of the synthetic body generator, for its tests: the model together with the
// joint centres it was designed with.
#pragma once

#include <array>

#include "flsh/body/smpl_skeleton.h"
#include "flsh/body/synthetic_body.h"

namespace flsh::synthetic {

struct SyntheticBodyBuild {
  BodyModel model;
  /// The designed joint centres of the template (SMPL order), m; the regressor reproduces them.
  std::array<Vec3, kNumJoints> joints;
};

/// makeSyntheticBody() with the designed joint centres.
SyntheticBodyBuild buildSyntheticBody(const SyntheticBodyOptions& options);

}  // namespace flsh::synthetic
