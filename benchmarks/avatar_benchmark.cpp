// Avatar generation at the default resolution (synthetic SMPL-size body, 6890 vertices), cold
// and warm, with the seconds of every stage:
//   skeleton       a skeleton-only avatar of a freshly loaded model (voxelized bone inertias)
//   fem cold       FEM avatar, empty cache: meshing, harmonic fields, bone nodes, materials,
//                  and writing both cache levels
//   fem warm       the same avatar again: both levels from the cache
//   fem new shape  another β: the template level from the cache, the shape level built
// Goals on the 2-core machine (issue "Volumetric avatar"): skeleton ≤ 0.2 s, FEM ≤ 8 s cold,
// any model ≤ 0.3 s from the cache. Usage: avatar_benchmark [RUNS] [BODY.npz]; prints the
// median over RUNS (default 3) of each figure.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <unistd.h>

#include "flsh/body/synthetic_body.h"
#include "flsh/volume/soft_avatar.h"

namespace {

using namespace flsh;
using Clock = std::chrono::steady_clock;

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

struct Timed {
  double total = 0;
  VolumetricBuildReport report;
  double skeleton = 0;
  int nodes = 0, tets = 0;
};

Timed build(const std::shared_ptr<const BodyModel>& body, const VecX& betas, bool soft,
            const std::string& cache_dir) {
  SoftAvatarSettings settings;
  settings.volumetric.cache_dir = cache_dir;
  SoftAvatar avatar(body, betas, settings);
  avatar.enableSoftTissue(soft);
  const auto t0 = Clock::now();
  avatar.initVolumetricData();
  Timed t;
  t.total = std::chrono::duration<double>(Clock::now() - t0).count();
  t.report = avatar.volumetricBuildReport();
  t.skeleton = avatar.skeletonSeconds();
  if (soft) {
    t.nodes = avatar.volumetricData().numNodes();
    t.tets = avatar.volumetricData().numTets();
  }
  return t;
}

}  // namespace

int main(int argc, char** argv) {
  const int runs = argc > 1 ? std::max(1, std::atoi(argv[1])) : 3;
  const std::string model_path = argc > 2 ? argv[2] : "";
  auto load = [&] {
    return std::make_shared<const BodyModel>(model_path.empty() ? makeSyntheticBody({})
                                                                : loadBodyModel(model_path));
  };
  std::map<std::string, std::vector<double>> f;
  int nodes = 0, tets = 0;
  const auto root = std::filesystem::temp_directory_path() /
                    ("flsh_avatar_benchmark_" + std::to_string(::getpid()));
  for (int run = 0; run < runs; ++run) {
    const std::string cache = (root / std::to_string(run)).string();
    const auto body = load();  // a fresh model: nothing shared with the previous run
    const VecX betas = VecX::Zero(body->numBetas());
    f["skeleton total"].push_back(build(body, betas, false, cache).total);

    const Timed cold = build(body, betas, true, cache);
    const VolumetricBuildReport& r = cold.report;
    f["fem cold total"].push_back(cold.total);
    f["  skeleton part"].push_back(cold.skeleton);
    f["  interior points (Mesh_3)"].push_back(r.meshing.interior_points);
    f["  delaunay"].push_back(r.meshing.delaunay);
    f["  surface recovery"].push_back(r.meshing.recovery);
    f["  quality improvement"].push_back(r.meshing.quality);
    f["  meshing total"].push_back(r.seconds_meshing);
    f["  harmonic fields"].push_back(r.seconds_harmonic);
    f["  bone nodes"].push_back(r.seconds_bone_nodes);
    f["  materials"].push_back(r.seconds_materials);
    f["  cache store"].push_back(r.seconds_cache_store);
    nodes = cold.nodes;
    tets = cold.tets;

    const Timed warm = build(body, betas, true, cache);
    if (!warm.report.template_from_cache || !warm.report.data_from_cache)
      std::fprintf(stderr, "warning: the warm run missed the cache\n");
    f["fem warm total"].push_back(warm.total);
    f["  cache load"].push_back(warm.report.seconds_cache_load);

    VecX other = betas;
    other(0) = 1.0;
    const Timed shaped = build(body, other, true, cache);
    f["fem new shape total"].push_back(shaped.total);
    std::filesystem::remove_all(cache);
  }
  std::filesystem::remove_all(root);
  std::printf("avatar generation, %s, %d nodes / %d tets, median of %d runs (s)\n",
              model_path.empty() ? "synthetic body (6890 vertices)" : model_path.c_str(), nodes,
              tets, runs);
  for (const char* key :
       {"skeleton total", "fem cold total", "  skeleton part", "  interior points (Mesh_3)",
        "  delaunay", "  surface recovery", "  quality improvement", "  meshing total",
        "  harmonic fields", "  bone nodes", "  materials", "  cache store", "fem warm total",
        "  cache load", "fem new shape total"})
    std::printf("  %-30s %8.3f\n", key, median(f[key]));
  return 0;
}
