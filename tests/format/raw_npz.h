// Test helpers that build `.npy` / `.npz` bytes by hand (libzip directly), so that tests can
// feed the readers what NpzWriter never writes: float32, Fortran order, uint32, strings,
// other header versions, malformed headers, truncated or corrupted archives.
#pragma once

#include <gtest/gtest.h>
#include <zip.h>

#include <cstdint>
#include <cstring>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

namespace flsh::test {

/// The bytes of a `.npy` array: header dict built from `descr`, `fortran` and `shape_text`
/// (Python tuple text such as "(2, 3)"), followed by `data` verbatim. `major` selects the
/// format version (1: 16-bit header length, 2 and 3: 32-bit).
inline std::vector<uint8_t> npyBytes(const std::string& descr, const std::string& shape_text,
                                     const void* data, size_t data_size, bool fortran = false,
                                     int major = 1) {
  std::string header = "{'descr': '" + descr +
                       "', 'fortran_order': " + (fortran ? "True" : "False") +
                       ", 'shape': " + shape_text + ", }";
  const size_t prefix = major == 1 ? 10 : 12;
  while ((prefix + header.size() + 1) % 64 != 0) header.push_back(' ');
  header.push_back('\n');
  std::vector<uint8_t> out = {0x93, 'N', 'U', 'M', 'P', 'Y', uint8_t(major), 0};
  const size_t n = header.size();
  out.push_back(uint8_t(n & 0xff));
  out.push_back(uint8_t((n >> 8) & 0xff));
  if (major != 1) {
    out.push_back(uint8_t((n >> 16) & 0xff));
    out.push_back(uint8_t((n >> 24) & 0xff));
  }
  out.insert(out.end(), header.begin(), header.end());
  const auto* bytes = static_cast<const uint8_t*>(data);
  out.insert(out.end(), bytes, bytes + data_size);
  return out;
}

/// `.npy` bytes of `values` (already in the element order the header announces).
template <class T>
std::vector<uint8_t> npyOf(const std::string& descr, const std::string& shape_text,
                           const std::vector<T>& values, bool fortran = false, int major = 1) {
  return npyBytes(descr, shape_text, values.data(), values.size() * sizeof(T), fortran, major);
}

struct RawMember {
  std::string name;  ///< member name in the zip, e.g. "poses.npy"
  std::vector<uint8_t> bytes;
};

/// Writes a zip archive holding `members` (stored, or deflated if `compress`).
inline void writeRawZip(const std::string& path, const std::vector<RawMember>& members,
                        bool compress = false) {
  int error = 0;
  zip_t* archive = zip_open(path.c_str(), ZIP_CREATE | ZIP_TRUNCATE, &error);
  ASSERT_NE(archive, nullptr) << "zip_open failed for " << path;
  for (const RawMember& m : members) {
    zip_source_t* source = zip_source_buffer(archive, m.bytes.data(), m.bytes.size(), 0);
    ASSERT_NE(source, nullptr);
    const zip_int64_t index = zip_file_add(archive, m.name.c_str(), source, ZIP_FL_OVERWRITE);
    ASSERT_GE(index, 0) << zip_strerror(archive);
    zip_set_file_compression(archive, zip_uint64_t(index), compress ? ZIP_CM_DEFLATE : ZIP_CM_STORE,
                             0);
  }
  ASSERT_EQ(zip_close(archive), 0) << zip_strerror(archive);
}

inline std::vector<uint8_t> readFileBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::vector<uint8_t>((std::istreambuf_iterator<char>(in)),
                              std::istreambuf_iterator<char>());
}

inline void writeFileBytes(const std::string& path, const std::vector<uint8_t>& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
}

}  // namespace flsh::test
