// Scene files for `flsh simulate` (docs/scene_format.md): a strict JSON reader whose every
// error names the origin and the key path, e.g. "scene.json: avatars[0].options.gravity: …".
// (Past 800 lines on purpose: one reader class for the whole format, whose sections — scene,
// newton with its lagged and presolve objects, avatars, colliders, outputs — share its
// key-path and range helpers; split, each piece would need them passed around.)
#include "flsh/io/scene_file.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>

#include "flsh/body/motion.h"
#include "flsh/core/error.h"
#include "flsh/format/input_file.h"

namespace flsh {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

constexpr double kPi = 3.14159265358979323846;

// The built-in default scene, kept byte-identical to examples/scenes/default.json (a test
// checks that they parse to the same scene). The ground sits at the 1.70 m synthetic body's
// sole height (rest min y = −0.952 m); the ball (r = 0.12 m) comes from the front at 4 m/s
// along −z, meets the walker's belly (y = 0.05 m; the belly's front is at z ≈ 1.31 m after
// 1 s of walking at 1.2 m/s) at t ≈ 1 s and bounces back 10 ms later: a scripted collider
// cannot be stopped by the body, so its path is the bounce.
constexpr const char* kDefaultSceneJson = R"({
  "time_step": 0.016666666666666666,
  "duration": 2.0,
  "avatar_contact": true,
  "newton": {"max_iterations": 30, "gradient_tolerance": 1e-6},
  "avatars": [
    {
      "name": "walker",
      "model": "synthetic",
      "vertices": 6890,
      "simulation": "skeleton",
      "motion": "builtin:walk",
      "motion_seconds": 2.0
    }
  ],
  "colliders": [
    {"name": "ground", "type": "plane", "point": [0.0, -0.952, 0.0], "normal": [0.0, 1.0, 0.0]},
    {"name": "ball", "type": "sphere", "center": [0.0, 0.05, 5.41], "radius": 0.12,
     "path": {"times": [0.0, 1.01, 2.0], "offsets": [[0, 0, 0], [0, 0, -4.04], [0, 0, -0.08]]}}
  ],
  "outputs": {"dir": "out/simulate", "ply": true, "npz": true, "gltf": true, "png": true,
              "png_frames": 5, "every": 1}
}
)";

std::string joinNames(const std::vector<std::string>& names) {
  std::string text;
  for (const auto& n : names) text += (text.empty() ? "" : ", ") + n;
  return text;
}

/// Appends compact JSON text of `value` to `out` (as dump() writes it) but stops adding
/// elements, and cuts strings, once `out` holds `limit` characters: a message never renders a
/// whole value of arbitrary size.
void appendShortDump(const json& value, std::string& out, size_t limit) {
  const auto quoted = [limit](const std::string& s) {
    // A cut may split a UTF-8 sequence: replace it rather than throw.
    return json(s.size() > limit ? s.substr(0, limit) : s)
        .dump(-1, ' ', false, json::error_handler_t::replace);
  };
  if (value.is_array()) {
    out += '[';
    for (size_t k = 0; k < value.size() && out.size() < limit; ++k) {
      if (k > 0) out += ',';
      appendShortDump(value[k], out, limit);
    }
    out += ']';
  } else if (value.is_object()) {
    out += '{';
    bool first = true;
    for (auto it = value.begin(); it != value.end() && out.size() < limit; ++it) {
      if (!first) out += ',';
      first = false;
      out += quoted(it.key()) + ':';
      appendShortDump(it.value(), out, limit);
    }
    out += '}';
  } else if (value.is_string()) {
    out += quoted(value.get_ref<const std::string&>());
  } else {
    out += value.dump();
  }
}

// A short rendering of a JSON value for messages ("string \"abc\"", "number -1").
std::string describe(const json& value) {
  std::string text;
  appendShortDump(value, text, 41);
  if (text.size() > 40) text = text.substr(0, 37) + "...";
  return std::string(value.type_name()) + " " + text;
}

std::string number(double value) {
  std::ostringstream out;
  out << value;
  return out.str();
}

/// Reads one scene document; every accessor takes the key path for messages.
class SceneReader {
 public:
  SceneReader(std::string origin, std::string base_dir)
      : origin_(std::move(origin)), base_dir_(std::move(base_dir)) {}

  [[noreturn]] void fail(const std::string& path, const std::string& message) const {
    throw InputError(origin_ + ": " + path + ": " + message);
  }

  static std::string child(const std::string& path, const std::string& key) {
    return path.empty() ? key : path + "." + key;
  }
  static std::string item(const std::string& path, size_t index) {
    return path + "[" + std::to_string(index) + "]";
  }

  void requireObject(const json& value, const std::string& path) const {
    if (!value.is_object()) fail(path, "expected a JSON object, got " + describe(value));
  }

  /// Every key of `object` must be in `known`.
  void checkKeys(const json& object, const std::string& path,
                 const std::vector<std::string>& known) const {
    for (const auto& [key, value] : object.items()) {
      if (std::find(known.begin(), known.end(), key) == known.end())
        fail(child(path, key), "unknown key (known: " + joinNames(known) + ")");
    }
  }

  double toDouble(const json& value, const std::string& path) const {
    if (!value.is_number()) fail(path, "expected a number, got " + describe(value));
    const double x = value.get<double>();
    if (!std::isfinite(x)) fail(path, "expected a finite number, got " + number(x));
    return x;
  }

  int toInt(const json& value, const std::string& path) const {
    const double x = toDouble(value, path);
    if (x != std::floor(x) || std::abs(x) > 2e9)
      fail(path, "expected an integer, got " + describe(value));
    return int(x);
  }

  /// Three numbers, each within ±`bound` (`unit` names it in messages): positions within the
  /// simulation's ±kMaxStatePosition by default.
  Vec3 toVec3(const json& value, const std::string& path, double bound = kMaxStatePosition,
              const std::string& unit = "m") const {
    if (!value.is_array() || value.size() != 3)
      fail(path, "expected 3 numbers [x, y, z], got " + describe(value));
    Vec3 v;
    for (int c = 0; c < 3; ++c) v[c] = toRange(value[c], item(path, c), -bound, bound, false, unit);
    return v;
  }

  bool toBool(const json& value, const std::string& path) const {
    if (!value.is_boolean()) fail(path, "expected true or false, got " + describe(value));
    return value.get<bool>();
  }

  std::string toString(const json& value, const std::string& path) const {
    if (!value.is_string()) fail(path, "expected a string, got " + describe(value));
    return value.get<std::string>();
  }

  /// A number in [lo, hi] (open at lo when `open_lo`): "expected 0 < time_step ≤ 1".
  double toRange(const json& value, const std::string& path, double lo, double hi, bool open_lo,
                 const std::string& unit = "") const {
    const double x = toDouble(value, path);
    if ((open_lo ? x <= lo : x < lo) || x > hi) {
      std::string expected = number(lo) + (open_lo ? " < value" : " <= value");
      if (std::isfinite(hi)) expected += " <= " + number(hi);
      fail(path,
           "expected " + expected + (unit.empty() ? "" : " (" + unit + ")") + ", got " + number(x));
    }
    return x;
  }

  int toIntRange(const json& value, const std::string& path, int lo, int hi) const {
    const int x = toInt(value, path);
    if (x < lo || x > hi)
      fail(path, "expected an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) +
                     "], got " + std::to_string(x));
    return x;
  }

  /// Names become folder names and npz key prefixes: letters, digits, '_' and '-'.
  std::string toName(const json& value, const std::string& path) const {
    const std::string name = toString(value, path);
    const bool ok =
        !name.empty() && name.size() <= 64 && std::all_of(name.begin(), name.end(), [](char c) {
          return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-';
        });
    if (!ok)
      fail(path, "expected a name of 1-64 letters, digits, '_' or '-', got \"" + name + "\"");
    return name;
  }

  /// Resolves a relative path against the scene file's folder and requires an existing file.
  std::string existingFile(const std::string& text, const std::string& path,
                           const std::string& what) const {
    const fs::path p = resolvedPath(text, path);
    std::error_code ec;
    if (!fs::is_regular_file(p, ec))
      throw FileError(origin_ + ": " + path + ": " + what + " file not found: " + p.string());
    return p.string();
  }

  /// `text` resolved against the scene file's folder, absolute and normal (not checked).
  std::string resolvedPath(const std::string& text, const std::string& path) const {
    if (text.empty()) fail(path, "expected a file path, got an empty string");
    fs::path p(text);
    if (p.is_relative()) p = fs::path(base_dir_) / p;
    std::error_code absolute_error;
    const fs::path absolute = fs::absolute(p, absolute_error);  // messages name a full path
    if (!absolute_error) p = absolute;
    return p.lexically_normal().string();
  }

  /// A folder that may not exist yet (it is created on use), resolved like existingFile;
  /// an existing path must be a folder.
  std::string directoryPath(const std::string& text, const std::string& path) const {
    if (text.empty()) fail(path, "expected a directory, got an empty string");
    fs::path p(text);
    if (p.is_relative()) p = fs::path(base_dir_) / p;
    std::error_code absolute_error;
    const fs::path absolute = fs::absolute(p, absolute_error);
    if (!absolute_error) p = absolute;
    p = p.lexically_normal();
    std::error_code ec;
    if (fs::exists(p, ec) && !fs::is_directory(p, ec))
      throw FileError(origin_ + ": " + path + ": expected a directory, but " + p.string() +
                      " is a file");
    return p.string();
  }

  SceneSpec read(const json& root, const SceneOverrides& overrides) const {
    if (!root.is_object()) fail("(top level)", "expected a JSON object, got " + describe(root));
    checkKeys(root, "",
              {"time_step", "duration", "preset", "avatar_contact", "newton", "avatars",
               "colliders", "ground", "outputs", "cache_dir", "use_cache"});
    SceneSpec scene;
    if (root.contains("preset")) {
      const std::string name = toString(root["preset"], "preset");
      try {
        scene.preset = parsePreset(name, "preset");
      } catch (const InputError&) {
        fail("preset", "expected \"none\" or \"realtime\", got \"" + name + "\"");
      }
      scene.reduced_iteration_budget = presetReducedIterationBudget(scene.preset);
    }
    if (root.contains("time_step"))
      scene.time_step = toRange(root["time_step"], "time_step", 0.0, 1.0, true, "s");
    if (root.contains("duration"))
      scene.duration = toRange(root["duration"], "duration", 0.0, 1e6, true, "s");
    applyOverrides(scene, overrides);
    if (scene.duration / scene.time_step > double(kMaxSceneSteps))
      fail("duration", "duration / time_step = " + number(scene.duration / scene.time_step) +
                           " steps, expected at most " + std::to_string(kMaxSceneSteps));
    if (root.contains("avatar_contact"))
      scene.avatar_contact = toBool(root["avatar_contact"], "avatar_contact");
    if (root.contains("newton")) {
      scene.newton = readNewton(root["newton"], "newton");
      if (root["newton"].contains("max_iterations")) scene.reduced_iteration_budget = 0;
      if (root["newton"].contains("soft_tissue_gradient_tolerance"))
        scene.soft_tissue_gradient_tolerance =
            toRange(root["newton"]["soft_tissue_gradient_tolerance"],
                    "newton.soft_tissue_gradient_tolerance", 0.0, 1.0, true);
      if (root["newton"].contains("reduced_gradient_tolerance"))
        scene.reduced_gradient_tolerance =
            toRange(root["newton"]["reduced_gradient_tolerance"],
                    "newton.reduced_gradient_tolerance", 0.0, 1.0, true);
      if (root["newton"].contains("soft_tissue_lagged"))
        readLagged(root["newton"]["soft_tissue_lagged"], "newton.soft_tissue_lagged",
                   scene.soft_tissue_lagged);
      if (root["newton"].contains("reduced_lagged"))
        readLagged(root["newton"]["reduced_lagged"], "newton.reduced_lagged", scene.reduced_lagged);
      if (root["newton"].contains("soft_tissue_presolve"))
        readPresolve(root["newton"]["soft_tissue_presolve"], "newton.soft_tissue_presolve",
                     scene.soft_tissue_presolve);
      if (root["newton"].contains("reduced_presolve"))
        readPresolve(root["newton"]["reduced_presolve"], "newton.reduced_presolve",
                     scene.reduced_presolve);
    }

    if (!root.contains("avatars")) fail("avatars", "missing (a scene needs at least one avatar)");
    const json& avatars = root["avatars"];
    if (!avatars.is_array() || avatars.empty())
      fail("avatars", "expected a list of at least one avatar, got " + describe(avatars));
    std::set<std::string> avatar_names;
    for (size_t i = 0; i < avatars.size(); ++i) {
      AvatarSpec avatar = readAvatar(avatars[i], item("avatars", i), i, scene);
      if (!avatar_names.insert(avatar.name).second)
        fail(item("avatars", i) + ".name", "duplicate avatar name \"" + avatar.name + "\"");
      scene.avatars.push_back(std::move(avatar));
    }

    if (root.contains("colliders")) {
      const json& colliders = root["colliders"];
      if (!colliders.is_array())
        fail("colliders", "expected a list of colliders, got " + describe(colliders));
      std::set<std::string> collider_names;
      for (size_t i = 0; i < colliders.size(); ++i) {
        Collider collider = readCollider(colliders[i], item("colliders", i), i, scene);
        if (!collider_names.insert(collider.name).second)
          fail(item("colliders", i) + ".name", "duplicate collider name \"" + collider.name + "\"");
        scene.colliders.push_back(std::move(collider));
      }
    }
    if (root.contains("ground")) {
      readGround(root["ground"], "ground", scene.ground);
      for (const Collider& collider : scene.colliders)
        if (collider.name == "ground")
          fail("ground",
               "the scene also has a collider named \"ground\": give one ground, or rename "
               "that collider");
    }
    if (root.contains("outputs")) scene.outputs = readOutputs(root["outputs"], "outputs");
    if (!overrides.output_dir.empty()) scene.outputs.dir = overrides.output_dir;
    if (root.contains("cache_dir"))
      scene.cache_dir = directoryPath(toString(root["cache_dir"], "cache_dir"), "cache_dir");
    if (root.contains("use_cache")) scene.use_cache = toBool(root["use_cache"], "use_cache");
    if (!overrides.cache_dir.empty()) scene.cache_dir = overrides.cache_dir;
    if (overrides.no_cache) scene.use_cache = false;
    return scene;
  }

 private:
  void applyOverrides(SceneSpec& scene, const SceneOverrides& overrides) const {
    if (overrides.time_step != 0.0) {
      if (!(overrides.time_step > 0.0 && overrides.time_step <= 1.0))
        throw InputError("--time-step: expected 0 < value <= 1 (s), got " +
                         number(overrides.time_step));
      scene.time_step = overrides.time_step;
    }
    if (overrides.duration != 0.0) {
      if (!(overrides.duration > 0.0 && overrides.duration <= 1e6))
        throw InputError("--duration: expected 0 < value <= 1e6 (s), got " +
                         number(overrides.duration));
      scene.duration = overrides.duration;
    }
  }

  NewtonOptions readNewton(const json& node, const std::string& path) const {
    requireObject(node, path);
    checkKeys(node, path,
              {"max_iterations", "gradient_tolerance", "step_tolerance", "linear_solver",
               "soft_tissue_gradient_tolerance", "reduced_gradient_tolerance", "soft_tissue_lagged",
               "reduced_lagged", "soft_tissue_presolve", "reduced_presolve"});
    NewtonOptions newton;
    if (node.contains("max_iterations"))
      newton.max_iterations =
          toIntRange(node["max_iterations"], child(path, "max_iterations"), 1, 10000);
    if (node.contains("gradient_tolerance"))
      newton.gradient_tolerance =
          toRange(node["gradient_tolerance"], child(path, "gradient_tolerance"), 0.0, 1.0, true);
    if (node.contains("step_tolerance"))
      newton.step_tolerance =
          toRange(node["step_tolerance"], child(path, "step_tolerance"), 0.0, 1.0, false);
    if (node.contains("linear_solver")) {
      const std::string p = child(path, "linear_solver");
      const std::string name = toString(node["linear_solver"], p);
      if (name == "auto")
        newton.linear_solver = LinearSolverType::Auto;
      else if (name == "dense")
        newton.linear_solver = LinearSolverType::Dense;
      else if (name == "cholmod")
        newton.linear_solver = LinearSolverType::Cholmod;
      else
        fail(p, "expected \"auto\", \"dense\" or \"cholmod\", got \"" + name + "\"");
    }
    return newton;
  }

  /// The keys given override `lagged` (LaggedFactorOptions, flsh/solve/newton.h).
  void readLagged(const json& node, const std::string& path, LaggedFactorOptions& lagged) const {
    requireObject(node, path);
    checkKeys(node, path,
              {"enabled", "cg_relative_tolerance", "adaptive_forcing", "max_cg_iterations",
               "refactor_after_cg_iterations", "fast_preconditioner", "reuse_hessian_below",
               "coarse_correction"});
    if (node.contains("enabled")) lagged.enabled = toBool(node["enabled"], child(path, "enabled"));
    if (node.contains("cg_relative_tolerance")) {
      const std::string p = child(path, "cg_relative_tolerance");
      const double eta = toDouble(node["cg_relative_tolerance"], p);
      if (!(eta > 0.0 && eta < 1.0)) fail(p, "expected 0 < value < 1, got " + number(eta));
      lagged.cg_relative_tolerance = eta;
    }
    if (node.contains("adaptive_forcing"))
      lagged.adaptive_forcing = toBool(node["adaptive_forcing"], child(path, "adaptive_forcing"));
    if (node.contains("max_cg_iterations"))
      lagged.max_cg_iterations =
          toIntRange(node["max_cg_iterations"], child(path, "max_cg_iterations"), 1, 100000);
    if (node.contains("refactor_after_cg_iterations"))
      lagged.refactor_after_cg_iterations =
          toIntRange(node["refactor_after_cg_iterations"],
                     child(path, "refactor_after_cg_iterations"), 0, 100000);
    if (node.contains("fast_preconditioner"))
      lagged.fast_preconditioner =
          toBool(node["fast_preconditioner"], child(path, "fast_preconditioner"));
    if (node.contains("reuse_hessian_below")) {
      const std::string p = child(path, "reuse_hessian_below");
      const double below = toDouble(node["reuse_hessian_below"], p);
      if (!(below >= 0.0)) fail(p, "expected a value ≥ 0 (0: never), got " + number(below));
      lagged.reuse_hessian_below = below;
    }
    if (node.contains("coarse_correction"))
      lagged.coarse_correction =
          toBool(node["coarse_correction"], child(path, "coarse_correction"));
  }

  /// The keys given override `presolve` (CoarsePresolveOptions, flsh/solve/newton.h).
  void readPresolve(const json& node, const std::string& path,
                    CoarsePresolveOptions& presolve) const {
    requireObject(node, path);
    checkKeys(node, path, {"max_iterations", "relative_tolerance"});
    if (node.contains("max_iterations"))
      presolve.max_iterations =
          toIntRange(node["max_iterations"], child(path, "max_iterations"), 0, 1000);
    if (node.contains("relative_tolerance")) {
      const std::string p = child(path, "relative_tolerance");
      const double tolerance = toDouble(node["relative_tolerance"], p);
      if (!(tolerance > 0.0 && tolerance < 1.0))
        fail(p, "expected 0 < value < 1, got " + number(tolerance));
      presolve.relative_tolerance = tolerance;
    }
  }

  AvatarSpec readAvatar(const json& node, const std::string& path, size_t index,
                        const SceneSpec& scene) const {
    requireObject(node, path);
    checkKeys(node, path,
              {"name",
               "model",
               "vertices",
               "betas",
               "simulation",
               "resolution",
               "materials",
               "handles",
               "elastic_cubature",
               "inertial_cubature",
               "surface_partition_of_unity",
               "basis",
               "vibration_modes",
               "modal_columns",
               "motion",
               "motion_seconds",
               "up",
               "offset",
               "yaw_degrees",
               "options"});
    AvatarSpec avatar;
    const ReducedSettings reduced =
        presetReducedSettings(scene.preset);  // defaults of the ROM keys
    avatar.basis = reduced.basis_kind;
    avatar.vibration_modes = reduced.modes.vibration_modes;
    avatar.modal_columns = reduced.modes.columns;
    avatar.handles = reduced.num_handles;
    avatar.elastic_cubature = reduced.elastic_cubature_points;
    avatar.inertial_cubature = reduced.inertial_cubature_points;
    avatar.surface_partition_of_unity = reduced.surface_partition_of_unity;
    avatar.name = node.contains("name") ? toName(node["name"], child(path, "name"))
                                        : "avatar" + std::to_string(index);
    if (node.contains("model")) {
      const std::string p = child(path, "model");
      const std::string model = toString(node["model"], p);
      // "{gender}" is filled in with the clip's gender when the avatar is built.
      avatar.model = model == "synthetic" ? model
                     : model.find(kGenderPlaceholder) != std::string::npos
                         ? resolvedPath(model, p)
                         : existingFile(model, p, "body model");
    }
    if (node.contains("vertices")) {
      const std::string p = child(path, "vertices");
      if (avatar.model != "synthetic")
        fail(p, "only for \"model\": \"synthetic\" (a model file fixes its vertex count)");
      avatar.synthetic_vertices = toIntRange(node["vertices"], p, 200, 100000);
    }
    if (node.contains("betas")) {
      const std::string p = child(path, "betas");
      const json& betas = node["betas"];
      if (!betas.is_array() || betas.size() > 300)
        fail(p, "expected a list of at most 300 numbers, got " + describe(betas));
      avatar.betas.resize(long(betas.size()));
      for (size_t k = 0; k < betas.size(); ++k)
        avatar.betas[long(k)] = toDouble(betas[k], item(p, k));
    }
    if (node.contains("simulation")) {
      const std::string p = child(path, "simulation");
      const std::string simulation = toString(node["simulation"], p);
      if (simulation != "skeleton" && simulation != "fem" && simulation != "rom")
        fail(p, "expected \"skeleton\", \"fem\" or \"rom\", got \"" + simulation + "\"");
      avatar.simulation = simulation;
    }
    // Settings of the volumetric body, which only the soft-tissue models build.
    const bool soft = avatar.simulation == "fem" || avatar.simulation == "rom";
    const char* only_soft =
        "only for \"simulation\": \"fem\" or \"rom\" (the skeleton builds no tet mesh)";
    if (node.contains("resolution")) {
      const std::string p = child(path, "resolution");
      if (!soft) fail(p, only_soft);
      avatar.resolution = toRange(node["resolution"], p, 0.01, 100.0, false,
                                  "interior node density relative to the default");
    }
    if (node.contains("materials")) {
      const std::string p = child(path, "materials");
      if (!soft) fail(p, only_soft);
      avatar.material_file = existingFile(toString(node["materials"], p), p, "material");
    }
    // Settings of the reduced basis and its cubatures, which only the ROM builds.
    const std::string only_rom = "only for \"simulation\": \"rom\" (this avatar is \"" +
                                 avatar.simulation + "\", which has no reduced basis)";
    if (node.contains("basis")) {
      const std::string p = child(path, "basis");
      if (avatar.simulation != "rom") fail(p, only_rom);
      const std::string kind = toString(node["basis"], p);
      try {
        avatar.basis = parseReducedBasisKind(kind, p);
      } catch (const InputError&) {
        fail(p, "expected \"handles\", \"modes\" or \"modes+handles\", got \"" + kind + "\"");
      }
    }
    if (node.contains("handles")) {
      const std::string p = child(path, "handles");
      if (avatar.simulation != "rom") fail(p, only_rom);
      // Handles without a basis choose the handle basis (the scene files written before the
      // modal basis became the default keep their meaning); the modal basis alone has none.
      if (!node.contains("basis"))
        avatar.basis = ReducedBasisKind::Handles;
      else if (avatar.basis == ReducedBasisKind::Modes)
        fail(p,
             "not used by \"basis\": \"modes\" (handles belong to \"basis\": \"handles\" "
             "or \"modes+handles\")");
      avatar.handles = toIntRange(node["handles"], p, 1, 100000);
    }
    for (const char* key : {"elastic_cubature", "inertial_cubature"}) {
      if (!node.contains(key)) continue;
      const std::string p = child(path, key);
      if (avatar.simulation != "rom") fail(p, only_rom);
      const int points = toInt(node[key], p);
      if (points < 0 || points > 10000000)
        fail(p,
             "expected a number of sample tets in [0, 10000000] (0 = off: exact "
             "integration), got " +
                 std::to_string(points));
      (std::string(key) == "elastic_cubature" ? avatar.elastic_cubature
                                              : avatar.inertial_cubature) = points;
    }
    if (node.contains("surface_partition_of_unity")) {
      const std::string p = child(path, "surface_partition_of_unity");
      if (avatar.simulation != "rom") fail(p, only_rom);
      avatar.surface_partition_of_unity = toBool(node["surface_partition_of_unity"], p);
    }
    for (const char* key : {"vibration_modes", "modal_columns"}) {
      if (!node.contains(key)) continue;
      const std::string p = child(path, key);
      if (avatar.simulation != "rom" || avatar.basis == ReducedBasisKind::Handles)
        fail(p, std::string("only for \"simulation\": \"rom\" with \"basis\": \"modes\" or "
                            "\"modes+handles\"") +
                    (avatar.simulation == "rom" && !node.contains("basis")
                         ? " (\"handles\" without a \"basis\" chooses the handle basis)"
                         : ""));
      (std::string(key) == "vibration_modes" ? avatar.vibration_modes : avatar.modal_columns) =
          toIntRange(node[key], p, 0, 100000);
    }
    bool builtin_motion = false;
    if (node.contains("motion")) {
      const std::string p = child(path, "motion");
      const std::string motion = toString(node["motion"], p);
      const std::string prefix = "builtin:";
      if (motion.rfind(prefix, 0) == 0) {
        const std::string name = motion.substr(prefix.size());
        const auto names = builtinMotionNames();
        if (std::find(names.begin(), names.end(), name) == names.end())
          fail(p, "unknown built-in motion \"" + name + "\" (known: " + joinNames(names) + ")");
        avatar.motion = motion;
        builtin_motion = true;
      } else {
        const auto names = builtinMotionNames();
        std::string resolved;
        try {
          resolved = existingFile(motion, p, "motion");
        } catch (const FileError& e) {
          if (std::find(names.begin(), names.end(), motion) != names.end())
            throw FileError(std::string(e.what()) +
                            " (for the built-in motion write \"builtin:" + motion + "\")");
          throw;
        }
        avatar.motion = resolved;
      }
    }
    if (node.contains("motion_seconds")) {
      const std::string p = child(path, "motion_seconds");
      if (!builtin_motion) fail(p, "only for a built-in motion (\"motion\": \"builtin:NAME\")");
      avatar.motion_seconds = toRange(node["motion_seconds"], p, 0.0, 1e5, true, "s");
    }
    if (node.contains("up")) {
      const std::string p = child(path, "up");
      if (avatar.motion.empty() || builtin_motion)
        fail(p, "only for a motion file (built-in motions are made y up)");
      avatar.up = toString(node["up"], p);
      if (avatar.up != "y" && avatar.up != "z")
        fail(p,
             "expected \"y\" or \"z\" (the up axis the clip was recorded in; AMASS: \"z\"), "
             "got \"" +
                 avatar.up + "\"");
    }
    if (avatar.model.find(kGenderPlaceholder) != std::string::npos && avatar.motion.empty())
      fail(child(path, "model"), std::string("\"") + kGenderPlaceholder +
                                     "\" is filled in with the motion's gender, but this avatar "
                                     "has no motion");
    if (node.contains("offset")) avatar.offset = toVec3(node["offset"], child(path, "offset"));
    if (node.contains("yaw_degrees"))
      avatar.yaw = toRange(node["yaw_degrees"], child(path, "yaw_degrees"), -3600.0, 3600.0, false,
                           "degrees") *
                   kPi / 180.0;
    avatar.options.time_step = scene.time_step;
    if (node.contains("options"))
      readSimulableOptions(node["options"], child(path, "options"), avatar.options);
    return avatar;
  }

  void readSimulableOptions(const json& node, const std::string& path,
                            SimulableOptions& options) const {
    requireObject(node, path);
    checkKeys(node, path,
              {"tracking_stiffness", "tracking_inertia_floor", "root_stiffness", "joint_stiffness",
               "contact_stiffness", "gravity", "kinematic_bones", "track_mocap"});
    // Bounds far beyond any body (defaults: tracking 355, root 630 1/s², joints 1e5 N/m,
    // contact 2e6 N/m³, gravity 9.81 m/s²) that keep each energy term finite.
    if (node.contains("tracking_stiffness"))
      options.tracking_stiffness = toRange(
          node["tracking_stiffness"], child(path, "tracking_stiffness"), 0.0, 1e9, false, "1/s²");
    if (node.contains("tracking_inertia_floor"))
      options.tracking_inertia_floor =
          toRange(node["tracking_inertia_floor"], child(path, "tracking_inertia_floor"), 0.0, 1e6,
                  false, "kg·m²");
    if (node.contains("root_stiffness"))
      options.root_stiffness =
          toRange(node["root_stiffness"], child(path, "root_stiffness"), 0.0, 1e9, false, "1/s²");
    if (node.contains("joint_stiffness"))
      options.joint_stiffness =
          toRange(node["joint_stiffness"], child(path, "joint_stiffness"), 0.0, 1e12, true, "N/m");
    if (node.contains("contact_stiffness"))
      options.contact.stiffness = toRange(
          node["contact_stiffness"], child(path, "contact_stiffness"), 0.0, 1e15, false, "N/m³");
    if (node.contains("gravity"))
      options.gravity = toVec3(node["gravity"], child(path, "gravity"), 1e3, "m/s²");
    if (node.contains("track_mocap"))
      options.track_mocap = toBool(node["track_mocap"], child(path, "track_mocap"));
    if (node.contains("kinematic_bones")) {
      const std::string p = child(path, "kinematic_bones");
      const json& bones = node["kinematic_bones"];
      if (!bones.is_array())
        fail(p, "expected a list of bone indices 0..23, got " + describe(bones));
      options.kinematic_bones.clear();
      for (size_t k = 0; k < bones.size(); ++k) {
        const int bone = toIntRange(bones[k], item(p, k), 0, 23);
        if (std::find(options.kinematic_bones.begin(), options.kinematic_bones.end(), bone) !=
            options.kinematic_bones.end())
          fail(item(p, k), "bone " + std::to_string(bone) + " is listed twice");
        options.kinematic_bones.push_back(bone);
      }
    }
  }

  Collider readCollider(const json& node, const std::string& path, size_t index,
                        const SceneSpec& scene) const {
    requireObject(node, path);
    if (!node.contains("type"))
      fail(child(path, "type"), "missing (expected \"plane\", \"sphere\" or \"capsule\")");
    const std::string type = toString(node["type"], child(path, "type"));
    Collider collider;
    if (type == "plane") {
      checkKeys(node, path, {"name", "type", "point", "normal", "velocity", "path"});
      const Vec3 point =
          node.contains("point") ? toVec3(node["point"], child(path, "point")) : Vec3::Zero();
      const Vec3 normal =
          node.contains("normal") ? toVec3(node["normal"], child(path, "normal")) : Vec3::UnitY();
      if (!(normal.norm() > 1e-12))
        fail(child(path, "normal"), "expected a nonzero vector, got [0, 0, 0]");
      collider = Collider::plane(point, normal);
    } else if (type == "sphere") {
      checkKeys(node, path, {"name", "type", "center", "radius", "velocity", "path"});
      if (!node.contains("center")) fail(child(path, "center"), "missing (expected [x, y, z], m)");
      if (!node.contains("radius"))
        fail(child(path, "radius"), "missing (expected a radius > 0, m)");
      collider = Collider::sphere(
          toVec3(node["center"], child(path, "center")),
          toRange(node["radius"], child(path, "radius"), 0.0, kMaxStatePosition, true, "m"));
    } else if (type == "capsule") {
      checkKeys(node, path, {"name", "type", "a", "b", "radius", "velocity", "path"});
      for (const char* key : {"a", "b"})
        if (!node.contains(key)) fail(child(path, key), "missing (expected [x, y, z], m)");
      if (!node.contains("radius"))
        fail(child(path, "radius"), "missing (expected a radius > 0, m)");
      collider = Collider::capsule(
          toVec3(node["a"], child(path, "a")), toVec3(node["b"], child(path, "b")),
          toRange(node["radius"], child(path, "radius"), 0.0, kMaxStatePosition, true, "m"));
    } else {
      fail(child(path, "type"),
           "expected \"plane\", \"sphere\" or \"capsule\", got \"" + type + "\"");
    }
    collider.name = node.contains("name") ? toName(node["name"], child(path, "name"))
                                          : type + std::to_string(index);
    if (node.contains("velocity") && node.contains("path"))
      fail(child(path, "velocity"), "give either \"velocity\" or \"path\", not both");
    if (node.contains("velocity")) {
      // Constant velocity over the whole simulation (held after the last key otherwise).
      const Vec3 velocity =
          toVec3(node["velocity"], child(path, "velocity"), kMaxStateVelocity, "m/s");
      collider.path = ColliderPath::constantVelocity(velocity, scene.duration + scene.time_step);
    }
    if (node.contains("path")) collider.path = readPath(node["path"], child(path, "path"));
    return collider;
  }

  ColliderPath readPath(const json& node, const std::string& path) const {
    requireObject(node, path);
    checkKeys(node, path, {"times", "offsets"});
    for (const char* key : {"times", "offsets"})
      if (!node.contains(key)) fail(child(path, key), "missing");
    const json& times = node["times"];
    const json& offsets = node["offsets"];
    if (!times.is_array() || times.empty())
      fail(child(path, "times"),
           "expected a list of at least one time (s), got " + describe(times));
    if (!offsets.is_array() || offsets.size() != times.size())
      fail(child(path, "offsets"), "expected a list of " + std::to_string(times.size()) +
                                       " offsets [x, y, z] (one per time), got " +
                                       describe(offsets));
    ColliderPath result;
    for (size_t k = 0; k < times.size(); ++k) {
      const double t = toDouble(times[k], item(child(path, "times"), k));
      if (k > 0 && !(t > result.times.back()))
        fail(item(child(path, "times"), k), "times must increase strictly, got " + number(t) +
                                                " after " + number(result.times.back()));
      result.times.push_back(t);
      result.offsets.push_back(toVec3(offsets[k], item(child(path, "offsets"), k)));
    }
    result.validate(origin_ + ": " + path);
    return result;
  }

  /// "ground": "auto" | height (m) | {"height": "auto" | height, "over_seconds": s}.
  void readGround(const json& node, const std::string& path, GroundSpec& ground) const {
    const auto readHeight = [&](const json& value, const std::string& p) {
      if (value.is_string()) {
        const std::string text = value.get<std::string>();
        if (text != "auto")
          fail(p,
               "expected \"auto\" (the plane under the avatars' lowest point) or a height "
               "(m), got \"" +
                   text + "\"");
        ground.automatic = true;
      } else {
        ground.height = toRange(value, p, -kMaxStatePosition, kMaxStatePosition, false, "m");
      }
    };
    ground.enabled = true;
    if (!node.is_object()) return readHeight(node, path);
    checkKeys(node, path, {"height", "over_seconds"});
    if (!node.contains("height"))
      fail(child(path, "height"), "missing (expected \"auto\" or a height, m)");
    readHeight(node["height"], child(path, "height"));
    if (node.contains("over_seconds")) {
      if (!ground.automatic) fail(child(path, "over_seconds"), "only for \"height\": \"auto\"");
      ground.over_seconds =
          toRange(node["over_seconds"], child(path, "over_seconds"), 0.0, 1e6, false, "s");
    }
  }

  OutputSpec readOutputs(const json& node, const std::string& path) const {
    requireObject(node, path);
    checkKeys(node, path, {"dir", "ply", "npz", "gltf", "png", "png_frames", "every"});
    OutputSpec outputs;
    if (node.contains("dir")) {
      outputs.dir = toString(node["dir"], child(path, "dir"));
      if (outputs.dir.empty())
        fail(child(path, "dir"), "expected a directory, got an empty string");
    }
    if (node.contains("ply")) outputs.ply = toBool(node["ply"], child(path, "ply"));
    if (node.contains("npz")) outputs.npz = toBool(node["npz"], child(path, "npz"));
    if (node.contains("gltf")) outputs.gltf = toBool(node["gltf"], child(path, "gltf"));
    if (node.contains("png")) outputs.png = toBool(node["png"], child(path, "png"));
    if (node.contains("png_frames"))
      outputs.png_frames = toIntRange(node["png_frames"], child(path, "png_frames"), 1, 100);
    if (node.contains("every"))
      outputs.every = toIntRange(node["every"], child(path, "every"), 1, 1000000);
    return outputs;
  }

  std::string origin_;
  std::string base_dir_;
};

}  // namespace

SceneSpec parseSceneJson(const std::string& text, const std::string& origin,
                         const std::string& base_dir, const SceneOverrides& overrides) {
  // Scene files nest a few levels ("avatars": [{"path": {"offsets": [[…]]}}]).
  io::checkJsonNesting(text, origin, "scene files nest a few levels");
  json root;
  try {
    root = json::parse(text);
  } catch (const json::parse_error& e) {
    throw InputError(origin + ": malformed JSON at byte " + std::to_string(e.byte) + " (" +
                     io::lineColumn(text, e.byte) + "): " + e.what());
  } catch (const json::exception& e) {
    // E.g. a number too large for a double (out_of_range.406).
    throw InputError(origin + ": invalid JSON: " + e.what());
  }
  SceneSpec scene = SceneReader(origin, base_dir).read(root, overrides);
  scene.source = origin;
  return scene;
}

SceneSpec loadSceneFile(const std::string& path, const SceneOverrides& overrides) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw FileError(path + ": scene file not found");
  // A FIFO, directory or device is refused (InputError), never opened.
  const std::string text = io::readRegularFileText(path, "a JSON scene file");
  const fs::path parent = fs::path(path).parent_path();
  return parseSceneJson(text, path, parent.empty() ? "." : parent.string(), overrides);
}

SceneSpec defaultScene(const SceneOverrides& overrides) {
  return parseSceneJson(kDefaultSceneJson, "builtin default scene", ".", overrides);
}

}  // namespace flsh
