// The fuzz targets' inputs replayed in the ordinary suite (no libFuzzer, no sanitizers): every
// seed of fuzz/corpus/TARGET/ and every input a fuzzer once crashed on, kept in
// fuzz/regressions/TARGET/ (docs/design.md, "Fuzzing"), goes through the same code as the fuzz
// target; only flsh::Error may come out of the readers.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>

#include "../fuzz/fuzz_inputs.h"

namespace flsh {
namespace {

namespace fs = std::filesystem;

struct Target {
  const char* name;
  void (*read)(const uint8_t*, size_t);
};

class FuzzReplay : public ::testing::TestWithParam<Target> {};

TEST_P(FuzzReplay, SeedsAndRegressionsAreReadOrRefusedCleanly) {
  const Target& target = GetParam();
  int inputs = 0;
  for (const char* folder : {"corpus", "regressions"}) {
    const fs::path dir = fs::path(FLSH_SOURCE_DIR) / "fuzz" / folder / target.name;
    if (!fs::is_directory(dir)) continue;
    for (const auto& entry : fs::directory_iterator(dir)) {
      if (!entry.is_regular_file() || entry.path().filename().string()[0] == '.') continue;
      SCOPED_TRACE(entry.path().string());
      std::ifstream in(entry.path(), std::ios::binary);
      const std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)),
                                       std::istreambuf_iterator<char>());
      EXPECT_NO_THROW(target.read(bytes.data(), bytes.size()));
      ++inputs;
    }
  }
  EXPECT_GT(inputs, 0) << "no seeds for " << target.name;
}

INSTANTIATE_TEST_SUITE_P(Targets, FuzzReplay,
                         ::testing::Values(Target{"fuzz_npz", fuzz::readNpzInput},
                                           Target{"fuzz_scene_file", fuzz::readSceneInput},
                                           Target{"fuzz_mesh", fuzz::readMeshInput},
                                           Target{"fuzz_avatar_cache", fuzz::readAvatarCacheInput}),
                         [](const auto& info) { return std::string(info.param.name); });

/// `arrays` as an archive in memory (through a temporary file).
io::NpzFile inMemory(const io::NpzWriter& arrays, const std::string& name) {
  const std::string path = ::testing::TempDir() + "/flsh_" + name + ".npz";
  arrays.save(path);
  std::ifstream in(path, std::ios::binary);
  std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)),
                             std::istreambuf_iterator<char>());
  fs::remove(path);
  return io::NpzFile::fromBytes(std::move(bytes), name);
}

// The tiny avatar of the fuzz target passes both levels' checks: its seeds reach past them.
TEST(FuzzReplay, TheTinyAvatarPassesTheCacheChecks) {
  const BodyModel body = fuzz::tinyBody();
  const VolumetricData data = fuzz::tinyData(body);
  VolumetricTemplate templ;
  EXPECT_NO_THROW(
      readTemplateCacheArrays(inMemory(templateCacheArrays(*data.templ), "template"), body, templ));
  EXPECT_EQ(templ.mesh.tets, data.templ->mesh.tets);
  VolumetricData d;
  d.templ = data.templ;
  d.material_model = data.material_model;
  EXPECT_NO_THROW(readDataCacheArrays(inMemory(dataCacheArrays(data), "data"), VecX::Zero(1), d));
  EXPECT_EQ(d.bone_of_node, data.bone_of_node);
  EXPECT_EQ(d.materials.density, data.materials.density);
}

}  // namespace
}  // namespace flsh
