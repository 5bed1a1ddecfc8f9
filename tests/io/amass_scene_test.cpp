// An AMASS clip in a scene file, as users have it (issue 27): recorded z up, SMPL-H poses, 16
// betas, a gender; with "ground": "auto" the body stands upright on the ground with its feet
// in contact; read with the wrong up axis, the scene warns. Gendered SMPL-H model files.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <random>

#include "flsh/body/motion.h"
#include "flsh/body/motion_frame.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "flsh/format/npz.h"
#include "flsh/io/scene_build.h"
#include "flsh/io/scene_file.h"
#include "flsh/solve/scene.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using ::testing::HasSubstr;
namespace fs = std::filesystem;
using test::messageOf;

constexpr int kVertices = 800;

/// Writes the built-in walk (1 s, 30 fps) as an AMASS file stores a clip: z up, standing on a
/// floor that is not at the origin (trans + (0.4, 1.5, 0.35) in the clip's frame), 156 pose
/// values, 16 betas of which the last 6 are nonzero, a gender, no `up` key.
std::string writeAmassClip(const std::string& path, const std::string& gender) {
  Motion clip = makeBuiltinMotion("walk", 1.0, 30.0);
  rotateMotion(clip, worldFromUpAxis("z").transpose());
  clip.trans.rowwise() += Eigen::RowVector3d(0.4, 1.5, 0.35);
  RowMatX poses = RowMatX::Zero(clip.numFrames(), 156);
  poses.leftCols(66) = clip.poses.leftCols(66);
  poses.rightCols(90).setConstant(0.1);  // curled fingers, which the simulation ignores
  VecX betas = VecX::Zero(16);
  betas.tail(6).setConstant(0.3);
  io::NpzWriter writer;
  writer.add("poses", poses);
  writer.add("trans", clip.trans);
  writer.add("betas", betas);
  writer.addScalar("mocap_framerate", 30.0);
  writer.addString("gender", gender);
  writer.save(path, true);
  return path;
}

SceneSpec sceneOf(const std::string& dir, const std::string& avatar_keys,
                  const std::string& scene_keys) {
  const std::string text = R"({"time_step": 0.016666666666666666, "duration": 0.5, )" + scene_keys +
                           R"(, "avatars": [{"model": "synthetic", "vertices": )" +
                           std::to_string(kVertices) + ", " + avatar_keys + "}]}";
  return parseSceneJson(text, dir + "/scene.json", dir);
}

TEST(AmassScene, ClipStandsUprightOnTheAutoGroundWithItsFeetInContact) {
  const std::string dir = test::freshTempDir("amass_scene_upright");
  writeAmassClip(dir + "/clip.npz", "female");
  const SceneSpec scene = sceneOf(dir, R"("motion": "clip.npz")", R"("ground": "auto")");
  std::vector<std::string> log;
  const auto logger = [&](const std::string& line) { log.push_back(line); };
  const std::vector<io::SceneAvatar> runs = io::buildSceneAvatars(scene, logger);
  ASSERT_EQ(runs[0].motion->up, "z");
  const std::vector<Collider> colliders = io::sceneColliders(scene, runs, logger);
  ASSERT_EQ(colliders.size(), 1u);
  EXPECT_EQ(colliders[0].name, "ground");
  const double ground = colliders[0].p0().y();
  const std::string all = ::testing::PrintToString(log);
  EXPECT_THAT(all, HasSubstr("ground: auto, plane at y = "));
  EXPECT_THAT(all, HasSubstr("16 shape coefficients"));  // the 6 dropped betas, once
  EXPECT_TRUE(io::startWarnings(runs, colliders).empty())
      << ::testing::PrintToString(io::startWarnings(runs, colliders));

  Scene sim(io::sceneOptionsOf(scene));
  sim.addSimulable(runs[0].simulable);
  for (const Collider& c : colliders) sim.addCollider(c);
  sim.initialize();
  const Simulable& body = *runs[0].simulable;
  int steps_in_contact = 0;
  double lowest_gap = 1e9, highest_gap = -1e9;  // lowest vertex above the ground, m
  for (int s = 0; s < 30; ++s) {
    steps_in_contact += sim.step().active_contacts > 0 ? 1 : 0;
    const double gap = body.getVertices().col(1).minCoeff() - ground;
    lowest_gap = std::min(lowest_gap, gap);
    highest_gap = std::max(highest_gap, gap);
    const Vec3 up = rodrigues(body.getPose().head<3>()) * Vec3::UnitY();
    ASSERT_GT(up.y(), 0.9) << "step " << s << ": the body should stand along +y, its up axis is "
                           << up.transpose();
    ASSERT_GT(body.getVertices().col(1).maxCoeff() - ground, 1.3) << "standing, not lying";
  }
  // Walking, the lowest foot stays on the ground: touching it (within the contact penalty's
  // few millimetres) and never lifted off as a whole.
  EXPECT_GE(steps_in_contact, 10) << "the feet should touch the ground";
  EXPECT_GT(lowest_gap, -0.02) << "the feet should not sink into the ground";
  EXPECT_LT(highest_gap, 0.03) << "the lowest foot should stay on the ground";
}

TEST(AmassScene, WrongUpAxisOrGroundHeightIsReportedAtTheStart) {
  const std::string dir = test::freshTempDir("amass_scene_warnings");
  writeAmassClip(dir + "/clip.npz", "male");
  // Read as y up, over a ground at the synthetic body's default height: the body lies ~2 m
  // above the ground (the clip's y, 1.5 m, taken for the height).
  const SceneSpec lying = sceneOf(dir, R"("motion": "clip.npz", "up": "y")", R"("ground": -0.952)");
  ::testing::internal::CaptureStderr();
  const std::vector<io::SceneAvatar> runs = io::buildSceneAvatars(lying);
  EXPECT_THAT(::testing::internal::GetCapturedStderr(),
              HasSubstr("the body is not upright at frame 0"));
  const std::vector<std::string> warnings =
      io::startWarnings(runs, io::sceneColliders(lying, runs));
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_THAT(warnings[0], HasSubstr("m above the nearest floor ('ground')"));
  EXPECT_THAT(warnings[0], HasSubstr("\"ground\": \"auto\""));
  EXPECT_THAT(warnings[0], HasSubstr("\"up\""));

  // Upright but the ground 0.5 m too high: the body starts deep in it.
  const SceneSpec deep = sceneOf(dir, R"("motion": "clip.npz")", R"("ground": 0.5)");
  const std::vector<io::SceneAvatar> deep_runs = io::buildSceneAvatars(deep);
  EXPECT_THAT(
      ::testing::PrintToString(io::startWarnings(deep_runs, io::sceneColliders(deep, deep_runs))),
      HasSubstr("m deep in plane 'ground'"));
}

TEST(AmassScene, GenderedSmplhModelFilesAreChosenByTheClipsGender) {
  const std::string dir = test::freshTempDir("amass_scene_gender");
  SyntheticBodyOptions options;
  options.vertices = kVertices;
  const BodyModel smpl = makeSyntheticBody(options);
  fs::create_directories(dir + "/models/female");
  saveBodyModel(test::smplhFrom(smpl), dir + "/models/female/model.npz");
  writeAmassClip(dir + "/female.npz", "female");
  writeAmassClip(dir + "/male.npz", "male");
  const std::string text =
      R"({"duration": 0.1, "avatars": [{"model": "models/{gender}/model.npz", "motion": ")";
  const SceneSpec female = parseSceneJson(text + R"(female.npz"}]})", dir + "/scene.json", dir);
  std::vector<std::string> log;
  const auto runs =
      io::buildSceneAvatars(female, [&](const std::string& line) { log.push_back(line); });
  EXPECT_EQ(runs[0].body->family, "SMPL-H");
  EXPECT_EQ(runs[0].body->source, dir + "/models/female/model.npz");
  EXPECT_THAT(::testing::PrintToString(log),
              HasSubstr("SMPL-H body model, its finger joints merged into SMPL's hand joints"));

  const SceneSpec male = parseSceneJson(text + R"(male.npz"}]})", dir + "/scene.json", dir);
  const std::string message = messageOf<FileError>([&] { io::buildSceneAvatars(male); });
  EXPECT_THAT(message, HasSubstr("scene.json: avatars[0].model: body model file not found: " + dir +
                                 "/models/male/model.npz"));
  EXPECT_THAT(message, HasSubstr("the gender of " + dir + "/male.npz: \"male\""));

  EXPECT_THAT(messageOf<InputError>([&] {
                parseSceneJson(R"({"avatars": [{"model": "m/{gender}.npz"}]})", "scene.json", dir);
              }),
              HasSubstr("scene.json: avatars[0].model: \"{gender}\" is filled in with the "
                        "motion's gender, but this avatar has no motion"));
}

TEST(AmassScene, GroundAndUpKeysAreChecked) {
  const auto error = [](const std::string& text) {
    return messageOf<InputError>([&] { parseSceneJson(text, "scene.json", "."); });
  };
  const std::string avatar = R"("avatars": [{"motion": "builtin:walk"}])";
  EXPECT_THAT(error("{" + avatar + R"(, "ground": "floor"})"),
              HasSubstr("scene.json: ground: expected \"auto\""));
  EXPECT_THAT(error("{" + avatar + R"(, "ground": {"height": 0.1, "over_seconds": 2}})"),
              HasSubstr("ground.over_seconds: only for \"height\": \"auto\""));
  EXPECT_THAT(error("{" + avatar + R"(, "ground": "auto", "colliders": [{"name": "ground",
                    "type": "plane"}]})"),
              HasSubstr("also has a collider named \"ground\""));
  EXPECT_THAT(error(R"({"avatars": [{"motion": "builtin:walk", "up": "z"}]})"),
              HasSubstr("avatars[0].up: only for a motion file"));
  const SceneSpec scene = parseSceneJson(
      "{" + avatar + R"(, "ground": {"height": "auto", "over_seconds": 0.5}})", "scene.json", ".");
  EXPECT_TRUE(scene.ground.enabled && scene.ground.automatic);
  EXPECT_EQ(scene.ground.over_seconds, 0.5);
}

TEST(AmassScene, AbsurdMagnitudesInSceneFilesAreRefusedNamingTheKey) {
  const auto error = [](const std::string& options) {
    return messageOf<InputError>([&] {
      parseSceneJson(R"({"avatars": [{"options": {)" + options + "}}]}", "scene.json", ".");
    });
  };
  EXPECT_THAT(error(R"("tracking_stiffness": 1e300)"),
              HasSubstr("avatars[0].options.tracking_stiffness: expected 0 <= value <= 1e+09"));
  EXPECT_THAT(error(R"("contact_stiffness": 1e300)"), HasSubstr("contact_stiffness"));
  EXPECT_THAT(error(R"("gravity": [0, -1e300, 0])"),
              HasSubstr("avatars[0].options.gravity[1]: expected -1000 <= value <= 1000 (m/s²)"));
  const auto collider = [](const std::string& json) {
    return messageOf<InputError>([&] {
      parseSceneJson(R"({"avatars": [{}], "colliders": [)" + json + "]}", "scene.json", ".");
    });
  };
  EXPECT_THAT(collider(R"({"type": "sphere", "center": [1e300, 0, 0], "radius": 1})"),
              HasSubstr("colliders[0].center[0]: expected -10000 <= value <= 10000 (m)"));
  EXPECT_THAT(collider(R"({"type": "sphere", "center": [0, 0, 0], "radius": 1e300})"),
              HasSubstr("colliders[0].radius"));
  EXPECT_THAT(collider(R"({"type": "sphere", "center": [0, 0, 0], "radius": 1,
                           "velocity": [0, 0, 1e300]})"),
              HasSubstr("colliders[0].velocity[2]: expected -10000 <= value <= 10000 (m/s)"));
}

}  // namespace
}  // namespace flsh
