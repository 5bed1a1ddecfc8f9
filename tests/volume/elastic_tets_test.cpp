// The elastic tets of a volumetric body (volume/elastic_tets.h): which tets are kept, their
// rest data against the material law's own functions, the order of a given list, and the
// error for a tet outside the mesh.
#include "flsh/volume/elastic_tets.h"

#include <gtest/gtest.h>

#include "flsh/core/error.h"
#include "flsh/volume/material_point.h"
#include "flsh/volume/soft_avatar.h"
#include "flsh/volume/tet_mesh.h"
#include "support/test_support.h"

namespace flsh {
namespace {

const VolumetricData& volume() {
  static std::shared_ptr<const SoftAvatar> avatar = [] {
    auto a = std::make_shared<SoftAvatar>(
        test::smallScene(800).body, VecX(),
        test::smallSoftAvatarSettings(test::freshTempDir("elastic_tets_cache")));
    a->enableSoftTissue();
    a->initVolumetricData();
    return a;
  }();
  return avatar->volumetricData();
}

TEST(ElasticTets, DeformableTetsAreExactlyThoseWithASoftNode) {
  const VolumetricData& data = volume();
  const MatX4i& tets = data.templ->mesh.tets;
  const ElasticTets kept = deformableTets(data);
  ASSERT_GT(kept.size(), 0);
  int bone_only = 0;
  std::vector<int> expected;
  for (int t = 0; t < int(tets.rows()); ++t) {
    bool soft = false;
    for (int a = 0; a < 4; ++a) soft = soft || data.bone_of_node[tets(t, a)] < 0;
    EXPECT_EQ(tetHasSoftNode(data, t), soft);
    if (soft)
      expected.push_back(t);
    else
      ++bone_only;
  }
  EXPECT_GT(bone_only, 0) << "the small body should have tets of bone nodes only";
  EXPECT_EQ(kept.tets, expected);
  ASSERT_EQ(kept.rest.size(), expected.size());
  ASSERT_EQ(kept.materials.size(), expected.size());
}

TEST(ElasticTets, RestDataAreTheLawsAtTheRestNodesInTheGivenOrder) {
  const VolumetricData& data = volume();
  const MatX4i& tets = data.templ->mesh.tets;
  const std::vector<int> list = {int(tets.rows()) - 1, 0, 7, 7};
  const ElasticTets out = elasticTets(data, list);
  ASSERT_EQ(out.tets, list);
  for (int k = 0; k < out.size(); ++k) {
    const int t = list[size_t(k)];
    Mat34 X;
    for (int a = 0; a < 4; ++a) X.col(a) = data.rest_nodes.row(tets(t, a)).transpose();
    const TetElementRest rest = tetElementRest(X, t);
    EXPECT_EQ(out.rest[size_t(k)].volume, rest.volume);
    EXPECT_EQ((out.rest[size_t(k)].Dm_inv - rest.Dm_inv).norm(), 0.0);
    const FemMaterialPoint m = femMaterialPoint(data.materials, t);
    EXPECT_EQ((out.materials[size_t(k)].C_world - m.C_world).norm(), 0.0);
    EXPECT_EQ(out.materials[size_t(k)].gamma, m.gamma);
  }
}

TEST(ElasticTets, ATetOutsideTheMeshIsAnInputErrorNamingIt) {
  const VolumetricData& data = volume();
  const int n = int(data.templ->mesh.tets.rows());
  const std::string message = test::messageOf<InputError>([&] {
    elasticTets(data, {0, n}, "my elastic cubature");
  });
  EXPECT_NE(message.find("my elastic cubature"), std::string::npos) << message;
  EXPECT_NE(message.find(std::to_string(n)), std::string::npos) << message;
  EXPECT_THROW(elasticTets(data, {-1}), InputError);
}

}  // namespace
}  // namespace flsh
