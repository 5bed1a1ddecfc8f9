// The small soft avatars the soft skeletons' tests share (tests/sim/soft, tests/diff): the FEM
// and the ROM on the 800-vertex synthetic body, built once per test binary.
#pragma once

#include <gtest/gtest.h>

#include <memory>
#include <string>

#include "flsh/volume/soft_avatar.h"
#include "support/test_support.h"

namespace flsh::test {

/// Rom: the handle basis; RomModes: modes and handles (ReducedBasisKind::ModesAndHandles).
enum class SoftModel { Fem, Rom, RomModes };

inline std::string modelName(const ::testing::TestParamInfo<SoftModel>& info) {
  return info.param == SoftModel::Fem ? "Fem" : info.param == SoftModel::Rom ? "Rom" : "RomModes";
}

/// The modal basis of the small tests' avatars: the static modes and 6 vibration modes,
/// compressed to 24 columns.
inline void useSmallModes(SoftAvatarSettings& s, ReducedBasisKind kind) {
  s.reduced.basis_kind = kind;
  s.reduced.modes.vibration_modes = 6;
  s.reduced.modes.columns = 24;
}

/// A new soft avatar of the 800-vertex synthetic body with settings `s`: the FEM (reduced
/// false) or the ROM with both cubatures, its volumetric data initialized.
inline std::shared_ptr<SoftAvatar> makeSmallSoftAvatar(const SoftAvatarSettings& s, bool reduced) {
  auto a = std::make_shared<SoftAvatar>(smallScene(800).body, VecX(), s);
  a->enableSoftTissue();
  a->enableReducedModel(reduced);
  a->enableElasticCubature(reduced);
  a->enableInertialCubature(reduced);
  a->initVolumetricData();
  return a;
}

/// Soft avatars of the 800-vertex synthetic body (coarse interior), built once per binary: the
/// FEM soft skeleton, and the ROM with both cubatures (16 handles, 60 tets each; RomModes with
/// the small modes too).
inline std::shared_ptr<const SoftAvatar> smallSoftAvatar(SoftModel model) {
  static const std::string cache = freshTempDir("soft_term_cache");
  auto make = [](SoftModel m) {
    SoftAvatarSettings s = smallSoftAvatarSettings(cache);
    if (m == SoftModel::RomModes) useSmallModes(s, ReducedBasisKind::ModesAndHandles);
    return makeSmallSoftAvatar(s, m != SoftModel::Fem);
  };
  static std::shared_ptr<const SoftAvatar> fem = make(SoftModel::Fem);
  if (model == SoftModel::Fem) return fem;
  if (model == SoftModel::Rom) {
    static std::shared_ptr<const SoftAvatar> rom = make(SoftModel::Rom);
    return rom;
  }
  static std::shared_ptr<const SoftAvatar> modes = make(SoftModel::RomModes);
  return modes;
}

}  // namespace flsh::test
