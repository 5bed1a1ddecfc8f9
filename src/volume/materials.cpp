// The log-linear material model, its JSON file (docs/materials.md), and per-tet materials with
// their orthotropy frames (materials.h).
#include "flsh/volume/materials.h"

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <algorithm>
#include <array>
#include <cmath>
#include <nlohmann/json.hpp>
#include <sstream>

#include "flsh/core/error.h"
#include "flsh/format/atomic_file.h"
#include "flsh/format/input_file.h"
#include "flsh/volume/soft_avatar.h"
#include "flsh/volume/tet_material_map.h"
#include "volume/kinematic_tree.h"
#include "volume/surface_query.h"

namespace flsh {

namespace {

using json = nlohmann::json;

constexpr const char* kFormatName = "flsh-materials";
// Version 2 adds "regions"; version-1 files (no regions) still load, with every region
// coefficient 1 (a body without regional differences, as version 1 described it).
constexpr int kFormatVersion = 2;
// Plausibility bounds that catch unit mistakes (g/cm³ for kg/m³, mm for m).
constexpr double kMinDensity = 100, kMaxDensity = 3000;  // kg/m³
constexpr double kMaxSkinThickness = 0.05;               // m
// Below this length of the bone axis projected on the tangent plane (axis within ~11.5° of the
// normal) the frame uses a world axis instead: the projection's direction is ill-conditioned.
constexpr double kMinProjectedAxis = 0.2;

const std::vector<std::string> kLayerQuantities = {
    "density", "E1", "E2", "E3", "nu12", "nu13", "nu23", "G12", "G13", "G23", "fung_gamma"};
const std::vector<std::string> kBodyQuantities = {"skin_thickness", "tissue_fraction"};
const std::vector<std::string> kLayerNames = {"skin", "soft_tissue"};
const std::vector<std::string> kRegionQuantities = {"tissue_scale", "stiffness_scale"};
const std::vector<std::string> kRegionNames = {"torso", "thighs",     "shins",    "feet",
                                               "head",  "upper_arms", "forearms", "hands"};
enum Region { kTorso, kThighs, kShins, kFeet, kHead, kUpperArms, kForearms, kHands };
// SMPL's 24 bones (joint order of smpl_skeleton.h) to regions.
constexpr int kSmplRegion[24] = {kTorso,    kThighs,   kThighs, kTorso, kShins,     kShins,
                                 kTorso,    kFeet,     kFeet,   kTorso, kFeet,      kFeet,
                                 kHead,     kTorso,    kTorso,  kHead,  kUpperArms, kUpperArms,
                                 kForearms, kForearms, kHands,  kHands, kHands,     kHands};
constexpr int kNumLayered = 2 * 11, kNumBody = 2;  // coefficients before the regions'

int layeredIndex(const std::string& quantity) {
  const auto it = std::find(kLayerQuantities.begin(), kLayerQuantities.end(), quantity);
  return it == kLayerQuantities.end() ? -1 : int(it - kLayerQuantities.begin());
}
int bodyIndex(const std::string& quantity) {
  const auto it = std::find(kBodyQuantities.begin(), kBodyQuantities.end(), quantity);
  return it == kBodyQuantities.end() ? -1 : int(it - kBodyQuantities.begin());
}
int regionQuantityIndex(const std::string& quantity) {
  const auto it = std::find(kRegionQuantities.begin(), kRegionQuantities.end(), quantity);
  return it == kRegionQuantities.end() ? -1 : int(it - kRegionQuantities.begin());
}
size_t numCoefficients() {
  return kNumLayered + kNumBody + kRegionNames.size() * kRegionQuantities.size();
}

std::string numberText(double x) {
  std::ostringstream s;
  s.precision(17);
  s << x;
  return s.str();
}

/// Orthotropic compliance of the normal block (3 × 3, 1/Pa) from E (3) and ν12, ν13, ν23.

VecX padded(const VecX& betas, int K, const char* who) {
  if (betas.size() > K)
    throw InputError(std::string(who) + ": betas has " + std::to_string(betas.size()) +
                     " values, expected at most " + std::to_string(K) +
                     " (the material model's K)");
  if (!betas.allFinite()) throw InputError(std::string(who) + ": betas contains NaN or Inf");
  VecX b = VecX::Zero(K);
  b.head(betas.size()) = betas;
  return b;
}

/// JSON text with objects indented by two spaces per level and arrays of numbers on one line;
/// keys sorted (nlohmann::json keeps objects in a std::map), numbers in nlohmann's shortest
/// round-trip form.
void writeCompact(const json& j, int depth, std::string& out) {
  if (j.is_object()) {
    const std::string indent(2 * (depth + 1), ' ');
    out += "{\n";
    bool first = true;
    for (const auto& item : j.items()) {
      out += (first ? "" : ",\n") + indent + json(item.key()).dump() + ": ";
      writeCompact(item.value(), depth + 1, out);
      first = false;
    }
    out += "\n" + std::string(2 * depth, ' ') + "}";
  } else if (j.is_array()) {
    out += "[";
    for (size_t k = 0; k < j.size(); ++k) {
      if (k) out += ", ";
      writeCompact(j[k], depth + 1, out);
    }
    out += "]";
  } else {
    out += j.dump();
  }
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// MaterialModel

const std::vector<std::string>& MaterialModel::layerQuantities() { return kLayerQuantities; }
const std::vector<std::string>& MaterialModel::bodyQuantities() { return kBodyQuantities; }
const std::vector<std::string>& MaterialModel::layerNames() { return kLayerNames; }
const std::vector<std::string>& MaterialModel::regionNames() { return kRegionNames; }
const std::vector<std::string>& MaterialModel::regionQuantities() { return kRegionQuantities; }

int MaterialModel::regionOfBone(int bone) {
  if (bone < 0)
    throw InputError("MaterialModel::regionOfBone: bone " + std::to_string(bone) +
                     ", expected ≥ 0");
  return bone < 24 ? kSmplRegion[bone] : kTorso;
}

Mat3 normalCompliance(const Vec3& E, const Vec3& nu) {
  Mat3 S;
  S << 1 / E[0], -nu[0] / E[0], -nu[1] / E[0],  //
      -nu[0] / E[0], 1 / E[1], -nu[2] / E[1],   //
      -nu[1] / E[0], -nu[2] / E[1], 1 / E[2];
  return S;
}

MatX MaterialModel::regionWeights(const MatX& bone_weights) {
  MatX omega = MatX::Zero(bone_weights.rows(), numRegions());
  for (Eigen::Index b = 0; b < bone_weights.cols(); ++b)
    omega.col(regionOfBone(int(b))) += bone_weights.col(b);
  return omega;
}

VecX MaterialModel::blendedRegionValue(const std::string& quantity, const MatX& region_weights,
                                       const VecX& betas) const {
  if (regionQuantityIndex(quantity) < 0)
    throw InputError("MaterialModel::blendedRegionValue: '" + quantity +
                     "' is not a region quantity, expected tissue_scale or stiffness_scale");
  if (region_weights.cols() != numRegions())
    throw InputError("MaterialModel::blendedRegionValue: region_weights has " +
                     std::to_string(region_weights.cols()) + " columns, expected " +
                     std::to_string(numRegions()) + " (one per region)");
  VecX log_scale(numRegions());
  for (int r = 0; r < numRegions(); ++r)
    log_scale[r] = std::log(value(quantity, regionLevel(r), betas));
  return (region_weights * log_scale).array().exp();
}

int MaterialModel::index(const std::string& quantity, int layer) const {
  const int layered = layeredIndex(quantity), body = bodyIndex(quantity);
  if (layered >= 0) {
    if (layer != kSkin && layer != kSoftTissue)
      throw InputError("MaterialModel: quantity '" + quantity + "' needs layer 0 (skin) or 1 " +
                       "(soft tissue), got " + std::to_string(layer));
    return layer * int(kLayerQuantities.size()) + layered;
  }
  if (body >= 0) {
    if (layer != kBodyLevel)
      throw InputError("MaterialModel: quantity '" + quantity +
                       "' is body-level, expected layer kBodyLevel (−1), got " +
                       std::to_string(layer));
    return kNumLayers * int(kLayerQuantities.size()) + body;
  }
  const int regional = regionQuantityIndex(quantity);
  if (regional >= 0) {
    const int r = layer - kFirstRegion;
    if (r < 0 || r >= numRegions())
      throw InputError("MaterialModel: quantity '" + quantity +
                       "' is a region quantity, expected layer regionLevel(r) = " +
                       std::to_string(kFirstRegion) + " + r with r in [0, " +
                       std::to_string(numRegions()) + "), got " + std::to_string(layer));
    return kNumLayered + kNumBody + r * int(kRegionQuantities.size()) + regional;
  }
  std::string known;
  for (const auto& q : kLayerQuantities) known += q + ", ";
  for (const auto& q : kBodyQuantities) known += q + ", ";
  for (const auto& q : kRegionQuantities) known += q + (q == kRegionQuantities.back() ? "" : ", ");
  throw InputError("MaterialModel: unknown quantity '" + quantity + "', expected one of " + known);
}

MaterialModel MaterialModel::defaults(int num_betas) {
  if (num_betas < 0)
    throw InputError("MaterialModel::defaults: num_betas = " + std::to_string(num_betas) +
                     ", expected ≥ 0");
  MaterialModel m;
  m.num_betas_ = num_betas;
  m.coefficients_.assign(numCoefficients(), Coefficient{1.0, VecX::Zero(num_betas)});
  // Log-slopes on β₀ (size / height) and β₁ (weight): bigger, heavier bodies get softer and
  // thicker tissue (docs/materials.md).
  auto set = [&](const std::string& q, int layer, double value, double slope0, double slope1) {
    VecX b = VecX::Zero(num_betas);
    if (num_betas > 0) b[0] = slope0;
    if (num_betas > 1) b[1] = slope1;
    m.setCoefficient(q, layer, value, b);
  };
  // Skin: dermis and epidermis, stiffer in plane than through the thickness, strongly
  // strain-stiffening.
  set("density", kSkin, 1070.0, 0.0, 0.0);
  set("E1", kSkin, 120e3, 0.0, -0.03);
  set("E2", kSkin, 80e3, 0.0, -0.03);
  set("E3", kSkin, 40e3, 0.0, -0.03);
  set("nu12", kSkin, 0.42, 0.0, 0.0);
  set("nu13", kSkin, 0.45, 0.0, 0.0);
  set("nu23", kSkin, 0.45, 0.0, 0.0);
  set("G12", kSkin, 34e3, 0.0, -0.03);
  set("G13", kSkin, 24e3, 0.0, -0.03);
  set("G23", kSkin, 19e3, 0.0, -0.03);
  set("fung_gamma", kSkin, 8.0, 0.0, 0.0);
  // Soft tissue: a fat and relaxed-muscle mix (≈ 30 % fat), stiffer along the bone (muscle
  // fibres) than across.
  set("density", kSoftTissue, 1030.0, 0.0, -0.004);
  set("E1", kSoftTissue, 15e3, -0.02, -0.08);
  set("E2", kSoftTissue, 10e3, -0.02, -0.08);
  set("E3", kSoftTissue, 10e3, -0.02, -0.08);
  set("nu12", kSoftTissue, 0.45, 0.0, 0.0);
  set("nu13", kSoftTissue, 0.45, 0.0, 0.0);
  set("nu23", kSoftTissue, 0.45, 0.0, 0.0);
  set("G12", kSoftTissue, 4.2e3, -0.02, -0.08);
  set("G13", kSoftTissue, 4.2e3, -0.02, -0.08);
  set("G23", kSoftTissue, 3.4e3, -0.02, -0.08);
  set("fung_gamma", kSoftTissue, 3.0, 0.0, -0.03);
  set("skin_thickness", kBodyLevel, 0.002, 0.02, 0.04);
  set("tissue_fraction", kBodyLevel, 0.5, 0.01, 0.05);
  // Body regions (docs/materials.md, "Body regions"): hands, feet and the head are mostly bone,
  // tendon and thin, fibrous skin-bound tissue (×100: an effective 1–1.5 MPa that also carries
  // fingers and toes where the mesh has no bone node; ×20 left fingertips and heels moving 1–2
  // cm); forearms and shins are in between; torso, thighs and upper arms keep the reference
  // tissue. No slopes of their own: the shape dependence is the body-level one.
  const double tissue_scale[8] = {1.0, 1.0, 0.4, 0.2, 0.2, 1.0, 0.4, 0.2};
  const double stiffness_scale[8] = {1.0, 1.0, 5.0, 100.0, 100.0, 1.0, 5.0, 100.0};
  for (int r = 0; r < numRegions(); ++r) {
    set("tissue_scale", regionLevel(r), tissue_scale[r], 0.0, 0.0);
    set("stiffness_scale", regionLevel(r), stiffness_scale[r], 0.0, 0.0);
  }
  m.validate("MaterialModel::defaults");
  return m;
}

double MaterialModel::baseValue(const std::string& quantity, int layer) const {
  return coefficients_[index(quantity, layer)].base;
}
const VecX& MaterialModel::logSlopes(const std::string& quantity, int layer) const {
  return coefficients_[index(quantity, layer)].slopes;
}
void MaterialModel::setCoefficient(const std::string& quantity, int layer, double base_value,
                                   const VecX& log_slopes) {
  const int i = index(quantity, layer);
  if (!(std::isfinite(base_value) && base_value > 0))
    throw InputError("MaterialModel::setCoefficient: " + quantity + " value " +
                     numberText(base_value) + ", expected finite and > 0");
  if (log_slopes.size() != num_betas_ || !log_slopes.allFinite())
    throw InputError("MaterialModel::setCoefficient: " + quantity + " log_slopes has " +
                     std::to_string(log_slopes.size()) + " values, expected " +
                     std::to_string(num_betas_) + " finite values");
  coefficients_[i] = Coefficient{base_value, log_slopes};
}

double MaterialModel::value(const std::string& quantity, int layer, const VecX& betas) const {
  const Coefficient& c = coefficients_[index(quantity, layer)];
  if (betas.size() == 0) return c.base;
  const VecX b = padded(betas, num_betas_, "MaterialModel::value");
  return c.base * std::exp(c.slopes.dot(b));
}

VecX MaterialModel::valueGradient(const std::string& quantity, int layer, const VecX& betas) const {
  const VecX b = padded(betas, num_betas_, "MaterialModel::valueGradient");
  const double v = value(quantity, layer, b);
  VecX g(1 + num_betas_);
  g[0] = v;
  g.tail(num_betas_) = v * b;
  return g;
}

int MaterialModel::numParameters() const { return int(coefficients_.size()) * (1 + num_betas_); }
int MaterialModel::parameterOffset(const std::string& quantity, int layer) const {
  return index(quantity, layer) * (1 + num_betas_);
}
VecX MaterialModel::parameters() const {
  VecX p(numParameters());
  for (size_t i = 0; i < coefficients_.size(); ++i) {
    p[i * (1 + num_betas_)] = std::log(coefficients_[i].base);
    p.segment(i * (1 + num_betas_) + 1, num_betas_) = coefficients_[i].slopes;
  }
  return p;
}
void MaterialModel::setParameters(const VecX& parameters) {
  if (parameters.size() != numParameters() || !parameters.allFinite())
    throw InputError("MaterialModel::setParameters: parameters has " +
                     std::to_string(parameters.size()) + " values, expected " +
                     std::to_string(numParameters()) + " finite values");
  MaterialModel candidate = *this;
  for (size_t i = 0; i < coefficients_.size(); ++i) {
    candidate.coefficients_[i].base = std::exp(parameters[i * (1 + num_betas_)]);
    candidate.coefficients_[i].slopes = parameters.segment(i * (1 + num_betas_) + 1, num_betas_);
  }
  candidate.validate("MaterialModel::setParameters: parameters");
  *this = std::move(candidate);
}

int MaterialModel::numCoefficients() { return int(flsh::numCoefficients()); }

std::vector<std::string> MaterialModel::parameterNames() const {
  std::vector<std::string> keys;
  for (const auto& layer : kLayerNames)
    for (const auto& q : kLayerQuantities) keys.push_back("layers." + layer + "." + q);
  for (const auto& q : kBodyQuantities) keys.push_back("body." + q);
  for (const auto& r : kRegionNames)
    for (const auto& q : kRegionQuantities) keys.push_back("regions." + r + "." + q);
  std::vector<std::string> names;
  for (const auto& key : keys) {
    names.push_back(key + ".log_value");
    for (int k = 0; k < num_betas_; ++k)
      names.push_back(key + ".log_slopes[" + std::to_string(k) + "]");
  }
  return names;
}

VecX MaterialModel::coefficientValues(const VecX& betas) const {
  const VecX b = padded(betas, num_betas_, "MaterialModel::coefficientValues");
  VecX values(coefficients_.size());
  for (size_t i = 0; i < coefficients_.size(); ++i)
    values[Eigen::Index(i)] = coefficients_[i].base * std::exp(coefficients_[i].slopes.dot(b));
  return values;
}

MatX MaterialModel::coefficientValuesShapeJacobian(const VecX& betas) const {
  const VecX c = coefficientValues(betas);
  MatX out(c.size(), num_betas_);
  for (size_t i = 0; i < coefficients_.size(); ++i)
    out.row(Eigen::Index(i)) = c[Eigen::Index(i)] * coefficients_[i].slopes.transpose();
  return out;
}

VecX MaterialModel::parametersCotangent(const VecX& values_bar, const VecX& betas) const {
  if (values_bar.size() != numCoefficients())
    throw InputError("MaterialModel::parametersCotangent: values_bar has " +
                     std::to_string(values_bar.size()) + " values, expected " +
                     std::to_string(numCoefficients()));
  const VecX b = padded(betas, num_betas_, "MaterialModel::parametersCotangent");
  const VecX c = coefficientValues(b);
  VecX out(numParameters());
  for (Eigen::Index i = 0; i < c.size(); ++i) {
    const double scaled = c[i] * values_bar[i];
    out[i * (1 + num_betas_)] = scaled;
    out.segment(i * (1 + num_betas_) + 1, num_betas_) = scaled * b;
  }
  return out;
}

VecX MaterialModel::coefficientValuesTangent(const VecX& parameters_direction,
                                             const VecX& betas) const {
  if (parameters_direction.size() != numParameters())
    throw InputError("MaterialModel::coefficientValuesTangent: direction has " +
                     std::to_string(parameters_direction.size()) + " values, expected " +
                     std::to_string(numParameters()));
  const VecX b = padded(betas, num_betas_, "MaterialModel::coefficientValuesTangent");
  VecX out = coefficientValues(b);
  for (Eigen::Index i = 0; i < out.size(); ++i)
    out[i] *= parameters_direction[i * (1 + num_betas_)] +
              parameters_direction.segment(i * (1 + num_betas_) + 1, num_betas_).dot(b);
  return out;
}

void MaterialModel::validate(const std::string& origin, const VecX& betas) const {
  const VecX b = padded(betas, num_betas_, "MaterialModel::validate");
  for (int layer = 0; layer < kNumLayers; ++layer) {
    const std::string where = origin + ": layers." + kLayerNames[layer] + ".";
    auto v = [&](const std::string& q) { return value(q, layer, b); };
    for (const auto& q : kLayerQuantities)
      if (!(std::isfinite(v(q)) && v(q) > 0))
        throw InputError(where + q + ": value " + numberText(v(q)) + ", expected finite and > 0");
    if (v("density") < kMinDensity || v("density") > kMaxDensity)
      throw InputError(where + "density: " + numberText(v("density")) + " kg/m³, expected " +
                       numberText(kMinDensity) + ".." + numberText(kMaxDensity) + " (SI units)");
    for (const char* q : {"nu12", "nu13", "nu23"})
      if (v(q) >= 0.5)
        throw InputError(where + q + ": Poisson ratio " + numberText(v(q)) +
                         (b.isZero() ? "" : " at the given β") + ", expected < 0.5");
    const Vec3 E(v("E1"), v("E2"), v("E3")), nu(v("nu12"), v("nu13"), v("nu23"));
    // Scaled by E3 so the positive-definiteness test is independent of the units' magnitude.
    const Eigen::LLT<Mat3> llt(normalCompliance(E, nu) * E[2]);
    if (llt.info() != Eigen::Success)
      throw InputError(where +
                       "E1..E3, nu12..nu23: orthotropic compliance is not positive "
                       "definite (E = " +
                       numberText(E[0]) + ", " + numberText(E[1]) + ", " + numberText(E[2]) +
                       " Pa; ν = " + numberText(nu[0]) + ", " + numberText(nu[1]) + ", " +
                       numberText(nu[2]) +
                       "), expected ν12² < E1/E2, ν13² < E1/E3, ν23² < E2/E3 and det > 0");
  }
  for (int r = 0; r < numRegions(); ++r)
    for (const auto& q : kRegionQuantities) {
      const double x = value(q, regionLevel(r), b);
      if (!(std::isfinite(x) && x > 0))
        throw InputError(origin + ": regions." + kRegionNames[r] + "." + q + ": value " +
                         numberText(x) + ", expected finite and > 0");
    }
  const double skin = value("skin_thickness", kBodyLevel, b),
               fraction = value("tissue_fraction", kBodyLevel, b);
  if (!(std::isfinite(skin) && skin > 0 && skin <= kMaxSkinThickness))
    throw InputError(origin + ": body.skin_thickness: " + numberText(skin) +
                     " m, expected in (0, 0.05] m (SI units)");
  if (!(std::isfinite(fraction) && fraction > 0 && fraction < 1))
    throw InputError(origin + ": body.tissue_fraction: " + numberText(fraction) +
                     ", expected in (0, 1) (soft-tissue thickness over body radius)");
  for (int r = 0; r < numRegions(); ++r) {
    const double scaled = fraction * value("tissue_scale", regionLevel(r), b);
    if (!(scaled < 1))
      throw InputError(origin + ": regions." + kRegionNames[r] +
                       ".tissue_scale: " + numberText(value("tissue_scale", regionLevel(r), b)) +
                       " times body.tissue_fraction " + numberText(fraction) + " is " +
                       numberText(scaled) +
                       ", expected < 1 (soft-tissue thickness over body radius)");
  }
}

bool MaterialModel::operator==(const MaterialModel& other) const {
  if (num_betas_ != other.num_betas_ || coefficients_.size() != other.coefficients_.size())
    return false;
  for (size_t i = 0; i < coefficients_.size(); ++i)
    if (coefficients_[i].base != other.coefficients_[i].base ||
        coefficients_[i].slopes != other.coefficients_[i].slopes)
      return false;
  return true;
}

// ---------------------------------------------------------------------------------------------
// JSON

std::string MaterialModel::canonicalText() const {
  auto coefficient = [&](const std::string& q, int layer) {
    const Coefficient& c = coefficients_[index(q, layer)];
    json slopes = json::array();
    for (int k = 0; k < num_betas_; ++k) slopes.push_back(c.slopes[k]);
    return json{{"value", c.base}, {"log_slopes", slopes}};
  };
  json root;
  root["format"] = kFormatName;
  root["version"] = kFormatVersion;
  for (int layer = 0; layer < kNumLayers; ++layer)
    for (const auto& q : kLayerQuantities)
      root["layers"][kLayerNames[layer]][q] = coefficient(q, layer);
  for (const auto& q : kBodyQuantities) root["body"][q] = coefficient(q, kBodyLevel);
  for (int r = 0; r < numRegions(); ++r)
    for (const auto& q : kRegionQuantities)
      root["regions"][kRegionNames[r]][q] = coefficient(q, regionLevel(r));
  std::string text;
  writeCompact(root, 0, text);
  return text + "\n";
}

void MaterialModel::save(const std::string& path) const {
  const std::string text = canonicalText();
  io::writeFileAtomically(path, [&](std::ostream& out) { out << text; });
}

MaterialModel MaterialModel::load(const std::string& path, int num_betas) {
  // A FIFO, directory or device is refused (InputError naming the path), never opened: an
  // ifstream on a FIFO blocked forever.
  return fromText(io::readRegularFileText(path, "a JSON material file"), num_betas, path);
}

MaterialModel MaterialModel::fromText(const std::string& text, int num_betas,
                                      const std::string& origin) {
  if (num_betas < 0)
    throw InputError(origin + ": num_betas = " + std::to_string(num_betas) + ", expected ≥ 0");
  // Material files nest 5 levels ({"layers": {"skin": {"E1": {"log_slopes": [ ) and deeper
  // input is refused before parsing: building, copying and dump()ing (in messages) the tree
  // recurse once per level, and 200 000 nested '[' overflowed the stack.
  io::checkJsonNesting(text, origin, "material files nest 5 levels");
  json root;
  try {
    root = json::parse(text);
  } catch (const json::exception& e) {  // syntax errors, and numbers beyond double's range
    throw InputError(origin + ": not valid JSON (" + e.what() + ")");
  }
  auto typeName = [](const json& j) { return std::string(j.type_name()); };
  auto requireObject = [&](const json& j, const std::string& key,
                           const std::vector<std::string>& keys) {
    if (!j.is_object())
      throw InputError(origin + ": " + key + ": expected an object, got " + typeName(j));
    for (const auto& k : keys)
      if (!j.contains(k))
        throw InputError(origin + ": " + (key.empty() ? "" : key + ".") + k + ": missing key");
    for (const auto& item : j.items())
      if (std::find(keys.begin(), keys.end(), item.key()) == keys.end()) {
        std::string known;
        for (const auto& k : keys) known += (known.empty() ? "" : ", ") + k;
        throw InputError(origin + ": " + (key.empty() ? "" : key + ".") + item.key() +
                         ": unknown key, expected one of " + known);
      }
  };
  // The version decides the keys: version 1 has no "regions".
  if (!root.is_object())
    throw InputError(origin + ": (top level): expected an object, got " + typeName(root));
  const json version = root.contains("version") ? root["version"] : json();
  if (!version.is_number_integer() ||
      (version.get<long>() != 1 && version.get<long>() != kFormatVersion))
    throw InputError(origin + ": version: expected " + std::to_string(kFormatVersion) +
                     " (or 1, without regions), got " +
                     (root.contains("version") ? version.dump() : std::string("no version")));
  const bool has_regions = version.get<long>() >= 2;
  if (has_regions)
    requireObject(root, "(top level)", {"format", "version", "layers", "body", "regions"});
  else
    requireObject(root, "(top level)", {"format", "version", "layers", "body"});
  if (!root["format"].is_string() || root["format"].get<std::string>() != kFormatName)
    throw InputError(origin + ": format: expected \"" + kFormatName + "\", got " +
                     root["format"].dump());
  requireObject(root["layers"], "layers", kLayerNames);

  MaterialModel m;
  m.num_betas_ = num_betas;
  m.coefficients_.assign(numCoefficients(), Coefficient{1.0, VecX::Zero(num_betas)});
  auto readCoefficient = [&](const json& j, const std::string& key, const std::string& q,
                             int layer) {
    requireObject(j, key, {"value", "log_slopes"});
    const json& v = j["value"];
    if (!v.is_number())
      throw InputError(origin + ": " + key + ".value: expected a number, got " + typeName(v));
    const double base = v.get<double>();
    if (!(std::isfinite(base) && base > 0))
      throw InputError(origin + ": " + key + ".value: " + v.dump() +
                       ", expected a finite number > 0");
    const json& s = j["log_slopes"];
    if (!s.is_array())
      throw InputError(origin + ": " + key + ".log_slopes: expected an array of numbers, got " +
                       typeName(s));
    VecX slopes = VecX::Zero(num_betas);
    for (size_t k = 0; k < s.size(); ++k) {
      const std::string at = key + ".log_slopes[" + std::to_string(k) + "]";
      if (!s[k].is_number())
        throw InputError(origin + ": " + at + ": expected a number, got " + typeName(s[k]));
      const double x = s[k].get<double>();
      if (!std::isfinite(x))
        throw InputError(origin + ": " + at + ": " + s[k].dump() + ", expected a finite number");
      if (int(k) < num_betas)
        slopes[k] = x;
      else if (x != 0)
        throw InputError(origin + ": " + key + ".log_slopes: " + std::to_string(s.size()) +
                         " values with a non-zero one at index " + std::to_string(k) +
                         ", expected at most " + std::to_string(num_betas) +
                         " (the body's shape components) or zeros beyond");
    }
    m.coefficients_[m.index(q, layer)] = Coefficient{base, slopes};
  };
  for (int layer = 0; layer < kNumLayers; ++layer) {
    const std::string key = "layers." + kLayerNames[layer];
    const json& j = root["layers"][kLayerNames[layer]];
    requireObject(j, key, kLayerQuantities);
    for (const auto& q : kLayerQuantities) readCoefficient(j[q], key + "." + q, q, layer);
  }
  requireObject(root["body"], "body", kBodyQuantities);
  for (const auto& q : kBodyQuantities)
    readCoefficient(root["body"][q], "body." + q, q, kBodyLevel);
  if (has_regions) {
    requireObject(root["regions"], "regions", kRegionNames);
    for (int r = 0; r < numRegions(); ++r) {
      const std::string key = "regions." + kRegionNames[r];
      const json& j = root["regions"][kRegionNames[r]];
      requireObject(j, key, kRegionQuantities);
      for (const auto& q : kRegionQuantities)
        readCoefficient(j[q], key + "." + q, q, regionLevel(r));
    }
  }
  m.validate(origin);
  return m;
}

// ---------------------------------------------------------------------------------------------
// Per-tet materials

namespace {

void checkSkeleton(const std::string& fn, const MatX& weights, long rows, const MatX3& joints,
                   const std::vector<int>& parents) {
  const long nb = joints.rows();
  if (nb < 1) throw InputError(fn + "joints has 0 rows, expected at least 1");
  if (weights.rows() != rows || weights.cols() != nb)
    throw InputError(fn + "weights has shape " +
                     shapeString({long(weights.rows()), long(weights.cols())}) + ", expected " +
                     shapeString({rows, nb}));
  if (long(parents.size()) != nb)
    throw InputError(fn + "parents has " + std::to_string(parents.size()) + " entries, expected " +
                     std::to_string(nb) + " (one per joint)");
  if (!weights.allFinite() || !joints.allFinite())
    throw InputError(fn + "weights or joints contains NaN or Inf");
}

/// Unit axis of each bone: its capsule's segment, else the direction to its only child, else
/// zero (the frame then falls back to a world axis).
std::vector<Vec3> boneAxes(const std::vector<BoneCapsule>& capsules, const MatX3& joints,
                           const std::vector<int>& parents) {
  const int nb = int(joints.rows());
  const std::vector<std::vector<int>> children = detail::jointChildren(parents);
  std::vector<Vec3> axes(nb, Vec3::Zero());
  for (int b = 0; b < nb; ++b) {
    Vec3 axis = capsules[b].b - capsules[b].a;
    if (axis.norm() <= 1e-9 && children[b].size() == 1)
      axis = (joints.row(children[b][0]) - joints.row(b)).transpose();
    if (axis.norm() > 1e-9) axes[b] = axis.normalized();
  }
  return axes;
}

/// Orthonormal frame [a1 a2 a3] with a3 = inward normal, a1 = axis projected on the tangent
/// plane (or the world axis least aligned with a3 when that projection is short).
Mat3 tissueFrame(const Vec3& inward, const Vec3& axis) {
  const Vec3 a3 = inward.normalized();
  Vec3 a1 = axis - axis.dot(a3) * a3;
  if (a1.norm() < kMinProjectedAxis) {
    int least = 0;
    a3.cwiseAbs().minCoeff(&least);  // |a3[least]| ≤ 1/√3: projection length ≥ √(2/3)
    a1 = Vec3::Unit(least) - a3[least] * a3;
  }
  a1.normalize();
  Mat3 frame;
  frame.col(0) = a1;
  frame.col(1) = a3.cross(a1);
  frame.col(2) = a3;
  return frame;
}

}  // namespace

VecX surfaceTissueThickness(const MatX3& surface_vertices, const MatX& surface_weights,
                            const MatX3& joints, const std::vector<int>& parents,
                            const MaterialModel& model, const VecX& betas) {
  const std::string fn = "surfaceTissueThickness: ";
  checkSkeleton(fn, surface_weights, surface_vertices.rows(), joints, parents);
  if (!surface_vertices.allFinite()) throw InputError(fn + "surface_vertices contains NaN or Inf");
  const double fraction = model.value("tissue_fraction", MaterialModel::kBodyLevel, betas);
  const VecX region_scale = model.blendedRegionValue(
      "tissue_scale", MaterialModel::regionWeights(surface_weights), betas);
  const std::vector<BoneCapsule> capsules =
      fitBoneCapsules(surface_vertices, surface_weights, joints, parents);
  VecX thickness(surface_vertices.rows());
  for (int v = 0; v < surface_vertices.rows(); ++v) {
    int dominant = 0;
    surface_weights.row(v).maxCoeff(&dominant);
    const BoneCapsule& c = capsules[dominant];
    const Vec3 x = surface_vertices.row(v).transpose(), ab = c.b - c.a;
    const double t =
        ab.squaredNorm() > 0 ? std::clamp((x - c.a).dot(ab) / ab.squaredNorm(), 0.0, 1.0) : 0.0;
    thickness[v] = fraction * region_scale[v] * (x - c.a - t * ab).norm();
  }
  return thickness;
}

VecX tetTissueStiffnessScale(const TetMesh& mesh, const MatX& node_weights,
                             const MaterialModel& model, const VecX& betas) {
  if (node_weights.rows() != mesh.numNodes())
    throw InputError("tetTissueStiffnessScale: node_weights has " +
                     std::to_string(node_weights.rows()) + " rows, expected " +
                     std::to_string(mesh.numNodes()) + " (one per node)");
  const MatX omega = MaterialModel::regionWeights(node_weights);
  MatX tet_omega = MatX::Zero(mesh.numTets(), omega.cols());
  for (int t = 0; t < mesh.numTets(); ++t)
    for (int k = 0; k < 4; ++k) tet_omega.row(t) += 0.25 * omega.row(mesh.tets(t, k));
  return model.blendedRegionValue("stiffness_scale", tet_omega, betas);
}

TetMaterials computeTetMaterials(const TetMesh& mesh, const MatX3& shaped_nodes,
                                 const MatX& node_weights, const MatX3& joints,
                                 const std::vector<int>& parents, const MaterialModel& model,
                                 const VecX& betas) {
  const std::string fn = "computeTetMaterials: ";
  detail::checkTetMesh(mesh, shaped_nodes, "computeTetMaterials", false);
  checkSkeleton(fn, node_weights, mesh.numNodes(), joints, parents);
  model.validate("computeTetMaterials: material model", betas);
  const MatX3i F = detail::outwardBoundaryFaces(mesh, "computeTetMaterials");
  if (F.rows() == 0) throw InputError(fn + "the tet mesh has no boundary faces");
  const int nv = mesh.num_surface_nodes, nt = mesh.numTets();

  const MatX3 surface = shaped_nodes.topRows(nv);
  const std::vector<Vec3> axes = boneAxes(
      fitBoneCapsules(surface, node_weights.topRows(nv), joints, parents), joints, parents);
  const MatX3 normals = detail::vertexNormals(shaped_nodes, F);
  const detail::SurfaceDistance distance(shaped_nodes, F);

  // The orthotropy frame of each tet; the coefficients follow from the material map.
  std::vector<Mat3> frames(static_cast<size_t>(nt));
#pragma omp parallel for schedule(static)
  for (int t = 0; t < nt; ++t) {
    Vec3 centroid = Vec3::Zero();
    Eigen::RowVectorXd tet_weights = Eigen::RowVectorXd::Zero(node_weights.cols());
    for (int k = 0; k < 4; ++k) {
      centroid += shaped_nodes.row(mesh.tets(t, k)).transpose() / 4;
      tet_weights += node_weights.row(mesh.tets(t, k));
    }
    int dominant = 0;
    tet_weights.maxCoeff(&dominant);
    const detail::SurfaceDistance::Hit hit = distance.closest(centroid);
    Vec3 outward = Vec3::Zero();
    for (int c = 0; c < 3; ++c)
      outward += hit.barycentric[c] * normals.row(F(hit.face, c)).transpose();
    if (outward.norm() < 1e-9) {  // opposite normals cancel (a sharp crease): the face normal
      const Vec3 a = shaped_nodes.row(F(hit.face, 0)), b = shaped_nodes.row(F(hit.face, 1)),
                 c = shaped_nodes.row(F(hit.face, 2));
      outward = (b - a).cross(c - a);
    }
    frames[size_t(t)] = tissueFrame(-outward, axes[dominant]);
  }
  const TetMaterialMap map(tetMaterialGeometry(mesh, shaped_nodes, node_weights, std::move(frames)),
                           model.coefficientValues(betas));
  return map.materials();
}

}  // namespace flsh
