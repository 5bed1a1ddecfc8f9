// Hostile material files (issue 23): a FIFO at the path blocked MaterialModel::load forever (an
// ifstream opens a FIFO and waits for a writer), and 200 000 nested '[' overflowed the stack.
// Both are now InputErrors naming the file, like the scene-file reader's.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <filesystem>
#include <fstream>

#include "flsh/core/error.h"
#include "flsh/format/input_file.h"
#include "flsh/volume/materials.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::messageOf;
using ::testing::HasSubstr;
using ::testing::Not;

/// The default material text with the value of "format" replaced by `value`.
std::string withFormatValue(const std::string& value) {
  std::string text = MaterialModel::defaults(10).canonicalText();
  const std::string from = "\"format\": \"flsh-materials\"";
  const size_t at = text.find(from);
  EXPECT_NE(at, std::string::npos);
  if (at != std::string::npos) text.replace(at, from.size(), "\"format\": " + value);
  return text;
}

std::string nested(size_t depth) { return std::string(depth, '[') + std::string(depth, ']'); }

std::string writeFile(const std::string& dir, const std::string& name, const std::string& text) {
  const std::string path = dir + "/" + name;
  std::ofstream(path, std::ios::binary) << text;
  return path;
}

TEST(MaterialModelInput, AFifoIsRefusedWithoutBlocking) {
  // Before the fix, load() opened the FIFO with an ifstream and waited for a writer forever.
  const std::string fifo = test::freshTempDir("materials_fifo") + "/materials.json";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  EXPECT_THAT(messageOf<InputError>([&] { MaterialModel::load(fifo, 10); }),
              HasSubstr(fifo + ": is a FIFO (named pipe), expected a JSON material file"));
}

TEST(MaterialModelInput, ADirectoryIsRefusedAsADirectory) {
  // Before the fix, the ifstream opened the directory and the read failed silently: the message
  // was "not valid JSON" about an empty text.
  const std::string dir = test::freshTempDir("materials_dir") + "/materials.json";
  std::filesystem::create_directory(dir);
  EXPECT_THAT(messageOf<InputError>([&] { MaterialModel::load(dir, 10); }),
              HasSubstr(dir + ": is a directory, expected a JSON material file"));
}

TEST(MaterialModelInput, DeeplyNestedJsonIsRefusedBeforeParsing) {
  // 200 000 nested arrays: as the whole file, and as the value of "format" (which the message
  // about a wrong format printed with dump(), recursing once per level).
  const std::string dir = test::freshTempDir("materials_deep");
  for (const std::string& text : {nested(200000), withFormatValue(nested(200000)),
                                  withFormatValue(std::string(200000, '{') + "\"a\": 1"),
                                  withFormatValue("[" + std::string(200000, '[') + "1")}) {
    const std::string path = writeFile(dir, "deep.json", text);
    const std::string message = messageOf<InputError>([&] { MaterialModel::load(path, 10); });
    EXPECT_THAT(message, HasSubstr(path + ": JSON nested deeper than 64 levels at byte "));
    EXPECT_THAT(message, HasSubstr("material files nest 5 levels"));
    // And from text, named by its origin.
    EXPECT_THAT(messageOf<InputError>([&] { MaterialModel::fromText(text, 10, "deep text"); }),
                HasSubstr("deep text: JSON nested deeper than 64 levels"));
  }
}

TEST(MaterialModelInput, NestingUpToTheBoundReachesTheOrdinaryChecks) {
  // 64 levels in all (the top-level object and 63 arrays) is allowed: the file is then refused
  // for what it says, a wrong format, the message printing the value.
  const std::string dir = test::freshTempDir("materials_depth_64");
  std::string path = writeFile(dir, "ok_depth.json", withFormatValue(nested(63)));
  std::string message = messageOf<InputError>([&] { MaterialModel::load(path, 10); });
  EXPECT_THAT(message, HasSubstr(path + ": format: expected \"flsh-materials\""));
  EXPECT_THAT(message, Not(HasSubstr("nested deeper")));
  // One more level is refused, at the byte of the 65th opening bracket.
  path = writeFile(dir, "too_deep.json", withFormatValue(nested(64)));
  message = messageOf<InputError>([&] { MaterialModel::load(path, 10); });
  EXPECT_THAT(message, HasSubstr(path + ": JSON nested deeper than 64 levels"));
  // Brackets inside strings do not count.
  path = writeFile(dir, "string.json", withFormatValue("\"" + std::string(1000, '[') + "\""));
  message = messageOf<InputError>([&] { MaterialModel::load(path, 10); });
  EXPECT_THAT(message, HasSubstr(path + ": format: expected \"flsh-materials\""));
}

TEST(MaterialModelInput, AMissingFileIsAFileErrorNamingIt) {
  const std::string missing = test::freshTempDir("materials_missing_input") + "/none.json";
  EXPECT_THAT(messageOf<FileError>([&] { MaterialModel::load(missing, 10); }),
              HasSubstr(missing + ": no such file"));
}

}  // namespace
}  // namespace flsh
