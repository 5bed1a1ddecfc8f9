// PLY and OBJ triangle meshes. Writers store x, y, z as double (binary PLY) or with the
// shortest round-trip decimal form (ASCII PLY, OBJ), so every write → read round trip of V
// is exact. Numbers are formatted and parsed with <charconv>: independent of the C locale.
#include "flsh/format/mesh_io.h"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <iomanip>
#include <limits>
#include <sstream>
#include <vector>

#include "flsh/core/error.h"
#include "flsh/format/atomic_file.h"
#include "flsh/format/input_file.h"

namespace flsh::io {
namespace {

// ---------------------------------------------------------------------------------------
// Input checks shared by the writers.

void checkMesh(const char* function, const std::string& path, const Eigen::Ref<const MatX3>& V,
               const Eigen::Ref<const MatX3i>& F) {
  for (Eigen::Index i = 0; i < V.rows(); ++i) {
    if (!V.row(i).allFinite()) {
      std::ostringstream msg;
      msg << function << "('" << path << "'): argument V (shape "
          << shapeString({long(V.rows()), 3}) << ") has a non-finite value in row " << i << ": ("
          << V(i, 0) << ", " << V(i, 1) << ", " << V(i, 2) << ")";
      throw InputError(msg.str());
    }
  }
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      if (F(f, k) < 0 || F(f, k) >= V.rows()) {
        std::ostringstream msg;
        msg << function << "('" << path << "'): argument F (shape "
            << shapeString({long(F.rows()), 3}) << ") row " << f << " has vertex index " << F(f, k)
            << ", expected an index in [0, " << V.rows() << ") (#V = " << V.rows() << ")";
        throw InputError(msg.str());
      }
    }
  }
}

void checkColors(const std::string& path, const Colors& colors, Eigen::Index vertices) {
  if (colors.size() == 0) return;
  if (colors.rows() != vertices) {
    throw InputError("writePly('" + path + "'): argument colors has shape " +
                     shapeString({long(colors.rows()), 3}) + ", expected " +
                     shapeString({long(vertices), 3}) + " (one RGB row per vertex of V) or empty");
  }
  if (!colors.allFinite()) {
    throw InputError("writePly('" + path + "'): argument colors " +
                     shapeString({long(colors.rows()), 3}) + " has a non-finite value");
  }
}

// [0, 1] → 0..255 with rounding; values slightly outside [0, 1] are clamped.
uint8_t colorByte(double c) { return uint8_t(std::lround(std::clamp(c, 0.0, 1.0) * 255.0)); }

// ---------------------------------------------------------------------------------------
// Little-endian binary output, independent of the host byte order.

void putU32(std::string& out, uint32_t v) {
  for (int b = 0; b < 4; ++b) out.push_back(char((v >> (8 * b)) & 0xff));
}
void putF64(std::string& out, double d) {
  uint64_t v;
  std::memcpy(&v, &d, 8);
  for (int b = 0; b < 8; ++b) out.push_back(char((v >> (8 * b)) & 0xff));
}

// Shortest decimal text that parses back to the same double.
void putNumber(std::string& out, double d) {
  char buffer[64];
  const auto result = std::to_chars(buffer, buffer + sizeof(buffer), d);
  out.append(buffer, result.ptr);
}

// ---------------------------------------------------------------------------------------
// Reading.

[[noreturn]] void malformed(const std::string& path, const std::string& what) {
  throw InputError("readMesh('" + path + "'): " + what);
}

enum class ScalarType { Int8, UInt8, Int16, UInt16, Int32, UInt32, Float32, Float64 };

bool parseScalarType(const std::string& name, ScalarType& type) {
  static const std::pair<const char*, ScalarType> kNames[] = {
      {"char", ScalarType::Int8},      {"int8", ScalarType::Int8},
      {"uchar", ScalarType::UInt8},    {"uint8", ScalarType::UInt8},
      {"short", ScalarType::Int16},    {"int16", ScalarType::Int16},
      {"ushort", ScalarType::UInt16},  {"uint16", ScalarType::UInt16},
      {"int", ScalarType::Int32},      {"int32", ScalarType::Int32},
      {"uint", ScalarType::UInt32},    {"uint32", ScalarType::UInt32},
      {"float", ScalarType::Float32},  {"float32", ScalarType::Float32},
      {"double", ScalarType::Float64}, {"float64", ScalarType::Float64}};
  for (const auto& [text, value] : kNames) {
    if (name == text) {
      type = value;
      return true;
    }
  }
  return false;
}

int scalarSize(ScalarType type) {
  switch (type) {
    case ScalarType::Int8:
    case ScalarType::UInt8:
      return 1;
    case ScalarType::Int16:
    case ScalarType::UInt16:
      return 2;
    case ScalarType::Int32:
    case ScalarType::UInt32:
    case ScalarType::Float32:
      return 4;
    case ScalarType::Float64:
      return 8;
  }
  return 0;
}

bool isIntegerType(ScalarType type) {
  return type != ScalarType::Float32 && type != ScalarType::Float64;
}

struct PlyProperty {
  std::string name;
  ScalarType type = ScalarType::Float64;  // item type for lists
  bool is_list = false;
  ScalarType count_type = ScalarType::UInt8;
};

struct PlyElement {
  std::string name;
  long long count = 0;
  std::vector<PlyProperty> properties;
};

enum class PlyFormat { Ascii, BinaryLittle, BinaryBig };

// Reads the scalar values of the body of a PLY file, one at a time, in either format, and
// reports truncation and malformed numbers with the element and row being read.
class PlyValueReader {
 public:
  PlyValueReader(const std::string& path, const std::string& data, size_t offset, PlyFormat format)
      : path_(path), data_(data), pos_(offset), format_(format) {}

  // `where` describes the value being read, e.g. "vertex 12".
  double read(ScalarType type, const std::string& where) {
    if (format_ == PlyFormat::Ascii) return readAscii(type, where);
    const int size = scalarSize(type);
    if (pos_ + size > data_.size()) {
      malformed(path_, "file is truncated: it ends while reading " + where + " (byte offset " +
                           std::to_string(pos_) + " of " + std::to_string(data_.size()) + ")");
    }
    unsigned char bytes[8];
    std::memcpy(bytes, data_.data() + pos_, size);
    pos_ += size;
    uint64_t bits = 0;
    for (int b = 0; b < size; ++b) {
      const int shift = format_ == PlyFormat::BinaryLittle ? 8 * b : 8 * (size - 1 - b);
      bits |= uint64_t(bytes[b]) << shift;
    }
    switch (type) {
      case ScalarType::Int8:
        return double(int8_t(uint8_t(bits)));
      case ScalarType::UInt8:
        return double(uint8_t(bits));
      case ScalarType::Int16:
        return double(int16_t(uint16_t(bits)));
      case ScalarType::UInt16:
        return double(uint16_t(bits));
      case ScalarType::Int32:
        return double(int32_t(uint32_t(bits)));
      case ScalarType::UInt32:
        return double(uint32_t(bits));
      case ScalarType::Float32: {
        const uint32_t bits32 = uint32_t(bits);
        float f;
        std::memcpy(&f, &bits32, 4);
        return double(f);
      }
      case ScalarType::Float64: {
        double d;
        std::memcpy(&d, &bits, 8);
        return d;
      }
    }
    return 0.0;
  }

  void skip(const PlyProperty& property, const std::string& where) {
    if (!property.is_list) {
      read(property.type, where);
      return;
    }
    const double count = read(property.count_type, where + " (list length)");
    if (count < 0) malformed(path_, where + " has a negative list length");
    for (long long k = 0; k < (long long)count; ++k) read(property.type, where);
  }

 private:
  double readAscii(ScalarType type, const std::string& where) {
    while (pos_ < data_.size() && std::isspace((unsigned char)data_[pos_])) ++pos_;
    if (pos_ >= data_.size()) {
      malformed(path_, "file is truncated: it ends while reading " + where);
    }
    size_t end = pos_;
    while (end < data_.size() && !std::isspace((unsigned char)data_[end])) ++end;
    const char* first = data_.data() + pos_;
    const char* last = data_.data() + end;
    double value = 0.0;
    if (isIntegerType(type)) {
      long long integer = 0;
      const auto result = std::from_chars(first, last, integer);
      if (result.ec != std::errc() || result.ptr != last) {
        malformed(path_, "expected an integer for " + where + ", found '" +
                             std::string(first, last) + "'");
      }
      value = double(integer);
    } else {
      const auto result = std::from_chars(first, last, value);
      if (result.ec != std::errc() || result.ptr != last) {
        malformed(path_,
                  "expected a number for " + where + ", found '" + std::string(first, last) + "'");
      }
    }
    pos_ = end;
    return value;
  }

  const std::string& path_;
  const std::string& data_;
  size_t pos_;
  PlyFormat format_;
};

void readPly(const std::string& path, const std::string& data, MatX3& V, MatX3i& F) {
  // Header: lines up to "end_header".
  size_t pos = 0;
  std::vector<PlyElement> elements;
  PlyFormat format = PlyFormat::Ascii;
  bool have_format = false, have_end = false;
  int line_number = 0;
  while (pos < data.size()) {
    size_t eol = data.find('\n', pos);
    if (eol == std::string::npos) eol = data.size();
    std::string line = data.substr(pos, eol - pos);
    pos = std::min(eol + 1, data.size());
    ++line_number;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream words(line);
    std::string keyword;
    words >> keyword;
    const std::string where = "header line " + std::to_string(line_number) + " '" + line + "'";
    if (line_number == 1) {
      if (keyword != "ply") malformed(path, "not a PLY file (first line is '" + line + "')");
      continue;
    }
    if (keyword == "end_header") {
      have_end = true;
      break;
    } else if (keyword == "format") {
      std::string name, version;
      words >> name >> version;
      if (name == "ascii")
        format = PlyFormat::Ascii;
      else if (name == "binary_little_endian")
        format = PlyFormat::BinaryLittle;
      else if (name == "binary_big_endian")
        format = PlyFormat::BinaryBig;
      else
        malformed(path, where + ": unknown format '" + name + "'");
      have_format = true;
    } else if (keyword == "element") {
      PlyElement element;
      words >> element.name >> element.count;
      if (!words || element.count < 0) {
        malformed(path, where + ": expected 'element <name> <count>'");
      }
      elements.push_back(element);
    } else if (keyword == "property") {
      if (elements.empty()) malformed(path, where + ": property before any element");
      PlyProperty property;
      std::string type_name;
      words >> type_name;
      if (type_name == "list") {
        std::string count_name, item_name;
        words >> count_name >> item_name >> property.name;
        property.is_list = true;
        if (!parseScalarType(count_name, property.count_type) ||
            !isIntegerType(property.count_type) || !parseScalarType(item_name, property.type)) {
          malformed(path, where + ": unknown list types '" + count_name + " " + item_name + "'");
        }
      } else {
        words >> property.name;
        if (!parseScalarType(type_name, property.type)) {
          malformed(path, where + ": unknown property type '" + type_name + "'");
        }
      }
      if (property.name.empty()) malformed(path, where + ": property without a name");
      elements.back().properties.push_back(property);
    } else if (keyword == "comment" || keyword == "obj_info" || keyword.empty()) {
      continue;
    } else {
      malformed(path, where + ": unknown header keyword '" + keyword + "'");
    }
  }
  if (!have_end) malformed(path, "PLY header has no 'end_header' line (truncated file?)");
  if (!have_format) malformed(path, "PLY header has no 'format' line");

  const PlyElement* vertex_element = nullptr;
  const PlyElement* face_element = nullptr;
  for (const PlyElement& element : elements) {
    if (element.name == "vertex") vertex_element = &element;
    if (element.name == "face") face_element = &element;
  }
  if (!vertex_element) malformed(path, "PLY header declares no 'vertex' element");
  int xyz[3] = {-1, -1, -1};
  for (int p = 0; p < int(vertex_element->properties.size()); ++p) {
    const PlyProperty& property = vertex_element->properties[p];
    for (int c = 0; c < 3; ++c) {
      if (property.name == std::string(1, char('x' + c)) && !property.is_list) xyz[c] = p;
    }
  }
  for (int c = 0; c < 3; ++c) {
    if (xyz[c] < 0) {
      malformed(path,
                std::string("PLY vertex element has no scalar property '") + char('x' + c) + "'");
    }
  }
  int indices_property = -1;
  if (face_element) {
    for (int p = 0; p < int(face_element->properties.size()); ++p) {
      const PlyProperty& property = face_element->properties[p];
      if ((property.name == "vertex_indices" || property.name == "vertex_index") &&
          property.is_list) {
        indices_property = p;
      }
    }
    if (indices_property < 0) {
      malformed(path, "PLY face element has no list property 'vertex_indices'");
    }
    if (!isIntegerType(face_element->properties[indices_property].type)) {
      malformed(path, "PLY face property 'vertex_indices' has a floating-point item type");
    }
  }

  // A header that promises more rows than the body can hold is rejected before allocating.
  double minimum_body_bytes = 0.0;
  for (const PlyElement& element : elements) {
    double row_bytes = 0.0;
    for (const PlyProperty& property : element.properties) {
      if (format == PlyFormat::Ascii)
        row_bytes += 2.0;  // one digit and one separator
      else
        row_bytes += scalarSize(property.is_list ? property.count_type : property.type);
    }
    minimum_body_bytes += row_bytes * double(element.count);
  }
  if (minimum_body_bytes > double(data.size() - pos)) {
    std::ostringstream msg;
    msg << "file is truncated: the header declares " << vertex_element->count << " vertices and "
        << (face_element ? face_element->count : 0) << " faces, which need at least " << std::fixed
        << std::setprecision(0) << minimum_body_bytes << " bytes, but the body has "
        << (data.size() - pos) << " bytes";
    malformed(path, msg.str());
  }

  // Body: elements in header order; those other than vertex and face are skipped.
  PlyValueReader reader(path, data, pos, format);
  V.resize(vertex_element->count, 3);
  F.resize(face_element ? face_element->count : 0, 3);
  for (const PlyElement& element : elements) {
    const bool is_vertex = &element == vertex_element;
    const bool is_face = &element == face_element;
    // An element without properties takes no bytes: its count (unbounded by the file size)
    // is not iterated.
    if (element.properties.empty()) continue;
    for (long long row = 0; row < element.count; ++row) {
      const std::string where = element.name + " " + std::to_string(row);
      for (int p = 0; p < int(element.properties.size()); ++p) {
        const PlyProperty& property = element.properties[p];
        if (is_vertex && !property.is_list && (p == xyz[0] || p == xyz[1] || p == xyz[2])) {
          const int c = p == xyz[0] ? 0 : (p == xyz[1] ? 1 : 2);
          V(row, c) = reader.read(property.type, where);
        } else if (is_face && p == indices_property) {
          const double count = reader.read(property.count_type, where + " (index count)");
          if (count != 3) {
            std::ostringstream msg;
            msg << "face " << row << " has " << count
                << " vertices; only triangles (3) are supported";
            malformed(path, msg.str());
          }
          for (int k = 0; k < 3; ++k) {
            const double index = reader.read(property.type, where);
            if (index < 0 || index >= double(V.rows())) {
              std::ostringstream msg;
              msg << "face " << row << " has vertex index " << (long long)index
                  << ", expected an index in [0, " << V.rows() << ")";
              malformed(path, msg.str());
            }
            F(row, k) = int(index);
          }
        } else {
          reader.skip(property, where);
        }
      }
      if (is_vertex && !V.row(row).allFinite()) {
        malformed(path, "vertex " + std::to_string(row) + " has a non-finite coordinate");
      }
    }
  }
}

// Parses one OBJ face corner "i", "i/j", "i//k" or "i/j/k" into a 0-based vertex index.
int objCornerIndex(const std::string& path, const std::string& token, long vertices_so_far,
                   int line_number) {
  const size_t slash = token.find('/');
  const std::string head = token.substr(0, slash);
  long long index = 0;
  const auto result = std::from_chars(head.data(), head.data() + head.size(), index);
  if (result.ec != std::errc() || result.ptr != head.data() + head.size() || index == 0) {
    malformed(path, "line " + std::to_string(line_number) + ": bad face vertex '" + token +
                        "' (expected a nonzero vertex number)");
  }
  // Negative indices count back from the last vertex defined so far (OBJ convention).
  const long long zero_based = index > 0 ? index - 1 : vertices_so_far + index;
  if (zero_based < 0) {
    malformed(path, "line " + std::to_string(line_number) + ": face vertex " +
                        std::to_string(index) + " refers before the first vertex (" +
                        std::to_string(vertices_so_far) + " vertices defined so far)");
  }
  if (zero_based > std::numeric_limits<int>::max()) {
    malformed(path, "line " + std::to_string(line_number) + ": face vertex " +
                        std::to_string(index) + " is too large");
  }
  return int(zero_based);
}

void readObj(const std::string& path, const std::string& data, MatX3& V, MatX3i& F) {
  std::vector<double> coordinates;
  std::vector<int> indices;
  std::vector<int> face_lines;  // line of each face, for range errors
  size_t pos = 0;
  int line_number = 0;
  while (pos < data.size()) {
    size_t eol = data.find('\n', pos);
    if (eol == std::string::npos) eol = data.size();
    std::string line = data.substr(pos, eol - pos);
    pos = eol + 1;
    ++line_number;
    const size_t hash = line.find('#');
    if (hash != std::string::npos) line.resize(hash);
    std::istringstream words(line);
    std::string keyword;
    words >> keyword;
    if (keyword == "v") {
      for (int c = 0; c < 3; ++c) {
        std::string token;
        words >> token;
        double value = 0.0;
        const auto result = std::from_chars(token.data(), token.data() + token.size(), value);
        if (token.empty() || result.ec != std::errc() ||
            result.ptr != token.data() + token.size() || !std::isfinite(value)) {
          malformed(path, "line " + std::to_string(line_number) + ": vertex '" + line +
                              "' needs 3 finite coordinates");
        }
        coordinates.push_back(value);
      }
    } else if (keyword == "f") {
      std::vector<std::string> corners;
      for (std::string token; words >> token;) corners.push_back(token);
      if (corners.size() != 3) {
        malformed(path, "line " + std::to_string(line_number) + ": face has " +
                            std::to_string(corners.size()) +
                            " vertices; only triangles (3) are supported");
      }
      const long vertices_so_far = long(coordinates.size() / 3);
      for (const std::string& corner : corners) {
        indices.push_back(objCornerIndex(path, corner, vertices_so_far, line_number));
      }
      face_lines.push_back(line_number);
    }
    // vn, vt, o, g, s, usemtl, mtllib, l, p, blank lines and comments carry no geometry.
  }
  const long vertex_count = long(coordinates.size() / 3);
  V.resize(vertex_count, 3);
  for (long i = 0; i < vertex_count; ++i) {
    for (int c = 0; c < 3; ++c) V(i, c) = coordinates[3 * i + c];
  }
  F.resize(long(indices.size() / 3), 3);
  for (long f = 0; f < F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const int index = indices[3 * f + k];
      if (index >= vertex_count) {
        malformed(path, "line " + std::to_string(face_lines[f]) + ": face vertex " +
                            std::to_string(index + 1) + " is out of range (the file has " +
                            std::to_string(vertex_count) + " vertices)");
      }
      F(f, k) = index;
    }
  }
}

std::string lowerExtension(const std::string& path) {
  const size_t dot = path.find_last_of('.');
  const size_t slash = path.find_last_of('/');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) return "";
  std::string ext = path.substr(dot + 1);
  for (char& c : ext) c = char(std::tolower((unsigned char)c));
  return ext;
}

}  // namespace

void writePly(const std::string& path, const Eigen::Ref<const MatX3>& V,
              const Eigen::Ref<const MatX3i>& F, const Colors& colors, bool binary) {
  checkMesh("writePly", path, V, F);
  checkColors(path, colors, V.rows());
  const bool with_colors = colors.rows() > 0;

  std::string text;
  text += "ply\n";
  text += binary ? "format binary_little_endian 1.0\n" : "format ascii 1.0\n";
  text += "comment written by flsh\n";
  text += "element vertex " + std::to_string(V.rows()) + "\n";
  text += "property double x\nproperty double y\nproperty double z\n";
  if (with_colors) text += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  text += "element face " + std::to_string(F.rows()) + "\n";
  text += "property list uchar int vertex_indices\n";
  text += "end_header\n";
  text.reserve(text.size() + V.rows() * (binary ? 27 : 64) + F.rows() * (binary ? 13 : 24));
  for (Eigen::Index i = 0; i < V.rows(); ++i) {
    for (int c = 0; c < 3; ++c) {
      if (binary) {
        putF64(text, V(i, c));
      } else {
        if (c) text += ' ';
        putNumber(text, V(i, c));
      }
    }
    if (with_colors) {
      for (int c = 0; c < 3; ++c) {
        const uint8_t byte = colorByte(colors(i, c));
        if (binary)
          text.push_back(char(byte));
        else
          text += ' ' + std::to_string(int(byte));
      }
    }
    if (!binary) text += '\n';
  }
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    if (binary) {
      text.push_back(char(3));
      for (int k = 0; k < 3; ++k) putU32(text, uint32_t(F(f, k)));
    } else {
      text += "3 " + std::to_string(F(f, 0)) + ' ' + std::to_string(F(f, 1)) + ' ' +
              std::to_string(F(f, 2)) + '\n';
    }
  }
  writeFileAtomically(path, [&](std::ostream& out) { out.write(text.data(), text.size()); });
}

void writeObj(const std::string& path, const Eigen::Ref<const MatX3>& V,
              const Eigen::Ref<const MatX3i>& F) {
  checkMesh("writeObj", path, V, F);
  std::string text = "# written by flsh\n";
  text.reserve(text.size() + V.rows() * 64 + F.rows() * 24);
  for (Eigen::Index i = 0; i < V.rows(); ++i) {
    text += 'v';
    for (int c = 0; c < 3; ++c) {
      text += ' ';
      putNumber(text, V(i, c));
    }
    text += '\n';
  }
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    text += "f " + std::to_string(F(f, 0) + 1) + ' ' + std::to_string(F(f, 1) + 1) + ' ' +
            std::to_string(F(f, 2) + 1) + '\n';
  }
  writeFileAtomically(path, [&](std::ostream& out) { out.write(text.data(), text.size()); });
}

void readMesh(const std::string& path, MatX3& V, MatX3i& F) {
  // A FIFO, directory or device is refused (InputError), never opened.
  const std::string data = readRegularFileText(path, "a PLY or OBJ mesh file");
  // PLY is recognised by its magic line whatever the extension; OBJ has none.
  const bool is_ply =
      data.compare(0, 3, "ply") == 0 && (data.size() == 3 || data[3] == '\n' || data[3] == '\r');
  const std::string ext = lowerExtension(path);
  MatX3 vertices;
  MatX3i faces;
  if (is_ply) {
    readPly(path, data, vertices, faces);
  } else if (ext == "obj") {
    readObj(path, data, vertices, faces);
  } else if (ext == "ply") {
    malformed(path, "not a PLY file (it does not start with the line 'ply')");
  } else {
    malformed(path,
              "unknown mesh format: expected a PLY file (starting with 'ply') or an "
              "'.obj' file, found extension '" +
                  ext + "'");
  }
  V = std::move(vertices);
  F = std::move(faces);
}

}  // namespace flsh::io
