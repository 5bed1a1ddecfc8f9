// The small soft avatars the soft skeletons' tests share (tests/sim/soft, tests/diff): the FEM
// and the ROM on the 800-vertex synthetic body, built once per test binary.
#pragma once

#include <gtest/gtest.h>

#include <memory>
#include <string>

#include "flsh/volume/soft_avatar.h"
#include "support/test_support.h"

namespace flsh::test {

enum class SoftModel { Fem, Rom };

inline std::string modelName(const ::testing::TestParamInfo<SoftModel>& info) {
  return info.param == SoftModel::Fem ? "Fem" : "Rom";
}

/// Soft avatars of the 800-vertex synthetic body (coarse interior), built once per binary: the
/// FEM soft skeleton, and the ROM with both cubatures (16 handles, 60 tets each).
inline std::shared_ptr<const SoftAvatar> smallSoftAvatar(SoftModel model) {
  static const std::string cache = freshTempDir("soft_term_cache");
  auto make = [](bool reduced) {
    auto a =
        std::make_shared<SoftAvatar>(smallScene(800).body, VecX(), smallSoftAvatarSettings(cache));
    a->enableSoftTissue();
    a->enableReducedModel(reduced);
    a->enableElasticCubature(reduced);
    a->enableInertialCubature(reduced);
    a->initVolumetricData();
    return a;
  };
  static std::shared_ptr<const SoftAvatar> fem = make(false);
  if (model == SoftModel::Fem) return fem;
  static std::shared_ptr<const SoftAvatar> rom = make(true);
  return rom;
}

}  // namespace flsh::test
