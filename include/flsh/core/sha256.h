// SHA-256 (FIPS 180-4) and XXH64: cache keys and content checksums of generated avatar data.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>

#include <Eigen/Core>

namespace flsh {

class Sha256 {
 public:
  Sha256();
  void update(const void* data, size_t bytes);
  void update(const std::string& text) { update(text.data(), text.size()); }
  /// A labelled value: the label, the size and the bytes are all hashed, so ("ab","c") and
  /// ("a","bc") differ.
  void updateField(const std::string& label, const void* data, size_t bytes);
  /// A large byte range, entered as its label, size and XXH64 (fast: keys of big arrays).
  void updateLarge(const std::string& label, const void* data, size_t bytes);
  /// A dense Eigen matrix through updateLarge: label, rows, cols and the coefficients in
  /// row-major order (the same digest for a row- or column-major matrix of equal values).
  template <class Derived>
  void updateMatrix(const std::string& label, const Eigen::DenseBase<Derived>& m) {
    using Scalar = typename Derived::Scalar;
    const Eigen::Matrix<Scalar, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> values = m;
    const int64_t dims[2] = {int64_t(m.rows()), int64_t(m.cols())};
    updateField(label, dims, sizeof(dims));
    updateLarge(label, values.data(), sizeof(Scalar) * size_t(values.size()));
  }
  /// The digest (32 bytes); the object must not be updated afterwards.
  std::array<uint8_t, 32> digest();
  /// The digest as 64 lower-case hex digits.
  std::string hexDigest();

 private:
  void compress(const uint8_t* block);
  std::array<uint32_t, 8> h_;
  std::array<uint8_t, 64> buffer_{};
  size_t buffered_ = 0;
  uint64_t total_bytes_ = 0;
  bool finished_ = false;
};

/// Hex SHA-256 of a byte string.
std::string sha256Hex(const std::string& bytes);

/// XXH64 (Yann Collet's xxHash, 64-bit variant) of a byte range: a fast non-cryptographic
/// checksum (~10× SHA-256's throughput) for large arrays, where SHA-256 would dominate the
/// time to load a cached avatar. Cache keys feed these into SHA-256 with their labels.
/// `data` may be null when `bytes` is 0 (the hash of the empty range).
uint64_t xxhash64(const void* data, size_t bytes, uint64_t seed = 0);

}  // namespace flsh
