// The volumetric levels in the avatar cache (volumetric_cache.h): entries whose content was
// changed and re-checksummed are rebuilt with a warning instead of used, and paths that are not
// regular files never block (issue 23).
#include "volume/volumetric_cache.h"

#include <gtest/gtest.h>
#include <sys/stat.h>

#include <cstring>
#include <filesystem>
#include <functional>

#include "flsh/body/synthetic_body.h"
#include "flsh/core/error.h"
#include "support/test_support.h"

namespace flsh {
namespace {

namespace fs = std::filesystem;

const BodyModel& body() {
  static const BodyModel b = makeSyntheticBody({600, 1.70});
  return b;
}

VecX shape() {
  VecX betas = VecX::Zero(10);
  betas(0) = 0.5;
  return betas;
}

VolumetricSettings settingsIn(const std::string& cache_dir) {
  VolumetricSettings settings;
  settings.cache_dir = cache_dir;
  return settings;
}

/// An edit of one cached array, as raw bytes (every cached array is <f8 or <i8).
using Edit = std::function<void(io::NpyArray&)>;

template <class T>
T& at(io::NpyArray& a, long index) {
  EXPECT_EQ(a.bytes.size() % sizeof(T), 0u);
  return reinterpret_cast<T*>(a.bytes.data())[index];
}

/// Rewrites the entry `key` with `edit` applied to array `name`, with a valid checksum (as a
/// tool that knows the format could): only the content checks can catch it.
void tamper(const AvatarCache& cache, const std::string& key, const std::string& name,
            const Edit& edit) {
  std::map<std::string, io::NpyArray> arrays = io::NpzFile(cache.pathFor(key)).arrays();
  ASSERT_TRUE(arrays.count(name)) << name;
  edit(arrays[name]);
  io::NpzWriter w;
  for (const auto& [k, a] : arrays) {
    if (k.size() > 4 && k.compare(0, 2, "__") == 0) continue;  // header: store() adds it
    if (a.dtype == "<f8")
      w.add(k, reinterpret_cast<const double*>(a.bytes.data()), a.shape);
    else if (a.dtype == "<i8")
      w.add(k, reinterpret_cast<const int64_t*>(a.bytes.data()), a.shape);
    else
      ADD_FAILURE() << k << ": dtype " << a.dtype;
  }
  cache.store(key, w);
}

struct Tampering {
  const char* name;
  bool template_level;
  const char* key;  ///< array edited
  std::function<void(io::NpyArray&, const VolumetricData&)> edit;
  const char* phrase;  ///< in the warning
};

/// The first node of the data that is (is not) a bone node.
long firstNode(const VolumetricData& d, bool bone) {
  for (long i = 0; i < d.bone_of_node.size(); ++i)
    if ((d.bone_of_node(i) >= 0) == bone) return i;
  ADD_FAILURE() << "no node found";
  return 0;
}

/// A bone other than node i's largest weight.
int otherBone(const VolumetricData& d, long i) {
  int best = 0;
  d.templ->fields.weights.row(i).maxCoeff(&best);
  return best == 0 ? 1 : 0;
}

/// Each tampering of a freshly built cache is caught: the level is rebuilt with a warning naming
/// the file and the key, the rebuilt data is the original, and the entry is trusted again.
void expectCaught(const std::vector<Tampering>& cases) {
  const std::string cache_dir = test::freshTempDir("volumetric_cache_tampering");
  const VolumetricData cold = buildVolumetricData(body(), shape(), settingsIn(cache_dir));
  const AvatarCache cache(cache_dir);
  for (const Tampering& c : cases) {
    SCOPED_TRACE(c.name);
    const std::string key = c.template_level ? cold.templ->key : cold.key;
    tamper(cache, key, c.key, [&](io::NpyArray& a) { c.edit(a, cold); });
    VolumetricBuildReport report;
    const VolumetricData again =
        buildVolumetricData(body(), shape(), settingsIn(cache_dir), &report);
    // A rebuilt template has the same key, so the shape level still comes from the cache.
    EXPECT_EQ(report.template_from_cache, !c.template_level);
    EXPECT_EQ(report.data_from_cache, c.template_level);
    EXPECT_NE(report.warnings.find(cache.pathFor(key)), std::string::npos) << report.warnings;
    EXPECT_NE(report.warnings.find(std::string("key '") + c.key), std::string::npos)
        << report.warnings;
    EXPECT_NE(report.warnings.find(c.phrase), std::string::npos) << report.warnings;
    EXPECT_NE(report.warnings.find("rebuilding it"), std::string::npos) << report.warnings;
    EXPECT_EQ(again.bone_of_node, cold.bone_of_node);
    EXPECT_EQ(again.materials.density, cold.materials.density);
    EXPECT_EQ(again.templ->mesh.tets, cold.templ->mesh.tets);
    VolumetricBuildReport warm;
    buildVolumetricData(body(), shape(), settingsIn(cache_dir), &warm);
    EXPECT_TRUE(warm.template_from_cache && warm.data_from_cache) << warm.warnings;
  }
}

TEST(VolumetricCache, ChecksummedButWrongShapeLevelIsRebuilt) {
  expectCaught({
      Tampering{"bone_out_of_range", false, "bone_of_node",
                [](io::NpyArray& a, const VolumetricData& d) {
                  at<int64_t>(a, firstNode(d, false)) = 99;
                },
                "expected -1 or a bone in [0, 24)"},
      Tampering{"bone_not_the_largest_weight", false, "bone_of_node",
                [](io::NpyArray& a, const VolumetricData& d) {
                  const long i = firstNode(d, true);
                  at<int64_t>(a, i) = otherBone(d, i);
                },
                "among the node's largest weights"},
      Tampering{"density_doubled", false, "density",
                [](io::NpyArray& a, const VolumetricData&) { at<double>(a, 3) *= 2; },
                "the material model's value"},
      Tampering{"shear_changed", false, "shear",
                [](io::NpyArray& a, const VolumetricData&) { at<double>(a, 4) *= 1.01; },
                "the material model's value"},
      Tampering{"young_negative", false, "young",
                [](io::NpyArray& a, const VolumetricData&) { at<double>(a, 0) = -1e4; },
                "expected moduli > 0"},
      Tampering{"poisson_unphysical", false, "poisson",
                [](io::NpyArray& a, const VolumetricData&) { at<double>(a, 0) = 5.0; },
                "positive-definite compliance"},
      Tampering{"skin_fraction_above_one", false, "skin_fraction",
                [](io::NpyArray& a, const VolumetricData&) { at<double>(a, 0) = 1.5; },
                "expected a fraction in [0, 1]"},
      Tampering{
          "layer_flipped", false, "layer",
          [](io::NpyArray& a, const VolumetricData&) { at<int64_t>(a, 0) = 1 - at<int64_t>(a, 0); },
          "for a skin fraction of"},
      Tampering{"frame_scaled", false, "frame",
                [](io::NpyArray& a, const VolumetricData&) { at<double>(a, 0) *= 2; },
                "expected a rotation"},
      Tampering{"thickness_negative", false, "tissue_thickness",
                [](io::NpyArray& a, const VolumetricData&) { at<double>(a, 0) = -0.01; },
                "expected thicknesses >= 0"},
  });
}

TEST(VolumetricCache, ChecksummedButWrongTemplateLevelIsRebuilt) {
  expectCaught({
      Tampering{"tet_index_out_of_range", true, "tets",
                [](io::NpyArray& a, const VolumetricData&) { at<int64_t>(a, 5) = 1 << 30; },
                "outside [0, "},
      Tampering{"tet_inverted", true, "nodes",  // "key 'nodes' or 'tets'"
                [](io::NpyArray& a, const VolumetricData& d) {
                  // Move an interior node far outside: some tets invert, the boundary breaks.
                  const long i = d.templ->mesh.num_surface_nodes;
                  at<double>(a, 3 * i) += 10.0;
                },
                "not a valid tet mesh of the body"},
      Tampering{"interior_weights", true, "weights",
                [](io::NpyArray& a, const VolumetricData& d) {
                  const long i = d.templ->mesh.num_surface_nodes + 1;
                  at<double>(a, 24 * i) += 0.5;
                },
                "expected weights >= 0 summing to 1"},
      Tampering{"surface_shapedirs", true, "shapedirs",
                [](io::NpyArray& a, const VolumetricData&) { at<double>(a, 7) += 1e-3; },
                "differs from the body model's"},
  });
}

TEST(VolumetricCache, NonRegularFilesAtTheCachePathNeverBlock) {
  const std::string cache_dir = test::freshTempDir("volumetric_cache_fifo");
  const VolumetricData cold = buildVolumetricData(body(), shape(), settingsIn(cache_dir));
  const AvatarCache cache(cache_dir);

  // A FIFO: reported as unreadable and replaced by the rebuilt entry.
  const std::string data_path = cache.pathFor(cold.key);
  fs::remove(data_path);
  ASSERT_EQ(::mkfifo(data_path.c_str(), 0600), 0);
  VolumetricBuildReport report;
  buildVolumetricData(body(), shape(), settingsIn(cache_dir), &report);
  EXPECT_FALSE(report.data_from_cache);
  EXPECT_NE(report.warnings.find(data_path + ": is a FIFO (named pipe)"), std::string::npos)
      << report.warnings;
  EXPECT_TRUE(fs::is_regular_file(data_path));

  // A directory cannot be replaced by the rebuilt entry: reported, then a FileError on store.
  fs::remove(data_path);
  fs::create_directory(data_path);
  fs::create_directory(data_path + "/keep");  // a non-empty directory is never renamed over
  EXPECT_THROW(buildVolumetricData(body(), shape(), settingsIn(cache_dir)), FileError);
}

}  // namespace
}  // namespace flsh
