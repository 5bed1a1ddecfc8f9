// numpy `.npz` reading and writing on top of libzip.
//
// Format references: the `.npy` format (numpy/lib/format.py, versions 1.0–3.0) and `.npz` =
// a zip archive with one member "KEY.npy" per array, stored or deflated.
#include "flsh/format/npz.h"

#include <zip.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <ctime>
#include <limits>

#include "flsh/core/error.h"
#include "flsh/format/atomic_file.h"
#include "flsh/format/input_file.h"
#include "npy_format.h"

#if !defined(__BYTE_ORDER__) || __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error \
    "flsh's npz code reads and writes little-endian data in place: a little-endian host is required"
#endif

namespace flsh::io {

namespace {

// ---------------------------------------------------------------------------------------------
// Reading the archive

std::string zipErrorText(zip_error_t* error) {
  const char* text = zip_error_strerror(error);
  return text ? text : "unknown libzip error";
}

std::string joinKeys(const std::map<std::string, NpyArray>& arrays) {
  std::string out;
  for (const auto& [key, array] : arrays) out += (out.empty() ? "" : ", ") + key;
  return out.empty() ? "none" : out;
}

std::string expectedShapeString(const std::vector<long>& shape) {
  std::string out = "(";
  for (size_t k = 0; k < shape.size(); ++k)
    out += (k ? ", " : "") + (shape[k] < 0 ? std::string("*") : std::to_string(shape[k]));
  if (shape.size() == 1) out += ",";
  return out + ")";
}

template <class T>
T load(const uint8_t* p) {
  T value;
  std::memcpy(&value, p, sizeof(T));
  return value;
}

/// Converts element `i` of a numeric array to double.
double elementAsDouble(const NpyArray& a, const DtypeInfo& d, long i) {
  const uint8_t* p = &a.bytes[size_t(i * d.itemsize)];
  switch (d.kind) {
    case 'f':
      return d.itemsize == 8 ? load<double>(p) : double(load<float>(p));
    case 'i':
      return d.itemsize == 8 ? double(load<int64_t>(p)) : double(load<int32_t>(p));
    case 'u':
      if (d.itemsize == 8) return double(load<uint64_t>(p));
      if (d.itemsize == 4) return double(load<uint32_t>(p));
      return double(*p);
    case 'b':
      return *p ? 1.0 : 0.0;
    default:
      return 0.0;
  }
}

/// Appends the UTF-8 encoding of code point `c`.
void appendUtf8(std::string& out, uint32_t c) {
  if (c < 0x80) {
    out.push_back(char(c));
  } else if (c < 0x800) {
    out.push_back(char(0xC0 | (c >> 6)));
    out.push_back(char(0x80 | (c & 0x3F)));
  } else if (c < 0x10000) {
    out.push_back(char(0xE0 | (c >> 12)));
    out.push_back(char(0x80 | ((c >> 6) & 0x3F)));
    out.push_back(char(0x80 | (c & 0x3F)));
  } else {
    out.push_back(char(0xF0 | (c >> 18)));
    out.push_back(char(0x80 | ((c >> 12) & 0x3F)));
    out.push_back(char(0x80 | ((c >> 6) & 0x3F)));
    out.push_back(char(0x80 | (c & 0x3F)));
  }
}

/// Decodes UTF-8 into code points (invalid bytes are taken as Latin-1 characters).
std::vector<uint32_t> decodeUtf8(const std::string& s) {
  std::vector<uint32_t> out;
  for (size_t i = 0; i < s.size();) {
    const auto b = static_cast<unsigned char>(s[i]);
    int extra = b >= 0xF0 ? 3 : b >= 0xE0 ? 2 : b >= 0xC0 ? 1 : 0;
    uint32_t c = extra == 3 ? (b & 0x07) : extra == 2 ? (b & 0x0F) : extra == 1 ? (b & 0x1F) : b;
    bool valid = i + size_t(extra) < s.size();
    for (int k = 1; valid && k <= extra; ++k) {
      const auto cont = static_cast<unsigned char>(s[i + k]);
      if ((cont & 0xC0) != 0x80) valid = false;
      c = (c << 6) | (cont & 0x3F);
    }
    if (!valid || (b >= 0x80 && extra == 0)) {
      out.push_back(b);
      ++i;
    } else {
      out.push_back(c);
      i += size_t(extra) + 1;
    }
  }
  return out;
}

/// Reads member `index` of `archive`, which its zip entry announces as `size` bytes and which
/// can inflate to at most `inflatable` bytes (deflate expands at most ~1032×). Nothing is
/// allocated on the announcement alone: the first MB is read, the .npy header in it must promise
/// exactly `size` bytes, and only then does the buffer take min(size, inflatable) (before that
/// it grows with the data, for headers over a MB). Errors are InputErrors for the caller to
/// prefix with the file and key.
std::vector<uint8_t> readMember(zip_t* archive, zip_uint64_t index, zip_uint64_t size,
                                zip_uint64_t inflatable) {
  zip_file_t* file = zip_fopen_index(archive, index, 0);
  if (!file) throw InputError(std::string("cannot open member: ") + zip_strerror(archive));
  struct Closer {
    zip_file_t* file;
    ~Closer() { zip_fclose(file); }
  } closer{file};
  auto corrupt = [&]() {
    throw InputError(std::string("corrupt member (") + zip_file_strerror(file) + ")");
  };
  constexpr size_t kFirstChunk = size_t(1) << 20;
  std::vector<uint8_t> blob(size_t(std::min<zip_uint64_t>(size, kFirstChunk)));
  size_t filled = 0;
  bool header_checked = false;
  while (true) {
    if (filled == blob.size()) {
      if (filled >= size) {  // all announced bytes are in: anything more is corruption
        uint8_t extra[256];
        const zip_int64_t got = zip_fread(file, extra, sizeof(extra));
        if (got < 0) corrupt();
        if (got > 0)
          throw InputError("corrupt member (more data than the announced " + std::to_string(size) +
                           " bytes)");
        break;
      }
      const zip_uint64_t grown = header_checked ? std::max<zip_uint64_t>(2 * filled, inflatable)
                                                : 2 * zip_uint64_t(filled);
      blob.resize(size_t(std::min<zip_uint64_t>(size, grown)));
    }
    const zip_int64_t got = zip_fread(file, blob.data() + filled, blob.size() - filled);
    if (got < 0) corrupt();
    if (got == 0) break;
    filled += size_t(got);
    NpyLayout layout;
    if (!header_checked && parseNpyLayout(blob.data(), filled, size_t(size), layout)) {
      header_checked = true;
      const size_t promised = layout.data_start + layout.data_bytes;
      if (layout.dtype.supported && promised != size)
        throw InputError("data size " + std::to_string(size - layout.data_start) +
                         " bytes does not match the header (" + layout.header.descr + " " +
                         shapeString(layout.header.shape) + " needs " +
                         std::to_string(layout.data_bytes) + " bytes)");
    }
  }
  blob.resize(filled);
  if (blob.size() != size)
    throw InputError("truncated member (" + std::to_string(blob.size()) + " of " +
                     std::to_string(size) + " bytes)");
  return blob;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// NpyArray

long NpyArray::size() const {
  long n = 1;
  for (long d : shape) n *= d;
  return n;
}

bool NpyArray::isFloat() const { return dtype.size() >= 2 && dtype[1] == 'f'; }

bool NpyArray::isInteger() const {
  return dtype.size() >= 2 && (dtype[1] == 'i' || dtype[1] == 'u' || dtype[1] == 'b');
}

// ---------------------------------------------------------------------------------------------
// NpzFile

NpzFile::NpzFile(const std::string& path) : path_(path) {
  std::vector<uint8_t> bytes = readRegularFileBytes(path, "an .npz file");
  readArchive(bytes);
}

NpzFile NpzFile::fromBytes(std::vector<uint8_t> bytes, const std::string& origin) {
  NpzFile file;
  file.path_ = origin;
  file.readArchive(bytes);
  return file;
}

void NpzFile::readArchive(std::vector<uint8_t>& bytes) {
  const std::string& path = path_;
  // libzip would open an empty source as an empty archive; numpy rejects it too.
  if (bytes.empty()) throw InputError(path + ": empty file, not an .npz archive");
  zip_error_t error;
  zip_error_init(&error);
  zip_source_t* source = zip_source_buffer_create(bytes.data(), bytes.size(), 0, &error);
  if (!source) {
    const std::string text = zipErrorText(&error);
    zip_error_fini(&error);
    throw FileError(path + ": cannot read: " + text);
  }
  zip_t* archive = zip_open_from_source(source, ZIP_RDONLY | ZIP_CHECKCONS, &error);
  if (!archive) {
    zip_source_free(source);
    const int code = zip_error_code_zip(&error);
    const std::string text = zipErrorText(&error);
    zip_error_fini(&error);
    if (code == ZIP_ER_NOZIP)
      throw InputError(path + ": not an .npz file (not a zip archive, or truncated; " +
                       std::to_string(bytes.size()) + " bytes)");
    throw InputError(path + ": corrupt or truncated .npz archive: " + text);
  }
  zip_error_fini(&error);
  // Closes the archive on every exit path (it owns `source`).
  struct Closer {
    zip_t* archive;
    ~Closer() { zip_discard(archive); }
  } closer{archive};

  const zip_int64_t members = zip_get_num_entries(archive, 0);
  for (zip_int64_t index = 0; index < members; ++index) {
    const char* raw_name = zip_get_name(archive, zip_uint64_t(index), ZIP_FL_ENC_GUESS);
    if (!raw_name) throw InputError(path + ": corrupt member name in zip archive");
    const std::string name(raw_name);
    // numpy names each array "KEY.npy"; other members (directories, notes) are not arrays.
    if (name.size() <= 4 || name.compare(name.size() - 4, 4, ".npy") != 0) continue;
    const std::string key = name.substr(0, name.size() - 4);
    const std::string where = path + ": key '" + key + "'";

    zip_stat_t stat;
    zip_stat_init(&stat);
    if (zip_stat_index(archive, zip_uint64_t(index), 0, &stat) != 0 ||
        !(stat.valid & ZIP_STAT_SIZE))
      throw InputError(where + ": cannot read member size: " + zip_strerror(archive));
    try {
      // What the member's compressed bytes (at most the archive's) could inflate to.
      zip_uint64_t compressed = zip_uint64_t(bytes.size());
      if ((stat.valid & ZIP_STAT_COMP_SIZE) && stat.comp_size < compressed)
        compressed = stat.comp_size;
      const zip_uint64_t inflatable = compressed * 1032 + 4096;
      arrays_[key] = parseNpy(readMember(archive, zip_uint64_t(index), stat.size, inflatable));
    } catch (const InputError& e) {
      throw InputError(where + ": " + e.what());
    }
  }
}

std::vector<std::string> NpzFile::keys() const {
  std::vector<std::string> out;
  for (const auto& [key, array] : arrays_) out.push_back(key);
  return out;
}

bool NpzFile::has(const std::string& key) const { return arrays_.count(key) > 0; }

const NpyArray& NpzFile::raw(const std::string& key) const {
  const auto it = arrays_.find(key);
  if (it == arrays_.end())
    throw InputError(path_ + ": missing key '" + key + "' (keys present: " + joinKeys(arrays_) +
                     ")");
  if (!parseDtype(it->second.dtype).supported)
    throw InputError(path_ + ": key '" + key + "': " + unsupportedDtypeMessage(it->second.dtype));
  return it->second;
}

namespace {
/// Throws InputError unless `actual` has the dimensions of `expected` (−1 = any extent).
void checkShape(const std::string& where, const std::vector<long>& actual,
                const std::vector<long>& expected) {
  bool match = actual.size() == expected.size();
  for (size_t k = 0; match && k < expected.size(); ++k)
    match = expected[k] < 0 || expected[k] == actual[k];
  if (!match)
    throw InputError(where + ": expected shape " + expectedShapeString(expected) + ", got " +
                     shapeString(actual));
}
}  // namespace

std::vector<double> NpzFile::doubles(const std::string& key, const std::vector<long>& shape) const {
  const NpyArray& a = raw(key);
  const std::string where = path_ + ": key '" + key + "'";
  if (!a.isFloat() && !a.isInteger())
    throw InputError(where + ": expected a numeric array, got dtype '" + a.dtype + "'");
  checkShape(where, a.shape, shape);
  const DtypeInfo d = parseDtype(a.dtype);
  const long n = a.size();
  std::vector<double> out(static_cast<size_t>(n));
  for (long i = 0; i < n; ++i) {
    out[size_t(i)] = elementAsDouble(a, d, i);
    if (!std::isfinite(out[size_t(i)]))
      throw InputError(where + ": contains NaN or Inf (first at flat index " + std::to_string(i) +
                       ")");
  }
  return out;
}

RowMatX NpzFile::matrix(const std::string& key, long rows, long cols) const {
  const std::vector<double> values = doubles(key, {rows, cols});
  const std::vector<long>& shape = arrays_.at(key).shape;
  return Eigen::Map<const RowMatX>(values.data(), shape[0], shape[1]);
}

VecX NpzFile::vector(const std::string& key, long size) const {
  const std::vector<double> values = doubles(key, {size});
  return Eigen::Map<const VecX>(values.data(), long(values.size()));
}

double NpzFile::scalar(const std::string& key) const {
  const NpyArray& a = raw(key);
  if (a.size() != 1)
    throw InputError(path_ + ": key '" + key + "': expected a scalar, got shape " +
                     shapeString(a.shape));
  return doubles(key, std::vector<long>(a.shape.size(), -1))[0];
}

std::vector<int64_t> NpzFile::integers(const std::string& key,
                                       const std::vector<long>& shape) const {
  const NpyArray& a = raw(key);
  const std::string where = path_ + ": key '" + key + "'";
  if (!a.isFloat() && !a.isInteger())
    throw InputError(where + ": expected an integer array, got dtype '" + a.dtype + "'");
  checkShape(where, a.shape, shape);
  const DtypeInfo d = parseDtype(a.dtype);
  const long n = a.size();
  std::vector<int64_t> out(static_cast<size_t>(n));
  for (long i = 0; i < n; ++i) {
    const uint8_t* p = &a.bytes[size_t(i * d.itemsize)];
    int64_t value = 0;
    if (d.kind == 'i') {
      value = d.itemsize == 8 ? load<int64_t>(p) : int64_t(load<int32_t>(p));
    } else if (d.kind == 'u' && d.itemsize == 8) {
      const uint64_t u = load<uint64_t>(p);
      // 2⁶⁴−1 is −1 stored unsigned (e.g. SMPL's root parent).
      if (u == std::numeric_limits<uint64_t>::max()) {
        value = -1;
      } else if (u > uint64_t(std::numeric_limits<int64_t>::max())) {
        throw InputError(where + ": value " + std::to_string(u) + " at flat index " +
                         std::to_string(i) + " does not fit a signed 64-bit integer");
      } else {
        value = int64_t(u);
      }
    } else if (d.kind == 'u' && d.itemsize == 4) {
      const uint32_t u = load<uint32_t>(p);
      value = u == std::numeric_limits<uint32_t>::max() ? -1 : int64_t(u);
    } else if (d.kind == 'u' || d.kind == 'b') {
      value = *p;
    } else {  // float holding integers
      const double x = elementAsDouble(a, d, i);
      if (!std::isfinite(x) || x != std::floor(x) || std::abs(x) > 9.0e15)
        throw InputError(where + ": expected integer values, got " + std::to_string(x) +
                         " at flat index " + std::to_string(i) + " (dtype " + a.dtype + ")");
      value = int64_t(x);
    }
    out[size_t(i)] = value;
  }
  return out;
}

std::string NpzFile::string(const std::string& key) const {
  if (!has(key)) return "";
  const NpyArray& a = raw(key);
  const std::string where = path_ + ": key '" + key + "'";
  const DtypeInfo d = parseDtype(a.dtype);
  if (d.kind != 'U' && d.kind != 'S')
    throw InputError(where + ": expected a string, got dtype '" + a.dtype + "' of shape " +
                     shapeString(a.shape));
  if (a.size() != 1)
    throw InputError(where + ": expected a single string, got shape " + shapeString(a.shape));
  std::string out;
  if (d.kind == 'S') {
    out.assign(reinterpret_cast<const char*>(a.bytes.data()), a.bytes.size());
  } else {
    for (size_t k = 0; k + 4 <= a.bytes.size(); k += 4)
      appendUtf8(out, load<uint32_t>(&a.bytes[k]));
  }
  // numpy pads fixed-width strings with NULs.
  while (!out.empty() && out.back() == '\0') out.pop_back();
  return out;
}

// ---------------------------------------------------------------------------------------------
// NpzWriter

namespace {

void checkNewKey(const std::map<std::string, NpyArray>& arrays, const std::string& key) {
  if (key.empty()) throw InputError("NpzWriter: empty key");
  if (arrays.count(key)) throw InputError("NpzWriter: key '" + key + "' added twice");
}

NpyArray makeArray(const std::string& dtype, const void* data, size_t itemsize,
                   const std::vector<long>& shape) {
  NpyArray a;
  a.dtype = dtype;
  a.shape = shape;
  const long n = elementCount(shape);
  if (size_t(n) > std::numeric_limits<size_t>::max() / 2 / itemsize)
    throw InputError("NpzWriter: shape " + shapeString(shape) + " is too large");
  a.bytes.resize(size_t(n) * itemsize);
  if (n > 0) std::memcpy(a.bytes.data(), data, a.bytes.size());
  return a;
}

}  // namespace

void NpzWriter::add(const std::string& key, const double* data, const std::vector<long>& shape) {
  checkNewKey(arrays_, key);
  arrays_[key] = makeArray("<f8", data, sizeof(double), shape);
}

void NpzWriter::add(const std::string& key, const int64_t* data, const std::vector<long>& shape) {
  checkNewKey(arrays_, key);
  arrays_[key] = makeArray("<i8", data, sizeof(int64_t), shape);
}

void NpzWriter::add(const std::string& key, const Eigen::Ref<const RowMatX>& matrix) {
  const RowMatX contiguous = matrix;  // a Ref may have an outer stride
  add(key, contiguous.data(), {long(contiguous.rows()), long(contiguous.cols())});
}

void NpzWriter::add(const std::string& key, const Eigen::Ref<const VecX>& vector) {
  const VecX contiguous = vector;
  add(key, contiguous.data(), {long(contiguous.size())});
}

void NpzWriter::addScalar(const std::string& key, double value) { add(key, &value, {}); }

void NpzWriter::addString(const std::string& key, const std::string& value) {
  checkNewKey(arrays_, key);
  const std::vector<uint32_t> code_points = decodeUtf8(value);
  // numpy's dtype for "" is '<U1' (one NUL), not '<U0'.
  const size_t width = std::max<size_t>(1, code_points.size());
  NpyArray a;
  a.dtype = "<U" + std::to_string(width);
  a.bytes.assign(4 * width, 0);
  for (size_t k = 0; k < code_points.size(); ++k) std::memcpy(&a.bytes[4 * k], &code_points[k], 4);
  arrays_[key] = std::move(a);
}

void NpzWriter::save(const std::string& path, bool compress) const {
  if (arrays_.empty()) {
    // libzip writes no file for an empty archive: write the 22-byte end-of-central-directory
    // record of an empty zip by hand (np.savez of nothing produces the same).
    writeFileAtomically(path, [](std::ostream& out) {
      const char empty_zip[22] = {'P', 'K', 5, 6};
      out.write(empty_zip, sizeof(empty_zip));
    });
    return;
  }
  AtomicPath target(path);
  std::vector<std::vector<uint8_t>> blobs;  // must outlive zip_close (libzip reads them then)
  blobs.reserve(arrays_.size());
  int error_code = 0;
  zip_t* archive = zip_open(target.tempPath().c_str(), ZIP_CREATE | ZIP_TRUNCATE, &error_code);
  if (!archive) {
    zip_error_t error;
    zip_error_init_with_code(&error, error_code);
    const std::string text = zipErrorText(&error);
    zip_error_fini(&error);
    throw FileError("cannot write '" + path + "': " + text);
  }
  auto fail = [&](const std::string& what) {
    const std::string text = zip_strerror(archive);
    zip_discard(archive);
    throw FileError("cannot write '" + path + "': " + what + ": " + text);
  };
  for (const auto& [key, array] : arrays_) {
    blobs.push_back(serializeNpy(array));
    zip_source_t* source = zip_source_buffer(archive, blobs.back().data(), blobs.back().size(), 0);
    if (!source) fail("key '" + key + "'");
    const zip_int64_t index =
        zip_file_add(archive, (key + ".npy").c_str(), source, ZIP_FL_ENC_UTF_8 | ZIP_FL_OVERWRITE);
    if (index < 0) {
      zip_source_free(source);
      fail("key '" + key + "'");
    }
    if (zip_set_file_compression(archive, zip_uint64_t(index),
                                 compress ? ZIP_CM_DEFLATE : ZIP_CM_STORE, 0) != 0)
      fail("key '" + key + "': compression");
    // A fixed entry time (1980-01-02, the DOS epoch plus a day, whatever the time zone) instead
    // of the clock: the same arrays always give the same bytes (saves 2 s apart differed).
    if (zip_file_set_mtime(archive, zip_uint64_t(index), time_t(315619200), 0) != 0)
      fail("key '" + key + "': entry time");
  }
  if (zip_close(archive) != 0) fail("finishing the archive");
  target.commit();
}

}  // namespace flsh::io
