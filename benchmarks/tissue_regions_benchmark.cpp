// Soft-tissue displacement per body region (issue 29, "The hands flop"): the FEM (or ROM) soft
// skeleton of the synthetic body runs built-in motions on the ground at h = 1/30 s, each followed
// by a rest in its last pose (the body stops), and the surface vertices' |u| (soft-tissue
// displacement in the unposed space) is summarized per region. A vertex's region is that of the
// bone with its largest skinning weight:
//   hands      wrists and hands (20–23)        forearms  elbows (18, 19)
//   upper arms shoulders (16, 17)              head      neck and head (12, 15)
//   torso      pelvis, spine, collars          thighs    hips (1, 2)
//   shins      knees (4, 5)                    feet      ankles and toes (7, 8, 10, 11)
// Columns per motion and region: the largest |u| over the vertices and the motion's steps
// ("max"), the root mean square over the same ("rms"), and the largest |u(t) − u(t_end)| over
// the last 0.5 s of the rest ("jiggle after stop": what is still moving once the body has stood
// still for a while; the static sag under gravity is not counted).
//
// Usage: tissue_regions_benchmark [--motions walk,jumping_jacks,jump] [--seconds S=1.5]
//                                 [--rest R=1.0] [--resolution R=1] [--vertices V=6890]
//                                 [--materials FILE] [--rom]
// Timing is not the point: every number is a displacement (mm).
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "flsh/body/synthetic_body.h"
#include "flsh/io/motion.h"
#include "flsh/solve/scene.h"

namespace {

using namespace flsh;

struct Region {
  const char* name;
  std::vector<int> bones;
};

const std::vector<Region>& regions() {
  static const std::vector<Region> r = {
      {"hands", {20, 21, 22, 23}}, {"forearms", {18, 19}},          {"upper arms", {16, 17}},
      {"head", {12, 15}},          {"torso", {0, 3, 6, 9, 13, 14}}, {"thighs", {1, 2}},
      {"shins", {4, 5}},           {"feet", {7, 8, 10, 11}}};
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
  double seconds = 1.5, rest = 1.0, resolution = 1.0;
  int vertices = 6890;
  std::string materials;
  bool rom = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--motions" && i + 1 < argc)
      motions = split(argv[++i]);
    else if (a == "--seconds" && i + 1 < argc)
      seconds = std::atof(argv[++i]);
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
    // Region of each surface vertex, and how many surface vertices are bone nodes.
    std::vector<int> region_of(V, -1);
    std::vector<int> count(regions().size(), 0), bone_count(regions().size(), 0);
    for (int v = 0; v < V; ++v) {
      int dominant = 0;
      body->weights.row(v).maxCoeff(&dominant);
      for (size_t r = 0; r < regions().size(); ++r)
        for (int b : regions()[r].bones)
          if (b == dominant) region_of[v] = int(r);
      if (region_of[v] >= 0) {
        ++count[region_of[v]];
        if (data.bone_of_node[v] >= 0) ++bone_count[region_of[v]];
      }
    }

    const double fps = 30.0, h = 1.0 / fps;
    std::printf(
        "h = 1/30 s, on the ground; each motion %.2f s, then %.2f s at rest in its last "
        "pose; |u| of the surface vertices, mm\n\n",
        seconds, rest);
    std::printf("%-14s %-11s %6s %9s %9s %17s\n", "motion", "region", "verts", "max", "rms",
                "jiggle after stop");
    for (const std::string& name : motions) {
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
      const int tail = std::min(rest_steps, int(std::lround(0.5 * fps)));
      std::vector<double> largest(regions().size(), 0.0), squares(regions().size(), 0.0);
      std::vector<MatX3> tail_u;
      int unconverged = 0;
      for (int k = 0; k < motion_steps + rest_steps; ++k) {
        const StepStats s = scene.step();
        unconverged += s.newton.converged ? 0 : 1;
        const MatX3 u = sim->getSoftTissueDisplacements();
        if (k < motion_steps) {
          for (int v = 0; v < V; ++v) {
            if (region_of[v] < 0) continue;
            const double n = u.row(v).norm();
            largest[region_of[v]] = std::max(largest[region_of[v]], n);
            squares[region_of[v]] += n * n;
          }
        } else if (k >= motion_steps + rest_steps - tail) {
          tail_u.push_back(u);
        }
      }
      std::vector<double> after(regions().size(), 0.0);
      for (const MatX3& u : tail_u)
        for (int v = 0; v < V; ++v)
          if (region_of[v] >= 0)
            after[region_of[v]] =
                std::max(after[region_of[v]], (u.row(v) - tail_u.back().row(v)).norm());
      for (size_t r = 0; r < regions().size(); ++r) {
        const double rms = std::sqrt(squares[r] / std::max(1, count[r] * motion_steps));
        std::printf("%-14s %-11s %6d %9.2f %9.2f %17.2f\n", r == 0 ? name.c_str() : "",
                    regions()[r].name, count[r], 1000 * largest[r], 1000 * rms, 1000 * after[r]);
      }
      if (unconverged > 0) std::printf("  (%d steps did not converge)\n", unconverged);
    }
    std::printf("\nsurface vertices that are bone nodes, per region:");
    for (size_t r = 0; r < regions().size(); ++r)
      std::printf(" %s %d/%d%s", regions()[r].name, bone_count[r], count[r],
                  r + 1 < regions().size() ? "," : "\n");
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "tissue_regions_benchmark: %s\n", e.what());
    return 1;
  }
}
