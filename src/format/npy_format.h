// The `.npy` array format (numpy/lib/format.py, versions 1.0–3.0), internal to src/format: dtype
// descriptors, the header dict, and the size checks that keep a crafted header from claiming
// more elements than its member holds (npz.cpp reads the archives around it).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "flsh/format/npz.h"

namespace flsh::io {

/// A dtype flsh understands: kind 'f' (float), 'i' (signed), 'u' (unsigned), 'b' (bool),
/// 'U' (UTF-32 string), 'S' (byte string); `itemsize` in bytes (0 for '<U0' and '|S0').
struct DtypeInfo {
  bool supported = false;
  char kind = 0;
  long itemsize = 0;
  std::string canonical;  ///< e.g. "<f8", "|u1", "<U6"
};

DtypeInfo parseDtype(const std::string& descr);
std::string unsupportedDtypeMessage(const std::string& descr);

/// The header dict, e.g. {'descr': '<f8', 'fortran_order': False, 'shape': (6890, 3), }.
struct NpyHeader {
  std::string descr;
  bool fortran_order = false;
  std::vector<long> shape;
};

/// A parsed preamble (magic, version, header) and what it promises.
struct NpyLayout {
  NpyHeader header;
  DtypeInfo dtype;        ///< dtype.supported == false: kept with empty bytes
  size_t data_start = 0;  ///< byte offset of the data
  size_t data_bytes = 0;  ///< element count × item size (0 for an unsupported dtype)
};

/// Product of `shape`; throws InputError for a negative dimension or a product beyond `long`.
long elementCount(const std::vector<long>& shape);

/// Parses the preamble of a `.npy` member of `member_size` bytes from its first `size` bytes.
/// Returns false when those do not hold the whole header yet (a member being streamed in);
/// throws InputError for a malformed header, and for a shape whose byte count overflows or
/// whose zero-byte items ('<U0', '|S0') outnumber the member's bytes, naming the shape.
bool parseNpyLayout(const uint8_t* data, size_t size, size_t member_size, NpyLayout& layout);

/// Parses one `.npy` blob. Unsupported dtypes are kept with empty bytes (reported on access).
/// The blob is consumed: its data bytes become the array's without a copy. Throws InputError
/// when the data size differs from the header's promise.
NpyArray parseNpy(std::vector<uint8_t>&& blob);

/// The `.npy` bytes of an array (format 1.0, header padded so the data starts 64-aligned).
std::vector<uint8_t> serializeNpy(const NpyArray& array);

}  // namespace flsh::io
