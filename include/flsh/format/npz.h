// Reading and writing numpy `.npy` arrays inside `.npz` archives (stored or deflated).
//
// Supported dtypes: little-endian float64/float32, int64/int32/uint64/uint32/uint8, bool.
// Every error names the file, the key, the expected and the actual shape/dtype.
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "flsh/core/types.h"

namespace flsh::io {

/// One array as stored: numpy dtype descriptor (e.g. "<f8"), shape, raw bytes (C order after
/// reading; Fortran-ordered arrays are transposed into C order on read).
struct NpyArray {
  std::string dtype;
  std::vector<long> shape;
  std::vector<uint8_t> bytes;

  long size() const;  ///< product of shape (1 for a 0-d array)
  bool isFloat() const;
  bool isInteger() const;  ///< signed, unsigned or bool
};

/// An `.npz` file read fully into memory. Conversions check shape and values and throw
/// InputError("FILE: key 'K': expected shape (…), got (…)") etc.
class NpzFile {
 public:
  /// Reads the archive. Throws FileError (missing/unreadable) or InputError (not a zip,
  /// truncated, corrupt member, malformed .npy header). A member of unsupported dtype (e.g.
  /// an object array) does not spoil the others: raw() and the conversions throw for it.
  /// `path` must be a regular file: a FIFO, directory or device is an InputError (never a
  /// blocking open). Every array's shape is checked against its member's bytes before anything
  /// is allocated or iterated (an overflowing shape, zero-byte items outnumbering the member's
  /// bytes or a zip entry announcing more than the header promises are InputErrors).
  explicit NpzFile(const std::string& path);
  /// The archive held in memory by `bytes`; `origin` stands for the path in messages.
  static NpzFile fromBytes(std::vector<uint8_t> bytes, const std::string& origin);

  const std::string& path() const { return path_; }
  std::vector<std::string> keys() const;
  /// All arrays, by key.
  const std::map<std::string, NpyArray>& arrays() const { return arrays_; }
  bool has(const std::string& key) const;
  /// The raw array; throws InputError naming the file and the missing key.
  const NpyArray& raw(const std::string& key) const;

  /// Array converted to float64, checked against `shape` (−1 = any extent; the number of
  /// dimensions must match) and for NaN/Inf. Returned flattened in C order.
  std::vector<double> doubles(const std::string& key, const std::vector<long>& shape) const;
  /// 2-D array as a row-major matrix (checked as doubles()).
  RowMatX matrix(const std::string& key, long rows = -1, long cols = -1) const;
  /// 1-D array (checked as doubles()).
  VecX vector(const std::string& key, long size = -1) const;
  /// Scalar (0-d or one-element array).
  double scalar(const std::string& key) const;
  /// Integer array converted to int64 (float arrays holding integers are accepted), checked
  /// against `shape`. uint32/uint64 values of 2³²−1 / 2⁶⁴−1 become −1.
  std::vector<int64_t> integers(const std::string& key, const std::vector<long>& shape) const;
  /// String array (numpy '<U…' or '|S…'), e.g. AMASS 'gender'; empty if absent.
  std::string string(const std::string& key) const;

 private:
  NpzFile() = default;
  void readArchive(std::vector<uint8_t>& bytes);  ///< libzip reads `bytes` in place

  std::string path_;
  std::map<std::string, NpyArray> arrays_;
};

/// Collects arrays and writes an `.npz` archive atomically (never a half-written file).
class NpzWriter {
 public:
  void add(const std::string& key, const double* data, const std::vector<long>& shape);
  void add(const std::string& key, const int64_t* data, const std::vector<long>& shape);
  void add(const std::string& key, const Eigen::Ref<const RowMatX>& matrix);  ///< 2-D float64
  void add(const std::string& key, const Eigen::Ref<const VecX>& vector);     ///< 1-D float64
  /// Any Eigen matrix or vector (e.g. RowMatX, MatX3, VecX): a compile-time column vector is
  /// written 1-D, anything else 2-D. Without it such calls are ambiguous between the two
  /// Ref overloads above (each Ref<const …> accepts any double expression).
  template <class Derived>
  void add(const std::string& key, const Eigen::MatrixBase<Derived>& values) {
    if constexpr (Derived::ColsAtCompileTime == 1)
      add(key, Eigen::Ref<const VecX>(values));
    else
      add(key, Eigen::Ref<const RowMatX>(values));
  }
  void addScalar(const std::string& key, double value);              ///< 0-d float64
  void addString(const std::string& key, const std::string& value);  ///< 0-d '<U'
  /// The arrays collected so far, by key (e.g. to checksum them before saving).
  const std::map<std::string, NpyArray>& arrays() const { return arrays_; }
  /// Writes the archive (deflate-compressed if `compress`), atomically.
  void save(const std::string& path, bool compress = false) const;

 private:
  std::map<std::string, NpyArray> arrays_;
};

}  // namespace flsh::io
