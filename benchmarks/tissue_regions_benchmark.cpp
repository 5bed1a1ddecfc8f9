// Soft-tissue displacement per body region (issue 29, "The hands flop"): the FEM (or ROM) soft
// skeleton of the synthetic body runs built-in motions on the ground at h = 1/30 s, each followed
// by a rest in its last pose (the body stops), and the surface vertices' |u| (soft-tissue
// displacement in the unposed space) is summarized per region. A vertex's region is that of the
// bone with its largest skinning weight:
//   hands      wrists and hands (20–23)        forearms  elbows (18, 19)
//   upper arms shoulders (16, 17)              head      neck and head (12, 15)
//   torso      pelvis, spine, collars          thighs    hips (1, 2)
//   shins      knees (4, 5)                    feet      ankles and toes (7, 8, 10, 11)
// Columns per motion and region, all in mm:
//   max       the largest |u| over the region's vertices and every step (motion and rest);
//   rms       the root mean square of |u| over the same vertices and the motion's steps;
//   stop      the largest |u(t) − u(t_end)| over the first 0.5 s of the rest: the ring-down
//             once the body stops (u(t_end), the last step, is the static sag under gravity,
//             which is not counted);
//   late      the same over the last 0.5 s of the rest: what still moves a while after the stop
//             (smaller than "stop" when the motion decays).
// Each motion runs whole cycles by default (walk 2.2 s, jumping_jacks 1.8 s, jump 1.6 s; other
// motions 1.5 s), so it stops in a pose it passes through naturally; --seconds overrides.
// --materials FILE takes a material file (docs/materials.md): a version-1 file (no "regions")
// gives the body without regional differences, for before/after tables.
//
// Usage: tissue_regions_benchmark [--motions walk,jumping_jacks,jump] [--seconds S]
//                                 [--rest R=1.0] [--resolution R=1] [--vertices V=6890]
//                                 [--materials FILE] [--rom]
// --vertices 6890 (the default) is the full-size synthetic body (SMPL's vertex count); 800 the
// tests' small body. Timing is not the point: every number is a displacement.
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "flsh/body/motion.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/solve/scene.h"
#include "flsh/volume/materials.h"

namespace {

using namespace flsh;

struct Region {
  const char* name;
  std::vector<int> bones;
};

// The material's regions (MaterialModel::regionOfBone) in the order and with the labels of the
// tables in docs/benchmarks.md.
const std::vector<Region>& regions() {
  static const std::vector<Region> r = [] {
    const std::pair<const char*, const char*> shown[] = {
        {"hands", "hands"}, {"forearms", "forearms"}, {"upper arms", "upper_arms"},
        {"head", "head"},   {"torso", "torso"},       {"thighs", "thighs"},
        {"shins", "shins"}, {"feet", "feet"}};
    const std::vector<std::string>& names = MaterialModel::regionNames();
    std::vector<Region> out;
    for (const auto& [label, region] : shown) {
      out.push_back({label, {}});
      for (int b = 0; b < kNumJoints; ++b)
        if (names[size_t(MaterialModel::regionOfBone(b))] == region) out.back().bones.push_back(b);
    }
    return out;
  }();
  return r;
}

std::vector<std::string> split(const std::string& text) {
  std::vector<std::string> out;
  std::stringstream s(text);
  std::string item;
  while (std::getline(s, item, ','))
    if (!item.empty()) out.push_back(item);
  return out;
}

/// Whole cycles of the built-in motions (motion_builtin.cpp): the motion ends in a pose it passes
/// through, with the body over its feet.
double defaultSeconds(const std::string& name) {
  if (name == "walk") return 2.2;           // two gait cycles of 1.1 s
  if (name == "jumping_jacks") return 1.8;  // two jacks of 0.9 s, arms down
  if (name == "jump") return 1.6;           // crouch, flight, landing
  return 1.5;
}

/// `name` for `seconds`, then its last frame held for `rest` seconds.
Motion motionThenRest(const std::string& name, double seconds, double rest, double fps) {
  Motion m = makeBuiltinMotion(name, seconds, fps);
  const int T = m.numFrames(), hold = int(std::lround(rest * fps));
  RowMatX poses(T + hold, m.poses.cols()), trans(T + hold, 3);
  poses.topRows(T) = m.poses;
  trans.topRows(T) = m.trans;
  for (int k = 0; k < hold; ++k) {
    poses.row(T + k) = m.poses.row(T - 1);
    trans.row(T + k) = m.trans.row(T - 1);
  }
  m.poses = poses;
  m.trans = trans;
  return m;
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> motions = {"walk", "jumping_jacks", "jump"};
  double seconds_override = -1.0, rest = 1.0, resolution = 1.0;
  int vertices = 6890;
  std::string materials;
  bool rom = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--motions" && i + 1 < argc)
      motions = split(argv[++i]);
    else if (a == "--seconds" && i + 1 < argc)
      seconds_override = std::atof(argv[++i]);
    else if (a == "--rest" && i + 1 < argc)
      rest = std::atof(argv[++i]);
    else if (a == "--resolution" && i + 1 < argc)
      resolution = std::atof(argv[++i]);
    else if (a == "--vertices" && i + 1 < argc)
      vertices = std::atoi(argv[++i]);
    else if (a == "--materials" && i + 1 < argc)
      materials = argv[++i];
    else if (a == "--rom")
      rom = true;
    else {
      std::fprintf(stderr,
                   "usage: tissue_regions_benchmark [--motions a,b] [--seconds S] [--rest R] "
                   "[--resolution R] [--vertices V] [--materials FILE] [--rom]\n");
      return 2;
    }
  }
  try {
    SyntheticBodyOptions body_options;
    body_options.vertices = vertices;
    auto body = std::make_shared<BodyModel>(makeSyntheticBody(body_options));
    SoftAvatarSettings settings;
    settings.volumetric.tet_mesh.resolution = resolution;
    settings.volumetric.material_file = materials;
    auto avatar = std::make_shared<SoftAvatar>(body, VecX(), settings);
    avatar->enableSoftTissue();
    if (rom) {
      avatar->enableReducedModel();
      avatar->enableElasticCubature();
      avatar->enableInertialCubature();
    }
    avatar->initVolumetricData();
    const VolumetricData& data = avatar->volumetricData();
    const int V = body->numVertices();
    std::printf(
        "%s, %d vertices, resolution %g: %d nodes (%d bone nodes), %d tets; materials: "
        "%s\n",
        rom ? "ROM" : "FEM", V, resolution, data.numNodes(), data.numBoneNodes(), data.numTets(),
        materials.empty() ? "built-in defaults" : materials.c_str());
    // Region of each node (its largest weight's bone); surface vertices are nodes 0..V−1.
    const MatX& node_weights = data.templ->fields.weights;
    const int N = data.numNodes();
    std::vector<int> region_of(N, -1);
    const size_t R = regions().size();
    std::vector<int> count(R, 0), bone_count(R, 0), interior(R, 0), interior_bone(R, 0);
    for (int i = 0; i < N; ++i) {
      int dominant = 0;
      node_weights.row(i).maxCoeff(&dominant);
      for (size_t r = 0; r < R; ++r)
        for (int b : regions()[r].bones)
          if (b == dominant) region_of[i] = int(r);
      if (region_of[i] < 0) continue;
      const bool bone = data.bone_of_node[i] >= 0;
      if (i < V) {
        ++count[region_of[i]];
        bone_count[region_of[i]] += bone;
      } else {
        ++interior[region_of[i]];
        interior_bone[region_of[i]] += bone;
      }
    }

    std::printf("nodes per region (dominant bone): surface bone/all, interior bone/all:");
    for (size_t r = 0; r < R; ++r)
      std::printf("%s %s %d/%d, %d/%d", r ? ";" : "", regions()[r].name, bone_count[r], count[r],
                  interior_bone[r], interior[r]);
    const double fps = 30.0, h = 1.0 / fps;
    std::printf(
        "\nh = 1/30 s, on the ground; each motion then %.2f s at rest in its last pose; |u| of "
        "the surface vertices, mm\n\n",
        rest);
    std::printf("%-20s %-11s %6s %8s %8s %8s %8s\n", "motion", "region", "verts", "max", "rms",
                "stop", "late");
    for (const std::string& name : motions) {
      const double seconds = seconds_override > 0 ? seconds_override : defaultSeconds(name);
      auto motion = std::make_shared<Motion>(motionThenRest(name, seconds, rest, fps));
      SimulableOptions options;
      options.time_step = h;
      auto sim = std::make_shared<Simulable>(avatar, motion, options);
      Scene scene;
      scene.addSimulable(sim);
      scene.initialize();
      scene.addCollider(
          Collider::plane(Vec3(0, sim->getNodes().col(1).minCoeff() - 0.002, 0), Vec3::UnitY()));
      const int motion_steps = int(std::lround(seconds * fps));
      const int rest_steps = int(std::lround(rest * fps));
      const int window = std::min(rest_steps, int(std::lround(0.5 * fps)));
      std::vector<double> largest(R, 0.0), squares(R, 0.0);
      std::vector<MatX3> rest_u;  // surface |u| of every rest step
      int unconverged = 0;
      const auto start = std::chrono::steady_clock::now();
      for (int k = 0; k < motion_steps + rest_steps; ++k) {
        const StepStats s = scene.step();
        unconverged += s.newton.converged ? 0 : 1;
        const MatX3 u = sim->getSoftTissueDisplacements();
        for (int v = 0; v < V; ++v) {
          if (region_of[v] < 0) continue;
          const double n = u.row(v).norm();
          largest[region_of[v]] = std::max(largest[region_of[v]], n);
          if (k < motion_steps) squares[region_of[v]] += n * n;
        }
        if (k >= motion_steps) rest_u.push_back(u);
      }
      const double elapsed =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      // Largest |u(t) − u(t_end)| per region over rest steps [first, last).
      auto jiggle = [&](int first, int last) {
        std::vector<double> out(R, 0.0);
        for (int k = std::max(0, first); k < last; ++k)
          for (int v = 0; v < V; ++v)
            if (region_of[v] >= 0)
              out[region_of[v]] =
                  std::max(out[region_of[v]], (rest_u[k].row(v) - rest_u.back().row(v)).norm());
        return out;
      };
      const std::vector<double> stop = jiggle(0, window);
      const std::vector<double> late = jiggle(rest_steps - window, rest_steps);
      char label[64];
      std::snprintf(label, sizeof(label), "%s %.1f s", name.c_str(), seconds);
      for (size_t r = 0; r < R; ++r) {
        const double rms = std::sqrt(squares[r] / std::max(1, count[r] * motion_steps));
        std::printf("%-20s %-11s %6d %8.1f %8.1f %8.1f %8.1f\n", r == 0 ? label : "",
                    regions()[r].name, count[r], 1000 * largest[r], 1000 * rms, 1000 * stop[r],
                    1000 * late[r]);
      }
      std::printf("  %d steps in %.0f s, %d did not converge\n", motion_steps + rest_steps, elapsed,
                  unconverged);
      std::fflush(stdout);
    }
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "tissue_regions_benchmark: %s\n", e.what());
    return 1;
  }
}
