// PNG files through libpng. libpng reports errors by longjmp, so each libpng call sequence
// lives in a function that owns no C++ objects with destructors; the callers turn the error
// text it leaves behind into exceptions.
#include <png.h>

#include <cerrno>
#include <csetjmp>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "flsh/core/error.h"
#include "flsh/format/atomic_file.h"
#include "flsh/format/input_file.h"
#include "flsh/render/render.h"

namespace flsh::render {
namespace {

struct PngContext {
  char message[512] = {0};
};

void pngError(png_structp png, png_const_charp text) {
  auto* context = static_cast<PngContext*>(png_get_error_ptr(png));
  std::snprintf(context->message, sizeof(context->message), "%s", text ? text : "libpng error");
  longjmp(png_jmpbuf(png), 1);
}

void pngWarning(png_structp, png_const_charp) {}

// Writes `rows` (height pointers to width·3 bytes) to an open file. Returns false with the
// reason in context.message on failure.
bool writePngRows(FILE* file, int width, int height, png_bytep* rows, PngContext& context) {
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, &context, pngError, pngWarning);
  if (!png) {
    std::snprintf(context.message, sizeof(context.message), "cannot create the PNG writer");
    return false;
  }
  png_infop info = png_create_info_struct(png);
  if (!info) {
    png_destroy_write_struct(&png, nullptr);
    std::snprintf(context.message, sizeof(context.message), "cannot create the PNG info");
    return false;
  }
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    return false;
  }
  png_init_io(png, file);
  png_set_IHDR(png, info, png_uint_32(width), png_uint_32(height), 8, PNG_COLOR_TYPE_RGB,
               PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  png_write_image(png, rows);
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  return true;
}

// A PNG file's bytes in memory, read by libpng through pngReadBytes.
struct PngBytes {
  const uint8_t* data;
  size_t size, position;
};

void pngReadBytes(png_structp png, png_bytep out, size_t count) {
  auto* bytes = static_cast<PngBytes*>(png_get_io_ptr(png));
  if (count > bytes->size - bytes->position) png_error(png, "unexpected end of file");
  std::memcpy(out, bytes->data + bytes->position, count);
  bytes->position += count;
}

// Reads the header and sets up the conversion of any 8/16-bit gray, palette, RGB or RGBA
// PNG to 8-bit RGB.
bool readPngHeader(png_structp png, png_infop info, PngBytes* bytes, png_uint_32& width,
                   png_uint_32& height, size_t& row_bytes) {
  if (setjmp(png_jmpbuf(png))) return false;
  png_set_read_fn(png, bytes, pngReadBytes);
  png_read_info(png, info);
  png_set_expand(png);
  png_set_strip_16(png);
  png_set_gray_to_rgb(png);
  png_set_strip_alpha(png);
  png_set_interlace_handling(png);
  png_read_update_info(png, info);
  width = png_get_image_width(png, info);
  height = png_get_image_height(png, info);
  row_bytes = png_get_rowbytes(png, info);
  return true;
}

bool readPngRows(png_structp png, png_infop info, png_bytep* rows) {
  if (setjmp(png_jmpbuf(png))) return false;
  png_read_image(png, rows);
  png_read_end(png, nullptr);
  return true;
}

}  // namespace

void writePng(const std::string& path, const Image& image) {
  if (image.width <= 0 || image.height <= 0 ||
      image.rgb.size() != size_t(image.width) * size_t(image.height) * 3) {
    throw InputError("writePng('" + path + "'): argument image is " + std::to_string(image.width) +
                     " × " + std::to_string(image.height) + " with " +
                     std::to_string(image.rgb.size()) +
                     " bytes, expected a positive size and width · height · 3 bytes");
  }
  io::AtomicPath target(path);  // throws FileError if the directory cannot be created
  FILE* file = std::fopen(target.tempPath().c_str(), "wb");
  if (!file) {
    throw FileError("writePng: cannot open '" + target.tempPath() + "' for writing (target '" +
                    path + "'): " + std::strerror(errno));
  }
  std::vector<png_bytep> rows(image.height);
  for (int y = 0; y < image.height; ++y) {
    rows[y] = const_cast<png_bytep>(image.pixel(0, y));
  }
  PngContext context;
  const bool written = writePngRows(file, image.width, image.height, rows.data(), context);
  const bool flushed = std::fflush(file) == 0 && !std::ferror(file);
  const bool closed = std::fclose(file) == 0;
  if (!written) throw FileError("writePng('" + path + "'): " + context.message);
  if (!flushed || !closed) {
    throw FileError("writePng('" + path + "'): write failed (disk full?): " + std::strerror(errno));
  }
  target.commit();
}

Image readPng(const std::string& path) {
  // Regular files only, read whole: a FIFO blocked fopen() forever; a directory or a device is
  // an InputError naming the path.
  const std::vector<uint8_t> file = io::readRegularFileBytes(path, "a PNG file");
  if (file.size() < 8 || png_sig_cmp(file.data(), 0, 8) != 0) {
    throw InputError("readPng('" + path + "'): not a PNG file (bad signature)");
  }
  PngBytes bytes{file.data(), file.size(), 8};
  PngContext context;
  png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &context, pngError, pngWarning);
  if (!png) throw FileError("readPng('" + path + "'): cannot create the PNG reader");
  png_infop info = png_create_info_struct(png);
  if (!info) {
    png_destroy_read_struct(&png, nullptr, nullptr);
    throw FileError("readPng('" + path + "'): cannot create the PNG info");
  }
  png_set_sig_bytes(png, 8);
  png_uint_32 width = 0, height = 0;
  size_t row_bytes = 0;
  if (!readPngHeader(png, info, &bytes, width, height, row_bytes)) {
    png_destroy_read_struct(&png, &info, nullptr);
    throw InputError("readPng('" + path + "'): malformed PNG: " + context.message);
  }
  if (row_bytes != size_t(width) * 3) {
    png_destroy_read_struct(&png, &info, nullptr);
    throw InputError("readPng('" + path + "'): unexpected row size " + std::to_string(row_bytes) +
                     " bytes after conversion to RGB, expected " + std::to_string(width * 3));
  }
  // The pixels are allocated only if the file can hold them: its compressed data inflates to
  // at most 1032 times its size (deflate's limit), at least one bit per pixel, and the RGB
  // conversion makes at most 24 bits of one. A header announcing 100 000 × 100 000 pixels in a
  // file of a few bytes asked for 30 GB before libpng found the data missing.
  const double rgb_bytes = double(width) * double(height) * 3.0;
  const double most_bytes = 24.0 * 1032.0 * double(file.size()) + double(1 << 20);
  if (rgb_bytes > most_bytes) {
    png_destroy_read_struct(&png, &info, nullptr);
    throw InputError("readPng('" + path + "'): header announces " + std::to_string(width) + " × " +
                     std::to_string(height) + " pixels, more than a file of " +
                     std::to_string(file.size()) + " bytes can hold");
  }
  Image image;
  image.width = int(width);
  image.height = int(height);
  image.rgb.resize(size_t(width) * height * 3);
  std::vector<png_bytep> rows(height);
  for (png_uint_32 y = 0; y < height; ++y) rows[y] = image.pixel(0, int(y));
  const bool read = readPngRows(png, info, rows.data());
  png_destroy_read_struct(&png, &info, nullptr);
  if (!read) throw InputError("readPng('" + path + "'): malformed PNG: " + context.message);
  return image;
}

}  // namespace flsh::render
