// numpy `.npz` reading and writing on top of libzip.
//
// Format references: the `.npy` format (numpy/lib/format.py, versions 1.0–3.0) and `.npz` =
// a zip archive with one member "KEY.npy" per array, stored or deflated.
#include "flsh/io/npz.h"

#include <zip.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

#include "flsh/core/error.h"
#include "flsh/io/atomic_file.h"

#if !defined(__BYTE_ORDER__) || __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error \
    "flsh's npz code reads and writes little-endian data in place: a little-endian host is required"
#endif

namespace flsh::io {

namespace {

const char kNpyMagic[] = "\x93NUMPY";
constexpr size_t kNpyMagicSize = 6;

// ---------------------------------------------------------------------------------------------
// dtypes

/// A dtype flsh understands: kind 'f' (float), 'i' (signed), 'u' (unsigned), 'b' (bool),
/// 'U' (UTF-32 string), 'S' (byte string); `itemsize` in bytes.
struct DtypeInfo {
  bool supported = false;
  char kind = 0;
  long itemsize = 0;
  std::string canonical;  ///< e.g. "<f8", "|u1", "<U6"
};

DtypeInfo parseDtype(const std::string& descr) {
  DtypeInfo info;
  if (descr.size() < 3) return info;
  char order = descr[0];
  const char kind = descr[1];
  long count = 0;
  for (size_t i = 2; i < descr.size(); ++i) {
    if (!std::isdigit(static_cast<unsigned char>(descr[i]))) return info;
    count = count * 10 + (descr[i] - '0');
    if (count > (1L << 30)) return info;
  }
  if (order == '=') order = '<';  // native order on a little-endian host
  auto accept = [&](long itemsize, const std::string& canonical) {
    info.supported = true;
    info.kind = kind;
    info.itemsize = itemsize;
    info.canonical = canonical;
  };
  const std::string bytes = std::to_string(count);
  switch (kind) {
    case 'f':
      if (order == '<' && (count == 8 || count == 4)) accept(count, "<f" + bytes);
      break;
    case 'i':
      if (order == '<' && (count == 8 || count == 4)) accept(count, "<i" + bytes);
      break;
    case 'u':
      if (order == '<' && (count == 8 || count == 4)) accept(count, "<u" + bytes);
      if (count == 1 && (order == '|' || order == '<')) accept(1, "|u1");
      break;
    case 'b':
      if (count == 1 && (order == '|' || order == '<')) accept(1, "|b1");
      break;
    case 'U':
      if (order == '<' || (order == '|' && count == 0)) accept(4 * count, "<U" + bytes);
      break;
    case 'S':
      if (order == '|' || order == '<') accept(count, "|S" + bytes);
      break;
    default:
      break;
  }
  return info;
}

std::string unsupportedDtypeMessage(const std::string& descr) {
  std::string msg = "unsupported dtype '" + descr +
                    "' (supported: <f8 <f4 <i8 <i4 <u8 <u4 |u1 |b1 and strings <U… |S…)";
  if (descr == "|O")
    msg +=
        "; object arrays hold pickled Python objects (e.g. scipy.sparse or chumpy arrays): "
        "convert an SMPL .pkl with tools/smpl_pkl_to_npz.py";
  return msg;
}

// ---------------------------------------------------------------------------------------------
// .npy header: a Python dict literal such as
//   {'descr': '<f8', 'fortran_order': False, 'shape': (6890, 3), }

struct NpyHeader {
  std::string descr;
  bool fortran_order = false;
  std::vector<long> shape;
};

class HeaderParser {
 public:
  explicit HeaderParser(const std::string& text) : s_(text) {}

  NpyHeader parse() {
    NpyHeader h;
    bool have_descr = false, have_order = false, have_shape = false;
    expect('{');
    while (true) {
      skipSpace();
      if (peek() == '}') break;
      const std::string key = parseString();
      expect(':');
      skipSpace();
      if (key == "descr") {
        if (peek() == '[') {
          skipBalanced();  // structured dtype: a list of fields
          h.descr = "structured";
        } else {
          h.descr = parseString();
        }
        have_descr = true;
      } else if (key == "fortran_order") {
        h.fortran_order = parseBool();
        have_order = true;
      } else if (key == "shape") {
        h.shape = parseShape();
        have_shape = true;
      } else {
        skipValue();
      }
      skipSpace();
      if (peek() == ',') {
        ++pos_;
        continue;
      }
      skipSpace();
      if (peek() != '}') fail("expected ',' or '}'");
    }
    if (!have_descr || !have_order || !have_shape)
      fail("missing one of the keys 'descr', 'fortran_order', 'shape'");
    return h;
  }

 private:
  [[noreturn]] void fail(const std::string& what) const {
    throw InputError("malformed .npy header (" + what + " at character " + std::to_string(pos_) +
                     "): " + s_);
  }
  char peek() const { return pos_ < s_.size() ? s_[pos_] : '\0'; }
  void skipSpace() {
    while (pos_ < s_.size() && std::isspace(static_cast<unsigned char>(s_[pos_]))) ++pos_;
  }
  void expect(char c) {
    skipSpace();
    if (peek() != c) fail(std::string("expected '") + c + "'");
    ++pos_;
  }
  std::string parseString() {
    skipSpace();
    const char quote = peek();
    if (quote != '\'' && quote != '"') fail("expected a string");
    const size_t end = s_.find(quote, pos_ + 1);
    if (end == std::string::npos) fail("unterminated string");
    std::string out = s_.substr(pos_ + 1, end - pos_ - 1);
    pos_ = end + 1;
    return out;
  }
  bool parseBool() {
    if (s_.compare(pos_, 4, "True") == 0) {
      pos_ += 4;
      return true;
    }
    if (s_.compare(pos_, 5, "False") == 0) {
      pos_ += 5;
      return false;
    }
    fail("expected True or False");
  }
  std::vector<long> parseShape() {
    expect('(');
    std::vector<long> shape;
    while (true) {
      skipSpace();
      if (peek() == ')') {
        ++pos_;
        break;
      }
      if (!std::isdigit(static_cast<unsigned char>(peek()))) fail("expected a dimension");
      long value = 0;
      while (std::isdigit(static_cast<unsigned char>(peek()))) {
        value = value * 10 + (s_[pos_++] - '0');
        if (value > (1L << 48)) fail("dimension too large");
      }
      if (peek() == 'L') ++pos_;  // Python 2 long literal, e.g. (6890L, 3L)
      shape.push_back(value);
      skipSpace();
      if (peek() == ',') {
        ++pos_;
      } else if (peek() != ')') {
        fail("expected ',' or ')' in shape");
      }
    }
    return shape;
  }
  void skipBalanced() {
    int depth = 0;
    do {
      const char c = peek();
      if (c == '\0') fail("unbalanced brackets");
      if (c == '\'' || c == '"') {
        parseString();
        continue;
      }
      if (c == '[' || c == '(' || c == '{') ++depth;
      if (c == ']' || c == ')' || c == '}') --depth;
      ++pos_;
    } while (depth > 0);
  }
  void skipValue() {
    const char c = peek();
    if (c == '\'' || c == '"') {
      parseString();
    } else if (c == '[' || c == '(' || c == '{') {
      skipBalanced();
    } else {
      while (pos_ < s_.size() && s_[pos_] != ',' && s_[pos_] != '}') ++pos_;
    }
  }

  const std::string& s_;
  size_t pos_ = 0;
};

long elementCount(const std::vector<long>& shape) {
  long n = 1;
  for (long d : shape) {
    if (d < 0) throw InputError("negative dimension in shape " + shapeString(shape));
    if (d != 0 && n > std::numeric_limits<long>::max() / d)
      throw InputError("shape " + shapeString(shape) + " is too large");
    n *= d;
  }
  return n;
}

/// Reorders Fortran-ordered (column-major) elements of `shape` into C (row-major) order.
std::vector<uint8_t> fortranToC(const std::vector<uint8_t>& in, const std::vector<long>& shape,
                                long itemsize) {
  const size_t ndim = shape.size();
  if (ndim < 2) return in;
  const long n = elementCount(shape);
  std::vector<uint8_t> out(in.size());
  std::vector<long> fstride(ndim);  // element strides of the Fortran layout
  long stride = 1;
  for (size_t k = 0; k < ndim; ++k) {
    fstride[k] = stride;
    stride *= shape[k];
  }
  std::vector<long> index(ndim, 0);  // C-order multi-index of element c
  long source = 0;
  for (long c = 0; c < n; ++c) {
    std::memcpy(&out[size_t(c * itemsize)], &in[size_t(source * itemsize)], size_t(itemsize));
    for (size_t k = ndim; k-- > 0;) {  // odometer increment, last axis fastest
      if (++index[k] < shape[k]) {
        source += fstride[k];
        break;
      }
      source -= fstride[k] * (shape[k] - 1);
      index[k] = 0;
    }
  }
  return out;
}

/// Parses one `.npy` blob. Unsupported dtypes are kept with empty bytes (reported on access).
/// The blob is consumed: its data bytes become the array's without a copy.
NpyArray parseNpy(std::vector<uint8_t>&& blob) {
  if (blob.size() < kNpyMagicSize + 4 || std::memcmp(blob.data(), kNpyMagic, kNpyMagicSize) != 0)
    throw InputError("not a .npy array (missing the \\x93NUMPY magic)");
  const int major = blob[6];
  size_t header_len = 0, header_start = 0;
  if (major == 1) {
    header_len = size_t(blob[8]) | (size_t(blob[9]) << 8);
    header_start = 10;
  } else if (major == 2 || major == 3) {
    if (blob.size() < 12) throw InputError("truncated .npy header");
    header_len = size_t(blob[8]) | (size_t(blob[9]) << 8) | (size_t(blob[10]) << 16) |
                 (size_t(blob[11]) << 24);
    header_start = 12;
  } else {
    throw InputError("unsupported .npy format version " + std::to_string(major) + "." +
                     std::to_string(int(blob[7])));
  }
  if (blob.size() < header_start + header_len)
    throw InputError("truncated .npy header (" + std::to_string(header_len) +
                     " header bytes announced, " + std::to_string(blob.size() - header_start) +
                     " present)");
  const std::string text(reinterpret_cast<const char*>(&blob[header_start]), header_len);
  const NpyHeader header = HeaderParser(text).parse();

  NpyArray array;
  array.shape = header.shape;
  const DtypeInfo dtype = parseDtype(header.descr);
  if (!dtype.supported) {
    array.dtype = header.descr;
    return array;
  }
  array.dtype = dtype.canonical;
  const long count = elementCount(header.shape);
  const size_t data_start = header_start + header_len;
  const size_t expected = size_t(count) * size_t(dtype.itemsize);
  const size_t actual = blob.size() - data_start;
  if (actual != expected)
    throw InputError("data size " + std::to_string(actual) + " bytes does not match the header (" +
                     header.descr + " " + shapeString(header.shape) + " needs " +
                     std::to_string(expected) + " bytes)");
  blob.erase(blob.begin(), blob.begin() + long(data_start));  // a move, not a second buffer
  array.bytes = std::move(blob);
  if (header.fortran_order) array.bytes = fortranToC(array.bytes, array.shape, dtype.itemsize);
  return array;
}

/// The `.npy` bytes of an array (format 1.0, header padded so the data starts 64-aligned).
std::vector<uint8_t> serializeNpy(const NpyArray& array) {
  std::ostringstream dict;
  dict << "{'descr': '" << array.dtype << "', 'fortran_order': False, 'shape': (";
  for (size_t k = 0; k < array.shape.size(); ++k) dict << (k ? ", " : "") << array.shape[k];
  if (array.shape.size() == 1) dict << ",";
  dict << "), }";
  std::string header = dict.str();
  const size_t prefix = kNpyMagicSize + 2 + 2;
  const size_t total = ((prefix + header.size() + 1 + 63) / 64) * 64;
  header.append(total - prefix - header.size() - 1, ' ');
  header.push_back('\n');
  if (header.size() > 65535)
    throw InputError("npz: .npy header of shape " + shapeString(array.shape) + " is too long");
  std::vector<uint8_t> out;
  out.reserve(total + array.bytes.size());
  out.insert(out.end(), kNpyMagic, kNpyMagic + kNpyMagicSize);
  out.push_back(1);
  out.push_back(0);
  out.push_back(uint8_t(header.size() & 0xff));
  out.push_back(uint8_t(header.size() >> 8));
  out.insert(out.end(), header.begin(), header.end());
  out.insert(out.end(), array.bytes.begin(), array.bytes.end());
  return out;
}

// ---------------------------------------------------------------------------------------------
// Reading the archive

std::vector<uint8_t> readWholeFile(const std::string& path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::file_status status = fs::status(path, ec);
  if (!fs::exists(status)) throw FileError(path + ": no such file");
  if (fs::is_directory(status)) throw FileError(path + ": is a directory, expected an .npz file");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw FileError(path + ": cannot open for reading");
  // One read of the announced size (byte-wise stream iteration costs ~3 ns per byte: 0.15 s
  // for a cached avatar), then whatever a growing file appended.
  const auto size = fs::file_size(path, ec);
  std::vector<uint8_t> bytes(ec ? 0 : size_t(size));
  in.read(reinterpret_cast<char*>(bytes.data()), std::streamsize(bytes.size()));
  bytes.resize(size_t(in.gcount()));
  if (!in.eof() && in.good()) {
    char chunk[1 << 16];
    while (in.read(chunk, sizeof(chunk)) || in.gcount() > 0)
      bytes.insert(bytes.end(), chunk, chunk + in.gcount());
  }
  if (in.bad()) throw FileError(path + ": read error");
  return bytes;
}

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
  std::vector<uint8_t> bytes = readWholeFile(path);
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
    zip_file_t* file = zip_fopen_index(archive, zip_uint64_t(index), 0);
    if (!file) throw InputError(where + ": cannot open member: " + zip_strerror(archive));
    // Trust the announced size only as far as the archive can hold it (stored members are at
    // most its size; deflate expands at most ~1000×), so a corrupt header cannot trigger a huge
    // allocation; read straight into the buffer, then make sure nothing follows.
    std::vector<uint8_t> blob;
    const zip_uint64_t plausible = zip_uint64_t(bytes.size()) * 1032 + 4096;
    blob.resize(size_t(std::min<zip_uint64_t>(stat.size, plausible)));
    size_t filled = 0;
    while (true) {
      uint8_t overflow[4096];
      const bool room = filled < blob.size();
      const zip_int64_t got = room ? zip_fread(file, blob.data() + filled, blob.size() - filled)
                                   : zip_fread(file, overflow, sizeof(overflow));
      if (got < 0) {
        const std::string text = zip_file_strerror(file);
        zip_fclose(file);
        throw InputError(where + ": corrupt member (" + text + ")");
      }
      if (got == 0) break;
      if (!room) {  // more data than announced: keep it for the size check below
        blob.insert(blob.end(), overflow, overflow + got);
        filled = blob.size();
        continue;
      }
      filled += size_t(got);
    }
    blob.resize(filled);
    zip_fclose(file);
    if (blob.size() != stat.size)
      throw InputError(where + ": truncated member (" + std::to_string(blob.size()) + " of " +
                       std::to_string(stat.size) + " bytes)");
    try {
      arrays_[key] = parseNpy(std::move(blob));
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
