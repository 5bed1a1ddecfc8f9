// The .glb writer: the container parses (our own reader of the chunks and, independently,
// tinygltf's loader), accessors match the data, and the skinned animation it describes
// reproduces linear blend skinning of the bone transforms that were written.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#define TINYGLTF_IMPLEMENTATION
#define TINYGLTF_NO_STB_IMAGE
#define TINYGLTF_NO_STB_IMAGE_WRITE
#define TINYGLTF_NO_EXTERNAL_IMAGE
#include <tiny_gltf.h>

#include <Eigen/Geometry>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>

#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "flsh/format/gltf.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using ::testing::HasSubstr;
using json = nlohmann::json;
namespace fs = std::filesystem;

/// A .glb split into its JSON document and binary chunk, with the header checked.
struct Glb {
  json doc;
  std::vector<uint8_t> bin;

  explicit Glb(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)),
                               std::istreambuf_iterator<char>());
    auto u32 = [&](size_t at) {
      uint32_t v = 0;
      EXPECT_LE(at + 4, bytes.size()) << "file too short";
      if (at + 4 <= bytes.size()) std::memcpy(&v, bytes.data() + at, 4);
      return v;
    };
    EXPECT_EQ(u32(0), 0x46546C67u) << "magic 'glTF'";
    EXPECT_EQ(u32(4), 2u) << "version";
    EXPECT_EQ(u32(8), bytes.size()) << "total length";
    const uint32_t json_length = u32(12);
    EXPECT_EQ(u32(16), 0x4E4F534Au) << "JSON chunk type";
    EXPECT_EQ(json_length % 4, 0u);
    doc = json::parse(bytes.begin() + 20, bytes.begin() + 20 + json_length);
    const size_t bin_at = 20 + json_length;
    const uint32_t bin_length = u32(bin_at);
    EXPECT_EQ(u32(bin_at + 4), 0x004E4942u) << "BIN chunk type";
    EXPECT_EQ(bin_at + 8 + bin_length, bytes.size());
    bin.assign(bytes.begin() + long(bin_at + 8), bytes.end());
    EXPECT_EQ(doc["buffers"][0]["byteLength"].get<size_t>(), bin.size());
  }

  /// Accessor `a` as floats or integers (converted to double), checked against its view.
  std::vector<double> read(int a) const {
    const json& accessor = doc["accessors"][a];
    const json& view = doc["bufferViews"][accessor["bufferView"].get<int>()];
    const int type = accessor["componentType"];
    const size_t count = accessor["count"];
    const std::string shape = accessor["type"];
    const size_t width = shape == "SCALAR" ? 1 : shape == "VEC3" ? 3 : shape == "VEC4" ? 4 : 16;
    const size_t component = type == 5126 || type == 5125 ? 4 : type == 5123 ? 2 : 1;
    const size_t offset = view["byteOffset"], length = view["byteLength"];
    EXPECT_EQ(length, count * width * component) << "accessor " << a;
    EXPECT_EQ(offset % component, 0u);
    EXPECT_LE(offset + length, bin.size());
    std::vector<double> out(count * width);
    for (size_t k = 0; k < out.size(); ++k) {
      const uint8_t* p = &bin[offset + k * component];
      if (type == 5126) {
        float f;
        std::memcpy(&f, p, 4);
        out[k] = f;
      } else if (type == 5125) {
        uint32_t u;
        std::memcpy(&u, p, 4);
        out[k] = u;
      } else if (type == 5123) {
        uint16_t u;
        std::memcpy(&u, p, 2);
        out[k] = u;
      } else {
        out[k] = *p;
      }
    }
    return out;
  }
};

Mat3 randomRotation(std::mt19937& rng, double angle) {
  std::normal_distribution<double> g;
  return rodrigues(angle * Vec3(g(rng), g(rng), g(rng)).normalized());
}

/// A random 300-vertex model animated over 4 frames with arbitrary (disconnected) bone
/// transforms: the writer must represent any rigid transform per bone exactly.
io::GltfSkinnedAvatar makeAvatar(int frames) {
  const BodyModel model = test::makeRandomModel(300, 4, 7);
  io::GltfSkinnedAvatar a;
  a.name = "walker";
  a.rest_vertices = model.v_template;
  a.faces = model.faces;
  a.weights = model.weights;
  a.parents = model.parents;
  a.rest_joints = MatX3(model.J_regressor * model.v_template);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> uni(-0.5, 0.5);
  for (int k = 0; k < frames; ++k) {
    std::vector<Mat3> R;
    MatX3 t(24, 3);
    for (int b = 0; b < 24; ++b) {
      R.push_back(randomRotation(rng, 0.3 + 0.8 * k));  // up to large angles
      t.row(b) = a.rest_joints.row(b) + Vec3(uni(rng), uni(rng), uni(rng)).transpose();
    }
    a.rotations.push_back(R);
    a.positions.push_back(t);
  }
  return a;
}

Mat4 nodeMatrix(const Vec3& t, const Eigen::Quaterniond& q) {
  Mat4 M = Mat4::Identity();
  M.topLeftCorner<3, 3>() = q.normalized().toRotationMatrix();
  M.topRightCorner<3, 1>() = t;
  return M;
}

TEST(Gltf, SkinnedAnimationReproducesBoneSkinning) {
  const std::string dir = test::freshTempDir("gltf");
  const std::string path = (fs::path(dir) / "animation.glb").string();
  const int T = 4;
  const io::GltfSkinnedAvatar avatar = makeAvatar(T);
  io::GltfRigidMesh ball;
  ball.name = "ball";
  ball.vertices = MatX3(4, 3);
  ball.vertices << 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1;
  ball.faces = MatX3i(4, 3);
  ball.faces << 0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3;
  for (int k = 0; k < T; ++k) ball.translations.push_back(Vec3(k, 0, 0));
  const std::vector<double> times = {0.0, 0.1, 0.2, 0.3};
  io::writeGlb(path, times, {avatar}, {ball});

  const Glb glb(path);
  const json& doc = glb.doc;
  EXPECT_EQ(doc["asset"]["version"], "2.0");
  ASSERT_EQ(doc["meshes"].size(), 2u);
  ASSERT_EQ(doc["skins"].size(), 1u);
  ASSERT_EQ(doc["animations"].size(), 1u);
  // 24 bones + the skinned mesh node + the ball node.
  ASSERT_EQ(doc["nodes"].size(), 26u);
  const json& attributes = doc["meshes"][0]["primitives"][0]["attributes"];
  const long V = avatar.rest_vertices.rows();

  // Positions: the rest shape, with exact float min/max.
  const std::vector<double> positions = glb.read(attributes["POSITION"]);
  ASSERT_EQ(positions.size(), size_t(3 * V));
  for (long i = 0; i < V; ++i)
    for (int c = 0; c < 3; ++c) EXPECT_FLOAT_EQ(positions[3 * i + c], avatar.rest_vertices(i, c));
  const json& position_accessor = doc["accessors"][attributes["POSITION"].get<int>()];
  for (int c = 0; c < 3; ++c) {
    EXPECT_FLOAT_EQ(position_accessor["min"][c].get<float>(),
                    float(avatar.rest_vertices.col(c).minCoeff()));
    EXPECT_FLOAT_EQ(position_accessor["max"][c].get<float>(),
                    float(avatar.rest_vertices.col(c).maxCoeff()));
  }
  const std::vector<double> normals = glb.read(attributes["NORMAL"]);
  for (long i = 0; i < V; ++i)
    EXPECT_NEAR(Vec3(normals[3 * i], normals[3 * i + 1], normals[3 * i + 2]).norm(), 1.0, 1e-6);
  const std::vector<double> indices = glb.read(doc["meshes"][0]["primitives"][0]["indices"]);
  ASSERT_EQ(indices.size(), size_t(3 * avatar.faces.rows()));
  EXPECT_EQ(indices[5], avatar.faces(1, 2));

  // Joints/weights: the 4 largest weights, renormalized.
  const std::vector<double> joints = glb.read(attributes["JOINTS_0"]);
  const std::vector<double> weights = glb.read(attributes["WEIGHTS_0"]);
  ASSERT_EQ(joints.size(), size_t(4 * V));
  ASSERT_EQ(weights.size(), size_t(4 * V));
  for (long i = 0; i < V; ++i) {
    double sum = 0, kept = 0;
    for (int k = 0; k < 4; ++k) {
      sum += weights[4 * i + k];
      kept += avatar.weights(i, int(joints[4 * i + k]));
    }
    EXPECT_NEAR(sum, 1.0, 1e-6);
    VecX sorted = avatar.weights.row(i).transpose();
    std::sort(sorted.data(), sorted.data() + sorted.size(), std::greater<double>());
    EXPECT_NEAR(kept, sorted.head(4).sum(), 1e-12) << "vertex " << i << " keeps its 4 largest";
    EXPECT_NEAR(weights[4 * i], avatar.weights(i, int(joints[4 * i])) / kept, 1e-6);
  }

  // Skin and animation: evaluate the glTF at every frame and compare with LBS of the input.
  const json& skin = doc["skins"][0];
  ASSERT_EQ(skin["joints"].size(), 24u);
  const std::vector<double> ibm = glb.read(skin["inverseBindMatrices"]);
  const json& animation = doc["animations"][0];
  ASSERT_EQ(animation["channels"].size(), 24u * 2 + 1);
  const json& time_accessor = doc["accessors"][animation["samplers"][0]["input"].get<int>()];
  EXPECT_EQ(time_accessor["count"], T);
  EXPECT_FLOAT_EQ(time_accessor["max"][0].get<float>(), 0.3f);
  // Per node and path: the sampled values.
  std::map<std::pair<int, std::string>, std::vector<double>> tracks;
  for (const json& channel : animation["channels"]) {
    const json& sampler = animation["samplers"][channel["sampler"].get<int>()];
    EXPECT_EQ(sampler["interpolation"], "LINEAR");
    tracks[{channel["target"]["node"].get<int>(), channel["target"]["path"].get<std::string>()}] =
        glb.read(sampler["output"]);
  }
  std::vector<int> parent_node(doc["nodes"].size(), -1);
  for (size_t n = 0; n < doc["nodes"].size(); ++n)
    if (doc["nodes"][n].contains("children"))
      for (const json& c : doc["nodes"][n]["children"]) parent_node[c.get<int>()] = int(n);

  double max_error = 0.0, max_motion = 0.0;
  for (int k = 0; k < T; ++k) {
    std::vector<Mat4> global(24);
    for (int b = 0; b < 24; ++b) {
      const int node = skin["joints"][b];
      const auto& t = tracks.at({node, "translation"});
      const auto& q = tracks.at({node, "rotation"});
      const Mat4 local =
          nodeMatrix(Vec3(t[3 * k], t[3 * k + 1], t[3 * k + 2]),
                     Eigen::Quaterniond(q[4 * k + 3], q[4 * k], q[4 * k + 1], q[4 * k + 2]));
      const int p = parent_node[node];
      if (b == 0) {
        EXPECT_EQ(p, -1);
        global[b] = local;
      } else {
        ASSERT_EQ(p, int(skin["joints"][avatar.parents[b]])) << "hierarchy follows the parents";
        global[b] = global[avatar.parents[b]] * local;
      }
    }
    for (long i = 0; i < V; ++i) {
      const Vec3 X = avatar.rest_vertices.row(i).transpose();
      Vec3 gltf = Vec3::Zero(), lbs = Vec3::Zero();
      for (int m = 0; m < 4; ++m) {
        const int b = int(joints[4 * i + m]);
        const double w = weights[4 * i + m];
        Mat4 inverse_bind;
        for (int e = 0; e < 16; ++e) inverse_bind(e % 4, e / 4) = ibm[16 * b + e];  // column-major
        gltf += w * (global[b] * inverse_bind * X.homogeneous()).head<3>();
        lbs += w * (avatar.rotations[k][b] * (X - avatar.rest_joints.row(b).transpose()) +
                    avatar.positions[k].row(b).transpose());
      }
      max_error = std::max(max_error, (gltf - lbs).norm());
      max_motion = std::max(max_motion, (lbs - X).norm());
    }
  }
  EXPECT_GT(max_motion, 0.1);  // the animation does move the mesh
  EXPECT_LT(max_error, 1e-4);  // float32 storage

  // The rigid mesh's translation track.
  const auto& ball_track = tracks.at({25, "translation"});
  EXPECT_FLOAT_EQ(ball_track[9], 3.0f);

  // tinygltf's loader accepts the file without errors or warnings.
  tinygltf::TinyGLTF loader;
  tinygltf::Model model;
  std::string error, warning;
  ASSERT_TRUE(loader.LoadBinaryFromFile(&model, &error, &warning, path)) << error;
  EXPECT_EQ(error, "");
  EXPECT_EQ(warning, "");
  EXPECT_EQ(model.skins.size(), 1u);
  EXPECT_EQ(model.animations.size(), 1u);
  EXPECT_EQ(model.accessors[model.meshes[0].primitives[0].attributes.at("POSITION")].count,
            size_t(V));
}

TEST(Gltf, InconsistentInputIsRejectedAndNothingIsWritten) {
  const std::string dir = test::freshTempDir("gltf_bad");
  const std::string path = (fs::path(dir) / "bad.glb").string();
  io::GltfSkinnedAvatar avatar = makeAvatar(3);
  EXPECT_THAT(test::messageOf<InputError>([&] {
                io::writeGlb(path, {0.0, 0.1}, {avatar});
              }),
              HasSubstr("avatar 'walker': 3 rotation and 3 position frames, expected 2"));
  avatar.positions[1](3, 1) = std::nan("");
  EXPECT_THAT(test::messageOf<InputError>([&] {
                io::writeGlb(path, {0.0, 0.1, 0.2}, {avatar});
              }),
              HasSubstr("frame 1 positions contain NaN"));
  avatar = makeAvatar(2);
  avatar.weights.conservativeResize(Eigen::NoChange, 23);
  EXPECT_THAT(test::messageOf<InputError>([&] {
                io::writeGlb(path, {0.0, 0.1}, {avatar});
              }),
              HasSubstr("weights has shape (300, 23), expected (300, 24)"));
  avatar = makeAvatar(2);
  EXPECT_THAT(test::messageOf<InputError>([&] {
                io::writeGlb(path, {0.1, 0.1}, {avatar});
              }),
              HasSubstr("strictly increasing"));
  EXPECT_FALSE(fs::exists(path));
  EXPECT_TRUE(fs::is_empty(dir));
}

TEST(Gltf, VertexNormalsPointOutOfAClosedMesh) {
  MatX3 V(4, 3);
  V << 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1;
  MatX3i F(4, 3);
  F << 0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3;
  const MatX3 N = io::vertexNormals(V, F);
  const Vec3 centroid = V.colwise().mean().transpose();
  for (int i = 0; i < 4; ++i) {
    EXPECT_NEAR(N.row(i).norm(), 1.0, 1e-12);
    EXPECT_GT(N.row(i).dot(V.row(i) - centroid.transpose()), 0.0);
  }
}

}  // namespace
}  // namespace flsh
