// The avatar's per-tet coefficients to the elastic law's material point.
#include "flsh/volume/material_point.h"

#include <gtest/gtest.h>

#include <string>

#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::messageOf;

// Default skin and soft-tissue coefficients of docs/materials.md.
const Vec3 kSkinYoung(120e3, 80e3, 40e3), kSkinPoisson(0.42, 0.45, 0.45),
    kSkinShear(34e3, 24e3, 19e3);
const Vec3 kTissueYoung(15e3, 10e3, 10e3), kTissuePoisson(0.45, 0.45, 0.45),
    kTissueShear(4.2e3, 4.2e3, 3.4e3);

TEST(FemMaterialPoint, BuiltFromATetMaterialsRow) {
  TetMaterials materials;
  materials.young.resize(2, 3);
  materials.poisson.resize(2, 3);
  materials.shear.resize(2, 3);
  materials.fung.resize(2);
  materials.young << kSkinYoung.transpose(), kTissueYoung.transpose();
  materials.poisson << kSkinPoisson.transpose(), kTissuePoisson.transpose();
  materials.shear << kSkinShear.transpose(), kTissueShear.transpose();
  materials.fung << 8.0, 3.0;
  materials.frame = {rodrigues(Vec3(0.3, -1.2, 2.0)), rodrigues(Vec3(-2.1, 0.4, 0.7))};
  const FemMaterialPoint m = femMaterialPoint(materials, 1);
  EXPECT_LT((m.C - orthotropicStiffness(kTissueYoung, kTissuePoisson, kTissueShear))
                .cwiseAbs()
                .maxCoeff(),
            1e-9);
  EXPECT_EQ(m.frame, materials.frame[1]);
  EXPECT_DOUBLE_EQ(m.modulus, kTissueYoung.sum() / 3.0);
  EXPECT_EQ(m.gamma, 3.0);

  const std::string range = messageOf<InputError>([&] { femMaterialPoint(materials, 2); });
  EXPECT_NE(range.find("tet 2"), std::string::npos) << range;
  EXPECT_NE(range.find("young"), std::string::npos) << range;

  TetMaterials bad_frame = materials;
  bad_frame.frame[0] = 2.0 * Mat3::Identity();
  const std::string frame = messageOf<InputError>([&] { femMaterialPoint(bad_frame, 0); });
  EXPECT_NE(frame.find("tet 0"), std::string::npos) << frame;
  EXPECT_NE(frame.find("orthonormal"), std::string::npos) << frame;

  TetMaterials reflected = materials;
  reflected.frame[0] = -Mat3::Identity();
  EXPECT_THROW(femMaterialPoint(reflected, 0), InputError);

  TetMaterials bad_gamma = materials;
  bad_gamma.fung[1] = -1.0;
  const std::string gamma = messageOf<InputError>([&] { femMaterialPoint(bad_gamma, 1); });
  EXPECT_NE(gamma.find("gamma"), std::string::npos) << gamma;
}

}  // namespace
}  // namespace flsh
