// The material model (defaults, log-linear evaluation and its gradient, JSON round trip, strict
// loading) and per-tet materials on a structured limb (frames, layers, β dependence).
#include "flsh/volume/materials.h"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <functional>

#include "flsh/core/error.h"
#include "flsh/volume/volume_fields.h"
#include "support/test_support.h"
#include "volume/volume_test_meshes.h"

namespace flsh {
namespace {

using test::messageOf;
constexpr int kSkin = MaterialModel::kSkin, kTissue = MaterialModel::kSoftTissue,
              kBody = MaterialModel::kBodyLevel;

TEST(MaterialModel, DefaultsArePlausibleHumanTissue) {
  const MaterialModel m = MaterialModel::defaults(10);
  const VecX zero;
  for (int layer : {kSkin, kTissue}) {
    EXPECT_GE(m.value("density", layer, zero), 1000.0);
    EXPECT_LE(m.value("density", layer, zero), 1070.0);
    for (const char* q : {"E1", "E2", "E3", "G12", "G13", "G23"}) {
      EXPECT_GE(m.value(q, layer, zero), 1e3) << q;
      EXPECT_LT(m.value(q, layer, zero), 1e6) << q;
    }
    for (const char* q : {"nu12", "nu13", "nu23"}) {
      EXPECT_GE(m.value(q, layer, zero), 0.4) << q;
      EXPECT_LE(m.value(q, layer, zero), 0.48) << q;
    }
    EXPECT_GE(m.value("fung_gamma", layer, zero), 1.0);
    EXPECT_LE(m.value("fung_gamma", layer, zero), 10.0);
    EXPECT_GT(m.value("E1", layer, zero), m.value("E2", layer, zero));  // stiffer along the bone
  }
  for (const char* q : {"E1", "E2", "E3"})
    EXPECT_GT(m.value(q, kSkin, zero), 2 * m.value(q, kTissue, zero)) << q;  // skin is stiffer
  EXPECT_GE(m.value("skin_thickness", kBody, zero), 0.0015);
  EXPECT_LE(m.value("skin_thickness", kBody, zero), 0.003);
  EXPECT_GT(m.value("tissue_fraction", kBody, zero), 0.2);
  EXPECT_LT(m.value("tissue_fraction", kBody, zero), 0.8);

  // A heavier body (β₁ = weight) has softer, thicker tissue; the shape stays physical at ±3.
  VecX heavy = VecX::Zero(10);
  heavy[1] = 2;
  EXPECT_LT(m.value("E2", kTissue, heavy), m.value("E2", kTissue, zero));
  EXPECT_GT(m.value("tissue_fraction", kBody, heavy), m.value("tissue_fraction", kBody, zero));
  EXPECT_GT(m.value("skin_thickness", kBody, heavy), m.value("skin_thickness", kBody, zero));
  for (double b : {-3.0, 3.0}) {
    VecX betas = VecX::Constant(10, b);
    EXPECT_NO_THROW(m.validate("defaults", betas)) << b;
  }
  // Fewer shape components: the same values at β = 0, slopes truncated.
  EXPECT_EQ(MaterialModel::defaults(1).value("E1", kTissue, VecX()), m.value("E1", kTissue, zero));
  // 22 layered + 2 body + 8 regions × 2 coefficients (issue 29's body regions).
  EXPECT_EQ(MaterialModel::defaults(0).numParameters(), 40);
}

TEST(MaterialModel, LogLinearValueAndGradient) {
  MaterialModel m = MaterialModel::defaults(10);
  const VecX betas = test::randomVector(10, 1.5, 4);
  for (const auto& [q, layer] : std::vector<std::pair<std::string, int>>{
           {"E1", kTissue},
           {"nu23", kSkin},
           {"skin_thickness", kBody},
           {"tissue_scale", MaterialModel::regionLevel(3)},
           {"stiffness_scale", MaterialModel::regionLevel(7)}}) {
    EXPECT_EQ(m.value(q, layer, VecX::Zero(10)), m.baseValue(q, layer));
    EXPECT_NEAR(m.value(q, layer, betas),
                m.baseValue(q, layer) * std::exp(m.logSlopes(q, layer).dot(betas)),
                1e-12 * m.baseValue(q, layer));
    // d value / d (a, b) against central differences over the parameter vector.
    const int offset = m.parameterOffset(q, layer);
    const VecX p0 = m.parameters();
    auto f = [&, q = q, layer = layer](const VecX& local) {
      MaterialModel copy = m;
      VecX p = p0;
      p.segment(offset, 11) = local;
      copy.setParameters(p);
      return VecX::Constant(1, copy.value(q, layer, betas));
    };
    const MatX analytic = m.valueGradient(q, layer, betas).transpose();
    EXPECT_TRUE(
        test::jacobianMatchesFiniteDifferences(f, p0.segment(offset, 11), analytic, 1e-6, 1e-7))
        << q;
  }
  // Parameters round trip.
  MaterialModel copy = MaterialModel::defaults(10);
  VecX p = m.parameters();
  p[m.parameterOffset("G13", kSkin) + 3] = 0.25;
  copy.setParameters(p);
  EXPECT_EQ(copy.logSlopes("G13", kSkin)[2], 0.25);
  EXPECT_LE((copy.parameters() - p).cwiseAbs().maxCoeff(), 1e-14);
  // Unknown quantities and wrong layers are named.
  std::string message = messageOf<InputError>([&] { m.value("E4", kSkin, betas); });
  EXPECT_NE(message.find("'E4'"), std::string::npos) << message;
  message = messageOf<InputError>([&] { m.value("E1", kBody, betas); });
  EXPECT_NE(message.find("layer"), std::string::npos) << message;
  message = messageOf<InputError>([&] { m.value("tissue_fraction", kSkin, betas); });
  EXPECT_NE(message.find("body-level"), std::string::npos) << message;
  message = messageOf<InputError>([&] { m.value("E1", kSkin, VecX::Zero(12)); });
  EXPECT_NE(message.find("betas has 12"), std::string::npos) << message;
  // Non-physical parameters are refused and leave the model unchanged.
  VecX bad = m.parameters();
  bad[m.parameterOffset("nu12", kTissue)] = std::log(0.55);
  message = messageOf<InputError>([&] { m.setParameters(bad); });
  EXPECT_NE(message.find("nu12"), std::string::npos) << message;
  EXPECT_TRUE(m == MaterialModel::defaults(10));
}

TEST(MaterialModel, JsonRoundTripIsExact) {
  MaterialModel m = MaterialModel::defaults(10);
  VecX slopes = test::randomVector(10, 0.1, 9);
  m.setCoefficient("E3", kTissue, 12345.678901234567, slopes);
  m.setCoefficient("fung_gamma", kSkin, 1.0 / 3.0, slopes);
  const std::string path = test::freshTempDir("materials") + "/model.json";
  m.save(path);
  const MaterialModel loaded = MaterialModel::load(path, 10);
  EXPECT_TRUE(loaded == m);
  EXPECT_EQ(loaded.canonicalText(), m.canonicalText());
  EXPECT_EQ(loaded.parameters(), m.parameters());
  // Canonical text is deterministic and changes with any coefficient.
  EXPECT_EQ(m.canonicalText(), MaterialModel::fromText(m.canonicalText(), 10).canonicalText());
  MaterialModel other = m;
  other.setCoefficient("E3", kTissue, std::nextafter(12345.678901234567, 2e4), slopes);
  EXPECT_NE(other.canonicalText(), m.canonicalText());
  // A body with more shape components zero-pads the slopes; fewer is fine if the extra are 0.
  const MaterialModel wide = MaterialModel::load(path, 16);
  EXPECT_EQ(wide.logSlopes("E3", kTissue).head(10), slopes);
  EXPECT_TRUE(wide.logSlopes("E3", kTissue).tail(6).isZero());
  const std::string defaults_path = test::freshTempDir("materials_narrow") + "/defaults.json";
  MaterialModel::defaults(10).save(defaults_path);
  EXPECT_TRUE(MaterialModel::load(defaults_path, 2) == MaterialModel::defaults(2));
}

TEST(MaterialModel, ShippedDefaultFileEqualsTheDefaults) {
  const std::string path = std::string(FLSH_SOURCE_DIR) + "/data/materials/default.json";
  EXPECT_TRUE(MaterialModel::load(path, 10) == MaterialModel::defaults(10));
  std::ifstream in(path);
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(text, MaterialModel::defaults(10).canonicalText());
}

/// Loads the default file edited by `edit` (a text replacement), returns the InputError message.
std::string loadError(const std::string& name, const std::string& from, const std::string& to,
                      int num_betas = 10) {
  std::string text = MaterialModel::defaults(10).canonicalText();
  const size_t at = text.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  if (at != std::string::npos) text.replace(at, from.size(), to);
  const std::string path = test::freshTempDir("materials_bad_" + name) + "/bad.json";
  std::ofstream(path) << text;
  const std::string message = messageOf<InputError>([&] { MaterialModel::load(path, num_betas); });
  EXPECT_NE(message.find(path), std::string::npos) << message;
  return message;
}

TEST(MaterialModel, MalformedFilesAreRejectedWithClearMessages) {
  // Section "body" comes first in the sorted text; "layers.skin" before "layers.soft_tissue".
  std::string m = loadError("unknown", "\"format\"", "\"colour\": 1, \"format\"");
  EXPECT_NE(m.find("colour: unknown key"), std::string::npos) << m;
  m = loadError("missing", "\"skin_thickness\"", "\"skin_thicknes\"");
  EXPECT_NE(m.find("body.skin_thickness: missing key"), std::string::npos) << m;
  m = loadError("missing_value", "\"value\": 0.002", "\"val\": 0.002");
  EXPECT_NE(m.find("body.skin_thickness"), std::string::npos) << m;
  m = loadError("type", "\"value\": 0.002", "\"value\": \"2 mm\"");
  EXPECT_NE(m.find("body.skin_thickness.value: expected a number, got string"), std::string::npos)
      << m;
  m = loadError("nonfinite", "\"value\": 0.002", "\"value\": 1e999");  // the parser refuses it
  EXPECT_NE(m.find("1e999"), std::string::npos) << m;
  m = loadError("units", "\"value\": 0.002", "\"value\": 2.0");
  EXPECT_NE(m.find("skin_thickness: 2 m"), std::string::npos) << m;
  m = loadError("negative", "\"value\": 1070.0", "\"value\": -1070.0");
  EXPECT_NE(m.find("layers.skin.density.value"), std::string::npos) << m;
  m = loadError("poisson", "\"value\": 0.42", "\"value\": 0.5");
  EXPECT_NE(m.find("layers.skin.nu12: Poisson ratio 0.5"), std::string::npos) << m;
  // Skin ν12 = 0.42 with E2 = 800 kPa violates ν12² < E1/E2 = 0.15 (ν < 0.5 itself is fine).
  m = loadError("compliance", "\"value\": 80000.0", "\"value\": 800000.0");
  EXPECT_NE(m.find("layers.skin.E1..E3, nu12..nu23: orthotropic compliance is not positive"),
            std::string::npos)
      << m;
  m = loadError("fraction", "\"value\": 0.5", "\"value\": 1.2");
  EXPECT_NE(m.find("body.tissue_fraction"), std::string::npos) << m;
  m = loadError("slopes_type", "\"log_slopes\": [", "\"log_slopes\": [\"a\", ");
  EXPECT_NE(m.find("log_slopes[0]: expected a number"), std::string::npos) << m;
  // A non-zero slope beyond the body's components: the default β₁ slope with a 1-β body.
  m = loadError("slopes_size", "\"format\"", "\"format\"", 1);
  EXPECT_NE(m.find("non-zero one at index 1"), std::string::npos) << m;
  m = loadError("version", "\"version\": 2", "\"version\": 3");
  EXPECT_NE(m.find("version: expected 2"), std::string::npos) << m;
  m = loadError("json", "{", "{{");
  EXPECT_NE(m.find("not valid JSON"), std::string::npos) << m;
  const std::string missing = test::freshTempDir("materials_missing") + "/none.json";
  m = messageOf<FileError>([&] { MaterialModel::load(missing, 10); });
  EXPECT_NE(m.find(missing), std::string::npos) << m;
}

// -------------------------------------------------------------------------------------------
// Per-tet materials on the limb

struct LimbMaterials {
  test::Limb limb = test::makeLimb();
  MaterialModel model = MaterialModel::defaults(10);
  TetMaterials at(const VecX& betas) const {
    return computeTetMaterials(limb.mesh, limb.mesh.nodes, limb.weights, limb.joints, limb.parents,
                               model, betas);
  }
};

TEST(TetMaterials, MeanShapeValuesFramesAndLayers) {
  const LimbMaterials lm;
  const TetMaterials m = lm.at(VecX());
  const int nt = lm.limb.mesh.numTets();
  ASSERT_EQ(m.density.size(), nt);
  ASSERT_EQ(int(m.frame.size()), nt);
  ASSERT_EQ(m.young.rows(), nt);
  int pure_tissue = 0, mixed = 0;
  const VecX volumes = [&] {
    VecX v(nt);
    for (int t = 0; t < nt; ++t) {
      const auto& X = lm.limb.mesh.nodes;
      const auto& T = lm.limb.mesh.tets;
      const Vec3 x0 = X.row(T(t, 0));
      v[t] = (X.row(T(t, 1)).transpose() - x0)
                 .cross(X.row(T(t, 2)).transpose() - x0)
                 .dot(X.row(T(t, 3)).transpose() - x0) /
             6;
    }
    return v;
  }();
  double skin_volume = 0;
  for (int t = 0; t < nt; ++t) {
    const Mat3& A = m.frame[t];
    ASSERT_TRUE(A.allFinite()) << t;
    EXPECT_LE((A.transpose() * A - Mat3::Identity()).cwiseAbs().maxCoeff(), 1e-12) << t;
    EXPECT_NEAR(A.determinant(), 1.0, 1e-12) << t;
    EXPECT_GE(m.skin_fraction[t], 0.0);
    EXPECT_LE(m.skin_fraction[t], 1.0);
    skin_volume += m.skin_fraction[t] * volumes[t];
    if (m.skin_fraction[t] == 0) {
      ++pure_tissue;
      // exp(a) at β = 0, exactly.
      EXPECT_EQ(m.density[t], lm.model.baseValue("density", kTissue));
      EXPECT_EQ(m.young(t, 0), lm.model.baseValue("E1", kTissue));
      EXPECT_EQ(m.poisson(t, 2), lm.model.baseValue("nu23", kTissue));
      EXPECT_EQ(m.shear(t, 1), lm.model.baseValue("G13", kTissue));
      EXPECT_EQ(m.fung[t], lm.model.baseValue("fung_gamma", kTissue));
      EXPECT_EQ(m.layer[t], kTissue);
    } else {
      ++mixed;
      // A mixture lies between the layers.
      EXPECT_GT(m.density[t], lm.model.baseValue("density", kTissue));
      EXPECT_LT(m.density[t], lm.model.baseValue("density", kSkin));
      for (int c = 0; c < 3; ++c) {
        EXPECT_GT(m.young(t, c), lm.model.baseValue("E" + std::to_string(c + 1), kTissue) * 0.999);
        EXPECT_LT(m.young(t, c), lm.model.baseValue("E" + std::to_string(c + 1), kSkin));
      }
      EXPECT_EQ(m.layer[t], m.skin_fraction[t] >= 0.5 ? kSkin : kTissue);
    }
  }
  EXPECT_GT(pure_tissue, nt / 4);
  EXPECT_GT(mixed, 0);
  // The skin volume is the surface area times skin_thickness: the shell under the limb's
  // surface to O(t²).
  const double t = lm.model.baseValue("skin_thickness", kBody);
  const Vec3 size = lm.limb.size;
  const double area = 2 * (size.x() * size.y() + size.y() * size.z() + size.z() * size.x());
  EXPECT_NEAR(skin_volume, area * t, 1e-12 * area * t);
  const double shell = size.prod() - (size.array() - 2 * t).prod();
  EXPECT_NEAR(skin_volume, shell, 0.03 * shell);
}

TEST(TetMaterials, FramesFollowTheNormalAndTheBone) {
  const LimbMaterials lm;
  const TetMaterials m = lm.at(VecX());
  const auto& X = lm.limb.mesh.nodes;
  int side_checked = 0, cap_checked = 0;
  for (int t = 0; t < lm.limb.mesh.numTets(); ++t) {
    Vec3 c = Vec3::Zero();
    for (int k = 0; k < 4; ++k) c += X.row(lm.limb.mesh.tets(t, k)).transpose() / 4;
    const Mat3& A = m.frame[t];
    // Tets near the middle of the −x side: a3 = +x (inward), a1 along the bone (z).
    if (c.x() < -0.05 && std::abs(c.y()) < 0.03 && c.z() > 0.08 && c.z() < 0.32) {
      EXPECT_GT(A.col(2).x(), 0.999) << A;
      EXPECT_GT(std::abs(A.col(0).z()), 0.999) << A;
      ++side_checked;
    }
    // Tets near the bottom cap: the bone axis is parallel to the normal; a frame still exists.
    if (c.z() < 0.01 && std::abs(c.x()) < 0.03 && std::abs(c.y()) < 0.03) {
      EXPECT_GT(A.col(2).z(), 0.999) << A;
      EXPECT_LT(std::abs(A.col(0).z()), 1e-9) << A;
      ++cap_checked;
    }
  }
  EXPECT_GT(side_checked, 0);
  EXPECT_GT(cap_checked, 0);
}

TEST(TetMaterials, DistinctShapesGetDistinctTissue) {
  const LimbMaterials lm;
  VecX slim = VecX::Zero(10), heavy = VecX::Zero(10);
  slim[1] = -1.5;
  heavy[1] = 2.0;
  const TetMaterials a = lm.at(slim), b = lm.at(heavy);
  int softer = 0, inner = 0;  // tets without skin in either shape
  for (int t = 0; t < lm.limb.mesh.numTets(); ++t)
    if (a.skin_fraction[t] == 0 && b.skin_fraction[t] == 0)
      ++inner, softer += b.young(t, 1) < a.young(t, 1);
  EXPECT_GT(inner, 0);
  EXPECT_EQ(softer, inner);
  EXPECT_GT((a.density - b.density).cwiseAbs().maxCoeff(), 1.0);
  EXPECT_GT(b.skin_fraction.sum(), a.skin_fraction.sum());  // thicker skin
  // Deterministic (parallel loop).
  const TetMaterials again = lm.at(heavy);
  EXPECT_TRUE(again.young == b.young && again.skin_fraction == b.skin_fraction);
}

TEST(TetMaterials, RejectsBadInput) {
  const LimbMaterials lm;
  std::string message = messageOf<InputError>([&] {
    computeTetMaterials(lm.limb.mesh, lm.limb.mesh.nodes, lm.limb.weights.topRows(5),
                        lm.limb.joints, lm.limb.parents, lm.model, VecX());
  });
  EXPECT_NE(message.find("weights has shape"), std::string::npos) << message;
  // Poisson slopes that leave the physical range at this β.
  MaterialModel steep = lm.model;
  VecX slopes = VecX::Zero(10);
  slopes[2] = 0.5;
  steep.setCoefficient("nu12", kTissue, 0.45, slopes);
  VecX betas = VecX::Zero(10);
  betas[2] = 1.0;
  message = messageOf<InputError>([&] {
    computeTetMaterials(lm.limb.mesh, lm.limb.mesh.nodes, lm.limb.weights, lm.limb.joints,
                        lm.limb.parents, steep, betas);
  });
  EXPECT_NE(message.find("nu12"), std::string::npos) << message;
}

TEST(TetMaterials, AShapeThatInvertsASliverStillGetsFiniteMaterials) {
  // X̄₀ + S β can flip a sliver at large β: materials and bone nodes stay defined (the
  // simulation reports the inversion).
  LimbMaterials lm;
  MatX3 X = lm.limb.mesh.nodes;
  const int moved = lm.limb.mesh.num_surface_nodes + 40;  // an interior node
  X(moved, 0) += 0.03;                                    // 1.5 cells: its tets invert
  int inverted = 0;
  for (int t = 0; t < lm.limb.mesh.numTets(); ++t) {
    const auto& T = lm.limb.mesh.tets;
    const Vec3 x0 = X.row(T(t, 0));
    inverted += (X.row(T(t, 1)).transpose() - x0)
                    .cross(X.row(T(t, 2)).transpose() - x0)
                    .dot(X.row(T(t, 3)).transpose() - x0) < 0;
  }
  ASSERT_GT(inverted, 0);
  const TetMaterials m = computeTetMaterials(lm.limb.mesh, X, lm.limb.weights, lm.limb.joints,
                                             lm.limb.parents, lm.model, VecX());
  EXPECT_TRUE(m.young.allFinite() && m.poisson.allFinite() && m.density.allFinite());
  EXPECT_GE(m.skin_fraction.minCoeff(), 0.0);
  EXPECT_LE(m.skin_fraction.maxCoeff(), 1.0);
  const VecXi bone =
      selectBoneNodes(lm.limb.mesh, X, lm.limb.weights, lm.limb.joints, lm.limb.parents,
                      VecX::Constant(lm.limb.mesh.num_surface_nodes, 0.02));
  EXPECT_EQ(bone.size(), lm.limb.mesh.numNodes());
}

TEST(TissueThickness, FractionOfTheDistanceToTheBoneAxis) {
  const test::Limb limb = test::makeLimb();
  const MaterialModel model = MaterialModel::defaults(10);
  const int V = limb.mesh.num_surface_nodes;
  const VecX thickness = surfaceTissueThickness(limb.mesh.nodes.topRows(V), limb.weights.topRows(V),
                                                limb.joints, limb.parents, model, VecX());
  const double fraction = model.baseValue("tissue_fraction", kBody);
  int checked = 0;
  for (int v = 0; v < V; ++v) {
    const Vec3 x = limb.mesh.nodes.row(v);
    EXPECT_GT(thickness[v], 0.0);
    if (std::abs(x.z() - 0.1) < 1e-9) {  // inside bone 0's axis segment
      EXPECT_NEAR(thickness[v], fraction * x.head<2>().norm(), 1e-12) << x.transpose();
      ++checked;
    }
  }
  EXPECT_GT(checked, 20);
}

}  // namespace
}  // namespace flsh
