#include "flsh/io/scene_outputs.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cstdio>
#include <filesystem>

#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "flsh/format/atomic_file.h"
#include "flsh/format/gltf.h"
#include "flsh/format/mesh_io.h"
#include "flsh/format/npz.h"
#include "flsh/render/plot.h"
#include "flsh/render/render.h"

namespace flsh::io {

namespace fs = std::filesystem;

namespace {

const Vec3 kAvatarColors[] = {Vec3(0.80, 0.62, 0.52), Vec3(0.55, 0.66, 0.80),
                              Vec3(0.62, 0.78, 0.55), Vec3(0.82, 0.72, 0.45)};
const Vec3 kColliderColor(0.90, 0.25, 0.20);

/// A closed UV sphere of radius r about the origin, axis +z, with no vertex ring on the equator
/// (so that stretching the halves apart along z turns it into a capsule). #V × 3, #F × 3.
void makeUvSphere(double r, int rings, int segments, MatX3& V, MatX3i& F) {
  const double pi = 3.14159265358979323846;
  V.resize(2 + rings * segments, 3);
  V.row(0) << 0, 0, r;
  for (int k = 0; k < rings; ++k) {
    const double polar = pi * (k + 0.5) / rings;
    for (int s = 0; s < segments; ++s) {
      const double azimuth = 2 * pi * s / segments;
      V.row(1 + k * segments + s) << r * std::sin(polar) * std::cos(azimuth),
          r * std::sin(polar) * std::sin(azimuth), r * std::cos(polar);
    }
  }
  V.row(1 + rings * segments) << 0, 0, -r;
  const int bottom = 1 + rings * segments;
  auto ring = [&](int k, int s) { return 1 + k * segments + (s % segments); };
  std::vector<Eigen::Vector3i> faces;
  for (int s = 0; s < segments; ++s) {
    faces.emplace_back(0, ring(0, s), ring(0, s + 1));
    for (int k = 0; k + 1 < rings; ++k) {
      faces.emplace_back(ring(k, s), ring(k + 1, s), ring(k + 1, s + 1));
      faces.emplace_back(ring(k, s), ring(k + 1, s + 1), ring(k, s + 1));
    }
    faces.emplace_back(bottom, ring(rings - 1, s + 1), ring(rings - 1, s));
  }
  F.resize(long(faces.size()), 3);
  for (size_t f = 0; f < faces.size(); ++f) F.row(long(f)) = faces[f].transpose();
}

/// Triangle mesh of a sphere or capsule collider at zero path offset (planes have none).
bool colliderMesh(const Collider& collider, MatX3& V, MatX3i& F) {
  if (collider.shape() == ColliderShape::Plane) return false;
  makeUvSphere(collider.radius(), 12, 24, V, F);  // 12 rings: none on the equator
  if (collider.shape() == ColliderShape::Sphere) {
    V.rowwise() += collider.p0().transpose();
    return true;
  }
  const Vec3 a = collider.p0(), b = collider.p1();
  const double half = 0.5 * (b - a).norm();
  for (Eigen::Index i = 0; i < V.rows(); ++i) V(i, 2) += V(i, 2) > 0 ? half : -half;
  const Mat3 R =
      Eigen::Quaterniond::FromTwoVectors(Vec3::UnitZ(), half > 0 ? Vec3(b - a) : Vec3::UnitZ())
          .toRotationMatrix();
  V = (V * R.transpose()).rowwise() + (0.5 * (a + b)).transpose();
  return true;
}

/// A square of `half` m half-size on a plane collider, centred at the point of the plane
/// nearest to `center` (a ground for glTF viewers).
void planeQuad(const Collider& plane, const Vec3& center, double half, MatX3& V, MatX3i& F) {
  const Vec3 n = plane.p1();
  const Vec3 c = center - (center - plane.p0()).dot(n) * n;
  const Vec3 u = n.unitOrthogonal(), w = n.cross(u);
  V.resize(4, 3);
  V.row(0) = (c - half * u - half * w).transpose();
  V.row(1) = (c + half * u - half * w).transpose();
  V.row(2) = (c + half * u + half * w).transpose();
  V.row(3) = (c - half * u + half * w).transpose();
  F.resize(2, 3);
  F << 0, 1, 2, 0, 2, 3;  // counter-clockwise seen from the normal side
}

/// (T, …) float64 array of per-frame matrices stacked in C order.
template <class M>
void addStacked(NpzWriter& npz, const std::string& key, const std::vector<M>& frames,
                std::vector<long> frame_shape) {
  size_t per_frame = 1;
  for (long n : frame_shape) per_frame *= size_t(n);
  std::vector<double> data(frames.size() * per_frame);
  for (size_t k = 0; k < frames.size(); ++k) {
    // Row-major copy (MatX3 is row-major; vectors are 1-D).
    const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> rows = frames[k];
    if (size_t(rows.size()) != per_frame)
      throw Error("SceneRecorder: internal shape mismatch in " + key);
    std::copy(rows.data(), rows.data() + per_frame, data.begin() + long(k * per_frame));
  }
  frame_shape.insert(frame_shape.begin(), long(frames.size()));
  npz.add(key, data.data(), frame_shape);
}

std::string plyName(int frame) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), "frame_%04d.ply", frame);
  return buffer;
}

double maxMm(const VecX& norms) { return norms.size() > 0 ? 1000.0 * norms.maxCoeff() : 0.0; }

}  // namespace

/// What is kept of one avatar: per saved frame for states.npz / animation.glb, per shown frame
/// for sheet.png.
struct SceneRecorder::AvatarFrames {
  std::vector<VecX> states, poses;
  std::vector<Vec3> trans;
  std::vector<MatX3> vertices, joints;
  std::vector<MatX3> displacements;  ///< soft avatars, states.npz: u per surface vertex, m
  std::vector<double> max_mm;        ///< soft avatars, states.npz
  std::vector<std::vector<Mat3>> rotations;
  std::vector<MatX3> shown_vertices;
  std::vector<VecX> shown_norms;  ///< soft avatars: ‖u_i‖ per surface vertex, m
  Vec3 first_root = Vec3::Zero();
};

SceneRecorder::SceneRecorder(const OutputSpec& outputs, std::string dir,
                             std::vector<RecordedAvatar> avatars, std::vector<Collider> colliders,
                             double time_step, int frames)
    : outputs_(outputs),
      dir_(std::move(dir)),
      avatars_(std::move(avatars)),
      colliders_(std::move(colliders)),
      time_step_(time_step),
      frames_(frames) {
  if (frames_ < 1)
    throw InputError("SceneRecorder: frames = " + std::to_string(frames_) + ", expected >= 1");
  if (outputs_.png) {
    const int shown = std::min(outputs_.png_frames, frames_);
    for (int j = 0; j < shown; ++j)
      shown_.push_back(shown > 1 ? j * (frames_ - 1) / (shown - 1) : 0);
  }
  collider_offsets_.resize(colliders_.size());
  for (size_t i = 0; i < avatars_.size(); ++i) data_.push_back(std::make_shared<AvatarFrames>());
  max_displacement_mm_.assign(avatars_.size(), 0.0);
  if (outputs_.ply)
    for (const auto& avatar : avatars_)
      ensureDirectory((fs::path(dir_) / "meshes" / avatar.name).string());
}

double SceneRecorder::bytesPerFrame(const OutputSpec& outputs,
                                    const std::vector<RecordedAvatar>& avatars,
                                    size_t num_colliders) {
  double doubles = 0.0;
  if (outputs.npz || outputs.gltf) doubles += 1.0 + 3.0 * double(num_colliders);
  for (const auto& avatar : avatars) {
    const double V = avatar.simulable->avatar().body().numVertices();
    const double joints = 3.0 * kNumJoints;
    if (outputs.npz)
      doubles += avatar.simulable->numDofs() + kSmplPoseSize + 3.0 + 3.0 * V + joints +
                 (avatar.soft ? 1.0 + 3.0 * V : 0.0);
    if (outputs.gltf) doubles += 9.0 * kNumJoints + (outputs.npz ? 0.0 : joints);
  }
  return 3.0 * 8.0 * doubles;  // the frames, their stacked copies and the written buffers
}

void SceneRecorder::record(double t) {
  if (recorded_ >= frames_)
    throw Error("SceneRecorder::record: all " + std::to_string(frames_) + " frames are recorded");
  const int frame = recorded_++;
  const bool every_frame = outputs_.npz || outputs_.gltf;
  const bool shown = std::binary_search(shown_.begin(), shown_.end(), frame);
  if (every_frame) times_.push_back(t);
  if (shown) shown_times_.push_back(t);
  for (size_t c = 0; c < colliders_.size(); ++c)
    if (every_frame || shown) collider_offsets_[c].push_back(colliders_[c].path.offsetAt(t));
  for (size_t i = 0; i < avatars_.size(); ++i) {
    const Simulable& sim = *avatars_[i].simulable;
    AvatarFrames& d = *data_[i];
    MatX3 vertices;  // skinning every vertex costs: only when an output takes them
    if (outputs_.ply || outputs_.npz || shown) vertices = sim.getVertices();
    VecX norms;
    MatX3 displacements;
    if (avatars_[i].soft) {
      displacements = sim.getSoftTissueDisplacements();
      norms = displacements.rowwise().norm();
      max_displacement_mm_[i] = std::max(max_displacement_mm_[i], maxMm(norms));
    }
    if (frame == 0) d.first_root = sim.bonePositions().row(0).transpose();
    if (outputs_.ply)
      writePly((fs::path(dir_) / "meshes" / avatars_[i].name / plyName(frame)).string(), vertices,
               sim.avatar().body().faces);
    if (outputs_.npz) {
      d.states.push_back(sim.getState());
      d.poses.push_back(sim.getPose());
      d.trans.push_back(sim.getTrans());
      d.vertices.push_back(vertices);
      if (avatars_[i].soft) {
        d.max_mm.push_back(maxMm(norms));
        d.displacements.push_back(std::move(displacements));
      }
    }
    if (every_frame) d.joints.push_back(sim.bonePositions());
    if (outputs_.gltf) d.rotations.push_back(sim.boneRotations());
    if (shown) {
      d.shown_vertices.push_back(vertices);
      if (avatars_[i].soft) d.shown_norms.push_back(norms);
    }
  }
}

std::vector<std::string> SceneRecorder::finish() {
  if (recorded_ != frames_)
    throw Error("SceneRecorder::finish: " + std::to_string(recorded_) + " of " +
                std::to_string(frames_) + " frames recorded");
  std::vector<std::string> written;
  if (outputs_.ply) written.push_back("meshes/<avatar>/frame_*.ply");
  if (outputs_.npz) {
    writeNpz();
    written.push_back("states.npz");
  }
  if (outputs_.gltf) {
    writeGltf();
    written.push_back("animation.glb");
  }
  if (outputs_.png) {
    writePng();
    written.push_back("sheet.png");
  }
  return written;
}

void SceneRecorder::writeNpz() const {
  const long T = long(times_.size());
  NpzWriter npz;
  npz.add("times", Eigen::Map<const VecX>(times_.data(), T));
  npz.addScalar("time_step", time_step_);
  for (size_t i = 0; i < avatars_.size(); ++i) {
    const AvatarFrames& d = *data_[i];
    const std::string& name = avatars_[i].name;
    const SoftAvatar& avatar = avatars_[i].simulable->avatar();
    const BodyModel& body = avatar.body();
    const long V = body.numVertices(), F = body.numFaces();
    addStacked(npz, name + "_states", d.states, {long(avatars_[i].simulable->numDofs())});
    addStacked(npz, name + "_poses", d.poses, {kSmplPoseSize});
    addStacked(npz, name + "_trans", d.trans, {3});
    addStacked(npz, name + "_vertices", d.vertices, {V, 3});
    addStacked(npz, name + "_joints", d.joints, {kNumJoints, 3});
    std::vector<int64_t> faces(size_t(F) * 3);
    for (long f = 0; f < F; ++f)
      for (int c = 0; c < 3; ++c) faces[size_t(3 * f + c)] = body.faces(f, c);
    npz.add(name + "_faces", faces.data(), {F, 3});
    npz.add(name + "_betas", Eigen::Ref<const VecX>(avatar.betas()));
    if (avatars_[i].soft) {
      npz.add(name + "_max_displacement_mm", Eigen::Map<const VecX>(d.max_mm.data(), T));
      addStacked(npz, name + "_displacements", d.displacements, {V, 3});
    }
  }
  for (size_t c = 0; c < colliders_.size(); ++c)
    addStacked(npz, colliders_[c].name + "_offset", collider_offsets_[c], {3});
  npz.save((fs::path(dir_) / "states.npz").string());
}

void SceneRecorder::writeGltf() const {
  std::vector<GltfSkinnedAvatar> avatars;
  Vec3 center = Vec3::Zero();
  for (size_t i = 0; i < avatars_.size(); ++i) {
    const SoftAvatar& avatar = avatars_[i].simulable->avatar();
    const BodyModel& body = avatar.body();
    GltfSkinnedAvatar a;
    a.name = avatars_[i].name;
    a.rest_vertices = avatar.restVertices();
    a.faces = body.faces;
    a.weights = body.weights;
    a.parents = body.parents;
    a.rest_joints = avatar.restJoints();
    a.bone_names.assign(kSmplJointNames.begin(), kSmplJointNames.end());
    a.rotations = data_[i]->rotations;
    a.positions = data_[i]->joints;
    a.color = kAvatarColors[i % 4];
    center += data_[i]->first_root / double(avatars_.size());
    avatars.push_back(std::move(a));
  }
  std::vector<GltfRigidMesh> rigid;
  for (size_t c = 0; c < colliders_.size(); ++c) {
    const Collider& collider = colliders_[c];
    GltfRigidMesh m;
    m.name = collider.name;
    if (colliderMesh(collider, m.vertices, m.faces)) {
      m.translations = collider_offsets_[c];
      m.color = kColliderColor;
    } else {
      planeQuad(collider, center, 5.0, m.vertices, m.faces);
      m.color = Vec3(0.7, 0.7, 0.7);
    }
    rigid.push_back(std::move(m));
  }
  writeGlb((fs::path(dir_) / "animation.glb").string(), times_, avatars, rigid);
}

void SceneRecorder::writePng() {
  // All avatars and the sphere/capsule colliders in one mesh per shown frame, framed on the
  // avatars (a collider far away is cut off rather than shrinking the bodies), each frame
  // labelled with its time. Soft avatars are coloured by ‖u_i‖ with one robust scale over the
  // whole sheet (the 99th percentile of the shown values, not their maximum: a few flopping
  // vertices would leave everything else in the bottom colour), drawn as a colour bar in mm.
  std::vector<VecX> shown_mm;
  double largest_mm = 0.0;
  for (size_t i = 0; i < avatars_.size(); ++i)
    for (const VecX& norms : data_[i]->shown_norms) {
      shown_mm.push_back(1000.0 * norms);
      largest_mm = std::max(largest_mm, maxMm(norms));
    }
  sheet_max_mm_ = render::quantileOf(shown_mm, kSheetScaleQuantile);
  if (!(sheet_max_mm_ > 0.0)) sheet_max_mm_ = largest_mm;
  const bool every_frame = outputs_.npz || outputs_.gltf;
  MatX3i faces;
  std::vector<MatX3> frames, colors;
  Eigen::AlignedBox3d box;
  for (size_t j = 0; j < shown_.size(); ++j) {
    std::vector<std::pair<MatX3, MatX3i>> parts;
    std::vector<MatX3> part_colors;  // #part vertices × 3 each
    auto uniform = [](long rows, const Vec3& color) {
      MatX3 C(rows, 3);
      C.rowwise() = color.transpose();
      return C;
    };
    for (size_t i = 0; i < avatars_.size(); ++i) {
      const MatX3& V = data_[i]->shown_vertices[j];
      parts.emplace_back(V, avatars_[i].simulable->avatar().body().faces);
      part_colors.push_back(avatars_[i].soft ? render::displacementColors(
                                                   1000.0 * data_[i]->shown_norms[j], sheet_max_mm_)
                                             : uniform(V.rows(), kAvatarColors[i % 4]));
      for (Eigen::Index v = 0; v < V.rows(); ++v) box.extend(V.row(v).transpose());
    }
    for (size_t c = 0; c < colliders_.size(); ++c) {
      MatX3 V;
      MatX3i F;
      if (!colliderMesh(colliders_[c], V, F)) continue;
      V.rowwise() += collider_offsets_[c][every_frame ? size_t(shown_[j]) : j].transpose();
      parts.emplace_back(V, F);
      part_colors.push_back(uniform(V.rows(), kColliderColor));
    }
    long nv = 0, nf = 0;
    for (const auto& p : parts) nv += p.first.rows(), nf += p.second.rows();
    MatX3 V(nv, 3), C(nv, 3);
    MatX3i F(nf, 3);
    long v0 = 0, f0 = 0;
    for (size_t p = 0; p < parts.size(); ++p) {
      V.middleRows(v0, parts[p].first.rows()) = parts[p].first;
      C.middleRows(v0, parts[p].first.rows()) = part_colors[p];
      F.middleRows(f0, parts[p].second.rows()) = parts[p].second.array() + int(v0);
      v0 += parts[p].first.rows();
      f0 += parts[p].second.rows();
    }
    faces = F;
    frames.push_back(std::move(V));
    colors.push_back(std::move(C));
  }
  render::RenderOptions view;
  view.width = 320;
  view.height = 480;
  // Padded except below: the renderer puts its floor at the bottom of the box (the soles).
  view.frame =
      Eigen::AlignedBox3d(box.min() - Vec3(0.15, 0.0, 0.15), box.max() + Vec3::Constant(0.15));
  render::Image sheet = render::renderSheet(frames, faces, view, 0, colors);
  for (size_t j = 0; j < shown_.size(); ++j) {
    char label[64];
    std::snprintf(label, sizeof(label), "t = %.2f s", shown_times_[j]);
    render::drawLabel(sheet, int(j) * view.width + 8, 8, label, Vec3(0.1, 0.1, 0.1), 2);
  }
  if (!shown_mm.empty()) {
    char caption[160];
    std::snprintf(caption, sizeof(caption),
                  "soft-tissue |u|, mm: scale to the 99th percentile (largest %.3g)", largest_mm);
    sheet = render::withColorBar(sheet, sheet_max_mm_, "mm", caption);
  }
  render::writePng((fs::path(dir_) / "sheet.png").string(), sheet);
}

}  // namespace flsh::io
