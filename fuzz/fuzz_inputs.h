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
#include "flsh/io/mesh_io.h"
#include "flsh/io/npz.h"
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

/// The .npz reader on bytes in memory (NpzFile::fromBytes), then every accessor on every array
/// it accepted.
inline void readNpzInput(const uint8_t* data, size_t size) {
  quietly([&] {
    const io::NpzFile file =
        io::NpzFile::fromBytes(std::vector<uint8_t>(data, data + size), "fuzz.npz");
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

/// The avatar-cache loader: the bytes as an .npz archive, its header checks
/// (AvatarCache::entryProblem), then, checksum or not, both volumetric levels of the tiny avatar
/// of tiny_avatar.h read from it.
inline void readAvatarCacheInput(const uint8_t* data, size_t size) {
  static const BodyModel body = tinyBody();
  static const VolumetricData reference = tinyData(body);
  quietly([&] {
    const io::NpzFile file =
        io::NpzFile::fromBytes(std::vector<uint8_t>(data, data + size), "fuzz.npz");
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
