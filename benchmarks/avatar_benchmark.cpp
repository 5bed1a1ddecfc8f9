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
//
// ROM mode, avatar_benchmark --rom [RUNS] [BODY.npz] [--modes V:C | --handles H] [--elastic N]
// [--inertial N] [--training-samples S]: the ROM avatar (soft tissue, reduced model, both
// cubatures; default ReducedSettings: the modal basis 24:72; or the modal basis of V vibration
// modes compressed to C columns (0: all), or the handle basis of H handles; cubatures of N tets
// trained on S samples):
//   rom cold       empty cache: template, shape and reduced levels, with the stages of each
//                  (handles, basis, training samples, cubature selection)
//   rom warm       the same avatar again: all three levels from the cache
// plus the handle count, the basis bound violation, the cubature sizes and held-out errors.
// Goals (issue "ROM soft skeleton"): ≤ 12 s cold, ≤ 0.3 s from the cache.
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

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

struct RomTimed {
  double total = 0;
  VolumetricBuildReport volumetric;
  ReducedBuildReport reduced;
  double skeleton = 0;
  int nodes = 0, tets = 0;
  ReducedData data;
};

RomTimed buildRom(const std::shared_ptr<const BodyModel>& body, const VecX& betas,
                  const ReducedSettings& reduced, const std::string& cache_dir) {
  SoftAvatarSettings settings;
  settings.volumetric.cache_dir = cache_dir;
  settings.reduced = reduced;
  SoftAvatar avatar(body, betas, settings);
  avatar.enableSoftTissue();
  avatar.enableReducedModel();
  avatar.enableElasticCubature();
  avatar.enableInertialCubature();
  const auto t0 = Clock::now();
  avatar.initVolumetricData();
  RomTimed t;
  t.total = std::chrono::duration<double>(Clock::now() - t0).count();
  t.volumetric = avatar.volumetricBuildReport();
  t.reduced = avatar.reducedBuildReport();
  t.skeleton = avatar.skeletonSeconds();
  t.nodes = avatar.volumetricData().numNodes();
  t.tets = avatar.volumetricData().numTets();
  t.data = avatar.reducedData();
  return t;
}

int romBenchmark(int runs, const std::string& model_path, const ReducedSettings& reduced) {
  std::map<std::string, std::vector<double>> f;
  RomTimed last;
  const auto root =
      std::filesystem::temp_directory_path() / ("flsh_rom_benchmark_" + std::to_string(::getpid()));
  for (int run = 0; run < runs; ++run) {
    const std::string cache = (root / std::to_string(run)).string();
    const auto body = std::make_shared<const BodyModel>(
        model_path.empty() ? makeSyntheticBody({}) : loadBodyModel(model_path));
    const VecX betas = VecX::Zero(body->numBetas());
    const RomTimed cold = buildRom(body, betas, reduced, cache);
    const VolumetricBuildReport& v = cold.volumetric;
    const ReducedBuildReport& r = cold.reduced;
    if (!cold.reduced.warnings.empty())
      std::fprintf(stderr, "warnings of the cold build:\n%s", cold.reduced.warnings.c_str());
    f["rom cold total"].push_back(cold.total);
    f["  skeleton part"].push_back(cold.skeleton);
    f["  template level (mesh, fields)"].push_back(v.seconds_meshing + v.seconds_harmonic +
                                                   v.seconds_quality);
    f["  shape level (bones, materials)"].push_back(v.seconds_bone_nodes + v.seconds_materials);
    f["  volumetric cache store"].push_back(v.seconds_cache_store);
    f["  reduced level total"].push_back(r.seconds_total);
    f["    handles"].push_back(r.seconds_handles);
    f["    basis (BBW)"].push_back(r.seconds_basis);
    f["    training samples"].push_back(r.seconds_training);
    f["    cubature selection"].push_back(r.seconds_cubature);
    f["    reduced cache store"].push_back(r.seconds_cache_store);

    const RomTimed warm = buildRom(body, betas, reduced, cache);
    if (!warm.volumetric.template_from_cache || !warm.volumetric.data_from_cache ||
        !warm.reduced.from_cache)
      std::fprintf(stderr, "warning: the warm run missed the cache\n");
    f["rom warm total"].push_back(warm.total);
    f["  volumetric cache load"].push_back(warm.volumetric.seconds_cache_load);
    f["  reduced cache load"].push_back(warm.reduced.seconds_cache_load);
    last = cold;
    std::filesystem::remove_all(cache);
  }
  std::filesystem::remove_all(root);
  const ReducedData& d = last.data;
  std::printf("ROM avatar generation, %s, %d nodes / %d tets, median of %d runs (s)\n",
              model_path.empty() ? "synthetic body (6890 vertices)" : model_path.c_str(),
              last.nodes, last.tets, runs);
  std::printf("basis %s", reducedBasisKindName(reduced.basis_kind));
  if (reduced.basis_kind != ReducedBasisKind::Handles)
    std::printf(" (%d vibration modes, %d columns)", reduced.modes.vibration_modes, d.numModes());
  std::printf(", cubatures of %d / %d tets asked, %d training samples\n",
              reduced.elastic_cubature_points, reduced.inertial_cubature_points,
              reduced.training_samples);
  for (const char* key :
       {"rom cold total", "  skeleton part", "  template level (mesh, fields)",
        "  shape level (bones, materials)", "  volumetric cache store", "  reduced level total",
        "    handles", "    basis (BBW)", "    training samples", "    cubature selection",
        "    reduced cache store", "rom warm total", "  volumetric cache load",
        "  reduced cache load"})
    std::printf("  %-34s %8.3f\n", key, median(f[key]));
  std::printf(
      "reduced data (last run): %d handles, basis %ld nonzeros (%.1f per handle), max bound "
      "violation %.2e, converged %s\n",
      d.numHandles(), long(d.basis.nonZeros()),
      double(d.basis.nonZeros()) / std::max(1, d.numHandles()), d.basis_max_bound_violation,
      d.basis_converged ? "yes" : "no");
  std::printf(
      "  elastic cubature:  %4ld tets, training error %.4f, held-out error %.4f, %d rounds\n",
      long(d.elastic.elements.size()), d.elastic.training_error, d.elastic_test_error,
      d.elastic.rounds);
  std::printf(
      "  inertial cubature: %4ld tets, training error %.4f, held-out error %.4f, %d rounds, "
      "rigid motions within %.4f\n",
      long(d.inertial.elements.size()), d.inertial.training_error, d.inertial_test_error,
      d.inertial.rounds, d.inertial_rigid_error);
  return 0;
}

}  // namespace

// avatar_benchmark --rom's arguments: RUNS and BODY.npz by position, then the reduced settings.
int romMain(int argc, char** argv) {
  int runs = 3;
  std::string model_path;
  ReducedSettings reduced;
  int positional = 0;
  for (int i = 2; i < argc; ++i) {
    const std::string a = argv[i];
    const bool has_value = i + 1 < argc;
    if (a == "--modes" && has_value) {
      const std::string v = argv[++i];
      const auto colon = v.find(':');
      reduced.basis_kind = ReducedBasisKind::Modes;
      reduced.modes.vibration_modes = std::atoi(v.substr(0, colon).c_str());
      reduced.modes.columns = colon == std::string::npos ? 0 : std::atoi(v.c_str() + colon + 1);
    } else if (a == "--handles" && has_value) {
      reduced.basis_kind = ReducedBasisKind::Handles;
      reduced.num_handles = std::atoi(argv[++i]);
    } else if (a == "--elastic" && has_value) {
      reduced.elastic_cubature_points = std::atoi(argv[++i]);
    } else if (a == "--inertial" && has_value) {
      reduced.inertial_cubature_points = std::atoi(argv[++i]);
    } else if (a == "--training-samples" && has_value) {
      reduced.training_samples = std::atoi(argv[++i]);
    } else if (a.rfind("--", 0) != 0 && positional == 0) {
      runs = std::max(1, std::atoi(a.c_str()));
      ++positional;
    } else if (a.rfind("--", 0) != 0 && positional == 1) {
      model_path = a;
      ++positional;
    } else {
      std::fprintf(
          stderr,
          "avatar_benchmark --rom: unknown or incomplete argument '%s' (expected [RUNS] "
          "[BODY.npz] [--modes V:C] [--elastic N] [--inertial N] [--training-samples S])\n",
          a.c_str());
      return 2;
    }
  }
  return romBenchmark(runs, model_path, reduced);
}

int main(int argc, char** argv) {
  if (argc > 1 && std::string(argv[1]) == "--rom") return romMain(argc, argv);
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
