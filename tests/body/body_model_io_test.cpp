#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>

#include "body/body_model_derived.h"
#include "flsh/body/body_model.h"
#include "flsh/core/error.h"
#include "flsh/format/npz.h"
#include "format/raw_npz.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using ::testing::HasSubstr;
namespace fs = std::filesystem;
using test::messageOf;

std::string tupleText(const std::vector<long>& shape) {
  std::string out = "(";
  for (size_t k = 0; k < shape.size(); ++k) out += (k ? ", " : "") + std::to_string(shape[k]);
  return out + (shape.size() == 1 ? ",)" : ")");
}

/// `.npy` bytes of `values` converted to T (e.g. float for "<f4", uint32_t for "<u4").
template <class T, class Source>
std::vector<uint8_t> npyAs(const std::string& descr, const std::vector<long>& shape,
                           const Source* values, size_t count) {
  std::vector<T> converted(count);
  for (size_t k = 0; k < count; ++k) converted[k] = T(values[k]);
  return test::npyOf(descr, tupleText(shape), converted);
}

/// The SMPL arrays of `m` as `.npy` members, each in the dtype given (default float64 and
/// int64), keyed by name, so that a test can replace one before writing.
struct ModelMembers {
  std::map<std::string, std::vector<uint8_t>> npy;

  ModelMembers(const BodyModel& m, const std::string& float_descr = "<f8",
               const std::string& tree_descr = "<i8", const std::string& faces_descr = "<i8") {
    const long V = m.numVertices(), J = m.numJoints(), K = m.numBetas();
    const RowMatX shapedirs = m.shapedirs, posedirs = m.posedirs, weights = m.weights;
    const RowMatX regressor = RowMatX(MatX(m.J_regressor));
    auto floats = [&](const std::vector<long>& shape, const double* values, size_t count) {
      return float_descr == "<f4" ? npyAs<float>(float_descr, shape, values, count)
                                  : npyAs<double>(float_descr, shape, values, count);
    };
    npy["v_template"] = floats({V, 3}, m.v_template.data(), size_t(3 * V));
    npy["shapedirs"] = floats({V, 3, K}, shapedirs.data(), size_t(shapedirs.size()));
    npy["posedirs"] =
        floats({V, 3, long(posedirs.cols())}, posedirs.data(), size_t(posedirs.size()));
    npy["J_regressor"] = floats({J, V}, regressor.data(), size_t(regressor.size()));
    npy["weights"] = floats({V, J}, weights.data(), size_t(weights.size()));
    std::vector<int64_t> tree(size_t(2 * J));
    for (long j = 0; j < J; ++j) {
      tree[size_t(j)] = m.parents[size_t(j)];
      tree[size_t(J + j)] = j;
    }
    if (tree_descr == "<u4") {
      tree[0] = 4294967295LL;  // official SMPL: the root's parent is −1 stored as uint32
      npy["kintree_table"] = npyAs<uint32_t>(tree_descr, {2, J}, tree.data(), tree.size());
    } else if (tree_descr == "<i8 with uint32 root") {
      tree[0] = 4294967295LL;
      npy["kintree_table"] = npyAs<int64_t>("<i8", {2, J}, tree.data(), tree.size());
    } else {
      npy["kintree_table"] = npyAs<int64_t>(tree_descr, {2, J}, tree.data(), tree.size());
    }
    const long F = m.numFaces();
    if (faces_descr == "<u4")
      npy["f"] = npyAs<uint32_t>(faces_descr, {F, 3}, m.faces.data(), size_t(3 * F));
    else if (faces_descr == "<f8")
      npy["f"] = npyAs<double>(faces_descr, {F, 3}, m.faces.data(), size_t(3 * F));
    else
      npy["f"] = npyAs<int64_t>(faces_descr, {F, 3}, m.faces.data(), size_t(3 * F));
  }

  std::string write(const std::string& path) const {
    std::vector<test::RawMember> members;
    for (const auto& [key, bytes] : npy) members.push_back({key + ".npy", bytes});
    test::writeRawZip(path, members);
    return path;
  }
};

void expectBitIdentical(const BodyModel& a, const BodyModel& b) {
  EXPECT_EQ(a.v_template, b.v_template);
  EXPECT_EQ(a.shapedirs, b.shapedirs);
  EXPECT_EQ(a.posedirs, b.posedirs);
  EXPECT_EQ(MatX(a.J_regressor), MatX(b.J_regressor));
  EXPECT_EQ(a.weights, b.weights);
  EXPECT_EQ(a.parents, b.parents);
  EXPECT_EQ(a.faces, b.faces);
}

TEST(BodyModelIo, SaveThenLoadIsBitIdentical) {
  const std::string dir = test::freshTempDir("body_io_roundtrip");
  for (int betas : {10, 0, 300}) {
    const BodyModel model = test::makeRandomModel(120, betas, 7);
    const std::string path = dir + "/model_" + std::to_string(betas) + ".npz";
    saveBodyModel(model, path);
    const BodyModel loaded = loadBodyModel(path);
    expectBitIdentical(model, loaded);
    EXPECT_EQ(loaded.numBetas(), betas);
    EXPECT_EQ(loaded.source, path);
    EXPECT_NE(loaded.derived, nullptr);  // finalized
    // Saving the loaded model again gives the same bytes: nothing drifts.
    saveBodyModel(loaded, dir + "/again.npz");
    EXPECT_EQ(test::readFileBytes(path), test::readFileBytes(dir + "/again.npz"));
  }
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 4);
}

TEST(BodyModelIo, SavedFileHasSmplShapesAndDtypes) {
  const BodyModel model = test::makeRandomModel(90, 10, 3);
  const std::string path = test::freshTempDir("body_io_layout") + "/model.npz";
  saveBodyModel(model, path);
  const io::NpzFile file(path);
  EXPECT_EQ(file.keys(), (std::vector<std::string>{"J_regressor", "f", "kintree_table", "posedirs",
                                                   "shapedirs", "v_template", "weights"}));
  auto expect = [&](const char* key, const char* dtype, std::vector<long> shape) {
    EXPECT_EQ(file.raw(key).dtype, dtype) << key;
    EXPECT_EQ(file.raw(key).shape, shape) << key;
  };
  expect("v_template", "<f8", {90, 3});
  expect("shapedirs", "<f8", {90, 3, 10});
  expect("posedirs", "<f8", {90, 3, 207});
  expect("J_regressor", "<f8", {24, 90});
  expect("weights", "<f8", {90, 24});
  expect("kintree_table", "<i8", {2, 24});
  expect("f", "<i8", {30, 3});
  const std::vector<int64_t> tree = file.integers("kintree_table", {2, 24});
  EXPECT_EQ(tree[0], -1);
  EXPECT_EQ(tree[24 + 23], 23);
  // shapedirs[i, c, k] is row 3i + c, column k of the 3V × K matrix.
  const std::vector<double> shapedirs = file.doubles("shapedirs", {90, 3, 10});
  EXPECT_EQ(shapedirs[size_t((7 * 3 + 2) * 10 + 4)], model.shapedirs(3 * 7 + 2, 4));
}

TEST(BodyModelIo, LoadsOfficialStyleDtypes) {
  // Official SMPL files: float32 (some conversions), kintree_table uint32 with root
  // 4294967295, faces uint32; other converters store faces as float64 or the uint32 root in
  // an int64 table.
  const BodyModel model = test::makeRandomModel(60, 10, 11);
  const std::string dir = test::freshTempDir("body_io_official");
  const BodyModel f32 =
      loadBodyModel(ModelMembers(model, "<f4", "<u4", "<u4").write(dir + "/a.npz"));
  EXPECT_EQ(f32.parents, model.parents);
  EXPECT_EQ(f32.faces, model.faces);
  EXPECT_EQ(f32.v_template, model.v_template.cast<float>().cast<double>());
  EXPECT_EQ(f32.posedirs, model.posedirs.cast<float>().cast<double>());
  EXPECT_LT((f32.shapedirs - model.shapedirs).cwiseAbs().maxCoeff(), 1e-6);

  const BodyModel mixed = loadBodyModel(
      ModelMembers(model, "<f8", "<i8 with uint32 root", "<f8").write(dir + "/b.npz"));
  expectBitIdentical(model, mixed);
}

class BodyModelIoErrors : public ::testing::Test {
 protected:
  void SetUp() override {
    model_ = test::makeRandomModel(30, 10, 5);
    dir_ = test::freshTempDir("body_io_errors");
  }
  /// Writes the model with `key` replaced by `npy` (or removed if empty), loads it, and
  /// returns the InputError message. Sets path_: read it only after the call returns.
  std::string loadWith(const std::string& key, const std::vector<uint8_t>& npy) {
    ModelMembers members(model_);
    if (npy.empty())
      members.npy.erase(key);
    else
      members.npy[key] = npy;
    path_ = members.write(dir_ + "/bad_" + key + ".npz");
    return messageOf<InputError>([&] { loadBodyModel(path_); });
  }
  std::vector<uint8_t> zeros(const std::vector<long>& shape) const {
    long n = 1;
    for (long d : shape) n *= d;
    return test::npyOf("<f8", tupleText(shape), std::vector<double>(size_t(n), 0.0));
  }
  BodyModel model_;
  std::string dir_, path_;
};

TEST_F(BodyModelIoErrors, MissingKeyNamesFileAndKey) {
  for (const char* key :
       {"v_template", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table", "f"}) {
    const std::string message = loadWith(key, {});
    EXPECT_THAT(message, HasSubstr(path_ + ": missing key '" + key + "'")) << key;
  }
}

TEST_F(BodyModelIoErrors, WrongShapesNameBothKeys) {
  std::string message = loadWith("posedirs", zeros({30, 3, 200}));
  EXPECT_THAT(message,
              HasSubstr(path_ + ": key 'posedirs' has shape (30, 3, 200), expected (V, 3, 9(J-1)) "
                                "with 9(J-1) = 207 from key 'kintree_table'"));
  EXPECT_THAT(loadWith("shapedirs", zeros({31, 3, 10})),
              HasSubstr("key 'shapedirs' has shape (31, 3, 10), expected (V, 3, K) with V = 30 "
                        "from key 'v_template'"));
  EXPECT_THAT(loadWith("weights", zeros({30, 23})),
              HasSubstr("key 'weights' has shape (30, 23), expected (V, J) with J = 24 from key "
                        "'kintree_table'"));
  EXPECT_THAT(loadWith("J_regressor", zeros({24, 29})),
              HasSubstr("key 'J_regressor' has shape (24, 29), expected (J, V) with V = 30 from "
                        "key 'v_template'"));
  EXPECT_THAT(loadWith("shapedirs", zeros({30, 30})),
              HasSubstr("key 'shapedirs': expected shape (V, 3, K), got (30, 30)"));
  message = loadWith("v_template", zeros({30, 2}));
  EXPECT_THAT(message,
              HasSubstr(path_ + ": key 'v_template': expected shape (30, 3), got (30, 2)"));
  EXPECT_THAT(loadWith("f", zeros({10, 4})),
              HasSubstr("key 'f': expected shape (F, 3), got (10, 4)"));
  EXPECT_THAT(loadWith("kintree_table", zeros({3, 24})),
              HasSubstr("key 'kintree_table': expected shape (2, J), got (3, 24)"));
}

TEST_F(BodyModelIoErrors, BadValuesNameTheKey) {
  std::vector<double> shapedirs(30 * 3 * 10, 0.0);
  shapedirs[17] = std::nan("");
  std::string message = loadWith("shapedirs", test::npyOf("<f8", "(30, 3, 10)", shapedirs));
  EXPECT_THAT(message, HasSubstr(path_ + ": key 'shapedirs': contains NaN or Inf"));

  std::vector<double> faces = {0, 1, 2, 3, 4.5, 5};
  EXPECT_THAT(loadWith("f", test::npyOf("<f8", "(2, 3)", faces)),
              HasSubstr("key 'f': expected integer values, got 4.5"));
  const std::vector<int64_t> out_of_range = {0, 1, 2, 3, 4, 30};
  EXPECT_THAT(loadWith("f", test::npyOf("<i8", "(2, 3)", out_of_range)),
              HasSubstr("key 'f': vertex index 30 of face 1 is outside [0, 29]"));
  const std::vector<int64_t> wrapping = {0, 1, 2, 3, 4, (1LL << 32) + 5};  // int would wrap to 5
  EXPECT_THAT(loadWith("f", test::npyOf("<i8", "(2, 3)", wrapping)), HasSubstr("key 'f'"));

  std::vector<int64_t> tree(48);
  for (int j = 0; j < 24; ++j)
    tree[size_t(j)] = model_.parents[size_t(j)], tree[size_t(24 + j)] = j;
  tree[5] = 99;
  EXPECT_THAT(loadWith("kintree_table", test::npyOf("<i8", "(2, 24)", tree)),
              HasSubstr("key 'kintree_table': parent of joint 5 is 99"));

  EXPECT_THAT(loadWith("v_template", test::npyOf("<U5", "(1,)", std::vector<uint32_t>(5, 'a'))),
              HasSubstr("key 'v_template': expected a numeric array (V, 3), got dtype '<U5'"));

  // Values that load but make an invalid model: BodyModel::validate() names the file.
  message = loadWith("weights", zeros({30, 24}));
  EXPECT_THAT(message, HasSubstr(path_ + ": array 'weights': row 0 sums to 0"));
}

// Finite but absurd values load as numbers but make no body; BodyModel::validate() names the
// file, the array and the entry (issue 23: a regressor entry of 1e300 crashed the FEM set-up).
TEST_F(BodyModelIoErrors, AbsurdValuesNameTheFileTheArrayAndTheEntry) {
  const RowMatX regressor = RowMatX(MatX(model_.J_regressor));
  std::vector<double> values(regressor.data(), regressor.data() + regressor.size());
  values[size_t(3 * 30 + 17)] = 1e300;
  std::string message = loadWith("J_regressor", test::npyOf("<f8", "(24, 30)", values));
  EXPECT_THAT(message, HasSubstr(path_ + ": array 'J_regressor': entry [3, 17] = 1e+300 is "
                                         "outside [-1000, 1000]"));

  // Entries within the bound can still regress a joint to an absurd place.
  values.assign(regressor.data(), regressor.data() + regressor.size());
  for (int i = 0; i < 30; ++i) values[size_t(5 * 30 + i)] = 900;  // joint 5 at y ~ 24 km
  message = loadWith("J_regressor", test::npyOf("<f8", "(24, 30)", values));
  EXPECT_THAT(message, HasSubstr(path_ + ": array 'J_regressor' places joint 5 at coordinate"));
  EXPECT_THAT(message, HasSubstr("expected within [-1000, 1000] m"));

  std::vector<double> v(model_.v_template.data(), model_.v_template.data() + 90);
  v[3 * 7 + 1] = -2e3;
  message = loadWith("v_template", test::npyOf("<f8", "(30, 3)", v));
  EXPECT_THAT(message, HasSubstr(path_ + ": array 'v_template': entry [7, 1] = -2000"));

  const RowMatX shapedirs = model_.shapedirs;
  std::vector<double> dirs(shapedirs.data(), shapedirs.data() + shapedirs.size());
  dirs[5] = 1e250;
  message = loadWith("shapedirs", test::npyOf("<f8", "(30, 3, 10)", dirs));
  EXPECT_THAT(message, HasSubstr(path_ + ": array 'shapedirs': entry [0, 5] = 1e+250"));

  // The same checks hold for a model built in memory (finalize() validates).
  BodyModel edited = model_;
  edited.posedirs(4, 100) = 5e3;
  EXPECT_THAT(messageOf<InputError>([&] { edited.finalize(); }),
              HasSubstr("array 'posedirs': entry [4, 100] = 5000 is outside [-1000, 1000]"));
}

TEST_F(BodyModelIoErrors, UnreadableFiles) {
  EXPECT_THROW(loadBodyModel(dir_ + "/missing.npz"), FileError);
  const std::string garbage = dir_ + "/garbage.npz";
  std::ofstream(garbage) << std::string(1000, '\x07');
  EXPECT_THAT(messageOf<InputError>([&] { loadBodyModel(garbage); }), HasSubstr(garbage));

  const std::string path = dir_ + "/model.npz";
  saveBodyModel(model_, path);
  std::vector<uint8_t> bytes = test::readFileBytes(path);
  bytes.resize(bytes.size() / 2);
  test::writeFileBytes(path, bytes);
  EXPECT_THAT(messageOf<InputError>([&] { loadBodyModel(path); }), HasSubstr(path));
}

TEST_F(BodyModelIoErrors, FailedSaveLeavesNoFile) {
  std::ofstream(dir_ + "/blocker") << "x";
  EXPECT_THROW(saveBodyModel(model_, dir_ + "/blocker/model.npz"), FileError);
  EXPECT_FALSE(fs::exists(dir_ + "/blocker/model.npz"));

  BodyModel invalid = model_;
  invalid.weights(3, 0) += 0.5;  // row no longer sums to 1
  EXPECT_THROW(saveBodyModel(invalid, dir_ + "/invalid.npz"), InputError);
  EXPECT_FALSE(fs::exists(dir_ + "/invalid.npz"));
  EXPECT_EQ(std::distance(fs::directory_iterator(dir_), fs::directory_iterator()), 1);
}

}  // namespace
}  // namespace flsh
