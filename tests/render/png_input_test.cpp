// Hostile inputs of readPng (issue 23): a FIFO at the path blocked fopen() forever, and a header
// announcing more pixels than the file holds made the reader allocate them (30 GB for a 100 000
// × 100 000 header) before libpng noticed the missing data. Both are InputErrors naming the file.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>

#include "flsh/core/error.h"
#include "flsh/render/render.h"
#include "support/test_support.h"

namespace flsh::render {
namespace {

using test::messageOf;
using ::testing::HasSubstr;

Image smallImage() {
  Image image;
  image.width = 5;
  image.height = 4;
  image.rgb.assign(5 * 4 * 3, 0);
  for (size_t k = 0; k < image.rgb.size(); ++k) image.rgb[k] = uint8_t(k * 7);
  return image;
}

std::string readBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

/// PNG's chunk CRC (CRC-32, polynomial 0xedb88320) of `bytes`.
uint32_t crc32(const std::string& bytes) {
  uint32_t crc = 0xffffffffu;
  for (const char c : bytes) {
    crc ^= uint8_t(c);
    for (int bit = 0; bit < 8; ++bit) crc = (crc >> 1) ^ (0xedb88320u & (0u - (crc & 1u)));
  }
  return ~crc;
}

void putBigEndian(std::string& bytes, size_t at, uint32_t value) {
  for (int k = 0; k < 4; ++k) bytes[at + k] = char((value >> (24 - 8 * k)) & 0xff);
}

TEST(PngInput, AFifoIsRefusedWithoutBlocking) {
  // Before the fix, fopen() on the FIFO waited for a writer forever.
  const std::string fifo = test::freshTempDir("png_fifo") + "/image.png";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  EXPECT_THAT(messageOf<InputError>([&] { readPng(fifo); }),
              HasSubstr(fifo + ": is a FIFO (named pipe), expected a PNG file"));
}

TEST(PngInput, ADirectoryIsRefusedAsADirectory) {
  // Before the fix, the directory opened and the signature read failed: "not a PNG file".
  const std::string dir = test::freshTempDir("png_dir") + "/image.png";
  std::filesystem::create_directory(dir);
  EXPECT_THAT(messageOf<InputError>([&] { readPng(dir); }),
              HasSubstr(dir + ": is a directory, expected a PNG file"));
}

TEST(PngInput, MissingShortAndCutFilesNameThePath) {
  const std::string dir = test::freshTempDir("png_short");
  EXPECT_THAT(messageOf<FileError>([&] { readPng(dir + "/missing.png"); }),
              HasSubstr(dir + "/missing.png: no such file"));
  writePng(dir + "/whole.png", smallImage());
  const std::string whole = readBytes(dir + "/whole.png");
  for (size_t size : {size_t(0), size_t(5), size_t(8), size_t(20), whole.size() - 5}) {
    const std::string path = dir + "/cut" + std::to_string(size) + ".png";
    std::ofstream(path, std::ios::binary) << whole.substr(0, size);
    EXPECT_THAT(messageOf<InputError>([&] { readPng(path); }), HasSubstr("readPng('" + path))
        << size;
  }
  EXPECT_EQ(readPng(dir + "/whole.png").rgb, smallImage().rgb);
}

TEST(PngInput, AHeaderAnnouncingMorePixelsThanTheFileHoldsIsRefusedBeforeAllocating) {
  const std::string dir = test::freshTempDir("png_huge_header");
  writePng(dir + "/small.png", smallImage());
  std::string bytes = readBytes(dir + "/small.png");
  // The IHDR chunk: length at 8, "IHDR" at 12, width at 16, height at 20, CRC at 29.
  ASSERT_EQ(bytes.substr(12, 4), "IHDR");
  putBigEndian(bytes, 16, 100000);
  putBigEndian(bytes, 20, 100000);
  putBigEndian(bytes, 29, crc32(bytes.substr(12, 17)));
  const std::string path = dir + "/huge.png";
  std::ofstream(path, std::ios::binary) << bytes;
  EXPECT_THAT(messageOf<InputError>([&] { readPng(path); }),
              HasSubstr("readPng('" + path + "'): header announces 100000 × 100000 pixels, " +
                        "more than a file of " + std::to_string(bytes.size()) + " bytes can hold"));
  // The same header with a correct CRC but the original size reads again (the CRC is right).
  putBigEndian(bytes, 16, 5);
  putBigEndian(bytes, 20, 4);
  putBigEndian(bytes, 29, crc32(bytes.substr(12, 17)));
  std::ofstream(path, std::ios::binary) << bytes;
  EXPECT_EQ(readPng(path).rgb, smallImage().rgb);
}

}  // namespace
}  // namespace flsh::render
