// Body regions of the soft tissue (issue 29, "The hands flop"; docs/materials.md, "Body
// regions"): region weights from the skinning weights, the blended region coefficients (smooth,
// log-linear in the parameters), the material file's "regions" (version 2; version 1 without
// them), and their effect on the volumetric body and its motion: hands mostly bone and stiff,
// the belly still soft.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>

#include "flsh/body/motion.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/core/error.h"
#include "flsh/solve/scene.h"
#include "flsh/volume/materials.h"
#include "flsh/volume/volumetric_data.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::messageOf;
using ::testing::HasSubstr;

int region(const std::string& name) {
  const auto& names = MaterialModel::regionNames();
  return int(std::find(names.begin(), names.end(), name) - names.begin());
}

std::shared_ptr<const BodyModel> smallBody() {
  static const std::shared_ptr<const BodyModel> body = [] {
    SyntheticBodyOptions options;
    options.vertices = 800;
    return std::make_shared<const BodyModel>(makeSyntheticBody(options));
  }();
  return body;
}

/// A material model whose regions all have coefficient 1 (no regional differences).
MaterialModel uniformModel(int K) {
  MaterialModel m = MaterialModel::defaults(K);
  for (int r = 0; r < MaterialModel::numRegions(); ++r)
    for (const auto& q : MaterialModel::regionQuantities())
      m.setCoefficient(q, MaterialModel::regionLevel(r), 1.0, VecX::Zero(K));
  return m;
}

TEST(BodyRegions, RegionWeightsSumToOneAndFollowTheSkinningWeights) {
  const BodyModel& body = *smallBody();
  const MatX omega = MaterialModel::regionWeights(body.weights);
  ASSERT_EQ(omega.rows(), body.numVertices());
  ASSERT_EQ(omega.cols(), MaterialModel::numRegions());
  EXPECT_GE(omega.minCoeff(), 0.0);
  EXPECT_LE((omega.rowwise().sum().array() - 1.0).abs().maxCoeff(), 1e-12);
  // SMPL's bones: wrists and hands → hands, ankles and toes → feet, neck and head → head, …
  EXPECT_EQ(MaterialModel::regionOfBone(20), region("hands"));
  EXPECT_EQ(MaterialModel::regionOfBone(23), region("hands"));
  EXPECT_EQ(MaterialModel::regionOfBone(10), region("feet"));
  EXPECT_EQ(MaterialModel::regionOfBone(15), region("head"));
  EXPECT_EQ(MaterialModel::regionOfBone(6), region("torso"));
  EXPECT_EQ(MaterialModel::regionOfBone(1), region("thighs"));
  EXPECT_EQ(MaterialModel::regionOfBone(16), region("upper_arms"));
  EXPECT_EQ(MaterialModel::regionOfBone(30), region("torso"));  // other skeletons
  int hand_vertices = 0;
  for (int v = 0; v < body.numVertices(); ++v) {
    int dominant = 0;
    body.weights.row(v).maxCoeff(&dominant);
    if (dominant == 22 || dominant == 23) {
      ++hand_vertices;
      EXPECT_GE(omega(v, region("hands")), 0.5) << v;
    }
  }
  EXPECT_GT(hand_vertices, 5);

  // Smooth across region borders: the default tissue_scale (0.2 on the hands, 1 on the upper
  // arms) blended at the vertices changes along an edge by no more than the weights do, never
  // by the whole step a hard switch would make; values between the regions' own exist.
  const MaterialModel m = MaterialModel::defaults(body.numBetas());
  const VecX scale = m.blendedRegionValue("tissue_scale", omega, VecX());
  const double full_step = std::log(1.0 / 0.2);
  double largest_jump = 0.0;
  int between = 0;
  for (int f = 0; f < body.numFaces(); ++f)
    for (int c = 0; c < 3; ++c) {
      const int i = body.faces(f, c), j = body.faces(f, (c + 1) % 3);
      const double jump = std::abs(std::log(scale[i]) - std::log(scale[j]));
      EXPECT_LE(jump, full_step * (omega.row(i) - omega.row(j)).cwiseAbs().sum() + 1e-12);
      largest_jump = std::max(largest_jump, jump);
    }
  for (int v = 0; v < body.numVertices(); ++v) between += scale[v] > 0.22 && scale[v] < 0.38;
  EXPECT_LT(largest_jump, 0.6 * full_step);
  EXPECT_GT(between, 0);
}

TEST(BodyRegions, DefaultsMakeHandsFeetAndHeadMostlyBoneAndStiff) {
  const MaterialModel m = MaterialModel::defaults(10);
  const VecX zero;
  for (const char* r : {"hands", "feet", "head"}) {
    EXPECT_LE(m.value("tissue_scale", MaterialModel::regionLevel(region(r)), zero), 0.25) << r;
    EXPECT_GE(m.value("stiffness_scale", MaterialModel::regionLevel(region(r)), zero), 5.0) << r;
  }
  for (const char* r : {"torso", "thighs", "upper_arms"}) {
    EXPECT_EQ(m.value("tissue_scale", MaterialModel::regionLevel(region(r)), zero), 1.0) << r;
    EXPECT_EQ(m.value("stiffness_scale", MaterialModel::regionLevel(region(r)), zero), 1.0) << r;
  }
  // The parameter vector holds the regions' coefficients after the body's: (22 + 2 + 16)(1 + K).
  EXPECT_EQ(m.numParameters(), 40 * 11);
  EXPECT_EQ(m.parameterOffset("tissue_scale", MaterialModel::regionLevel(0)), 24 * 11);
  EXPECT_THAT(
      messageOf<InputError>([&] { m.value("tissue_scale", MaterialModel::kBodyLevel, zero); }),
      HasSubstr("region quantity"));
}

TEST(BodyRegions, BlendedValueIsLogLinearInTheRegionCoefficients) {
  const MaterialModel m = MaterialModel::defaults(10);
  const VecX betas = test::randomVector(10, 1.0, 3);
  MatX omega = MatX::Zero(2, MaterialModel::numRegions());
  omega(0, region("hands")) = 0.7, omega(0, region("forearms")) = 0.3;
  omega(1, region("torso")) = 1.0;
  const VecX s = m.blendedRegionValue("stiffness_scale", omega, betas);
  const auto v = [&](const char* r) {
    return m.value("stiffness_scale", MaterialModel::regionLevel(region(r)), betas);
  };
  EXPECT_NEAR(s[0], std::pow(v("hands"), 0.7) * std::pow(v("forearms"), 0.3), 1e-12 * s[0]);
  EXPECT_EQ(s[1], v("torso"));
  // d log s / d(a_r, b_r) = ω_r (1, β): central differences over the parameter vector.
  const VecX p0 = m.parameters();
  for (const char* r : {"hands", "forearms", "torso"}) {
    const int offset = m.parameterOffset("stiffness_scale", MaterialModel::regionLevel(region(r)));
    for (int k = 0; k < 3; ++k) {
      const double h = 1e-6;
      VecX p = p0;
      p[offset + k] += h;
      MaterialModel plus = m;
      plus.setParameters(p);
      p[offset + k] -= 2 * h;
      MaterialModel minus = m;
      minus.setParameters(p);
      const double fd = (std::log(plus.blendedRegionValue("stiffness_scale", omega, betas)[0]) -
                         std::log(minus.blendedRegionValue("stiffness_scale", omega, betas)[0])) /
                        (2 * h);
      const double expected = omega(0, region(r)) * (k == 0 ? 1.0 : betas[k - 1]);
      EXPECT_NEAR(fd, expected, 1e-7) << r << " " << k;
    }
  }
  EXPECT_THAT(messageOf<InputError>([&] { m.blendedRegionValue("E1", omega, betas); }),
              HasSubstr("not a region quantity"));
  EXPECT_THAT(
      messageOf<InputError>([&] { m.blendedRegionValue("tissue_scale", MatX::Zero(1, 3), betas); }),
      HasSubstr("expected 8"));
}

TEST(BodyRegions, MaterialFileVersionTwoHasRegionsAndVersionOneLoadsUniform) {
  const std::string dir = test::freshTempDir("body_regions_files");
  const MaterialModel m = MaterialModel::defaults(10);
  nlohmann::json j = nlohmann::json::parse(m.canonicalText());
  EXPECT_EQ(j["version"], 2);
  EXPECT_EQ(j["regions"]["hands"]["tissue_scale"]["value"], 0.2);
  auto write = [&](const std::string& name, const nlohmann::json& content) {
    const std::string path = dir + "/" + name;
    std::ofstream(path) << content.dump(2);
    return path;
  };
  // Version 1 (the format before regions): no "regions" key; every region coefficient is 1.
  nlohmann::json v1 = j;
  v1.erase("regions");
  v1["version"] = 1;
  EXPECT_TRUE(MaterialModel::load(write("v1.json", v1), 10) == uniformModel(10));
  nlohmann::json v1_regions = j;
  v1_regions["version"] = 1;
  EXPECT_THAT(
      messageOf<InputError>([&] { MaterialModel::load(write("v1r.json", v1_regions), 10); }),
      HasSubstr("regions: unknown key"));
  // Version 2 requires every region and quantity, and nothing else.
  nlohmann::json missing = j;
  missing["regions"].erase("feet");
  EXPECT_THAT(messageOf<InputError>([&] { MaterialModel::load(write("m.json", missing), 10); }),
              HasSubstr("regions.feet: missing key"));
  nlohmann::json unknown = j;
  unknown["regions"]["hands"]["colour"] = 1;
  EXPECT_THAT(messageOf<InputError>([&] { MaterialModel::load(write("u.json", unknown), 10); }),
              HasSubstr("regions.hands.colour: unknown key"));
  // tissue_fraction (0.5) × tissue_scale must stay < 1.
  nlohmann::json thick = j;
  thick["regions"]["torso"]["tissue_scale"]["value"] = 2.5;
  EXPECT_THAT(messageOf<InputError>([&] { MaterialModel::load(write("t.json", thick), 10); }),
              HasSubstr("regions.torso.tissue_scale: 2.5 times body.tissue_fraction 0.5"));
  nlohmann::json later = j;
  later["version"] = 3;
  EXPECT_THAT(messageOf<InputError>([&] { MaterialModel::load(write("v3.json", later), 10); }),
              HasSubstr("version: expected 2 (or 1, without regions), got 3"));
  // Round trip of a version-2 file with changed region coefficients.
  MaterialModel changed = m;
  changed.setCoefficient("stiffness_scale", MaterialModel::regionLevel(region("head")), 7.5,
                         test::randomVector(10, 0.1, 5));
  changed.save(dir + "/changed.json");
  EXPECT_TRUE(MaterialModel::load(dir + "/changed.json", 10) == changed);
  EXPECT_NE(changed.canonicalText(), m.canonicalText());
}

// The volumetric body of the 800-vertex synthetic body (coarse interior), with the default
// materials, with regions switched off (every region coefficient 1), and with thin torso
// tissue (torso tissue_scale 0.3, every other region 1). The coarse interior has no interior
// node in the hands, feet or forearms (their surface anchors carry them), so the thin-tissue
// rule is checked on the torso, which has ~80 interior nodes.
struct TwoBodies {
  VolumetricData regional, uniform, thin_torso;
};
const TwoBodies& twoBodies() {
  static const TwoBodies bodies = [] {
    const std::string dir = test::freshTempDir("body_regions_volume");
    VolumetricSettings settings = test::smallSoftAvatarSettings(dir + "/cache").volumetric;
    TwoBodies b;
    b.regional = buildVolumetricData(*smallBody(), VecX(), settings);
    const int K = smallBody()->numBetas();
    uniformModel(K).save(dir + "/uniform.json");
    settings.material_file = dir + "/uniform.json";
    b.uniform = buildVolumetricData(*smallBody(), VecX(), settings);
    MaterialModel thin = uniformModel(K);
    thin.setCoefficient("tissue_scale", MaterialModel::regionLevel(region("torso")), 0.3,
                        VecX::Zero(K));
    thin.save(dir + "/thin_torso.json");
    settings.material_file = dir + "/thin_torso.json";
    b.thin_torso = buildVolumetricData(*smallBody(), VecX(), settings);
    return b;
  }();
  return bodies;
}

TEST(BodyRegions, ThinTissueMakesBoneNodesAndHandTissueIsStiffer) {
  const TwoBodies& b = twoBodies();
  const VolumetricData& d = b.regional;
  const MatX omega = MaterialModel::regionWeights(d.templ->fields.weights);
  const int V = smallBody()->numVertices(), N = d.numNodes();
  // The tissue thickness at the surface: ×0.2 on the hands, unchanged on the torso.
  int hand_vertices = 0, torso_vertices = 0;
  for (int v = 0; v < V; ++v) {
    if (omega(v, region("hands")) >= 1.0 - 1e-12) {
      ++hand_vertices;
      EXPECT_NEAR(d.tissue_thickness[v], 0.2 * b.uniform.tissue_thickness[v],
                  1e-9 * b.uniform.tissue_thickness[v])
          << v;
    }
    if (omega(v, region("torso")) == 1.0) {
      ++torso_vertices;
      EXPECT_EQ(d.tissue_thickness[v], b.uniform.tissue_thickness[v]) << v;
    }
  }
  EXPECT_GT(hand_vertices, 5);
  EXPECT_GT(torso_vertices, 5);
  // Thinner tissue makes more interior nodes bone nodes: the torso's interior with its
  // tissue_scale at 0.3 is mostly bone, with 1 (uniform) only about half of it is.
  auto boneShare = [&](const VolumetricData& data, const char* r) {
    int nodes = 0, bone = 0;
    for (int i = V; i < N; ++i)
      if (omega(i, region(r)) >= 0.9) ++nodes, bone += data.bone_of_node[i] >= 0;
    return std::pair<int, double>(nodes, nodes ? double(bone) / nodes : 0.0);
  };
  const auto [torso_nodes, thin_share] = boneShare(b.thin_torso, "torso");
  const double uniform_share = boneShare(b.uniform, "torso").second;
  ASSERT_GT(torso_nodes, 20);
  EXPECT_GE(thin_share, 0.8);
  EXPECT_LT(uniform_share, 0.7);
  // The default regions leave the torso's tissue as it is: only interior nodes whose nearest
  // surface point lies where the torso blends into the neck or the thighs may change role.
  EXPECT_NEAR(boneShare(d, "torso").second, uniform_share, 0.05);
  // Tets: the soft-tissue moduli scaled by the regions' stiffness_scale blended at the mean of
  // the tet's four node weights (×100 in the hands, ~1 in the torso; the interior's harmonic
  // weights are slightly positive on every bone, so no interior torso tet is exactly 1). The
  // shear moduli mix linearly in the skin fraction s, so every tet's differs from the uniform
  // body's by (1 − s)(k − 1) G_tissue.
  const TetMaterials& m = d.materials;
  const TetMaterials& u = b.uniform.materials;
  ASSERT_EQ(m.tissue_stiffness_scale.size(), d.numTets());
  const MaterialModel& model = d.material_model;
  VecX log_scale(MaterialModel::numRegions());
  for (int r = 0; r < MaterialModel::numRegions(); ++r)
    log_scale[r] = std::log(model.value("stiffness_scale", MaterialModel::regionLevel(r), VecX()));
  const Vec3 tissue_shear(model.value("G12", MaterialModel::kSoftTissue, VecX()),
                          model.value("G13", MaterialModel::kSoftTissue, VecX()),
                          model.value("G23", MaterialModel::kSoftTissue, VecX()));
  const double hand_scale = std::exp(log_scale[region("hands")]);
  const double largest_scale = std::exp(log_scale.maxCoeff());
  ASSERT_GE(hand_scale, 5.0);
  int hand_tets = 0, torso_tets = 0;
  for (int t = 0; t < d.numTets(); ++t) {
    VecX tet_omega = VecX::Zero(MaterialModel::numRegions());
    for (int k = 0; k < 4; ++k) tet_omega += 0.25 * omega.row(d.templ->mesh.tets(t, k)).transpose();
    const double k = m.tissue_stiffness_scale[t], s = m.skin_fraction[t];
    EXPECT_NEAR(k, std::exp(tet_omega.dot(log_scale)), 1e-12 * k) << t;
    EXPECT_GE(k, 1.0 - 1e-12);
    EXPECT_LE(k, largest_scale * (1 + 1e-12));
    const Vec3 shear_difference = (m.shear.row(t) - u.shear.row(t)).transpose();
    EXPECT_TRUE(shear_difference.isApprox((1 - s) * (k - 1) * tissue_shear, 1e-9) ||
                shear_difference.norm() <= 1e-9 * tissue_shear.norm())
        << t;
    EXPECT_EQ(m.density[t], u.density[t]) << t;  // density and ν are not scaled
    EXPECT_EQ(m.fung[t], u.fung[t]) << t;
    if (tet_omega[region("hands")] >= 1.0 - 1e-12) {
      ++hand_tets;
      EXPECT_NEAR(k, hand_scale, 1e-12 * hand_scale);
      if (s < 0.5) {  // mostly tissue: much stiffer in every direction
        EXPECT_GT(m.young.row(t).cwiseQuotient(u.young.row(t)).minCoeff(), 2.0) << t;
      }
    }
    if (tet_omega[region("torso")] >= 0.99) {
      ++torso_tets;
      EXPECT_LE(k, std::pow(largest_scale, 0.01) * (1 + 1e-12)) << t;
    }
  }
  EXPECT_GT(hand_tets, 0);
  EXPECT_GT(torso_tets, 10);
  EXPECT_NE(d.key, b.uniform.key);  // the cache tells them apart
}

TEST(BodyRegions, ShakingTheArmsMovesTheHandsMuchLessThanTheBelly) {
  // The small FEM avatar does jumping jacks for 0.5 s on the ground (h = 1/30 s). With uniform
  // tissue (a version-1 material file) its hands moved further than its belly (19.6 mm and
  // 17.4 mm, and this test failed); with the default regions the hands follow their bones to
  // within a millimetre (0.8 mm) while the torso still moves (17.0 mm).
  auto avatar = std::make_shared<SoftAvatar>(
      smallBody(), VecX(), test::smallSoftAvatarSettings(test::freshTempDir("body_regions_sim")));
  avatar->enableSoftTissue();
  avatar->initVolumetricData();
  auto motion = std::make_shared<Motion>(makeBuiltinMotion("jumping_jacks", 1.0, 30.0));
  SimulableOptions options;
  options.time_step = 1.0 / 30.0;
  auto sim = std::make_shared<Simulable>(avatar, motion, options);
  Scene scene;
  scene.addSimulable(sim);
  scene.initialize();
  scene.addCollider(
      Collider::plane(Vec3(0, sim->getNodes().col(1).minCoeff() - 0.002, 0), Vec3::UnitY()));
  const BodyModel& body = *smallBody();
  double hands = 0, torso = 0;
  for (int k = 0; k < 15; ++k) {
    const StepStats s = scene.step();
    EXPECT_TRUE(s.newton.converged) << k;
    const MatX3 u = sim->getSoftTissueDisplacements();
    for (int v = 0; v < body.numVertices(); ++v) {
      int dominant = 0;
      body.weights.row(v).maxCoeff(&dominant);
      const int r = MaterialModel::regionOfBone(dominant);
      if (r == region("hands")) hands = std::max(hands, u.row(v).norm());
      if (r == region("torso")) torso = std::max(torso, u.row(v).norm());
    }
  }
  EXPECT_GT(torso, 0.005) << "the belly should still move by millimetres to centimetres";
  EXPECT_LT(hands, 0.3 * torso) << "hands " << hands << " m, torso " << torso << " m";
  EXPECT_LT(hands, 0.005) << "issue 29's goal: hands within 5 mm of their bones";
}

}  // namespace
}  // namespace flsh
