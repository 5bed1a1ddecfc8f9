// On-disk cache of generated avatar data (tet mesh, interior fields, materials…).
//
// One `<key>.npz` file per entry in a cache directory; `key` is the hex SHA-256 of everything
// the entry depends on (model arrays, β, settings, resolution, material file, format version),
// built by the caller with Sha256. Besides the caller's arrays each file stores
//   __format__   "flsh-avatar-cache"      __version__  AvatarCache::kFormatVersion
//   __key__      the key it was stored under
//   __checksum__ SHA-256 of every other array's name, dtype, shape and XXH64 of its bytes, in
//                key order (XXH64: a 50 MB entry is checked in ~10 ms instead of ~0.3 s).
// load() trusts a file only if it reads as a complete archive and all four agree; anything
// else (truncated, corrupted, written by another format version, renamed) is reported through
// `problem`, so the caller warns and rebuilds, and store() then replaces it. Files are written
// atomically: a reader never sees a half-written entry, even with concurrent writers.
#pragma once

#include <optional>
#include <string>

#include "flsh/format/npz.h"

namespace flsh {

class AvatarCache {
 public:
  /// Bump when the meaning or layout of any cached array changes: older files become stale.
  static constexpr int kFormatVersion = 1;

  /// `dir` is created on the first store(). An empty `dir` means defaultDirectory().
  explicit AvatarCache(std::string dir = {});
  const std::string& directory() const { return dir_; }
  std::string pathFor(const std::string& key) const;

  /// The entry stored under `key`, or nullopt when there is none or it cannot be trusted; in
  /// the latter case `problem` (if given) receives a one-line reason naming the file.
  std::optional<io::NpzFile> load(const std::string& key, std::string* problem = nullptr) const;
  /// Why `file` cannot be trusted as the entry stored under `key` (missing header array, other
  /// format, version or key, checksum mismatch: "is corrupted (…)"), or "" when it can. The
  /// caller still checks the content's ranges (e.g. readTemplateCacheArrays).
  static std::string entryProblem(const io::NpzFile& file, const std::string& key);
  /// Writes `arrays` (plus the header arrays above) under `key`, atomically. Throws FileError
  /// when the directory or file cannot be written.
  void store(const std::string& key, const io::NpzWriter& arrays) const;

  /// $FLSH_CACHE_DIR, else $XDG_CACHE_HOME/flsh, else $HOME/.cache/flsh, else ./.flsh_cache.
  static std::string defaultDirectory();

 private:
  std::string dir_;
};

/// SHA-256 over the arrays of an archive except the header ones ("__…__"): names, dtypes,
/// shapes and the XXH64 of the bytes, in key order.
std::string npzContentChecksum(const std::map<std::string, io::NpyArray>& arrays);

}  // namespace flsh
