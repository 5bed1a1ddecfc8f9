#include "flsh/format/npz.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>

#include "flsh/core/error.h"
#include "format/raw_npz.h"
#include "support/test_support.h"

namespace flsh::io {
namespace {

using test::npyOf;
using test::RawMember;
using ::testing::HasSubstr;
namespace fs = std::filesystem;
using test::messageOf;

std::vector<std::string> filesIn(const std::string& dir) {
  std::vector<std::string> names;
  for (const auto& entry : fs::directory_iterator(dir)) names.push_back(entry.path().filename());
  std::sort(names.begin(), names.end());
  return names;
}

class NpzRoundTrip : public ::testing::TestWithParam<bool> {};

TEST_P(NpzRoundTrip, EveryWrittenDtypeComesBackExactly) {
  const bool compress = GetParam();
  const std::string dir = test::freshTempDir(compress ? "npz_roundtrip_deflate" : "npz_roundtrip");
  const std::string path = dir + "/all.npz";

  std::vector<double> cube(2 * 3 * 4);
  for (size_t k = 0; k < cube.size(); ++k) cube[k] = 0.1 * double(k) - 1.0 / 3.0;
  cube[5] = std::numeric_limits<double>::denorm_min();
  cube[6] = -0.0;
  const std::vector<int64_t> ints = {
      -1, 0, 7, std::numeric_limits<int64_t>::max(), std::numeric_limits<int64_t>::min(), 42};
  RowMatX matrix(3, 2);
  matrix << 1, 2, 3, 4, 5, 6.5;
  VecX vector(4);
  vector << -1.5, 0, 2.25, 1e300;
  MatX3 points(2, 3);
  points << 1, 2, 3, 4, 5, 6;

  NpzWriter writer;
  writer.add("cube", cube.data(), {2, 3, 4});
  writer.add("ints", ints.data(), {3, 2});
  writer.add("matrix", matrix);
  writer.add("vector", vector);
  writer.add("points", points);  // fixed-column Eigen type: written 2-D
  writer.add("empty", cube.data(), {0, 3});
  writer.addScalar("rate", 120.0);
  writer.addString("gender", "female");
  writer.addString("unicode",
                   "gr\xc3\xb6\xc3\x9f"
                   "e \xe2\x82\xac");  // "größe €"
  writer.addString("blank", "");
  writer.save(path, compress);

  const NpzFile file(path);
  EXPECT_EQ(file.path(), path);
  EXPECT_EQ(file.keys(),
            (std::vector<std::string>{"blank", "cube", "empty", "gender", "ints", "matrix",
                                      "points", "rate", "unicode", "vector"}));
  EXPECT_EQ(file.raw("cube").dtype, "<f8");
  EXPECT_EQ(file.raw("cube").shape, (std::vector<long>{2, 3, 4}));
  const std::vector<double> cube_read = file.doubles("cube", {2, 3, 4});
  ASSERT_EQ(cube_read.size(), cube.size());
  EXPECT_EQ(std::memcmp(cube_read.data(), cube.data(), cube.size() * sizeof(double)), 0);

  EXPECT_EQ(file.raw("ints").dtype, "<i8");
  EXPECT_EQ(file.integers("ints", {3, 2}), ints);
  EXPECT_TRUE(file.raw("ints").isInteger());
  EXPECT_FALSE(file.raw("ints").isFloat());

  EXPECT_EQ(file.matrix("matrix", 3, 2), matrix);
  EXPECT_EQ(file.matrix("matrix"), matrix);
  EXPECT_EQ(file.vector("vector", 4), vector);
  EXPECT_EQ(file.raw("points").shape, (std::vector<long>{2, 3}));
  EXPECT_EQ(file.matrix("points", 2, 3), RowMatX(points));
  EXPECT_EQ(file.raw("empty").shape, (std::vector<long>{0, 3}));
  EXPECT_EQ(file.raw("empty").size(), 0);
  EXPECT_EQ(file.matrix("empty", -1, 3).rows(), 0);

  EXPECT_EQ(file.raw("rate").shape, std::vector<long>{});
  EXPECT_EQ(file.raw("rate").size(), 1);
  EXPECT_EQ(file.scalar("rate"), 120.0);
  EXPECT_EQ(file.raw("gender").dtype, "<U6");
  EXPECT_EQ(file.string("gender"), "female");
  EXPECT_EQ(file.string("unicode"),
            "gr\xc3\xb6\xc3\x9f"
            "e \xe2\x82\xac");
  EXPECT_EQ(file.string("blank"), "");
  EXPECT_EQ(file.string("not_there"), "");

  // Atomic write: nothing but the target is left in the directory.
  EXPECT_EQ(filesIn(dir), std::vector<std::string>{"all.npz"});
}

INSTANTIATE_TEST_SUITE_P(StoredAndDeflated, NpzRoundTrip, ::testing::Bool());

TEST(NpzWriter, EmptyArchiveIsReadable) {
  const std::string path = test::freshTempDir("npz_empty") + "/empty.npz";
  NpzWriter().save(path);
  const NpzFile file(path);
  EXPECT_TRUE(file.keys().empty());
  EXPECT_FALSE(file.has("anything"));
}

TEST(NpzWriter, RejectsDuplicateAndEmptyKeys) {
  NpzWriter writer;
  writer.addScalar("a", 1.0);
  EXPECT_THAT(messageOf<InputError>([&] { writer.addScalar("a", 2.0); }),
              HasSubstr("'a' added twice"));
  EXPECT_THROW(writer.addScalar("", 2.0), InputError);
}

TEST(NpzWriter, SaveOverExistingFileReplacesIt) {
  const std::string path = test::freshTempDir("npz_replace") + "/x.npz";
  NpzWriter first;
  first.addScalar("value", 1.0);
  first.save(path);
  NpzWriter second;
  second.addScalar("value", 2.0);
  second.save(path, true);
  EXPECT_EQ(NpzFile(path).scalar("value"), 2.0);
}

TEST(NpzWriter, FailedSaveLeavesNoFile) {
  const std::string dir = test::freshTempDir("npz_failed_save");
  const std::string blocker = dir + "/not_a_dir";
  std::ofstream(blocker) << "a regular file";
  NpzWriter writer;
  writer.addScalar("value", 1.0);
  const std::string target = blocker + "/out.npz";
  const std::string message = messageOf<FileError>([&] { writer.save(target); });
  EXPECT_THAT(message, HasSubstr("not_a_dir"));
  EXPECT_FALSE(fs::exists(target));
  EXPECT_EQ(filesIn(dir), std::vector<std::string>{"not_a_dir"});
}

// ---------------------------------------------------------------------------------------------
// Input that NpzWriter never writes, crafted byte by byte.

TEST(NpzFile, ReadsFloat32AndNarrowIntegerDtypes) {
  const std::string path = test::freshTempDir("npz_dtypes") + "/dtypes.npz";
  const std::vector<float> f32 = {1.5f, -2.25f, 3.0f, 1e-3f};
  const std::vector<int32_t> i32 = {-7, 0, 2147483647, -2147483647 - 1};
  const std::vector<uint32_t> u32 = {4294967295u, 0, 1, 23};
  const std::vector<uint64_t> u64 = {std::numeric_limits<uint64_t>::max(), 5};
  const std::vector<uint8_t> u8 = {0, 255, 3};
  const std::vector<uint8_t> b1 = {1, 0, 1};
  const std::vector<double> f64_integral = {0, 1, 2, -1};
  test::writeRawZip(path, {{"f32.npy", npyOf("<f4", "(2, 2)", f32)},
                           {"i32.npy", npyOf("<i4", "(4,)", i32)},
                           {"u32.npy", npyOf("<u4", "(2, 2)", u32)},
                           {"u64.npy", npyOf("<u8", "(2,)", u64)},
                           {"u8.npy", npyOf("|u1", "(3,)", u8)},
                           {"b1.npy", npyOf("|b1", "(3,)", b1)},
                           {"f64_integral.npy", npyOf("<f8", "(4,)", f64_integral)}});
  const NpzFile file(path);
  EXPECT_EQ(file.raw("f32").dtype, "<f4");
  EXPECT_TRUE(file.raw("f32").isFloat());
  const RowMatX m = file.matrix("f32", 2, 2);
  EXPECT_EQ(m(0, 0), 1.5);
  EXPECT_EQ(m(0, 1), -2.25);
  EXPECT_EQ(m(1, 1), double(1e-3f));
  EXPECT_EQ(file.integers("i32", {4}), (std::vector<int64_t>{-7, 0, 2147483647, -2147483648LL}));
  // uint32/uint64 all-ones is −1 stored unsigned (SMPL's kintree_table root).
  EXPECT_EQ(file.integers("u32", {2, 2}), (std::vector<int64_t>{-1, 0, 1, 23}));
  EXPECT_EQ(file.integers("u64", {2}), (std::vector<int64_t>{-1, 5}));
  EXPECT_EQ(file.doubles("u32", {2, 2})[0], 4294967295.0);
  EXPECT_EQ(file.integers("u8", {3}), (std::vector<int64_t>{0, 255, 3}));
  EXPECT_EQ(file.vector("b1", 3), (VecX(3) << 1, 0, 1).finished());
  EXPECT_TRUE(file.raw("b1").isInteger());
  EXPECT_EQ(file.integers("f64_integral", {4}), (std::vector<int64_t>{0, 1, 2, -1}));
}

TEST(NpzFile, TransposesFortranOrderIntoCOrder) {
  const std::string path = test::freshTempDir("npz_fortran") + "/fortran.npz";
  // A 2 × 3 matrix a(r, c) = 10 r + c stored column by column.
  const std::vector<double> m_fortran = {0, 10, 1, 11, 2, 12};
  // A 2 × 3 × 4 int32 array a(i, j, k) = 100 i + 10 j + k, first axis fastest.
  std::vector<int32_t> cube_fortran;
  for (int k = 0; k < 4; ++k)
    for (int j = 0; j < 3; ++j)
      for (int i = 0; i < 2; ++i) cube_fortran.push_back(100 * i + 10 * j + k);
  const std::vector<float> v_fortran = {1, 2, 3};  // 1-D: same in both orders
  test::writeRawZip(path,
                    {{"m.npy", npyOf("<f8", "(2, 3)", m_fortran, true)},
                     {"cube.npy", npyOf("<i4", "(2, 3, 4)", cube_fortran, true)},
                     {"v.npy", npyOf("<f4", "(3,)", v_fortran, true)}},
                    true);
  const NpzFile file(path);
  RowMatX expected(2, 3);
  expected << 0, 1, 2, 10, 11, 12;
  EXPECT_EQ(file.matrix("m", 2, 3), expected);
  const std::vector<int64_t> cube = file.integers("cube", {2, 3, 4});
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 3; ++j)
      for (int k = 0; k < 4; ++k)
        EXPECT_EQ(cube[size_t(12 * i + 4 * j + k)], 100 * i + 10 * j + k) << i << j << k;
  EXPECT_EQ(file.vector("v", 3), (VecX(3) << 1, 2, 3).finished());
}

TEST(NpzFile, ReadsHeaderVersions2And3AndPython2Longs) {
  const std::string path = test::freshTempDir("npz_versions") + "/versions.npz";
  const std::vector<double> values = {1, 2, 3, 4, 5, 6};
  std::vector<uint8_t> py2 = npyOf("<f8", "(2L, 3L)", values);
  test::writeRawZip(path, {{"v2.npy", npyOf("<f8", "(2, 3)", values, false, 2)},
                           {"v3.npy", npyOf("<f8", "(3, 2)", values, false, 3)},
                           {"py2.npy", py2},
                           {"notes.txt", {'h', 'i'}}});
  const NpzFile file(path);
  EXPECT_EQ(file.keys(), (std::vector<std::string>{"py2", "v2", "v3"}));  // non-.npy ignored
  EXPECT_EQ(file.raw("v2").shape, (std::vector<long>{2, 3}));
  EXPECT_EQ(file.matrix("v3", 3, 2)(2, 1), 6.0);
  EXPECT_EQ(file.matrix("py2", 2, 3)(1, 0), 4.0);
}

TEST(NpzFile, ReadsByteAndUnicodeStrings) {
  const std::string path = test::freshTempDir("npz_strings") + "/strings.npz";
  const std::string bytes("male\0\0", 6);  // |S6 pads with NULs
  const std::vector<char> s6(bytes.begin(), bytes.end());
  const std::vector<uint32_t> u7 = {'n', 'e', 'u', 't', 'r', 'a', 'l'};
  const std::vector<uint32_t> u3_in_1 = {'a', 'b', 'c'};
  test::writeRawZip(path, {{"s.npy", npyOf("|S6", "()", s6)},
                           {"u.npy", npyOf("<U7", "()", u7)},
                           {"one.npy", npyOf("<U3", "(1,)", u3_in_1)},
                           {"two.npy", npyOf("<U1", "(2,)", std::vector<uint32_t>{'a', 'b'})}});
  const NpzFile file(path);
  EXPECT_EQ(file.string("s"), "male");
  EXPECT_EQ(file.string("u"), "neutral");
  EXPECT_EQ(file.string("one"), "abc");
  EXPECT_THAT(messageOf<InputError>([&] { file.string("two"); }),
              HasSubstr("key 'two': expected a single string, got shape (2,)"));
}

// ---------------------------------------------------------------------------------------------
// Errors

class NpzErrors : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = test::freshTempDir("npz_errors");
    path_ = dir_ + "/model.npz";
    const std::vector<double> posedirs(5 * 3 * 200, 0.5);
    std::vector<double> with_nan = {1.0, 2.0, std::nan(""), 4.0};
    std::vector<double> with_inf = {1.0, std::numeric_limits<double>::infinity()};
    std::vector<double> fractional = {1.0, 1.5};
    const std::vector<uint32_t> text = {'o', 'o', 'p', 's'};
    NpzWriter writer;
    writer.add("posedirs", posedirs.data(), {5, 3, 200});
    writer.add("with_nan", with_nan.data(), {2, 2});
    writer.add("with_inf", with_inf.data(), {2});
    writer.add("fractional", fractional.data(), {2});
    writer.addString("text", "oops");
    writer.addScalar("scalar", 3.0);
    writer.save(path_);
  }
  std::string dir_, path_;
};

TEST_F(NpzErrors, WrongShapeNamesFileKeyAndBothShapes) {
  const NpzFile file(path_);
  EXPECT_THAT(messageOf<InputError>([&] {
                file.doubles("posedirs", {5, 3, 207});
              }),
              HasSubstr(path_ + ": key 'posedirs': expected shape (5, 3, 207), got (5, 3, 200)"));
  EXPECT_THAT(messageOf<InputError>([&] { file.matrix("posedirs"); }),
              HasSubstr("key 'posedirs': expected shape (*, *), got (5, 3, 200)"));
  EXPECT_THAT(messageOf<InputError>([&] { file.vector("with_nan", 4); }),
              HasSubstr("key 'with_nan': expected shape (4,), got (2, 2)"));
  EXPECT_THAT(messageOf<InputError>([&] {
                file.integers("posedirs", {5, 3, 1});
              }),
              HasSubstr("expected shape (5, 3, 1), got (5, 3, 200)"));
  EXPECT_THAT(messageOf<InputError>([&] { file.scalar("posedirs"); }),
              HasSubstr("key 'posedirs': expected a scalar, got shape (5, 3, 200)"));
  EXPECT_NO_THROW(file.doubles("posedirs", {5, -1, 200}));
}

TEST_F(NpzErrors, MissingKeyListsTheKeysPresent) {
  const NpzFile file(path_);
  const std::string message = messageOf<InputError>([&] { file.raw("J_regressor"); });
  EXPECT_THAT(message, HasSubstr(path_ + ": missing key 'J_regressor'"));
  EXPECT_THAT(message, HasSubstr("posedirs"));
  EXPECT_THROW(file.doubles("J_regressor", {1}), InputError);
}

TEST_F(NpzErrors, StringWhereNumbersExpectedNamesTheDtype) {
  const NpzFile file(path_);
  EXPECT_THAT(messageOf<InputError>([&] { file.doubles("text", {}); }),
              HasSubstr("key 'text': expected a numeric array, got dtype '<U4'"));
  EXPECT_THAT(messageOf<InputError>([&] { file.integers("text", {}); }),
              HasSubstr("key 'text': expected an integer array, got dtype '<U4'"));
  EXPECT_THAT(messageOf<InputError>([&] { file.string("scalar"); }),
              HasSubstr("key 'scalar': expected a string, got dtype '<f8'"));
}

TEST_F(NpzErrors, NaNInfAndFractionsAreRejectedNamingTheKey) {
  const NpzFile file(path_);
  EXPECT_THAT(messageOf<InputError>([&] {
                file.doubles("with_nan", {2, 2});
              }),
              HasSubstr("key 'with_nan': contains NaN or Inf (first at flat index 2)"));
  EXPECT_THAT(messageOf<InputError>([&] { file.vector("with_inf"); }),
              HasSubstr("key 'with_inf': contains NaN or Inf"));
  EXPECT_THAT(messageOf<InputError>([&] { file.integers("fractional", {2}); }),
              HasSubstr("key 'fractional': expected integer values, got 1.5"));
  EXPECT_THAT(messageOf<InputError>([&] {
                file.integers("with_nan", {2, 2});
              }),
              HasSubstr("key 'with_nan': expected integer values"));
}

TEST_F(NpzErrors, MissingFileIsAFileErrorADirectoryAnInputError) {
  const std::string missing = dir_ + "/does_not_exist.npz";
  EXPECT_THAT(messageOf<FileError>([&] { NpzFile{missing}; }), HasSubstr(missing));
  // Not a regular file, like a FIFO or a device (input_file_test.cpp).
  EXPECT_THAT(messageOf<InputError>([&] { NpzFile{dir_}; }),
              HasSubstr(dir_ + ": is a directory, expected an .npz file"));
}

TEST_F(NpzErrors, GarbageAndEmptyFilesAreInputErrors) {
  const std::string garbage = dir_ + "/garbage.npz";
  std::ofstream(garbage) << "this is certainly not a zip archive, just some text\n";
  EXPECT_THAT(messageOf<InputError>([&] { NpzFile{garbage}; }),
              HasSubstr(garbage + ": not an .npz file"));
  const std::string empty = dir_ + "/empty.npz";
  std::ofstream{empty};
  EXPECT_THAT(messageOf<InputError>([&] { NpzFile{empty}; }), HasSubstr(empty));
}

TEST_F(NpzErrors, EveryTruncationIsAnInputErrorNamingTheFile) {
  const std::vector<uint8_t> bytes = test::readFileBytes(path_);
  ASSERT_GT(bytes.size(), 1000u);
  const std::string cut = dir_ + "/cut.npz";
  for (size_t keep : {size_t(0), size_t(30), bytes.size() / 3, bytes.size() / 2, bytes.size() - 30,
                      bytes.size() - 1}) {
    test::writeFileBytes(cut, std::vector<uint8_t>(bytes.begin(), bytes.begin() + long(keep)));
    EXPECT_THAT(messageOf<InputError>([&] { NpzFile{cut}; }), HasSubstr(cut))
        << "kept " << keep << " of " << bytes.size() << " bytes";
  }
}

TEST_F(NpzErrors, CorruptedMemberDataFailsItsCrcCheck) {
  std::vector<uint8_t> bytes = test::readFileBytes(path_);
  // Members are stored (not deflated), so the payload of 'posedirs' is visible: flip a byte
  // of its data (past its header), which only the CRC can notice.
  const std::string header = "'shape': (5, 3, 200)";
  const auto at = std::search(bytes.begin(), bytes.end(), header.begin(), header.end());
  ASSERT_NE(at, bytes.end());
  const size_t offset = size_t(at - bytes.begin()) + 500;
  ASSERT_LT(offset, bytes.size());
  bytes[offset] ^= 0x5a;
  const std::string corrupt = dir_ + "/corrupt.npz";
  test::writeFileBytes(corrupt, bytes);
  const std::string message = messageOf<InputError>([&] { NpzFile{corrupt}; });
  EXPECT_THAT(message, HasSubstr(corrupt + ": key '"));
  EXPECT_THAT(message, HasSubstr("CRC"));
}

TEST_F(NpzErrors, DataSizeNotMatchingTheHeader) {
  const std::string path = dir_ + "/short.npz";
  const std::vector<double> ten(10, 1.0);
  test::writeRawZip(path, {{"a.npy", npyOf("<f8", "(3, 4)", ten)}});
  const std::string message = messageOf<InputError>([&] { NpzFile{path}; });
  EXPECT_THAT(message, HasSubstr(path + ": key 'a': data size 80 bytes does not match"));
  EXPECT_THAT(message, HasSubstr("(3, 4) needs 96 bytes"));
}

TEST_F(NpzErrors, MalformedHeadersAreInputErrorsNamingTheKey) {
  const std::vector<double> one = {1.0};
  // A version-1 .npy whose header dict is `text`, followed by one float64.
  auto withHeader = [&](const std::string& text) {
    std::vector<uint8_t> blob = {0x93, 'N', 'U', 'M', 'P', 'Y', 1, 0, uint8_t(text.size()), 0};
    blob.insert(blob.end(), text.begin(), text.end());
    blob.insert(blob.end(), 8, 0);
    return blob;
  };
  const std::vector<std::pair<std::string, std::vector<uint8_t>>> cases = {
      {"no magic", std::vector<uint8_t>(64, 'x')},
      {"short", {0x93, 'N', 'U'}},
      {"bad shape", npyOf("<f8", "(1, x)", one)},
      {"no shape", withHeader("{'descr': '<f8', 'fortran_order': False}\n")},
      {"bad bool", withHeader("{'descr': '<f8', 'fortran_order': Maybe, 'shape': (1,)}\n")},
      {"not a dict", withHeader("descr <f8 shape 1\n")},
      {"unterminated", withHeader("{'descr': '<f8, 'shape': (1,)\n")},
      {"header past the end",
       [&] {
         std::vector<uint8_t> blob =
             withHeader("{'descr': '<f8', 'fortran_order': False, 'shape': (1,)}\n");
         blob.resize(20);
         return blob;
       }()},
      {"version 9", npyOf("<f8", "(1,)", one, false, 9)},
  };
  for (const auto& [what, blob] : cases) {
    const std::string path = dir_ + "/bad_header.npz";
    test::writeRawZip(path, {{"arr.npy", blob}});
    EXPECT_THAT(messageOf<InputError>([&] { NpzFile{path}; }), HasSubstr(path + ": key 'arr'"))
        << what;
  }
}

TEST_F(NpzErrors, UnsupportedDtypeIsReportedWhenItsKeyIsRead) {
  const std::string path = dir_ + "/unsupported.npz";
  const std::vector<double> pair = {1.0, 2.0};
  test::writeRawZip(path, {{"complex.npy", npyOf("<c16", "(1,)", pair)},
                           {"bigendian.npy", npyOf(">f8", "(2,)", pair)},
                           {"object.npy", npyOf("|O", "(2,)", pair)},
                           {"fine.npy", npyOf("<f8", "(2,)", pair)}});
  // Other keys stay usable: SMPL-X/AMASS files carry object arrays nobody here needs.
  const NpzFile file(path);
  EXPECT_TRUE(file.has("complex"));
  EXPECT_EQ(file.vector("fine", 2), (VecX(2) << 1, 2).finished());
  EXPECT_THAT(messageOf<InputError>([&] { file.vector("complex"); }),
              HasSubstr(path + ": key 'complex': unsupported dtype '<c16'"));
  EXPECT_THAT(messageOf<InputError>([&] { file.raw("bigendian"); }),
              HasSubstr("unsupported dtype '>f8'"));
  EXPECT_THAT(messageOf<InputError>([&] { file.raw("object"); }), HasSubstr("smpl_pkl_to_npz.py"));
}

// ---------------------------------------------------------------------------------------------
// Interoperability with numpy itself (skipped when /usr/bin/python3 lacks numpy).

bool haveNumpy() { return std::system("/usr/bin/python3 -c 'import numpy' >/dev/null 2>&1") == 0; }

int runPython(const std::string& dir, const std::string& script) {
  const std::string file = dir + "/script.py";
  std::ofstream(file) << script;
  return std::system(("/usr/bin/python3 " + file).c_str());
}

TEST(NpzNumpy, NumpyLoadsWhatNpzWriterWrites) {
  if (!haveNumpy()) GTEST_SKIP() << "/usr/bin/python3 with numpy not available";
  const std::string dir = test::freshTempDir("npz_numpy_reads");
  for (bool compress : {false, true}) {
    const std::string path = dir + (compress ? "/deflated.npz" : "/stored.npz");
    const std::vector<double> cube = {0.5, 1, 2, 3, 4, 5, 6, 7};
    const std::vector<int64_t> ints = {-1, 0, 1, 2, 3, 4};
    NpzWriter writer;
    writer.add("cube", cube.data(), {2, 2, 2});
    writer.add("ints", ints.data(), {2, 3});
    writer.addScalar("rate", 59.94);
    writer.addString("gender", "female");
    writer.add("empty", cube.data(), {0});
    writer.save(path, compress);
  }
  const int status = runPython(dir, R"(
import numpy as np, sys
for name in ('stored', 'deflated'):
    d = np.load(sys.argv[0].rsplit('/', 1)[0] + '/' + name + '.npz')
    assert sorted(d.files) == ['cube', 'empty', 'gender', 'ints', 'rate'], d.files
    assert d['cube'].dtype == np.float64 and d['cube'].shape == (2, 2, 2)
    assert np.array_equal(d['cube'].ravel(), [0.5, 1, 2, 3, 4, 5, 6, 7])
    assert d['ints'].dtype == np.int64 and d['ints'].shape == (2, 3)
    assert d['ints'][0, 0] == -1 and d['ints'][1, 2] == 4
    assert d['rate'].shape == () and float(d['rate']) == 59.94
    assert str(d['gender']) == 'female' and d['gender'].dtype == np.dtype('<U6')
    assert d['empty'].shape == (0,)
)");
  EXPECT_EQ(status, 0) << "numpy could not read the archives (see stderr)";
}

TEST(NpzNumpy, ReadsWhatNumpyWrites) {
  if (!haveNumpy()) GTEST_SKIP() << "/usr/bin/python3 with numpy not available";
  const std::string dir = test::freshTempDir("npz_numpy_writes");
  const int status = runPython(dir, R"(
import numpy as np, sys
d = sys.argv[0].rsplit('/', 1)[0]
a = np.arange(24, dtype=np.float64).reshape(2, 3, 4) / 8
arrays = dict(a=a, f32=a.astype(np.float32), fort=np.asfortranarray(a), i4=np.arange(6, dtype=np.int32).reshape(2, 3),
              u4=np.array([4294967295, 1], dtype=np.uint32), b=np.array([True, False]),
              gender=np.array('male'), rate=np.array(120.0), sb=np.array(b'female'))
np.savez(d + '/plain.npz', **arrays)
np.savez_compressed(d + '/compressed.npz', **arrays)
)");
  ASSERT_EQ(status, 0);
  for (const char* name : {"/plain.npz", "/compressed.npz"}) {
    const NpzFile file(dir + name);
    const std::vector<double> a = file.doubles("a", {2, 3, 4});
    for (int k = 0; k < 24; ++k) EXPECT_EQ(a[size_t(k)], k / 8.0);
    EXPECT_EQ(file.doubles("f32", {2, 3, 4}), a);
    EXPECT_EQ(file.doubles("fort", {2, 3, 4}), a);
    EXPECT_EQ(file.integers("i4", {2, 3}), (std::vector<int64_t>{0, 1, 2, 3, 4, 5}));
    EXPECT_EQ(file.integers("u4", {2}), (std::vector<int64_t>{-1, 1}));
    EXPECT_EQ(file.integers("b", {2}), (std::vector<int64_t>{1, 0}));
    EXPECT_EQ(file.string("gender"), "male");
    EXPECT_EQ(file.string("sb"), "female");
    EXPECT_EQ(file.scalar("rate"), 120.0);
  }
}

}  // namespace
}  // namespace flsh::io
