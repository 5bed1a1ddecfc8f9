// Crafted `.npy` headers and zip entries: every one a clean InputError naming the file, the key
// and the shape, never a crash, a hang or a huge allocation (issue 23).
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cstring>

#include "flsh/body/motion.h"
#include "flsh/core/error.h"
#include "flsh/format/npz.h"
#include "format/raw_npz.h"
#include "support/test_support.h"

namespace flsh::io {
namespace {

using test::messageOf;
using test::npyBytes;
using test::npyOf;
using test::RawMember;
using ::testing::HasSubstr;

// 2^48 × 2^14 = 2^62 elements: × 4 bytes wraps to 0 modulo 2^64, so an empty data section
// passed the size check; the Fortran transpose then wrote 2^62 items into an empty buffer.
const std::string kWrappingShape = "(281474976710656, 16384)";

/// A valid motion (read by loadMotion) plus one hostile member `junk` that nothing reads.
std::string motionWithJunk(const std::string& name, const std::vector<uint8_t>& junk,
                           bool compress = false) {
  const std::string path = test::freshTempDir("npy_format") + "/" + name + ".npz";
  const std::vector<double> poses(2 * 72, 0.0), trans(2 * 3, 0.0), fps = {30.0};
  test::writeRawZip(path,
                    {{"poses.npy", npyOf("<f8", "(2, 72)", poses)},
                     {"trans.npy", npyOf("<f8", "(2, 3)", trans)},
                     {"mocap_framerate.npy", npyOf("<f8", "()", fps)},
                     {"junk.npy", junk}},
                    compress);
  return path;
}

struct HostileHeader {
  const char* name;
  const char* descr;
  bool fortran;
  const char* expected;
};

class NpyHostileHeaders : public ::testing::TestWithParam<HostileHeader> {};

TEST_P(NpyHostileHeaders, AreInputErrorsNamingFileKeyAndShape) {
  const HostileHeader& c = GetParam();
  const std::string path =
      motionWithJunk(c.name, npyBytes(c.descr, kWrappingShape, nullptr, 0, c.fortran));
  // Every reader goes through NpzFile: the key nobody asks for spoils the archive cleanly.
  for (const std::string& message : {messageOf<InputError>([&] { NpzFile{path}; }),
                                     messageOf<InputError>([&] { loadMotion(path); })}) {
    EXPECT_THAT(message, HasSubstr(path + ": key 'junk'"));
    EXPECT_THAT(message, HasSubstr("shape (281474976710656, 16384)"));
    EXPECT_THAT(message, HasSubstr(c.expected));
  }
}

INSTANTIATE_TEST_SUITE_P(
    ByteCountOverflowAndZeroByteItems, NpyHostileHeaders,
    ::testing::Values(HostileHeader{"overflow_c", "<f4", false, "needs more than 2^63 bytes"},
                      HostileHeader{"overflow_fortran", "<f4", true, "needs more than 2^63 bytes"},
                      HostileHeader{"overflow_f8", "<f8", true, "needs more than 2^63 bytes"},
                      HostileHeader{"zero_unicode", "<U0", true, "zero-byte items"},
                      HostileHeader{"zero_bytes", "|S0", true, "zero-byte items"},
                      HostileHeader{"zero_bytes_c", "|S0", false, "zero-byte items"}),
    [](const auto& info) { return std::string(info.param.name); });

TEST(NpyFormat, ShapesWhoseElementCountOverflowsAreRefused) {
  // 2^48 · 2^48: the element count itself overflows (also for dtypes flsh does not read).
  for (const char* descr : {"<f8", "|O"}) {
    const std::string path =
        motionWithJunk(std::string("count_") + (descr[1] == 'O' ? "object" : "f8"),
                       npyBytes(descr, "(281474976710656, 281474976710656)", nullptr, 0));
    const std::string message = messageOf<InputError>([&] { NpzFile{path}; });
    EXPECT_THAT(message, HasSubstr(path + ": key 'junk': shape (281474976710656, "
                                          "281474976710656) is too large"));
  }
}

TEST(NpyFormat, SmallZeroByteItemArraysStillRead) {
  // numpy can write '<U0' arrays (all strings empty): no data bytes, and nothing to transpose.
  const std::string path = motionWithJunk("small_u0", npyBytes("<U0", "(3, 2)", nullptr, 0, true));
  const NpzFile file(path);
  EXPECT_EQ(file.raw("junk").shape, (std::vector<long>{3, 2}));
  EXPECT_TRUE(file.raw("junk").bytes.empty());
  EXPECT_EQ(loadMotion(path).poses.rows(), 2);
}

TEST(NpyFormat, MalformedHeaderMessagesAreCutShort) {
  // A 60 kB header of garbage is echoed in 200 characters, not all of it.
  std::vector<uint8_t> junk = {0x93, 'N', 'U', 'M', 'P', 'Y', 1, 0, 0x60, 0xEA};
  junk.push_back('{');
  junk.resize(10 + 0xEA60, 'x');
  const std::string path = motionWithJunk("long_header", junk);
  const std::string message = messageOf<InputError>([&] { NpzFile{path}; });
  EXPECT_THAT(message, HasSubstr(path + ": key 'junk': malformed .npy header"));
  EXPECT_LT(message.size(), 600u);
}

/// Sets the uncompressed size of every member in the local and central zip headers.
void claimUncompressedSize(std::vector<uint8_t>& zip, uint32_t size) {
  for (size_t k = 0; k + 30 <= zip.size(); ++k) {
    if (zip[k] != 'P' || zip[k + 1] != 'K') continue;
    if (zip[k + 2] == 3 && zip[k + 3] == 4) std::memcpy(&zip[k + 22], &size, 4);  // local
    if (zip[k + 2] == 1 && zip[k + 3] == 2) std::memcpy(&zip[k + 24], &size, 4);  // central
  }
}

TEST(NpyFormat, ZipEntryClaimingAHugeSizeIsCheckedAgainstTheHeaderBeforeReading) {
  // A deflated member whose zip entry announces 4 GB: the buffer grows with the data inflated,
  // and the .npy header (800 data bytes) contradicts the claim as soon as it is read.
  const std::vector<double> values(100, 1.0);
  const std::string path = motionWithJunk("huge_claim", npyOf("<f8", "(100,)", values), true);
  std::vector<uint8_t> bytes = test::readFileBytes(path);
  claimUncompressedSize(bytes, 0xFFFFFF00u);
  test::writeFileBytes(path, bytes);
  const std::string message = messageOf<InputError>([&] { NpzFile{path}; });
  EXPECT_THAT(message, HasSubstr(path + ": key '"));
  EXPECT_THAT(message, HasSubstr("does not match the header"));
}

TEST(NpyFormat, ArchivesReadFromMemoryLikeFromFiles) {
  const std::vector<double> values = {1, 2, 3};
  const std::string path = motionWithJunk("memory", npyOf("<f8", "(3,)", values), true);
  const NpzFile file = NpzFile::fromBytes(test::readFileBytes(path), "in-memory");
  EXPECT_EQ(file.path(), "in-memory");
  EXPECT_EQ(file.vector("junk", 3)[2], 3.0);
  const std::string message = messageOf<InputError>([&] {
    NpzFile::fromBytes(std::vector<uint8_t>{'P', 'K', 0, 0}, "bytes");
  });
  EXPECT_THAT(message, HasSubstr("bytes: "));
}

}  // namespace
}  // namespace flsh::io
