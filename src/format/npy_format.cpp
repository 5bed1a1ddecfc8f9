// The `.npy` array format (npy_format.h).
#include "npy_format.h"

#include <cctype>
#include <cstring>
#include <limits>
#include <sstream>

#include "flsh/core/error.h"

namespace flsh::io {

namespace {

const char kNpyMagic[] = "\x93NUMPY";
constexpr size_t kNpyMagicSize = 6;

// ---------------------------------------------------------------------------------------------
// .npy header: a Python dict literal such as
//   {'descr': '<f8', 'fortran_order': False, 'shape': (6890, 3), }

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
    // The header is echoed for context, cut short: it may be megabytes of garbage.
    const std::string text = s_.size() > 200 ? s_.substr(0, 200) + "..." : s_;
    throw InputError("malformed .npy header (" + what + " at character " + std::to_string(pos_) +
                     "): " + text);
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

/// Reorders Fortran-ordered (column-major) elements of `shape` into C (row-major) order.
std::vector<uint8_t> fortranToC(const std::vector<uint8_t>& in, const std::vector<long>& shape,
                                long itemsize) {
  const size_t ndim = shape.size();
  const long n = elementCount(shape);
  // Zero-byte items ('<U0') or no elements: nothing to reorder (and no loop over a huge count).
  if (ndim < 2 || n == 0 || itemsize == 0) return in;
  if (in.size() / size_t(itemsize) != size_t(n))
    throw InputError("Fortran-ordered data of " + std::to_string(in.size()) +
                     " bytes does not hold shape " + shapeString(shape));
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

}  // namespace

// ---------------------------------------------------------------------------------------------
// dtypes

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

bool parseNpyLayout(const uint8_t* data, size_t size, size_t member_size, NpyLayout& layout) {
  if (size < kNpyMagicSize + 4 || std::memcmp(data, kNpyMagic, kNpyMagicSize) != 0) {
    if (size < member_size && size < kNpyMagicSize + 4) return false;
    throw InputError("not a .npy array (missing the \\x93NUMPY magic)");
  }
  const int major = data[6];
  size_t header_len = 0, header_start = 0;
  if (major == 1) {
    header_len = size_t(data[8]) | (size_t(data[9]) << 8);
    header_start = 10;
  } else if (major == 2 || major == 3) {
    if (size < 12) {
      if (size < member_size) return false;
      throw InputError("truncated .npy header");
    }
    header_len = size_t(data[8]) | (size_t(data[9]) << 8) | (size_t(data[10]) << 16) |
                 (size_t(data[11]) << 24);
    header_start = 12;
  } else {
    throw InputError("unsupported .npy format version " + std::to_string(major) + "." +
                     std::to_string(int(data[7])));
  }
  if (member_size < header_start + header_len)
    throw InputError("truncated .npy header (" + std::to_string(header_len) +
                     " header bytes announced, " + std::to_string(member_size - header_start) +
                     " present)");
  if (size < header_start + header_len) return false;
  const std::string text(reinterpret_cast<const char*>(data + header_start), header_len);
  layout.header = HeaderParser(text).parse();
  layout.dtype = parseDtype(layout.header.descr);
  layout.data_start = header_start + header_len;
  const std::vector<long>& shape = layout.header.shape;
  // Sizes are checked before anything is allocated or iterated: a shape whose byte count
  // overflows would otherwise pass the size check modulo 2^64, and zero-byte items would let a
  // shape of 2^62 elements through with no data at all.
  const long count = elementCount(shape);
  if (!layout.dtype.supported) {
    layout.data_bytes = 0;
    return true;
  }
  const long itemsize = layout.dtype.itemsize;
  if (itemsize == 0) {
    if (size_t(count) > member_size)
      throw InputError("shape " + shapeString(shape) + " of zero-byte items ('" +
                       layout.header.descr + "') claims " + std::to_string(count) +
                       " elements, more than the member's " + std::to_string(member_size) +
                       " bytes");
    layout.data_bytes = 0;
    return true;
  }
  if (count > std::numeric_limits<long>::max() / itemsize)
    throw InputError("shape " + shapeString(shape) + " of '" + layout.header.descr +
                     "' needs more than 2^63 bytes");
  layout.data_bytes = size_t(count) * size_t(itemsize);
  return true;
}

NpyArray parseNpy(std::vector<uint8_t>&& blob) {
  NpyLayout layout;
  parseNpyLayout(blob.data(), blob.size(), blob.size(), layout);  // the whole blob: never false
  const NpyHeader& header = layout.header;
  NpyArray array;
  array.shape = header.shape;
  if (!layout.dtype.supported) {
    array.dtype = header.descr;
    return array;
  }
  array.dtype = layout.dtype.canonical;
  const size_t actual = blob.size() - layout.data_start;
  if (actual != layout.data_bytes)
    throw InputError("data size " + std::to_string(actual) + " bytes does not match the header (" +
                     header.descr + " " + shapeString(header.shape) + " needs " +
                     std::to_string(layout.data_bytes) + " bytes)");
  blob.erase(blob.begin(), blob.begin() + long(layout.data_start));  // a move, no second buffer
  array.bytes = std::move(blob);
  if (header.fortran_order)
    array.bytes = fortranToC(array.bytes, array.shape, layout.dtype.itemsize);
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

}  // namespace flsh::io
