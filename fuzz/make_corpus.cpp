// Writes the seed entries of fuzz/corpus/fuzz_avatar_cache/ with the project's own writers:
// the tiny avatar's template level, its shape level, and both in one entry, each as
// AvatarCache::store writes it (header arrays and checksum). Run by scripts/fuzz.sh --seeds.
//   make_corpus OUTPUT_DIR
#include <cstdio>
#include <filesystem>

#include "flsh/core/error.h"
#include "tiny_avatar.h"
#include "volume/volumetric_cache.h"

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: make_corpus OUTPUT_DIR\n");
    return 1;
  }
  namespace fs = std::filesystem;
  try {
    const flsh::BodyModel body = flsh::fuzz::tinyBody();
    const flsh::VolumetricData data = flsh::fuzz::tinyData(body);
    // Both levels must pass their own checks, or the seeds would not reach past them.
    flsh::VolumetricTemplate templ;
    flsh::io::NpzWriter both = flsh::templateCacheArrays(*data.templ);
    const flsh::io::NpzWriter data_arrays = flsh::dataCacheArrays(data);
    for (const auto& [key, array] : data_arrays.arrays()) {
      if (array.dtype == "<f8")
        both.add(key, reinterpret_cast<const double*>(array.bytes.data()), array.shape);
      else
        both.add(key, reinterpret_cast<const int64_t*>(array.bytes.data()), array.shape);
    }
    const std::string dir = argv[1];
    const flsh::AvatarCache cache(dir);
    const std::string key = data.key;
    const struct {
      const char* name;
      flsh::io::NpzWriter arrays;
    } seeds[] = {{"template.npz", flsh::templateCacheArrays(*data.templ)},
                 {"data.npz", data_arrays},
                 {"both.npz", both}};
    for (const auto& seed : seeds) {
      cache.store(key, seed.arrays);
      const flsh::io::NpzFile file(cache.pathFor(key));
      if (!flsh::AvatarCache::entryProblem(file, key).empty()) return 2;
      fs::rename(cache.pathFor(key), fs::path(dir) / seed.name);
    }
    const flsh::io::NpzFile file(dir + "/both.npz");
    flsh::readTemplateCacheArrays(file, body, templ);
    flsh::VolumetricData d;
    d.templ = data.templ;
    d.material_model = data.material_model;
    flsh::readDataCacheArrays(file, flsh::VecX::Zero(1), d);
  } catch (const flsh::Error& e) {
    std::fprintf(stderr, "make_corpus: %s\n", e.what());
    return 1;
  }
  return 0;
}
