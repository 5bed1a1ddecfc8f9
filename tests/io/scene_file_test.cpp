#include "flsh/io/scene_file.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <initializer_list>

#include "flsh/body/body_forward.h"
#include "flsh/body/motion.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/core/error.h"
#include "flsh/io/scene_build.h"
#include "flsh/solve/scene.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using ::testing::HasSubstr;
namespace fs = std::filesystem;
using test::messageOf;

SceneSpec parse(const std::string& text, const std::string& base_dir = ".") {
  return parseSceneJson(text, "scene.json", base_dir);
}

std::string inputError(const std::string& text) {
  return messageOf<InputError>([&] { parse(text); });
}

/// A scene text and a part of the InputError it must raise.
struct ErrorCase {
  const char* json;
  const char* expected;
};

void expectInputErrors(std::initializer_list<ErrorCase> cases) {
  for (const ErrorCase& c : cases) {
    SCOPED_TRACE(c.json);
    EXPECT_THAT(inputError(c.json), HasSubstr(c.expected));
  }
}

void writeText(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
}

const BodyModel& smallBody() {
  static const BodyModel body = [] {
    SyntheticBodyOptions options;
    options.vertices = 1000;
    return makeSyntheticBody(options);
  }();
  return body;
}

TEST(SceneFile, MinimalSceneGetsDocumentedDefaults) {
  const SceneSpec scene = parse(R"({"avatars": [{}]})");
  EXPECT_EQ(scene.source, "scene.json");
  ASSERT_EQ(scene.avatars.size(), 1u);
  const AvatarSpec& a = scene.avatars[0];
  EXPECT_EQ(a.name, "avatar0");
  EXPECT_EQ(a.model, "synthetic");
  EXPECT_EQ(a.synthetic_vertices, 6890);
  EXPECT_EQ(a.simulation, "skeleton");
  EXPECT_TRUE(a.motion.empty());
  EXPECT_EQ(a.betas.size(), 0);
  EXPECT_DOUBLE_EQ(scene.time_step, 1.0 / 60.0);
  EXPECT_DOUBLE_EQ(a.options.time_step, 1.0 / 60.0);
  EXPECT_DOUBLE_EQ(scene.duration, 2.0);
  EXPECT_TRUE(scene.avatar_contact);
  EXPECT_TRUE(scene.colliders.empty());
  EXPECT_EQ(scene.outputs.dir, "out/simulate");
  EXPECT_TRUE(scene.outputs.ply && scene.outputs.npz && scene.outputs.gltf && scene.outputs.png);
  EXPECT_EQ(scene.outputs.png_frames, 5);
  EXPECT_EQ(scene.outputs.every, 1);
  EXPECT_EQ(scene.newton.max_iterations, NewtonOptions().max_iterations);
}

TEST(SceneFile, ReadsEveryKey) {
  const SceneSpec scene = parse(R"({
    "time_step": 0.01, "duration": 0.5, "avatar_contact": false,
    "newton": {"max_iterations": 12, "gradient_tolerance": 1e-5, "step_tolerance": 1e-8,
               "linear_solver": "dense", "soft_tissue_gradient_tolerance": 3e-4},
    "avatars": [{"name": "a-1", "vertices": 800, "betas": [0.5, -1],
                 "motion": "builtin:jumping_jacks", "motion_seconds": 1.5,
                 "offset": [1, 0, -2], "yaw_degrees": 90,
                 "options": {"tracking_stiffness": 100, "tracking_inertia_floor": 0.02,
                             "root_stiffness": 50, "joint_stiffness": 2e4, "contact_stiffness": 1e5,
                             "gravity": [0, -1.62, 0], "kinematic_bones": [0, 15],
                             "track_mocap": false}},
                {"name": "b"}],
    "colliders": [{"type": "plane", "point": [0, -1, 0], "normal": [0, 2, 0]},
                  {"name": "ball", "type": "sphere", "center": [1, 2, 3], "radius": 0.2,
                   "velocity": [-4, 0, 0]},
                  {"type": "capsule", "a": [0, 0, 0], "b": [0, 1, 0], "radius": 0.1,
                   "path": {"times": [0, 1], "offsets": [[0, 0, 0], [1, 0, 0]]}}],
    "outputs": {"dir": "elsewhere", "ply": false, "npz": true, "gltf": false, "png": false,
                "png_frames": 3, "every": 2}})");
  EXPECT_DOUBLE_EQ(scene.time_step, 0.01);
  EXPECT_DOUBLE_EQ(scene.duration, 0.5);
  EXPECT_FALSE(scene.avatar_contact);
  EXPECT_EQ(scene.newton.max_iterations, 12);
  EXPECT_DOUBLE_EQ(scene.newton.gradient_tolerance, 1e-5);
  EXPECT_DOUBLE_EQ(scene.newton.step_tolerance, 1e-8);
  EXPECT_EQ(scene.newton.linear_solver, LinearSolverType::Dense);
  EXPECT_DOUBLE_EQ(scene.soft_tissue_gradient_tolerance, 3e-4);
  ASSERT_EQ(scene.avatars.size(), 2u);
  const AvatarSpec& a = scene.avatars[0];
  EXPECT_EQ(a.name, "a-1");
  EXPECT_EQ(a.synthetic_vertices, 800);
  ASSERT_EQ(a.betas.size(), 2);
  EXPECT_DOUBLE_EQ(a.betas[1], -1.0);
  EXPECT_EQ(a.motion, "builtin:jumping_jacks");
  EXPECT_DOUBLE_EQ(a.motion_seconds, 1.5);
  EXPECT_TRUE(a.offset.isApprox(Vec3(1, 0, -2)));
  EXPECT_NEAR(a.yaw, M_PI / 2, 1e-12);
  EXPECT_DOUBLE_EQ(a.options.time_step, 0.01);
  EXPECT_DOUBLE_EQ(a.options.tracking_stiffness, 100);
  EXPECT_DOUBLE_EQ(a.options.tracking_inertia_floor, 0.02);
  EXPECT_DOUBLE_EQ(a.options.root_stiffness, 50);
  EXPECT_DOUBLE_EQ(a.options.joint_stiffness, 2e4);
  EXPECT_DOUBLE_EQ(a.options.contact.stiffness, 1e5);
  EXPECT_TRUE(a.options.gravity.isApprox(Vec3(0, -1.62, 0)));
  EXPECT_EQ(a.options.kinematic_bones, (std::vector<int>{0, 15}));
  EXPECT_FALSE(a.options.track_mocap);
  EXPECT_EQ(scene.avatars[1].name, "b");

  ASSERT_EQ(scene.colliders.size(), 3u);
  const Collider& plane = scene.colliders[0];
  EXPECT_EQ(plane.shape(), ColliderShape::Plane);
  EXPECT_EQ(plane.name, "plane0");
  EXPECT_NEAR(plane.signedDistance(Vec3(5, 0.5, 7), 0.0), 1.5, 1e-12);  // normal normalized
  const Collider& ball = scene.colliders[1];
  EXPECT_EQ(ball.shape(), ColliderShape::Sphere);
  EXPECT_EQ(ball.name, "ball");
  EXPECT_DOUBLE_EQ(ball.radius(), 0.2);
  // The velocity holds over the whole simulation.
  EXPECT_TRUE(ball.path.offsetAt(0.5).isApprox(Vec3(-2, 0, 0), 1e-12));
  const Collider& capsule = scene.colliders[2];
  EXPECT_EQ(capsule.name, "capsule2");
  EXPECT_TRUE(capsule.path.offsetAt(0.5).isApprox(Vec3(0.5, 0, 0), 1e-12));

  EXPECT_EQ(scene.outputs.dir, "elsewhere");
  EXPECT_FALSE(scene.outputs.ply);
  EXPECT_FALSE(scene.outputs.gltf);
  EXPECT_FALSE(scene.outputs.png);
  EXPECT_EQ(scene.outputs.png_frames, 3);
  EXPECT_EQ(scene.outputs.every, 2);
}

TEST(SceneFile, UnknownKeysAreNamedWithTheirPath) {
  std::string m = inputError(R"({"avatars": [{"optoins": {}}]})");
  EXPECT_THAT(m, HasSubstr("scene.json: avatars[0].optoins: unknown key (known: name, model"));
  EXPECT_THAT(m, HasSubstr("options"));
  m = inputError(R"({"avatars": [{}], "tim_step": 0.1})");
  EXPECT_THAT(m, HasSubstr("scene.json: tim_step: unknown key (known: time_step"));
  m = inputError(R"({"avatars": [{"options": {"gravty": [0, 0, 0]}}]})");
  EXPECT_THAT(m, HasSubstr("avatars[0].options.gravty: unknown key"));
  m = inputError(R"({"avatars": [{}], "newton": {"iterations": 3}})");
  EXPECT_THAT(m, HasSubstr("newton.iterations: unknown key (known: max_iterations"));
  m = inputError(R"({"avatars": [{}], "colliders": [{"type": "plane", "radius": 1}]})");
  EXPECT_THAT(m, HasSubstr("colliders[0].radius: unknown key (known: name, type, point, normal"));
  m = inputError(R"({"avatars": [{}], "outputs": {"obj": true}})");
  EXPECT_THAT(m, HasSubstr("outputs.obj: unknown key"));
  m = inputError(R"({"avatars": [{}], "colliders": [{"type": "capsule", "a": [0,0,0],
                    "b": [0,1,0], "radius": 1, "path": {"times": [0], "offset": [[0,0,0]]}}]})");
  EXPECT_THAT(m, HasSubstr("colliders[0].path.offset: unknown key (known: times, offsets)"));
}

TEST(SceneFile, WrongTypesAndValuesAreNamedWithTheirPath) {
  expectInputErrors({
      {R"({"avatars": [{}], "time_step": -0.1})",
       "scene.json: time_step: expected 0 < value <= 1 (s), got -0.1"},
      {R"({"avatars": [{}], "time_step": "fast"})",
       "time_step: expected a number, got string \"fast\""},
      {R"({"avatars": [{}], "duration": 0})", "duration: expected 0 < value"},
      {R"({"avatars": [{}], "duration": 1e6, "time_step": 1e-4})",
       "duration: duration / time_step"},
      {R"({"avatars": [{}], "avatar_contact": 1})", "avatar_contact: expected true or false"},
      {R"({"avatars": [{}], "newton": {"max_iterations": 2.5}})",
       "newton.max_iterations: expected an integer"},
      {R"({"avatars": [{}], "newton": {"linear_solver": "lu"}})",
       "newton.linear_solver: expected \"auto\""},
      {R"({"avatars": []})", "avatars: expected a list of at least one avatar"},
      {R"({"time_step": 0.01})", "avatars: missing"},
      {R"([1, 2])", "expected a JSON object, got array"},
      {R"({"avatars": [{"offset": [1, 2]}]})",
       "avatars[0].offset: expected 3 numbers [x, y, z], got array [1,2]"},
      {R"({"avatars": [{"options": {"gravity": [0, "down", 0]}}]})",
       "avatars[0].options.gravity[1]: expected a number"},
      {R"({"avatars": [{"simulation": "cloth"}]})",
       "avatars[0].simulation: expected \"skeleton\", \"fem\" or \"rom\", got \"cloth\""},
      {R"({"avatars": [{"simulation": "ROM"}]})", "avatars[0].simulation: expected \"skeleton\""},
      {R"({"avatars": [{"simulation": "FEM"}]})", "avatars[0].simulation: expected \"skeleton\""},
      {R"({"avatars": [{"vertices": 50}]})",
       "avatars[0].vertices: expected an integer in [200, 100000], got 50"},
      {R"({"avatars": [{"name": "a/b"}]})", "avatars[0].name: expected a name"},
      {R"({"avatars": [{"name": "x"}, {"name": "x"}]})", "avatars[1].name: duplicate avatar name"},
      {R"({"avatars": [{"motion": "builtin:moonwalk"}]})",
       "avatars[0].motion: unknown built-in motion \"moonwalk\" (known: "},
      {R"({"avatars": [{"motion_seconds": 2}]})",
       "avatars[0].motion_seconds: only for a built-in motion"},
      {R"({"avatars": [{"options": {"kinematic_bones": [0, 24]}}]})",
       "avatars[0].options.kinematic_bones[1]: expected an integer in [0, 23], got 24"},
      {R"({"avatars": [{"options": {"kinematic_bones": [3, 3]}}]})",
       "kinematic_bones[1]: bone 3 is listed twice"},
      {R"({"avatars": [{"options": {"joint_stiffness": 0}}]})",
       "avatars[0].options.joint_stiffness: expected 0 < value"},
      {R"({"avatars": [{"options": {"tracking_stiffness": -1}}]})",
       "options.tracking_stiffness: expected 0 <= value"},
      {R"({"avatars": [{"options": {"tracking_inertia_floor": -0.01}}]})",
       "options.tracking_inertia_floor: expected 0 <= value"},
      {R"({"avatars": [{}], "colliders": [{"type": "sphere", "center": [0,0,0], "radius": 0}]})",
       "colliders[0].radius: expected 0 < value <= 10000 (m), got 0"},
      {R"({"avatars": [{}], "colliders": [{"type": "sphere", "radius": 1}]})",
       "colliders[0].center: missing"},
      {R"({"avatars": [{}], "colliders": [{"type": "box"}]})",
       "colliders[0].type: expected \"plane\", \"sphere\" or \"capsule\", got \"box\""},
      {R"({"avatars": [{}], "colliders": [{"point": [0,0,0]}]})", "colliders[0].type: missing"},
      {R"({"avatars": [{}], "colliders": [{"type": "plane", "normal": [0,0,0]}]})",
       "colliders[0].normal: expected a nonzero vector"},
      {R"({"avatars": [{}], "colliders": [{"type": "plane", "velocity": [1,0,0], "path": {"times": [0], "offsets": [[0,0,0]]}}]})",
       "colliders[0].velocity: give either"},
      {R"({"avatars": [{}], "colliders": [{"type": "plane", "path": {"times": [0, 0], "offsets": [[0,0,0], [1,0,0]]}}]})",
       "colliders[0].path.times[1]: times must increase strictly"},
      {R"({"avatars": [{}], "colliders": [{"type": "plane", "path": {"times": [0, 1], "offsets": [[0,0,0]]}}]})",
       "colliders[0].path.offsets: expected a list of 2 offsets"},
      {R"({"avatars": [{}], "colliders": [{"type": "plane", "name": "g"}, {"type": "plane", "name": "g"}]})",
       "colliders[1].name: duplicate collider name"},
      {R"({"avatars": [{}], "outputs": {"every": 0}})",
       "outputs.every: expected an integer in [1, 1000000], got 0"},
      {R"({"avatars": [{}], "outputs": {"dir": ""}})", "outputs.dir: expected a directory"},
      {R"({"avatars": [{}], "duration": 1e400})",
       "scene.json: invalid JSON: [json.exception.out_of_range.406] number overflow"},
  });
}

TEST(SceneFile, FemAvatarsReadTheirVolumetricSettings) {
  const SceneSpec plain = parse(R"({"avatars": [{"simulation": "fem"}]})");
  EXPECT_EQ(plain.avatars[0].simulation, "fem");
  EXPECT_DOUBLE_EQ(plain.avatars[0].resolution, TetMeshOptions().resolution);
  EXPECT_TRUE(plain.avatars[0].material_file.empty());
  EXPECT_TRUE(plain.cache_dir.empty());
  EXPECT_TRUE(plain.use_cache);

  const std::string dir = test::freshTempDir("scene_fem");
  fs::create_directories(fs::path(dir) / "data");
  writeText((fs::path(dir) / "data" / "soft.json").string(), "{}");
  const std::string scene_path = (fs::path(dir) / "scene.json").string();
  writeText(scene_path, R"({"cache_dir": "cache", "use_cache": false, "avatars": [
      {"name": "soft", "vertices": 600, "simulation": "fem", "resolution": 0.25,
       "materials": "data/soft.json"},
      {"name": "rigid", "vertices": 600, "simulation": "skeleton"}]})");
  const SceneSpec scene = loadSceneFile(scene_path);
  ASSERT_EQ(scene.avatars.size(), 2u);
  EXPECT_EQ(scene.avatars[0].simulation, "fem");
  EXPECT_DOUBLE_EQ(scene.avatars[0].resolution, 0.25);
  EXPECT_EQ(fs::path(scene.avatars[0].material_file),
            (fs::path(dir) / "data" / "soft.json").lexically_normal());
  EXPECT_EQ(scene.avatars[1].simulation, "skeleton");
  EXPECT_EQ(fs::path(scene.cache_dir), (fs::path(dir) / "cache").lexically_normal());
  EXPECT_FALSE(scene.use_cache);

  // The command line's --cache / --no-cache win over the file.
  SceneOverrides overrides;
  overrides.cache_dir = "elsewhere";
  EXPECT_EQ(loadSceneFile(scene_path, overrides).cache_dir, "elsewhere");
  writeText(scene_path, R"({"use_cache": true, "avatars": [{"simulation": "fem"}]})");
  overrides = SceneOverrides();
  overrides.no_cache = true;
  EXPECT_FALSE(loadSceneFile(scene_path, overrides).use_cache);
  EXPECT_TRUE(loadSceneFile(scene_path).use_cache);

  // A missing material file names the key and the resolved path; a cache_dir that is a file
  // cannot be a cache.
  writeText(scene_path, R"({"avatars": [{"simulation": "fem", "materials": "none.json"}]})");
  EXPECT_THAT(messageOf<FileError>([&] { loadSceneFile(scene_path); }),
              HasSubstr(scene_path + ": avatars[0].materials: material file not found: " +
                        (fs::path(dir) / "none.json").string()));
  writeText(scene_path, R"({"cache_dir": "data/soft.json", "avatars": [{"simulation": "fem"}]})");
  EXPECT_THAT(messageOf<FileError>([&] { loadSceneFile(scene_path); }),
              HasSubstr(scene_path + ": cache_dir: expected a directory, but " +
                        (fs::path(dir) / "data" / "soft.json").string() + " is a file"));
}

TEST(SceneFile, RomAvatarsReadTheirVolumetricAndReducedSettings) {
  const SceneSpec plain = parse(R"({"avatars": [{"simulation": "rom"}]})");
  const AvatarSpec& a = plain.avatars[0];
  EXPECT_EQ(a.simulation, "rom");
  EXPECT_DOUBLE_EQ(a.resolution, TetMeshOptions().resolution);
  EXPECT_TRUE(a.material_file.empty());
  // The documented defaults: the modal basis of 24 vibration modes compressed to 72 columns, 500
  // sample tets per cubature (both on); 87 handles for the handle basis.
  EXPECT_EQ(a.basis, ReducedBasisKind::Modes);
  EXPECT_EQ(a.vibration_modes, 24);
  EXPECT_EQ(a.modal_columns, 72);
  EXPECT_EQ(a.basis, ReducedSettings().basis_kind);
  EXPECT_EQ(a.vibration_modes, ReducedSettings().modes.vibration_modes);
  EXPECT_EQ(a.modal_columns, ReducedSettings().modes.columns);
  EXPECT_EQ(a.handles, 87);
  EXPECT_EQ(a.elastic_cubature, 500);
  EXPECT_EQ(a.inertial_cubature, 500);
  EXPECT_EQ(a.handles, ReducedSettings().num_handles);
  EXPECT_EQ(a.elastic_cubature, ReducedSettings().elastic_cubature_points);
  EXPECT_EQ(a.inertial_cubature, ReducedSettings().inertial_cubature_points);
  EXPECT_FALSE(a.surface_partition_of_unity);
  EXPECT_EQ(a.surface_partition_of_unity, ReducedSettings().surface_partition_of_unity);
  EXPECT_LT(plain.reduced_gradient_tolerance, 0.0);  // absent: the scene's default

  const std::string dir = test::freshTempDir("scene_rom");
  writeText((fs::path(dir) / "soft.json").string(), "{}");
  const SceneSpec scene = parse(R"({
    "newton": {"soft_tissue_gradient_tolerance": 2e-4, "reduced_gradient_tolerance": 3e-6},
    "avatars": [{"name": "r", "vertices": 600, "simulation": "rom", "resolution": 0.3,
                 "materials": "soft.json", "handles": 12, "elastic_cubature": 40,
                 "inertial_cubature": 0, "surface_partition_of_unity": true,
                 "basis": "modes+handles", "vibration_modes": 12, "modal_columns": 48},
                {"name": "f", "simulation": "fem", "resolution": 0.5}]})",
                                dir);
  ASSERT_EQ(scene.avatars.size(), 2u);
  const AvatarSpec& r = scene.avatars[0];
  EXPECT_EQ(r.simulation, "rom");
  EXPECT_DOUBLE_EQ(r.resolution, 0.3);
  EXPECT_EQ(fs::path(r.material_file), (fs::path(dir) / "soft.json").lexically_normal());
  EXPECT_EQ(r.handles, 12);
  EXPECT_EQ(r.elastic_cubature, 40);
  EXPECT_EQ(r.inertial_cubature, 0);  // off
  EXPECT_TRUE(r.surface_partition_of_unity);
  EXPECT_EQ(r.basis, ReducedBasisKind::ModesAndHandles);
  EXPECT_EQ(r.vibration_modes, 12);
  EXPECT_EQ(r.modal_columns, 48);
  EXPECT_EQ(scene.avatars[1].basis, ReducedBasisKind::Modes);  // the default
  EXPECT_DOUBLE_EQ(scene.reduced_gradient_tolerance, 3e-6);
  EXPECT_DOUBLE_EQ(scene.soft_tissue_gradient_tolerance, 2e-4);
  // Absent lagged-factor keys: each solver's defaults.
  EXPECT_DOUBLE_EQ(scene.soft_tissue_lagged.cg_relative_tolerance,
                   softTissueNewtonDefaults().lagged.cg_relative_tolerance);
  EXPECT_DOUBLE_EQ(scene.reduced_lagged.cg_relative_tolerance,
                   reducedNewtonDefaults().lagged.cg_relative_tolerance);
  EXPECT_TRUE(scene.soft_tissue_lagged.enabled && scene.reduced_lagged.enabled);
  // The FEM avatar keeps the (unused) reduced defaults.
  EXPECT_EQ(scene.avatars[1].simulation, "fem");
  EXPECT_EQ(scene.avatars[1].handles, 87);
}

// Scene files written before the modal basis became the default name handles without a basis:
// they keep the handle basis. "basis" given wins, and its order among the keys does not matter.
TEST(SceneFile, HandlesWithoutABasisChooseTheHandleBasis) {
  const SceneSpec scene = parse(R"({"avatars": [
    {"simulation": "rom", "handles": 24},
    {"simulation": "rom", "handles": 24, "basis": "modes+handles"},
    {"basis": "handles", "simulation": "rom"},
    {"simulation": "rom", "vibration_modes": 12}]})");
  ASSERT_EQ(scene.avatars.size(), 4u);
  EXPECT_EQ(scene.avatars[0].basis, ReducedBasisKind::Handles);
  EXPECT_EQ(scene.avatars[0].handles, 24);
  EXPECT_EQ(scene.avatars[1].basis, ReducedBasisKind::ModesAndHandles);
  EXPECT_EQ(scene.avatars[1].handles, 24);
  EXPECT_EQ(scene.avatars[2].basis, ReducedBasisKind::Handles);
  EXPECT_EQ(scene.avatars[2].handles, 87);
  EXPECT_EQ(scene.avatars[3].basis, ReducedBasisKind::Modes);
  EXPECT_EQ(scene.avatars[3].vibration_modes, 12);
  EXPECT_EQ(scene.avatars[3].modal_columns, 72);
}

// "preset": "realtime" gives every "rom" avatar the preset's basis and cubatures (the avatar's
// own keys win) and the ROM's solver its iteration budget (unless newton.max_iterations is
// given); "none" and an absent key are the defaults.
TEST(SceneFile, ThePresetFillsInTheRomDefaultsAndTheIterationBudget) {
  const ReducedSettings realtime = presetReducedSettings(Preset::Realtime);
  const SceneSpec scene = parse(R"({"preset": "realtime", "avatars": [
    {"simulation": "rom"},
    {"simulation": "rom", "elastic_cubature": 300, "modal_columns": 36},
    {"simulation": "rom", "handles": 20},
    {"simulation": "fem"}]})");
  EXPECT_EQ(scene.preset, Preset::Realtime);
  EXPECT_EQ(scene.reduced_iteration_budget, 3);
  EXPECT_EQ(io::sceneOptionsOf(scene).reduced_newton.max_iterations, 3);
  EXPECT_EQ(io::sceneOptionsOf(scene).soft_tissue_newton.max_iterations,
            scene.newton.max_iterations);
  const AvatarSpec& a = scene.avatars[0];
  EXPECT_EQ(a.basis, ReducedBasisKind::Modes);
  EXPECT_EQ(a.vibration_modes, 12);
  EXPECT_EQ(a.modal_columns, 24);
  EXPECT_EQ(a.elastic_cubature, 100);
  EXPECT_EQ(a.inertial_cubature, 100);
  EXPECT_EQ(a.vibration_modes, realtime.modes.vibration_modes);
  EXPECT_EQ(a.elastic_cubature, realtime.elastic_cubature_points);
  EXPECT_EQ(scene.avatars[1].elastic_cubature, 300);
  EXPECT_EQ(scene.avatars[1].modal_columns, 36);
  EXPECT_EQ(scene.avatars[1].vibration_modes, 12);
  EXPECT_EQ(scene.avatars[1].inertial_cubature, 100);
  EXPECT_EQ(scene.avatars[2].basis, ReducedBasisKind::Handles);  // handles without a basis
  EXPECT_EQ(scene.avatars[2].handles, 20);
  EXPECT_EQ(scene.avatars[2].elastic_cubature, 100);

  const SceneSpec limited = parse(
      R"({"preset": "realtime", "newton": {"max_iterations": 7}, "avatars": [{"simulation": "rom"}]})");
  EXPECT_EQ(limited.reduced_iteration_budget, 0);
  EXPECT_EQ(io::sceneOptionsOf(limited).reduced_newton.max_iterations, 7);
  EXPECT_EQ(limited.avatars[0].modal_columns, 24);

  for (const char* text : {R"({"avatars": [{"simulation": "rom"}]})",
                           R"({"preset": "none", "avatars": [{"simulation": "rom"}]})"}) {
    const SceneSpec plain = parse(text);
    EXPECT_EQ(plain.preset, Preset::None);
    EXPECT_EQ(plain.reduced_iteration_budget, 0);
    EXPECT_EQ(plain.avatars[0].modal_columns, ReducedSettings().modes.columns);
    EXPECT_EQ(plain.avatars[0].elastic_cubature, ReducedSettings().elastic_cubature_points);
  }
  EXPECT_THAT(messageOf<InputError>([] { parse(R"({"preset": "fast", "avatars": [{}]})"); }),
              HasSubstr("scene.json: preset: expected \"none\" or \"realtime\", got \"fast\""));
  EXPECT_THAT(messageOf<InputError>([] { parse(R"({"preset": 3, "avatars": [{}]})"); }),
              HasSubstr("scene.json: preset: expected a string"));
}

TEST(SceneFile, ReadsTheLaggedFactorSettingsOfBothSoftSolvers) {
  const SceneSpec scene = parse(R"({
    "newton": {"soft_tissue_lagged": {"cg_relative_tolerance": 0.02, "max_cg_iterations": 40,
                                      "refactor_after_cg_iterations": 15,
                                      "fast_preconditioner": false},
               "reduced_lagged": {"enabled": false, "adaptive_forcing": false,
                                  "reuse_hessian_below": 0, "coarse_correction": false}},
    "avatars": [{}]})");
  const LaggedFactorOptions& fem = scene.soft_tissue_lagged;
  EXPECT_DOUBLE_EQ(fem.cg_relative_tolerance, 0.02);
  EXPECT_EQ(fem.max_cg_iterations, 40);
  EXPECT_EQ(fem.refactor_after_cg_iterations, 15);
  EXPECT_FALSE(fem.fast_preconditioner);
  EXPECT_TRUE(fem.enabled);  // not given: the FEM solver's default
  EXPECT_TRUE(fem.adaptive_forcing);
  EXPECT_DOUBLE_EQ(fem.reuse_hessian_below, softTissueNewtonDefaults().lagged.reuse_hessian_below);
  EXPECT_GT(fem.reuse_hessian_below, 0.0);
  const LaggedFactorOptions& rom = scene.reduced_lagged;
  EXPECT_FALSE(rom.enabled);
  EXPECT_FALSE(rom.adaptive_forcing);
  EXPECT_EQ(rom.reuse_hessian_below, 0.0);
  EXPECT_FALSE(rom.coarse_correction);
  EXPECT_TRUE(fem.coarse_correction);  // not given: the FEM solver's default
  EXPECT_DOUBLE_EQ(rom.cg_relative_tolerance, reducedNewtonDefaults().lagged.cg_relative_tolerance);
  EXPECT_EQ(rom.max_cg_iterations, reducedNewtonDefaults().lagged.max_cg_iterations);
  // No presolve keys: each solver's defaults (on for both).
  EXPECT_EQ(scene.soft_tissue_presolve.max_iterations,
            softTissueNewtonDefaults().coarse_presolve.max_iterations);
  EXPECT_GT(scene.reduced_presolve.max_iterations, 0);

  expectInputErrors({
      {R"({"newton": {"soft_tissue_lagged": {"cg_relative_tolerance": 1}}, "avatars": [{}]})",
       "newton.soft_tissue_lagged.cg_relative_tolerance: expected 0 < value < 1, got 1"},
      {R"({"newton": {"reduced_lagged": {"max_cg_iterations": 0}}, "avatars": [{}]})",
       "newton.reduced_lagged.max_cg_iterations: expected an integer in [1, 100000], got 0"},
      {R"({"newton": {"reduced_lagged": {"reuse_hessian_below": -1e-4}}, "avatars": [{}]})",
       "newton.reduced_lagged.reuse_hessian_below: expected a value ≥ 0 (0: never), got -0.0001"},
      {R"({"newton": {"reduced_lagged": {"enabled": 1}}, "avatars": [{}]})",
       "newton.reduced_lagged.enabled: expected true or false, got number 1"},
      {R"({"newton": {"soft_tissue_lagged": {"coarse_correction": "yes"}}, "avatars": [{}]})",
       "newton.soft_tissue_lagged.coarse_correction: expected true or false, got string \"yes\""},
      {R"({"newton": {"soft_tissue_lagged": {"refactor_after": 3}}, "avatars": [{}]})",
       "newton.soft_tissue_lagged.refactor_after: unknown key (known: "},
      {R"({"newton": {"soft_tissue_lagged": 0.05}, "avatars": [{}]})",
       "newton.soft_tissue_lagged: expected a JSON object, got number 0.05"},
  });
}

TEST(SceneFile, ReadsTheBonesFirstSettingsOfBothSoftSolvers) {
  const SceneSpec scene = parse(R"({
    "newton": {"soft_tissue_presolve": {"max_iterations": 3},
               "reduced_presolve": {"max_iterations": 0, "relative_tolerance": 0.01}},
    "avatars": [{}]})");
  EXPECT_EQ(scene.soft_tissue_presolve.max_iterations, 3);
  EXPECT_DOUBLE_EQ(scene.soft_tissue_presolve.relative_tolerance,
                   softTissueNewtonDefaults().coarse_presolve.relative_tolerance);
  EXPECT_EQ(scene.reduced_presolve.max_iterations, 0);
  EXPECT_DOUBLE_EQ(scene.reduced_presolve.relative_tolerance, 0.01);
  const SceneOptions options = io::sceneOptionsOf(scene);
  EXPECT_EQ(options.soft_tissue_newton.coarse_presolve.max_iterations, 3);
  EXPECT_EQ(options.reduced_newton.coarse_presolve.max_iterations, 0);
  EXPECT_DOUBLE_EQ(options.reduced_newton.coarse_presolve.relative_tolerance, 0.01);

  expectInputErrors({
      {R"({"newton": {"soft_tissue_presolve": {"max_iterations": -1}}, "avatars": [{}]})",
       "newton.soft_tissue_presolve.max_iterations: expected an integer in [0, 1000], got -1"},
      {R"({"newton": {"reduced_presolve": {"relative_tolerance": 1}}, "avatars": [{}]})",
       "newton.reduced_presolve.relative_tolerance: expected 0 < value < 1, got 1"},
      {R"({"newton": {"reduced_presolve": {"iterations": 2}}, "avatars": [{}]})",
       "newton.reduced_presolve.iterations: unknown key (known: "},
      {R"({"newton": {"soft_tissue_presolve": 8}, "avatars": [{}]})",
       "newton.soft_tissue_presolve: expected a JSON object, got number 8"},
  });
}

TEST(SceneFile, BadRomSettingsAreNamedWithTheirPath) {
  expectInputErrors({
      // ROM-only keys on the other models.
      {R"({"avatars": [{"handles": 10}]})",
       "scene.json: avatars[0].handles: only for \"simulation\": \"rom\" (this avatar is "
       "\"skeleton\", which has no reduced basis)"},
      {R"({"avatars": [{"simulation": "fem", "handles": 10}]})",
       "avatars[0].handles: only for \"simulation\": \"rom\" (this avatar is \"fem\""},
      {R"({"avatars": [{"simulation": "fem", "elastic_cubature": 100}]})",
       "avatars[0].elastic_cubature: only for \"simulation\": \"rom\""},
      {R"({"avatars": [{"simulation": "skeleton", "inertial_cubature": 0}]})",
       "avatars[0].inertial_cubature: only for \"simulation\": \"rom\""},
      {R"({"avatars": [{"simulation": "fem", "surface_partition_of_unity": true}]})",
       "avatars[0].surface_partition_of_unity: only for \"simulation\": \"rom\""},
      {R"({"avatars": [{"simulation": "rom", "surface_partition_of_unity": 1}]})",
       "avatars[0].surface_partition_of_unity: expected true or false, got number 1"},
      {R"({"avatars": [{"simulation": "fem", "basis": "modes"}]})",
       "avatars[0].basis: only for \"simulation\": \"rom\""},
      {R"({"avatars": [{"simulation": "rom", "basis": "mode"}]})",
       "avatars[0].basis: expected \"handles\", \"modes\" or \"modes+handles\", got \"mode\""},
      {R"({"avatars": [{"simulation": "rom", "basis": "handles", "vibration_modes": 10}]})",
       "avatars[0].vibration_modes: only for \"simulation\": \"rom\" with \"basis\": "
       "\"modes\" or \"modes+handles\""},
      {R"({"avatars": [{"simulation": "rom", "handles": 20, "modal_columns": 30}]})",
       "avatars[0].modal_columns: only for \"simulation\": \"rom\" with \"basis\": "
       "\"modes\" or \"modes+handles\" (\"handles\" without a \"basis\" chooses the handle "
       "basis)"},
      {R"({"avatars": [{"simulation": "rom", "basis": "modes", "handles": 20}]})",
       "avatars[0].handles: not used by \"basis\": \"modes\" (handles belong to \"basis\": "
       "\"handles\" or \"modes+handles\")"},
      {R"({"avatars": [{"simulation": "rom", "basis": "modes", "modal_columns": -3}]})",
       "avatars[0].modal_columns: expected an integer in [0, 100000], got -3"},
      // Volumetric keys are for both soft-tissue models, not the skeleton.
      {R"({"avatars": [{"resolution": 0.5}]})",
       "avatars[0].resolution: only for \"simulation\": \"fem\" or \"rom\" (the skeleton "
       "builds no tet mesh)"},
      // Types and ranges.
      {R"({"avatars": [{"simulation": "rom", "handles": 0}]})",
       "avatars[0].handles: expected an integer in [1, 100000], got 0"},
      {R"({"avatars": [{"simulation": "rom", "handles": 2.5}]})",
       "avatars[0].handles: expected an integer, got number 2.5"},
      {R"({"avatars": [{"simulation": "rom", "handles": "many"}]})",
       "avatars[0].handles: expected a number, got string \"many\""},
      {R"({"avatars": [{"simulation": "rom", "elastic_cubature": -1}]})",
       "avatars[0].elastic_cubature: expected a number of sample tets in [0, 10000000] (0 = off: "
       "exact integration), got -1"},
      {R"({"avatars": [{"simulation": "rom", "inertial_cubature": true}]})",
       "avatars[0].inertial_cubature: expected a number, got boolean true"},
      {R"({"avatars": [{"simulation": "rom", "inertial_cubature": 10.5}]})",
       "avatars[0].inertial_cubature: expected an integer"},
      {R"({"avatars": [{"simulation": "rom", "resolution": 0}]})",
       "avatars[0].resolution: expected 0.01 <= value <= 100"},
      {R"({"newton": {"reduced_gradient_tolerance": 0}, "avatars": [{}]})",
       "newton.reduced_gradient_tolerance: expected 0 < value <= 1, got 0"},
      {R"({"newton": {"reduced_gradient_tolerance": 2}, "avatars": [{}]})",
       "newton.reduced_gradient_tolerance: expected 0 < value <= 1, got 2"},
      {R"({"newton": {"reduced_gradient_tolerance": "loose"}, "avatars": [{}]})",
       "newton.reduced_gradient_tolerance: expected a number, got string \"loose\""},
      {R"({"avatars": [{"simulation": "rom", "handle": 5}]})",
       "avatars[0].handle: unknown key (known: "},
  });
}

TEST(SceneFile, BadFemSettingsAreNamedWithTheirPath) {
  expectInputErrors({
      {R"({"avatars": [{"resolution": 0.5}]})",
       "scene.json: avatars[0].resolution: only for \"simulation\": \"fem\""},
      {R"({"newton": {"soft_tissue_gradient_tolerance": 0}, "avatars": [{}]})",
       "newton.soft_tissue_gradient_tolerance: expected 0 < value <= 1"},
      {R"({"newton": {"soft_tissue_gradient_tolerance": "tight"}, "avatars": [{}]})",
       "newton.soft_tissue_gradient_tolerance: expected a number"},
      {R"({"avatars": [{"simulation": "skeleton", "materials": "m.json"}]})",
       "avatars[0].materials: only for \"simulation\": \"fem\""},
      {R"({"avatars": [{"simulation": "fem", "resolution": 0}]})",
       "avatars[0].resolution: expected 0.01 <= value <= 100 (interior node density relative to "
       "the default), got 0"},
      {R"({"avatars": [{"simulation": "fem", "resolution": -2}]})",
       "avatars[0].resolution: expected 0.01 <= value <= 100"},
      {R"({"avatars": [{"simulation": "fem", "resolution": 500}]})", "got 500"},
      {R"({"avatars": [{"simulation": "fem", "resolution": "low"}]})",
       "avatars[0].resolution: expected a number, got string \"low\""},
      {R"({"avatars": [{"simulation": "fem", "materials": 3}]})",
       "avatars[0].materials: expected a string, got number 3"},
      {R"({"avatars": [{"simulation": "fem", "materials": ""}]})",
       "avatars[0].materials: expected a file path, got an empty string"},
      {R"({"avatars": [{}], "cache_dir": ""})", "scene.json: cache_dir: expected a directory"},
      {R"({"avatars": [{}], "cache_dir": 1})", "cache_dir: expected a string, got number 1"},
      {R"({"avatars": [{}], "use_cache": "no"})", "use_cache: expected true or false"},
      {R"({"avatars": [{}], "cache": "x"})", "cache: unknown key (known: "},
  });
}

TEST(SceneFile, MalformedJsonNamesTheBytePosition) {
  const std::string m = inputError("{\"avatars\": [{}],\n \"duration\": }");
  EXPECT_THAT(m, HasSubstr("scene.json: malformed JSON at byte 32 (line 2, column 14)"));
  EXPECT_THAT(inputError(""), HasSubstr("scene.json: malformed JSON at byte"));
}

// 200 000 nested '[' overflowed the stack (nlohmann's dump() of the value in the message):
// nesting beyond 64 levels is refused before nlohmann sees the text, wherever it is.
TEST(SceneFile, DeepNestingIsAnInputErrorNotAStackOverflow) {
  const std::string deep = std::string(200000, '[') + std::string(200000, ']');
  const std::string deep_objects = [] {
    std::string text;
    for (int k = 0; k < 100000; ++k) text += "{\"a\":";
    return text + "1" + std::string(100000, '}');
  }();
  for (const std::string& text :
       {deep, "{\"avatars\": " + deep + "}", deep_objects,
        "{\"avatars\": [{}], \"duration\": " + std::string(65, '[') + "}"}) {
    const std::string message = inputError(text);
    EXPECT_THAT(message, HasSubstr("scene.json: JSON nested deeper than 64 levels at byte"));
    EXPECT_LT(message.size(), 200u);
  }
  // From a file too (the path is named), and brackets inside strings do not count.
  const std::string path = test::freshTempDir("scene_deep") + "/deep.json";
  std::ofstream(path) << deep;
  EXPECT_THAT(messageOf<InputError>([&] { loadSceneFile(path); }),
              HasSubstr(path + ": JSON nested deeper than 64 levels at byte 64 (line 1, "
                               "column 65)"));
  const std::string brackets = std::string(1000, '[') + "{\\\"]";  // [[…[{\"] in JSON
  const SceneSpec in_string =
      parse("{\"avatars\": [{}], \"outputs\": {\"dir\": \"" + brackets + "\"}}");
  EXPECT_EQ(in_string.outputs.dir, std::string(1000, '[') + "{\"]");
  // 64 levels are fine as far as nesting goes (the value is still of the wrong type).
  EXPECT_THAT(inputError("{\"avatars\": [{}], \"duration\": " + std::string(63, '[') +
                         std::string(63, ']') + "}"),
              HasSubstr("duration: expected a number, got array [[[["));
}

// A wrong value is shown in 40 characters, however large (the whole dump was built first).
TEST(SceneFile, WrongValuesAreShownCutShort) {
  std::string big = "[";
  for (int k = 0; k < 100000; ++k) big += (k ? "," : "") + std::to_string(k);
  big += "]";
  const std::string message = inputError("{\"avatars\": [{}], \"duration\": " + big + "}");
  EXPECT_THAT(message, HasSubstr("duration: expected a number, got array [0,1,2,3,4,5,6,7,8,"));
  EXPECT_LT(message.size(), 200u);
  EXPECT_THAT(inputError("{\"avatars\": [{}], \"duration\": \"" + std::string(100000, 'x') + "\"}"),
              HasSubstr("got string \"xxxxxxxx"));
  EXPECT_THAT(inputError(R"({"avatars": [{}], "duration": {"a": [1, 2], "b": "c"}})"),
              HasSubstr(R"(got object {"a":[1,2],"b":"c"})"));
}

TEST(SceneFile, RelativePathsResolveAgainstTheSceneFolder) {
  const std::string dir = test::freshTempDir("scene_paths");
  fs::create_directories(fs::path(dir) / "data");
  saveMotion(makeBuiltinMotion("walk", 0.2), (fs::path(dir) / "data" / "walk.npz").string());
  writeText((fs::path(dir) / "data" / "body.npz").string(),
            "any content: only existence is checked here");
  const std::string scene_path = (fs::path(dir) / "scene.json").string();
  writeText(scene_path, R"({"avatars": [{"model": "data/body.npz", "motion": "data/walk.npz"}]})");
  const SceneSpec scene = loadSceneFile(scene_path);
  EXPECT_EQ(scene.source, scene_path);
  EXPECT_EQ(fs::path(scene.avatars[0].model),
            (fs::path(dir) / "data" / "body.npz").lexically_normal());
  EXPECT_EQ(fs::path(scene.avatars[0].motion),
            (fs::path(dir) / "data" / "walk.npz").lexically_normal());
  // "vertices" only makes sense for the synthetic body.
  writeText(scene_path, R"({"avatars": [{"model": "data/body.npz", "vertices": 900}]})");
  EXPECT_THAT(messageOf<InputError>([&] { loadSceneFile(scene_path); }),
              HasSubstr("avatars[0].vertices: only for \"model\": \"synthetic\""));
}

TEST(SceneFile, MissingFilesAreFileErrorsNamingKeyAndResolvedPath) {
  const std::string dir = test::freshTempDir("scene_missing");
  const std::string scene_path = (fs::path(dir) / "scene.json").string();
  writeText(scene_path, R"({"avatars": [{"motion": "nowhere/run.npz"}]})");
  std::string m = messageOf<FileError>([&] { loadSceneFile(scene_path); });
  EXPECT_THAT(m, HasSubstr(scene_path + ": avatars[0].motion: motion file not found: " +
                           (fs::path(dir) / "nowhere" / "run.npz").string()));
  writeText(scene_path, R"({"avatars": [{}, {"model": "smpl.npz"}]})");
  m = messageOf<FileError>([&] { loadSceneFile(scene_path); });
  EXPECT_THAT(m, HasSubstr("avatars[1].model: body model file not found: " +
                           (fs::path(dir) / "smpl.npz").string()));
  // A built-in name without its prefix is a missing file, with a hint.
  writeText(scene_path, R"({"avatars": [{"motion": "walk"}]})");
  m = messageOf<FileError>([&] { loadSceneFile(scene_path); });
  EXPECT_THAT(m, HasSubstr("builtin:walk"));
  m = messageOf<FileError>([&] { loadSceneFile((fs::path(dir) / "absent.json").string()); });
  EXPECT_THAT(m, HasSubstr("absent.json: scene file not found"));
}

TEST(SceneFile, OverridesApplyBeforeCollidersAreBuilt) {
  const std::string text = R"({"avatars": [{}], "duration": 1.0,
      "colliders": [{"type": "sphere", "center": [0, 0, 0], "radius": 0.1, "velocity": [2, 0, 0]}]})";
  SceneOverrides overrides;
  overrides.duration = 3.0;
  overrides.time_step = 0.005;
  overrides.output_dir = "here";
  const SceneSpec scene = parseSceneJson(text, "scene.json", ".", overrides);
  EXPECT_DOUBLE_EQ(scene.duration, 3.0);
  EXPECT_DOUBLE_EQ(scene.time_step, 0.005);
  EXPECT_DOUBLE_EQ(scene.avatars[0].options.time_step, 0.005);
  EXPECT_EQ(scene.outputs.dir, "here");
  // The ball keeps flying for the overridden duration, not only the file's.
  EXPECT_TRUE(scene.colliders[0].path.offsetAt(2.5).isApprox(Vec3(5, 0, 0), 1e-12));
  overrides.duration = -1;
  EXPECT_THAT(messageOf<InputError>([&] { parseSceneJson(text, "scene.json", ".", overrides); }),
              HasSubstr("--duration: expected 0 < value"));
}

TEST(SceneFile, ExampleFilesParseAndTheDefaultMatchesTheBuiltIn) {
  const fs::path examples = fs::path(FLSH_SOURCE_DIR) / "examples" / "scenes";
  const SceneSpec file = loadSceneFile((examples / "default.json").string());
  const SceneSpec builtin = defaultScene();
  EXPECT_EQ(builtin.source, "builtin default scene");
  ASSERT_EQ(file.avatars.size(), builtin.avatars.size());
  EXPECT_EQ(file.avatars[0].name, builtin.avatars[0].name);
  EXPECT_EQ(file.avatars[0].motion, builtin.avatars[0].motion);
  EXPECT_EQ(file.avatars[0].synthetic_vertices, builtin.avatars[0].synthetic_vertices);
  EXPECT_DOUBLE_EQ(file.time_step, builtin.time_step);
  EXPECT_DOUBLE_EQ(file.duration, builtin.duration);
  ASSERT_EQ(file.colliders.size(), builtin.colliders.size());
  for (size_t c = 0; c < file.colliders.size(); ++c) {
    EXPECT_EQ(file.colliders[c].name, builtin.colliders[c].name);
    EXPECT_EQ(file.colliders[c].p0(), builtin.colliders[c].p0());
    EXPECT_EQ(file.colliders[c].radius(), builtin.colliders[c].radius());
    EXPECT_EQ(file.colliders[c].path.offsetAt(1.0), builtin.colliders[c].path.offsetAt(1.0));
  }
  EXPECT_EQ(file.outputs.dir, builtin.outputs.dir);

  // The brief's default: one walking synthetic avatar, h = 1/60 s, ground and a thrown ball.
  EXPECT_NEAR(builtin.time_step, 1.0 / 60.0, 1e-15);
  EXPECT_EQ(builtin.avatars[0].synthetic_vertices, 6890);
  EXPECT_EQ(builtin.avatars[0].motion, "builtin:walk");
  EXPECT_EQ(builtin.colliders[0].shape(), ColliderShape::Plane);
  EXPECT_EQ(builtin.colliders[1].shape(), ColliderShape::Sphere);
  EXPECT_DOUBLE_EQ(builtin.colliders[1].radius(), 0.12);

  const SceneSpec two = loadSceneFile((examples / "two_avatars.json").string());
  EXPECT_EQ(two.avatars.size(), 2u);
  EXPECT_NEAR(two.avatars[1].yaw, M_PI, 1e-12);

  const SceneSpec soft = loadSceneFile((examples / "soft_jumping_jacks.json").string());
  ASSERT_EQ(soft.avatars.size(), 1u);
  EXPECT_EQ(soft.avatars[0].simulation, "fem");
  EXPECT_DOUBLE_EQ(soft.soft_tissue_gradient_tolerance, 1e-5);

  // The ROM example: full-body defaults (the modal basis 24:72, both cubatures with 500 tets).
  const SceneSpec rom = loadSceneFile((examples / "soft_rom_jumping_jacks.json").string());
  ASSERT_EQ(rom.avatars.size(), 1u);
  EXPECT_EQ(rom.avatars[0].simulation, "rom");
  EXPECT_EQ(rom.avatars[0].synthetic_vertices, 6890);
  EXPECT_EQ(rom.avatars[0].basis, ReducedBasisKind::Modes);
  EXPECT_EQ(rom.avatars[0].vibration_modes, ReducedSettings().modes.vibration_modes);
  EXPECT_EQ(rom.avatars[0].modal_columns, ReducedSettings().modes.columns);
  EXPECT_EQ(rom.avatars[0].elastic_cubature, 500);
  EXPECT_EQ(rom.avatars[0].inertial_cubature, 500);
  EXPECT_EQ(rom.avatars[0].motion, "builtin:jumping_jacks");
  EXPECT_DOUBLE_EQ(rom.reduced_gradient_tolerance, reducedNewtonDefaults().gradient_tolerance);
}

TEST(SceneFile, DefaultGroundSitsAtTheSolesAndTheBallMeetsTheWalkerNearOneSecond) {
  const SceneSpec scene = defaultScene();
  const BodyModel& body = smallBody();
  // Ground: the plane's height is the rest body's lowest point (1000-vertex body: within 5 mm
  // of the 6890-vertex one).
  const double sole = body.v_template.col(1).minCoeff();
  EXPECT_NEAR(scene.colliders[0].p0().y(), sole, 5e-3);

  const Collider& ball = scene.colliders[1];
  const Motion walk = makeBuiltinMotion("walk", 2.0, 30.0);
  auto clearance = [&](int frame) {  // smallest signed distance of the body to the ball
    const double t = frame / walk.fps;
    const PosedBody posed =
        poseBody(body, VecX::Zero(body.numBetas()), walk.poses.row(frame).transpose(),
                 walk.trans.row(frame).transpose());
    double d = 1e9;
    for (Eigen::Index i = 0; i < posed.vertices.rows(); ++i)
      d = std::min(d, ball.signedDistance(posed.vertices.row(i).transpose(), t));
    return d;
  };
  EXPECT_GT(clearance(24), 0.3);   // t = 0.8 s: still well away
  EXPECT_LT(clearance(30), 0.02);  // t = 1.0 s: touching or inside
  EXPECT_GT(clearance(30), -0.1);
}

}  // namespace
}  // namespace flsh
