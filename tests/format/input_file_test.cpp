// Input paths that are not regular files: a FIFO blocked every reader forever (the open waits
// for a writer), a directory or device misbehaved. Each reader now refuses them with an
// InputError naming the path, before opening anything (issue 23).
#include "flsh/format/input_file.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <filesystem>
#include <fstream>

#include "flsh/body/motion.h"
#include "flsh/core/error.h"
#include "flsh/format/mesh_io.h"
#include "flsh/format/npz.h"
#include "flsh/io/scene_file.h"
#include "support/test_support.h"

namespace flsh::io {
namespace {

using test::messageOf;
using ::testing::HasSubstr;
namespace fs = std::filesystem;

struct Special {
  std::string path, kind;
};

/// A FIFO, a directory and a character device.
std::vector<Special> specialFiles(const std::string& name) {
  const std::string dir = test::freshTempDir(name);
  const std::string fifo = dir + "/input.fifo", sub = dir + "/input.dir";
  EXPECT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  fs::create_directory(sub);
  return {{fifo, "is a FIFO (named pipe)"},
          {sub, "is a directory"},
          {"/dev/null", "is a character device"}};
}

TEST(InputFile, RegularFilesAreReadWhole) {
  const std::string path = test::freshTempDir("input_file") + "/text.txt";
  std::ofstream(path, std::ios::binary) << std::string(100000, 'a') << "end";
  EXPECT_EQ(readRegularFileText(path, "a text").size(), 100003u);
  EXPECT_EQ(readRegularFileBytes(path, "a text").back(), 'd');
  EXPECT_EQ(nonRegularFileKind(path), "");
  EXPECT_THAT(messageOf<FileError>([&] { readRegularFileText(path + ".missing", "a text"); }),
              HasSubstr(path + ".missing: no such file"));
}

TEST(InputFile, FifosDirectoriesAndDevicesAreInputErrorsNamingThePath) {
  for (const Special& s : specialFiles("input_file_special")) {
    EXPECT_THAT(messageOf<InputError>([&] { readRegularFileText(s.path, "a text file"); }),
                HasSubstr(s.path + ": " + s.kind + ", expected a text file (a regular file)"));
  }
}

TEST(InputFile, EveryReaderRefusesThemWithoutBlocking) {
  for (const Special& s : specialFiles("input_file_readers")) {
    MatX3 V;
    MatX3i F;
    for (const std::string& message : {
             messageOf<InputError>([&] { NpzFile{s.path}; }),
             messageOf<InputError>([&] { loadMotion(s.path); }),
             messageOf<InputError>([&] { readMesh(s.path, V, F); }),
             messageOf<InputError>([&] { loadSceneFile(s.path); }),
         }) {
      EXPECT_THAT(message, HasSubstr(s.path + ": " + s.kind));
    }
  }
}

}  // namespace
}  // namespace flsh::io
