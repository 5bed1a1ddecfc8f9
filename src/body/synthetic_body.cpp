// The synthetic SMPL-format body.
//
// Conventions (fixed, documented choices):
// - Axes as SMPL: y up, the body faces +z, its left side is +x; T-pose with the arms
//   horizontal and the palms down.
// - The pelvis joint is at the origin (SMPL's own template has it near y = −0.22); the soles
//   are flat at y ≈ −0.56 × height, the top of the head at y ≈ +0.44 × height.
// - The template is scaled so that its vertical extent (top of the head to the soles) is
//   exactly options.height.
// - Joint 20/21 (wrist) owns the palm and the thumb, joint 22/23 (hand) the fingers beyond the
//   knuckles, as in SMPL; joint 10/11 (foot) owns the toes, 7/8 (ankle) the rest of the foot.
//
// Pipeline: designed joints and body-part primitives (synthetic_design.cpp) → signed distance
// of their smooth union → mesh with exactly options.vertices vertices (synthetic_mesher.cpp) →
// skinning weights from the per-joint part distances, smoothed on the mesh → joint regressor
// by a constrained least-squares fit on a ring of vertices around each joint → shape
// directions and pose correctives from the skeleton and the weights.
#include "flsh/body/synthetic_body.h"

#include <Eigen/Dense>
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <list>
#include <mutex>
#include <numeric>
#include <string>
#include <vector>

#include "body/synthetic_body_detail.h"
#include "body/synthetic_design.h"
#include "body/synthetic_mesher.h"
#include "flsh/core/error.h"

namespace flsh {

const std::vector<std::string> kSyntheticShapeNames = {
    "height",    "weight", "leg_length", "arm_length", "shoulder_width",
    "hip_width", "belly",  "chest",      "head_size",  "muscularity"};

namespace synthetic {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr int kMinVertices = kMinSyntheticVertices;
constexpr int kMaxVertices = kMaxSyntheticVertices;
constexpr int kMaxInfluences = 4;  // nonzero skinning weights per vertex

using JointWeights = std::array<double, kNumJoints>;

double smoothstep(double x) {
  x = std::clamp(x, 0.0, 1.0);
  return x * x * (3 - 2 * x);
}

// Parameter t ∈ [0, 1] of the point of segment [a, b] closest to p.
double segmentParameter(const Vec3& p, const Vec3& a, const Vec3& b) {
  const Vec3 ab = b - a;
  const double l2 = ab.squaredNorm();
  return l2 > 0 ? std::clamp((p - a).dot(ab) / l2, 0.0, 1.0) : 0.0;
}

std::vector<std::vector<int>> vertexNeighbours(int num_vertices, const MatX3i& F) {
  std::vector<std::vector<int>> nbrs(num_vertices);
  for (int f = 0; f < F.rows(); ++f)
    for (int e = 0; e < 3; ++e) {
      nbrs[F(f, e)].push_back(F(f, (e + 1) % 3));
      nbrs[F(f, e)].push_back(F(f, (e + 2) % 3));
    }
  for (auto& list : nbrs) {
    std::sort(list.begin(), list.end());
    list.erase(std::unique(list.begin(), list.end()), list.end());
  }
  return nbrs;
}

// Area-weighted unit vertex normals, #V × 3.
MatX3 vertexNormals(const MatX3& V, const MatX3i& F) {
  MatX3 N = MatX3::Zero(V.rows(), 3);
  for (int f = 0; f < F.rows(); ++f) {
    const Vec3 a = V.row(F(f, 0)), b = V.row(F(f, 1)), c = V.row(F(f, 2));
    const Vec3 n = (b - a).cross(c - a);
    for (int k = 0; k < 3; ++k) N.row(F(f, k)) += n.transpose();
  }
  for (int i = 0; i < N.rows(); ++i) N.row(i).normalize();
  return N;
}

// Keeps the kMaxInfluences largest weights (ties: lower joint first) and renormalizes.
void truncateAndNormalize(JointWeights& w) {
  std::array<int, kNumJoints> order;
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return w[a] > w[b]; });
  for (int r = kMaxInfluences; r < kNumJoints; ++r) w[order[r]] = 0.0;
  double total = 0;
  for (double x : w) total += x;
  for (double& x : w) x /= total;
}

// Skinning weights (#V × 24): each joint's influence falls off smoothly with how far the
// vertex is outside the parts that joint owns, relative to the nearest part; then a few
// rounds of neighbour averaging on the mesh, keeping the 4 largest per vertex.
MatX skinningWeights(const BodyDesign& design, const MatX3& V,
                     const std::vector<std::vector<int>>& nbrs) {
  const int nv = int(V.rows());
  const double falloff_width = 0.03;  // m: joints whose parts are this much farther get 0
  std::vector<JointWeights> W(nv);
  JointWeights dist;
  for (int i = 0; i < nv; ++i) {
    design.partDistances(V.row(i).transpose(), dist);
    const double nearest = *std::min_element(dist.begin(), dist.end());
    for (int j = 0; j < kNumJoints; ++j) {
      const double x = std::clamp((dist[j] - nearest) / falloff_width, 0.0, 1.0);
      W[i][j] = (1 - x) * (1 - x) * (1 + 2 * x);  // C¹ Hermite falloff from 1 to 0
    }
    truncateAndNormalize(W[i]);
  }
  for (int round = 0; round < 3; ++round) {
    std::vector<JointWeights> next(nv);
    for (int i = 0; i < nv; ++i) {
      JointWeights mean{};
      for (int n : nbrs[i])
        for (int j = 0; j < kNumJoints; ++j) mean[j] += W[n][j];
      for (int j = 0; j < kNumJoints; ++j)
        next[i][j] = 0.5 * W[i][j] + 0.5 * mean[j] / double(nbrs[i].size());
      truncateAndNormalize(next[i]);
    }
    W.swap(next);
  }
  MatX weights(nv, kNumJoints);
  for (int i = 0; i < nv; ++i)
    for (int j = 0; j < kNumJoints; ++j) weights(i, j) = W[i][j];
  return weights;
}

// Regressor row of one joint: on the K vertices nearest to the joint's cross-section (a ring
// around the limb or trunk), the weights closest to uniform with Σw = 1 and Σ w v = J (a 4×4
// KKT solve). K grows until the weights are nonnegative.
std::vector<std::pair<int, double>> regressorRow(const MatX3& V, const Vec3& joint,
                                                 const Vec3& axis) {
  const int nv = int(V.rows());
  std::vector<std::pair<double, int>> score(nv);
  for (int i = 0; i < nv; ++i) {
    const Vec3 d = V.row(i).transpose() - joint;
    const double along = axis.dot(d);
    score[i] = {d.squaredNorm() + 8.0 * along * along, i};
  }
  std::sort(score.begin(), score.end());
  std::vector<std::pair<int, double>> best;
  double best_min = -std::numeric_limits<double>::infinity();
  for (int K : {8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256}) {
    if (K > nv) break;
    Eigen::MatrixXd A(4, K);  // rows: 1, x − Jx, y − Jy, z − Jz
    for (int k = 0; k < K; ++k) {
      A(0, k) = 1.0;
      A.block<3, 1>(1, k) = V.row(score[k].second).transpose() - joint;
    }
    const VecX w0 = VecX::Constant(K, 1.0 / K);
    Vec4 rhs(1.0, 0.0, 0.0, 0.0);
    rhs -= A * w0;
    const Mat4 AAt = A * A.transpose();
    const Vec4 lambda = AAt.colPivHouseholderQr().solve(rhs);
    const VecX w = w0 + A.transpose() * lambda;
    if (!w.allFinite()) continue;
    const double min_w = w.minCoeff();
    if (min_w > best_min) {
      best_min = min_w;
      best.clear();
      for (int k = 0; k < K; ++k) best.push_back({score[k].second, w[k]});
    }
    if (min_w >= 0) break;
  }
  if (best.empty())
    throw Error("makeSyntheticBody: cannot fit the joint regressor (degenerate vertex ring)");
  return best;
}

SpMatR jointRegressor(const BodyDesign& design, const MatX3& V) {
  std::vector<Triplet> triplets;
  for (int j = 0; j < kNumJoints; ++j) {
    Vec3 axis = design.bone_end[j] - design.joints[j];
    axis = axis.norm() > 1e-9 ? axis.normalized() : Vec3::UnitY();
    for (const auto& [vertex, weight] : regressorRow(V, design.joints[j], axis))
      triplets.emplace_back(j, vertex, weight);
  }
  SpMatR R(kNumJoints, V.rows());
  R.setFromTriplets(triplets.begin(), triplets.end());
  return R;
}

double jointSum(const MatX& W, int i, std::initializer_list<int> joints) {
  double s = 0;
  for (int j : joints) s += W(i, j);
  return s;
}

// Shape directions, 3#V × 10, per unit β (β = ±3 stays human), in kSyntheticShapeNames order.
MatX shapeDirections(const BodyDesign& design, const MatX3& V, const MatX3& N, const MatX& W) {
  const int nv = int(V.rows());
  const auto& J = design.joints;
  MatX S = MatX::Zero(3 * nv, 10);
  const double x_shoulder = J[16].x(), x_wrist = J[20].x(), y_shoulder = J[16].y();
  const double x_hip = J[1].x(), y_hip = J[1].y(), y_ankle = J[7].y();
  const double y_spine1 = J[3].y(), y_spine2 = J[6].y();
  const double muscle[kNumJoints] = {0, 1.0, 1.0, 0, 0.8, 0.8, 0,   0,   0, 0.5, 0, 0,
                                     0, 0.6, 0.6, 0, 1.0, 1.0, 0.8, 0.8, 0, 0,   0, 0};
  auto set = [&](int i, int k, const Vec3& d) { S.block<3, 1>(3 * i, k) = d; };
  for (int i = 0; i < nv; ++i) {
    const Vec3 v = V.row(i).transpose(), n = N.row(i).transpose();
    const double x = v.x(), y = v.y();
    const double sx = x >= 0 ? 1.0 : -1.0;
    const double arm_l = jointSum(W, i, {16, 18, 20, 22}), arm_r = jointSum(W, i, {17, 19, 21, 23});
    const double leg_l = jointSum(W, i, {1, 4, 7, 10}), leg_r = jointSum(W, i, {2, 5, 8, 11});
    const double arms = arm_l + arm_r, legs = leg_l + leg_r;
    const double head = W(i, 15), neck = W(i, 12);
    const double extremities = head + jointSum(W, i, {7, 8, 10, 11, 20, 21, 22, 23});
    const double trunk = jointSum(W, i, {0, 3, 6, 9});
    const double front = std::max(n.z(), 0.0);

    // height: taller (and a little broader) about the soles, 6 cm per unit at 1.70 m.
    set(i, 0, Vec3(0.012 * x, 0.035 * (y - design.sole_y), 0.012 * v.z()));

    // weight: girth everywhere, pushing out from the bone axes (7 % of the radius per unit);
    // the inner thighs grow less where they face each other at the crotch.
    Vec3 radial = Vec3::Zero();
    const double midplane_fade = smoothstep(std::abs(x) / 0.05);
    for (int j = 0; j < kNumJoints; ++j) {
      if (W(i, j) == 0.0) continue;
      const double t = segmentParameter(v, J[j], design.bone_end[j]);
      const bool leg = j == 1 || j == 2 || j == 4 || j == 5;
      radial +=
          W(i, j) * (leg ? midplane_fade : 1.0) * (v - (J[j] + t * (design.bone_end[j] - J[j])));
    }
    set(i, 1, 0.07 * (1.0 + 0.3 * trunk - 0.6 * extremities) * radial);

    // leg_length: the legs grow downwards from the hips, 3 cm per unit.
    const double down = std::clamp((y_hip - y) / (y_hip - y_ankle), 0.0, 1.0);
    set(i, 2, Vec3(0, -0.03 * legs * down, 0));

    // arm_length: the arms grow outwards from the shoulders, 2.5 cm per unit.
    const double out = std::clamp((std::abs(x) - x_shoulder) / (x_wrist - x_shoulder), 0.0, 1.0);
    set(i, 3, Vec3(0.025 * arms * out * sx, 0, 0));

    // shoulder_width: arms translate rigidly, the upper trunk widens, 1.2 cm per unit and side.
    {
      const double x_ref = x * (1 - arms) + x_shoulder * (arm_l - arm_r);
      const double y_ref = y * (1 - arms) + y_shoulder * arms;
      const double rise = smoothstep((y_ref - y_spine2) / (y_shoulder - y_spine2));
      set(i, 4,
          Vec3(0.012 * std::clamp(x_ref / x_shoulder, -1.0, 1.0) * rise * (1 - neck - head), 0, 0));
    }

    // hip_width: the pelvis and the inner thighs widen in proportion to |x|, everything
    // outside the hip joints moves out by 1 cm per unit and side (the legs stay apart at the
    // crotch, which a rigid translation of the legs would not guarantee).
    {
      const double y_ref = y * (1 - legs) + y_hip * legs;
      const double low = 1.0 - smoothstep((y_ref - y_hip) / (y_spine1 - y_hip));
      set(i, 5, Vec3(0.01 * std::clamp(x / x_hip, -1.0, 1.0) * low * (1 - arms), 0, 0));
    }

    // belly: a bump on the front of the abdomen, 2 cm per unit at its centre.
    {
      const double bump = std::exp(-std::pow(x / 0.12, 2) - std::pow((y - 0.1) / 0.12, 2));
      set(i, 6, 0.02 * bump * front * (1 - arms - legs) * n);
    }

    // chest: two bumps on the front of the chest, 1.5 cm per unit.
    {
      double bump = 0;
      for (double cx : {-0.07, 0.07})
        bump += std::exp(-std::pow((x - cx) / 0.08, 2) - std::pow((y - 0.34) / 0.07, 2));
      set(i, 7, 0.015 * bump * front * (1 - arms) * n);
    }

    // head_size: the head scales about the head joint, 4 % per unit.
    set(i, 8, 0.04 * head * (v - J[15]));

    // muscularity: bulges in the middle of the limb and trunk muscles, 6 mm per unit.
    {
      double bulge = 0;
      for (int j = 0; j < kNumJoints; ++j) {
        if (W(i, j) == 0.0 || muscle[j] == 0.0) continue;
        bulge +=
            W(i, j) * muscle[j] * std::sin(kPi * segmentParameter(v, J[j], design.bone_end[j]));
      }
      // Fades out at the mid-plane, where the inner thighs face each other at the crotch.
      set(i, 9, 0.006 * bulge * smoothstep(std::abs(x) / 0.05) * n);
    }
  }
  return S;
}

// Pose correctives, 3#V × 207: around joint j, an outward bulge on the vertices blending
// between bone j and its parent (weight product w_ij·w_i,parent, above a floor), scaled by the pose
// feature 1 − cos(angle) = −trace(R_j − I)/2: the same column, times −1/2, in the three diagonal
// entries (r, r) of joint j's 3×3 block. Zero at rest; exactly zero away from the joints.
MatX poseDirections(const MatX3& N, const MatX& W) {
  const int nv = int(N.rows());
  // Bulge at a 90° bend where the weight product peaks (w = ½, ½), m.
  std::array<double, kNumJoints> amplitude{};
  for (int j : {1, 2, 16, 17}) amplitude[j] = 0.02;       // hips, shoulders
  for (int j : {4, 5}) amplitude[j] = 0.015;              // knees
  for (int j : {18, 19}) amplitude[j] = 0.012;            // elbows
  for (int j : {7, 8, 12, 13, 14}) amplitude[j] = 0.008;  // ankles, neck, collars
  for (int j : {20, 21}) amplitude[j] = 0.006;            // wrists
  MatX P = MatX::Zero(3 * nv, kPoseFeatureSize);
  for (int j = 1; j < kNumJoints; ++j) {
    if (amplitude[j] == 0.0) continue;
    const int parent = kSmplParents[j];
    for (int i = 0; i < nv; ++i) {
      // Weight product above a small floor, rescaled to 1 at its peak (w = ½, ½): continuous,
      // and exactly zero where the weights' smoothing left only faint tails.
      const double blend = std::max(0.0, W(i, j) * W(i, parent) - 0.01) / 0.24;
      if (blend == 0.0) continue;
      const Vec3 d = amplitude[j] * blend * N.row(i).transpose();
      for (int r = 0; r < 3; ++r) P.block<3, 1>(3 * i, 9 * (j - 1) + 3 * r + r) = -0.5 * d;
    }
  }
  return P;
}

}  // namespace

SyntheticBodyBuild buildSyntheticBody(const SyntheticBodyOptions& options) {
  if (options.vertices < kMinVertices || options.vertices > kMaxVertices)
    throw InputError("makeSyntheticBody: options.vertices = " + std::to_string(options.vertices) +
                     ", expected an integer in [" + std::to_string(kMinVertices) + ", " +
                     std::to_string(kMaxVertices) + "]");
  if (!(options.height >= kMinSyntheticHeight && options.height <= kMaxSyntheticHeight))
    throw InputError("makeSyntheticBody: options.height = " + std::to_string(options.height) +
                     " m, expected a height in [" + std::to_string(kMinSyntheticHeight) + ", " +
                     std::to_string(kMaxSyntheticHeight) + "] m");

  const BodyDesign design = makeBodyDesign();
  ImplicitSurface surface;
  surface.value = [&design](const Vec3& p) { return design.distance(p); };
  surface.relative_edge_length = [&design](const Vec3& p) { return design.relativeEdgeLength(p); };
  surface.box_min = design.boxMin();
  surface.box_max = design.boxMax();
  MesherOptions mesher;
  mesher.vertices = options.vertices;
  // A 1.25 cm grid resolves the fingers and gives ~47 000 isosurface vertices; finer for
  // meshes above ~12 000 vertices, so decimation always starts from ≥ 4× the target.
  mesher.grid_spacing = std::min(0.0125, 0.01 * std::sqrt(73000.0 / (4.0 * options.vertices)));
  const TriangleMesh mesh = meshImplicitSurface(surface, mesher);

  const MatX3& V = mesh.vertices;
  const MatX3 N = vertexNormals(V, mesh.faces);
  const auto nbrs = vertexNeighbours(int(V.rows()), mesh.faces);

  SyntheticBodyBuild build;
  BodyModel& model = build.model;
  model.weights = skinningWeights(design, V, nbrs);
  model.J_regressor = jointRegressor(design, V);
  model.shapedirs = shapeDirections(design, V, N, model.weights);
  model.posedirs = poseDirections(N, model.weights);

  // Exact height: scale every length about the pelvis (the regressor is scale invariant).
  const double scale = options.height / (V.col(1).maxCoeff() - V.col(1).minCoeff());
  model.v_template = scale * V;
  model.shapedirs *= scale;
  model.posedirs *= scale;
  for (int j = 0; j < kNumJoints; ++j) build.joints[j] = scale * design.joints[j];
  model.faces = mesh.faces;
  model.parents.assign(kSmplParents.begin(), kSmplParents.end());
  char source[96];
  std::snprintf(source, sizeof(source), "synthetic(vertices=%d, height=%g)", options.vertices,
                options.height);
  model.source = source;
  model.finalize();
  return build;
}

}  // namespace synthetic

BodyModel makeSyntheticBody(const SyntheticBodyOptions& options) {
  return synthetic::buildSyntheticBody(options).model;
}

std::shared_ptr<const BodyModel> sharedSyntheticBody(const SyntheticBodyOptions& options) {
  struct Entry {
    SyntheticBodyOptions options;
    std::shared_ptr<const BodyModel> body;
  };
  static std::mutex mutex;
  static std::list<Entry> recent;  // most recent first, at most kKept
  constexpr size_t kKept = 2;
  const auto same = [&](const Entry& e) {
    return e.options.vertices == options.vertices && e.options.height == options.height;
  };
  {
    std::lock_guard<std::mutex> lock(mutex);
    for (auto it = recent.begin(); it != recent.end(); ++it)
      if (same(*it)) {
        recent.splice(recent.begin(), recent, it);
        return recent.front().body;
      }
  }
  // Generated outside the lock (seconds at full size); two threads asking for the same new body
  // at once may both generate it, and the first one kept wins.
  auto body = std::make_shared<const BodyModel>(makeSyntheticBody(options));
  std::lock_guard<std::mutex> lock(mutex);
  for (const Entry& e : recent)
    if (same(e)) return e.body;
  recent.push_front({options, body});
  if (recent.size() > kKept) recent.pop_back();
  return body;
}

}  // namespace flsh
