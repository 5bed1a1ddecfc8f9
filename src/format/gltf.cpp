// Binary glTF 2.0 writer (the JSON chunk with nlohmann-json, the binary chunk by hand).
// Layout: one buffer; one tightly packed bufferView per accessor, 4-byte aligned.
#include "flsh/format/gltf.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <nlohmann/json.hpp>
#include <numeric>

#include "flsh/core/error.h"
#include "flsh/format/atomic_file.h"

namespace flsh::io {
namespace {

using json = nlohmann::json;

// glTF enumerations.
constexpr int kFloat = 5126, kUnsignedInt = 5125, kUnsignedShort = 5123, kUnsignedByte = 5121;
constexpr int kArrayBuffer = 34962, kElementArrayBuffer = 34963;
constexpr uint32_t kGlbMagic = 0x46546C67, kChunkJson = 0x4E4F534A, kChunkBin = 0x004E4942;

/// Collects binary data and the JSON document.
class GlbBuilder {
 public:
  json doc = {{"asset", {{"version", "2.0"}, {"generator", "flsh"}}}};

  /// Appends bytes as one bufferView (4-byte aligned); returns its index.
  int addView(const void* data, size_t bytes, int target) {
    while (bin_.size() % 4 != 0) bin_.push_back(0);
    json view = {{"buffer", 0}, {"byteOffset", bin_.size()}, {"byteLength", bytes}};
    if (target != 0) view["target"] = target;
    const auto* p = static_cast<const uint8_t*>(data);
    bin_.insert(bin_.end(), p, p + bytes);
    doc["bufferViews"].push_back(view);
    return int(doc["bufferViews"].size()) - 1;
  }

  /// Float accessor of `count` elements of `width` components ("SCALAR", "VEC3", …), with
  /// min/max per component when `bounds` (required for positions and animation inputs).
  int addFloats(const std::vector<float>& values, int width, const char* type, int target,
                bool bounds) {
    const size_t count = values.size() / size_t(width);
    const int view = addView(values.data(), values.size() * sizeof(float), target);
    json accessor = {
        {"bufferView", view}, {"componentType", kFloat}, {"count", count}, {"type", type}};
    if (bounds && count > 0) {
      std::vector<float> lo(values.begin(), values.begin() + width), hi = lo;
      for (size_t i = 0; i < count; ++i)
        for (int c = 0; c < width; ++c) {
          lo[c] = std::min(lo[c], values[i * width + c]);
          hi[c] = std::max(hi[c], values[i * width + c]);
        }
      accessor["min"] = lo;
      accessor["max"] = hi;
    }
    return pushAccessor(accessor);
  }

  template <class T>
  int addIntegers(const std::vector<T>& values, int component_type, int width, const char* type,
                  int target) {
    const int view = addView(values.data(), values.size() * sizeof(T), target);
    return pushAccessor({{"bufferView", view},
                         {"componentType", component_type},
                         {"count", values.size() / size_t(width)},
                         {"type", type}});
  }

  int pushAccessor(const json& accessor) {
    doc["accessors"].push_back(accessor);
    return int(doc["accessors"].size()) - 1;
  }

  int push(const char* array, const json& value) {
    doc[array].push_back(value);
    return int(doc[array].size()) - 1;
  }

  void write(const std::string& path) {
    while (bin_.size() % 4 != 0) bin_.push_back(0);
    doc["buffers"] = json::array({{{"byteLength", bin_.size()}}});
    std::string text = doc.dump();
    while (text.size() % 4 != 0) text.push_back(' ');
    const uint32_t total = uint32_t(12 + 8 + text.size() + 8 + bin_.size());
    writeFileAtomically(path, [&](std::ostream& out) {
      auto u32 = [&](uint32_t v) {
        const uint8_t b[4] = {uint8_t(v), uint8_t(v >> 8), uint8_t(v >> 16), uint8_t(v >> 24)};
        out.write(reinterpret_cast<const char*>(b), 4);
      };
      u32(kGlbMagic);
      u32(2);
      u32(total);
      u32(uint32_t(text.size()));
      u32(kChunkJson);
      out.write(text.data(), std::streamsize(text.size()));
      u32(uint32_t(bin_.size()));
      u32(kChunkBin);
      out.write(reinterpret_cast<const char*>(bin_.data()), std::streamsize(bin_.size()));
    });
  }

 private:
  std::vector<uint8_t> bin_;
};

std::vector<float> toFloats(const Eigen::Ref<const MatX3>& M) {
  std::vector<float> out(size_t(M.rows()) * 3);
  for (Eigen::Index i = 0; i < M.rows(); ++i)
    for (int c = 0; c < 3; ++c) out[3 * i + c] = float(M(i, c));
  return out;
}

int addMaterial(GlbBuilder& glb, const std::string& name, const Vec3& color) {
  return glb.push("materials", {{"name", name},
                                {"pbrMetallicRoughness",
                                 {{"baseColorFactor", {color.x(), color.y(), color.z(), 1.0}},
                                  {"metallicFactor", 0.0},
                                  {"roughnessFactor", 0.8}}}});
}

/// POSITION, NORMAL and indices of a triangle mesh: the primitive's JSON (without a material).
json addGeometry(GlbBuilder& glb, const MatX3& V, const MatX3i& F) {
  const int position = glb.addFloats(toFloats(V), 3, "VEC3", kArrayBuffer, true);
  const int normal = glb.addFloats(toFloats(vertexNormals(V, F)), 3, "VEC3", kArrayBuffer, false);
  std::vector<uint32_t> indices(size_t(F.rows()) * 3);
  for (Eigen::Index f = 0; f < F.rows(); ++f)
    for (int c = 0; c < 3; ++c) indices[3 * f + c] = uint32_t(F(f, c));
  const int index = glb.addIntegers(indices, kUnsignedInt, 1, "SCALAR", kElementArrayBuffer);
  return {{"attributes", {{"POSITION", position}, {"NORMAL", normal}}}, {"indices", index}};
}

void checkMesh(const std::string& what, const MatX3& V, const MatX3i& F) {
  if (V.rows() == 0 || F.rows() == 0)
    throw InputError("writeGlb: " + what + ": empty mesh (" + std::to_string(V.rows()) +
                     " vertices, " + std::to_string(F.rows()) + " faces)");
  if (!V.allFinite()) throw InputError("writeGlb: " + what + ": vertices contain NaN or Inf");
  if (F.minCoeff() < 0 || F.maxCoeff() >= V.rows())
    throw InputError("writeGlb: " + what + ": face index out of range [0, " +
                     std::to_string(V.rows()) + ")");
}

void checkAvatar(const GltfSkinnedAvatar& a, size_t frames) {
  const std::string what = "avatar '" + a.name + "'";
  checkMesh(what, a.rest_vertices, a.faces);
  const long V = a.rest_vertices.rows(), B = long(a.parents.size());
  auto shape = [](long r, long c) { return shapeString({r, c}); };
  if (B == 0 || B > 65535)
    throw InputError("writeGlb: " + what + ": expected 1..65535 bones, got " + std::to_string(B));
  if (a.weights.rows() != V || a.weights.cols() != B)
    throw InputError("writeGlb: " + what + ": weights has shape " +
                     shape(a.weights.rows(), a.weights.cols()) + ", expected " + shape(V, B));
  if (!a.weights.allFinite())
    throw InputError("writeGlb: " + what + ": weights contain NaN or Inf");
  if (a.rest_joints.rows() != B || !a.rest_joints.allFinite())
    throw InputError("writeGlb: " + what + ": rest_joints has shape " +
                     shape(a.rest_joints.rows(), 3) + " (expected " + shape(B, 3) + ", finite)");
  for (long b = 0; b < B; ++b)
    if ((b == 0) != (a.parents[b] < 0) || a.parents[b] >= b)
      throw InputError("writeGlb: " + what + ": parents[" + std::to_string(b) + "] = " +
                       std::to_string(a.parents[b]) + " (expected −1 for bone 0, else 0..b−1)");
  if (!a.bone_names.empty() && long(a.bone_names.size()) != B)
    throw InputError("writeGlb: " + what + ": " + std::to_string(a.bone_names.size()) +
                     " bone names for " + std::to_string(B) + " bones");
  if (a.rotations.size() != frames || a.positions.size() != frames)
    throw InputError("writeGlb: " + what + ": " + std::to_string(a.rotations.size()) +
                     " rotation and " + std::to_string(a.positions.size()) +
                     " position frames, expected " + std::to_string(frames) + " (one per time)");
  for (size_t k = 0; k < frames; ++k) {
    if (long(a.rotations[k].size()) != B || a.positions[k].rows() != B)
      throw InputError("writeGlb: " + what + ": frame " + std::to_string(k) + " has " +
                       std::to_string(a.rotations[k].size()) + " rotations and positions " +
                       shape(a.positions[k].rows(), 3) + ", expected " + std::to_string(B) +
                       " and " + shape(B, 3));
    if (!a.positions[k].allFinite())
      throw InputError("writeGlb: " + what + ": frame " + std::to_string(k) +
                       " positions contain NaN or Inf");
    for (const Mat3& R : a.rotations[k])
      if (!R.allFinite() || (R.transpose() * R - Mat3::Identity()).cwiseAbs().maxCoeff() > 1e-6)
        throw InputError("writeGlb: " + what + ": frame " + std::to_string(k) +
                         " has a rotation that is not orthonormal or not finite");
  }
}

/// Quaternions (x, y, z, w) of a bone over all frames, sign-continuous so that LINEAR
/// interpolation between frames takes the short way.
void appendQuaternion(std::vector<float>& out, const Mat3& R, Eigen::Quaterniond& previous,
                      bool first) {
  Eigen::Quaterniond q(R);
  q.normalize();
  if (!first && q.coeffs().dot(previous.coeffs()) < 0) q.coeffs() = -q.coeffs();
  previous = q;
  out.insert(out.end(), {float(q.x()), float(q.y()), float(q.z()), float(q.w())});
}

}  // namespace

MatX3 vertexNormals(const Eigen::Ref<const MatX3>& V, const Eigen::Ref<const MatX3i>& F) {
  MatX3 N = MatX3::Zero(V.rows(), 3);
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    const Vec3 a = V.row(F(f, 0)), b = V.row(F(f, 1)), c = V.row(F(f, 2));
    const Vec3 n = (b - a).cross(c - a);  // length = 2 · area: area weighting
    for (int k = 0; k < 3; ++k) N.row(F(f, k)) += n.transpose();
  }
  for (Eigen::Index i = 0; i < N.rows(); ++i) {
    const double length = N.row(i).norm();
    if (length > 1e-300 && std::isfinite(length))
      N.row(i) /= length;
    else
      N.row(i) = Vec3::UnitY().transpose();
  }
  return N;
}

void writeGlb(const std::string& path, const std::vector<double>& times,
              const std::vector<GltfSkinnedAvatar>& avatars,
              const std::vector<GltfRigidMesh>& rigid_meshes) {
  const size_t T = times.size();
  if (T == 0)
    throw InputError("writeGlb: " + path + ": expected at least one frame time, got none");
  for (size_t k = 0; k < T; ++k)
    if (!std::isfinite(times[k]) || (k > 0 && !(float(times[k]) > float(times[k - 1]))))
      throw InputError("writeGlb: " + path +
                       ": times must be finite and strictly increasing (as float32); times[" +
                       std::to_string(k) + "] = " + std::to_string(times[k]));
  for (const auto& a : avatars) checkAvatar(a, T);
  for (const auto& m : rigid_meshes) {
    checkMesh("rigid mesh '" + m.name + "'", m.vertices, m.faces);
    if (!m.translations.empty() && m.translations.size() != T)
      throw InputError("writeGlb: rigid mesh '" + m.name +
                       "': " + std::to_string(m.translations.size()) + " translations, expected " +
                       std::to_string(T) + " (one per time) or none");
  }

  GlbBuilder glb;
  std::vector<int> scene_nodes;
  json samplers = json::array(), channels = json::array();
  std::vector<float> time_values(times.begin(), times.end());
  const int time_accessor = glb.addFloats(time_values, 1, "SCALAR", 0, true);
  auto animate = [&](int node, const char* path_name, const std::vector<float>& values, int width,
                     const char* type) {
    const int output = glb.addFloats(values, width, type, 0, false);
    samplers.push_back({{"input", time_accessor}, {"output", output}, {"interpolation", "LINEAR"}});
    channels.push_back(
        {{"sampler", int(samplers.size()) - 1}, {"target", {{"node", node}, {"path", path_name}}}});
  };

  for (const auto& a : avatars) {
    const long V = a.rest_vertices.rows(), B = long(a.parents.size());
    json primitive = addGeometry(glb, a.rest_vertices, a.faces);

    // The four largest weights per vertex, renormalized in float so they sum to 1.
    std::vector<uint16_t> joints16(size_t(V) * 4, 0);
    std::vector<float> weights(size_t(V) * 4, 0.0f);
    std::vector<int> order(static_cast<size_t>(B));
    for (long i = 0; i < V; ++i) {
      std::iota(order.begin(), order.end(), 0);
      const int keep = int(std::min<long>(4, B));
      std::partial_sort(order.begin(), order.begin() + keep, order.end(),
                        [&](int x, int y) { return a.weights(i, x) > a.weights(i, y); });
      double sum = 0;
      for (int k = 0; k < keep; ++k) sum += std::max(0.0, a.weights(i, order[k]));
      if (!(sum > 0))
        throw InputError("writeGlb: avatar '" + a.name + "': vertex " + std::to_string(i) +
                         " has no positive skinning weight");
      float partial = 0.0f;
      int last = 0;
      for (int k = 0; k < keep; ++k) {
        joints16[4 * i + k] = uint16_t(order[k]);
        weights[4 * i + k] = float(std::max(0.0, a.weights(i, order[k])) / sum);
        if (weights[4 * i + k] > 0) last = k;
      }
      for (int k = 0; k < keep; ++k)
        if (k != last) partial += weights[4 * i + k];
      weights[4 * i + last] = 1.0f - partial;
    }
    int joints_accessor;
    if (B <= 256) {
      std::vector<uint8_t> joints8(joints16.begin(), joints16.end());
      joints_accessor = glb.addIntegers(joints8, kUnsignedByte, 4, "VEC4", kArrayBuffer);
    } else {
      joints_accessor = glb.addIntegers(joints16, kUnsignedShort, 4, "VEC4", kArrayBuffer);
    }
    primitive["attributes"]["JOINTS_0"] = joints_accessor;
    primitive["attributes"]["WEIGHTS_0"] = glb.addFloats(weights, 4, "VEC4", kArrayBuffer, false);
    primitive["material"] = addMaterial(glb, a.name, a.color);
    const int mesh = glb.push("meshes", {{"name", a.name}, {"primitives", {primitive}}});

    // Bone nodes: local transforms relative to the parent bone, frame 0 as the static pose.
    auto localTransform = [&](size_t k, long b, Mat3& R, Vec3& t) {
      const Mat3& Rb = a.rotations[k][b];
      const Vec3 tb = a.positions[k].row(b).transpose();
      if (a.parents[b] < 0) {
        R = Rb;
        t = tb;
      } else {
        const Mat3& Rp = a.rotations[k][a.parents[b]];
        R = Rp.transpose() * Rb;
        t = Rp.transpose() * (tb - a.positions[k].row(a.parents[b]).transpose());
      }
    };
    const int first_node = glb.doc.contains("nodes") ? int(glb.doc["nodes"].size()) : 0;
    std::vector<float> inverse_bind(size_t(B) * 16, 0.0f);
    for (long b = 0; b < B; ++b) {
      Mat3 R;
      Vec3 t;
      localTransform(0, b, R, t);
      const Eigen::Quaterniond q = Eigen::Quaterniond(R).normalized();
      json node = {
          {"name",
           a.name + "/" + (a.bone_names.empty() ? "bone" + std::to_string(b) : a.bone_names[b])},
          {"translation", {t.x(), t.y(), t.z()}},
          {"rotation", {q.x(), q.y(), q.z(), q.w()}}};
      json children = json::array();
      for (long c = b + 1; c < B; ++c)
        if (a.parents[c] == b) children.push_back(first_node + c);
      if (!children.empty()) node["children"] = children;
      glb.push("nodes", node);
      // Column-major [I | −J_b]: the rest frame of bone b is a translation to its joint.
      float* m = &inverse_bind[16 * b];
      m[0] = m[5] = m[10] = m[15] = 1.0f;
      for (int c = 0; c < 3; ++c) m[12 + c] = float(-a.rest_joints(b, c));
    }
    json skin_joints = json::array();
    for (long b = 0; b < B; ++b) skin_joints.push_back(first_node + b);
    const int inverse_bind_accessor = glb.addFloats(inverse_bind, 16, "MAT4", 0, false);
    const int skin = glb.push("skins", {{"name", a.name},
                                        {"joints", skin_joints},
                                        {"inverseBindMatrices", inverse_bind_accessor},
                                        {"skeleton", first_node}});
    const int mesh_node = glb.push("nodes", {{"name", a.name}, {"mesh", mesh}, {"skin", skin}});
    scene_nodes.push_back(first_node);
    scene_nodes.push_back(mesh_node);

    for (long b = 0; b < B; ++b) {
      std::vector<float> translation, rotation;
      translation.reserve(3 * T);
      rotation.reserve(4 * T);
      Eigen::Quaterniond previous;
      for (size_t k = 0; k < T; ++k) {
        Mat3 R;
        Vec3 t;
        localTransform(k, b, R, t);
        translation.insert(translation.end(), {float(t.x()), float(t.y()), float(t.z())});
        appendQuaternion(rotation, R, previous, k == 0);
      }
      animate(first_node + int(b), "translation", translation, 3, "VEC3");
      animate(first_node + int(b), "rotation", rotation, 4, "VEC4");
    }
  }

  for (const auto& m : rigid_meshes) {
    json primitive = addGeometry(glb, m.vertices, m.faces);
    primitive["material"] = addMaterial(glb, m.name, m.color);
    const int mesh = glb.push("meshes", {{"name", m.name}, {"primitives", {primitive}}});
    const Vec3 t0 = m.translations.empty() ? Vec3::Zero() : m.translations[0];
    const int node = glb.push(
        "nodes", {{"name", m.name}, {"mesh", mesh}, {"translation", {t0.x(), t0.y(), t0.z()}}});
    scene_nodes.push_back(node);
    if (!m.translations.empty()) {
      std::vector<float> translation;
      for (const Vec3& t : m.translations) {
        if (!t.allFinite())
          throw InputError("writeGlb: rigid mesh '" + m.name +
                           "': translation contains NaN or Inf");
        translation.insert(translation.end(), {float(t.x()), float(t.y()), float(t.z())});
      }
      animate(node, "translation", translation, 3, "VEC3");
    }
  }

  glb.doc["scenes"] = json::array({{{"nodes", scene_nodes}}});
  glb.doc["scene"] = 0;
  if (!channels.empty())
    glb.doc["animations"] =
        json::array({{{"name", "simulation"}, {"samplers", samplers}, {"channels", channels}}});
  glb.write(path);
}

}  // namespace flsh::io
