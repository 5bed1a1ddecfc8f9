// What each fuzz target does with one input, shared by the libFuzzer targets (fuzz_*.cpp) and
// by tests/io/fuzz_replay_test.cpp, which replays the seed corpus and every regression input in
// the ordinary test suite. Each function lets only flsh::Error through silently: anything else
// escaping, a crash or a sanitizer report is a bug of the reader.
#pragma once

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "flsh/core/error.h"
#include "flsh/format/mesh_io.h"
#include "flsh/format/npz.h"
#include "flsh/io/scene_file.h"
#include "flsh/volume/avatar_cache.h"
#include "tiny_avatar.h"
#include "volume/volumetric_cache.h"

namespace flsh::fuzz {

template <class F>
void quietly(F&& read) {
  try {
    read();
  } catch (const Error&) {
  }
}

/// CRC-32 (zip's polynomial), bitwise: inputs are small.
inline uint32_t crc32(const uint8_t* data, size_t size) {
  uint32_t crc = 0xFFFFFFFFu;
  for (size_t i = 0; i < size; ++i) {
    crc ^= data[i];
    for (int k = 0; k < 8; ++k) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
  }
  return ~crc;
}

/// `bytes` with the CRC-32 of every stored (uncompressed) zip member recomputed in its central
/// directory entry and local header. libzip rejects a member whose CRC does not match, so
/// nearly every mutation of an array's bytes stopped at the CRC check: with the CRCs repaired,
/// mutations reach the .npy parser and the checks after it. Entries that do not parse are left.
inline std::vector<uint8_t> withStoredCrcsRepaired(std::vector<uint8_t> bytes) {
  const auto u16 = [&](size_t at) { return uint32_t(bytes[at]) | uint32_t(bytes[at + 1]) << 8; };
  const auto u32 = [&](size_t at) { return u16(at) | u16(at + 2) << 16; };
  const auto put32 = [&](size_t at, uint32_t v) {
    for (int k = 0; k < 4; ++k) bytes[at + k] = uint8_t(v >> (8 * k));
  };
  for (size_t c = 0; c + 46 <= bytes.size(); ++c) {
    if (u32(c) != 0x02014b50u || u16(c + 10) != 0) continue;  // central entry of a stored member
    const size_t local = u32(c + 42), length = u32(c + 20);
    if (local + 30 > bytes.size() || u32(local) != 0x04034b50u) continue;
    const size_t start = local + 30 + u16(local + 26) + u16(local + 28);
    if (start > bytes.size() || length > bytes.size() - start) continue;
    const uint32_t crc = crc32(bytes.data() + start, length);
    put32(c + 16, crc);
    put32(local + 14, crc);
  }
  return bytes;
}

/// The .npz reader on bytes in memory (NpzFile::fromBytes), then every accessor on every array
/// it accepted; then the same with the stored members' CRCs repaired, if that changes the bytes.
inline void readNpzInput(const uint8_t* data, size_t size) {
  const std::vector<uint8_t> raw(data, data + size);
  const std::vector<uint8_t> repaired = withStoredCrcsRepaired(raw);
  for (const std::vector<uint8_t>* bytes : {&raw, &repaired}) {
    if (bytes == &repaired && repaired == raw) break;
    quietly([&] {
      const io::NpzFile file = io::NpzFile::fromBytes(*bytes, "fuzz.npz");
      for (const std::string& key : file.keys()) {
        const std::vector<long>& shape = file.arrays().at(key).shape;
        quietly([&] { file.doubles(key, shape); });
        quietly([&] { file.integers(key, shape); });
        quietly([&] { file.string(key); });
        quietly([&] { file.scalar(key); });
        quietly([&] { file.matrix(key); });
        quietly([&] { file.vector(key); });
      }
    });
  }
}

/// The scene-file parser on text. Paths named by the text resolve against a folder that does
/// not exist, so nothing else is read.
inline void readSceneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  quietly([&] { parseSceneJson(text, "fuzz.json", "/nonexistent-flsh-fuzz-dir"); });
}

/// readMesh on the bytes written to a per-process temporary file, once as .ply and once as .obj
/// (PLY is recognised by its magic line, OBJ by the extension). A mesh it accepts must have
/// finite vertices and faces indexing them.
inline void readMeshInput(const uint8_t* data, size_t size) {
  const char* tmp = std::getenv("TMPDIR");
  const std::string stem =
      std::string(tmp && *tmp ? tmp : "/tmp") + "/flsh_fuzz_mesh_" + std::to_string(::getpid());
  for (const char* extension : {".ply", ".obj"}) {
    const std::string path = stem + extension;
    FILE* file = std::fopen(path.c_str(), "wb");
    if (!file) std::abort();
    if (size > 0 && std::fwrite(data, 1, size, file) != size) std::abort();
    std::fclose(file);
    MatX3 V;
    MatX3i F;
    quietly([&] {
      io::readMesh(path, V, F);
      if (!V.allFinite()) std::abort();
      if (F.size() > 0 && (F.minCoeff() < 0 || F.maxCoeff() >= V.rows())) std::abort();
    });
    std::remove(path.c_str());
  }
}

/// The avatar-cache loader: the bytes as an .npz archive (stored members' CRCs repaired, so that
/// mutated arrays reach the checks), its header checks (AvatarCache::entryProblem), then,
/// checksum or not, both volumetric levels of the tiny avatar of tiny_avatar.h read from it.
inline void readAvatarCacheInput(const uint8_t* data, size_t size) {
  static const BodyModel body = tinyBody();
  static const VolumetricData reference = tinyData(body);
  quietly([&] {
    const io::NpzFile file = io::NpzFile::fromBytes(
        withStoredCrcsRepaired(std::vector<uint8_t>(data, data + size)), "fuzz.npz");
    quietly([&] { AvatarCache::entryProblem(file, reference.key); });
    quietly([&] {
      VolumetricTemplate templ;
      readTemplateCacheArrays(file, body, templ);
    });
    quietly([&] {
      VolumetricData d;
      d.templ = reference.templ;
      d.material_model = reference.material_model;
      readDataCacheArrays(file, VecX::Zero(1), d);
    });
  });
}

}  // namespace flsh::fuzz
