#include "flsh/volume/avatar_cache.h"

#include <cstdio>
#include <cstdlib>
#include <filesystem>

#include "flsh/core/error.h"
#include "flsh/core/sha256.h"
#include "flsh/format/atomic_file.h"

namespace flsh {

namespace {

constexpr const char* kFormatName = "flsh-avatar-cache";

bool isHeaderKey(const std::string& key) {
  return key.size() >= 4 && key.compare(0, 2, "__") == 0 &&
         key.compare(key.size() - 2, 2, "__") == 0;
}

bool isHexKey(const std::string& key) {
  if (key.empty() || key.size() > 128) return false;
  for (char c : key)
    if (!((c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'))) return false;
  return true;
}

void checkKey(const std::string& key) {
  // Keys become file names: only hex digests, so no path can escape the cache directory.
  if (!isHexKey(key))
    throw InputError("avatar cache: key '" + key +
                     "' is not a lower-case hex digest (use Sha256::hexDigest())");
}

/// A stored version number as text (any finite double: a corrupt file may hold 1e300).
std::string versionText(double version) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.17g", version);
  return text;
}

}  // namespace

std::string npzContentChecksum(const std::map<std::string, io::NpyArray>& arrays) {
  // An empty vector's data() may be null, and pointer arithmetic on null (xxhash64 does some
  // even for 0 bytes) is undefined: empty fields hash 0 bytes at a valid address instead (the
  // digest is the same). Found by fuzz_avatar_cache under UBSan.
  static const uint8_t kNothing = 0;
  const auto at = [](const auto& v) -> const void* {
    return v.empty() ? static_cast<const void*>(&kNothing) : static_cast<const void*>(v.data());
  };
  Sha256 h;
  for (const auto& [key, array] : arrays) {
    if (isHeaderKey(key)) continue;
    h.updateField("key", at(key), key.size());
    h.updateField("dtype", at(array.dtype), array.dtype.size());
    h.updateField("shape", at(array.shape), array.shape.size() * sizeof(long));
    h.updateLarge("bytes", at(array.bytes), array.bytes.size());
  }
  return h.hexDigest();
}

AvatarCache::AvatarCache(std::string dir)
    : dir_(dir.empty() ? defaultDirectory() : std::move(dir)) {}

std::string AvatarCache::defaultDirectory() {
  if (const char* d = std::getenv("FLSH_CACHE_DIR"); d && *d) return d;
  if (const char* d = std::getenv("XDG_CACHE_HOME"); d && *d) return std::string(d) + "/flsh";
  if (const char* d = std::getenv("HOME"); d && *d) return std::string(d) + "/.cache/flsh";
  return ".flsh_cache";
}

std::string AvatarCache::pathFor(const std::string& key) const {
  checkKey(key);
  return (std::filesystem::path(dir_) / (key + ".npz")).string();
}

std::string AvatarCache::entryProblem(const io::NpzFile& file, const std::string& key) {
  for (const char* header : {"__format__", "__version__", "__key__", "__checksum__"})
    if (!file.has(header)) return std::string("has no '") + header + "' entry";
  if (file.string("__format__") != kFormatName)
    return "is not an flsh avatar cache file (format '" + file.string("__format__") + "')";
  const double version = file.scalar("__version__");
  if (version != kFormatVersion)
    return "is stale: format version " + versionText(version) + ", expected " +
           std::to_string(kFormatVersion);
  if (file.string("__key__") != key)
    return "was stored under another key (" + file.string("__key__") + ")";
  if (file.string("__checksum__") != npzContentChecksum(file.arrays()))
    return "is corrupted (content checksum mismatch)";
  return "";
}

std::optional<io::NpzFile> AvatarCache::load(const std::string& key, std::string* problem) const {
  const std::string path = pathFor(key);
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) return std::nullopt;
  auto fail = [&](const std::string& why) -> std::optional<io::NpzFile> {
    if (problem) *problem = "avatar cache file " + path + " " + why + "; rebuilding it";
    return std::nullopt;
  };
  try {
    // A FIFO, directory or device at the path is refused by NpzFile (never opened), and
    // reported like any unreadable entry.
    io::NpzFile file(path);
    const std::string why = entryProblem(file, key);
    if (!why.empty()) return fail(why);
    return file;
  } catch (const Error& e) {
    return fail(std::string("is unreadable (") + e.what() + ")");
  }
}

namespace {
constexpr double kStaleTemporarySeconds = 3600.0;
}  // namespace

void AvatarCache::store(const std::string& key, const io::NpzWriter& arrays) const {
  const std::string path = pathFor(key);
  for (const auto& [name, array] : arrays.arrays())
    if (isHeaderKey(name))
      throw InputError("avatar cache: array name '" + name + "' is reserved for the header");
  io::NpzWriter out = arrays;
  out.addString("__format__", kFormatName);
  out.addScalar("__version__", kFormatVersion);
  out.addString("__key__", key);
  out.addString("__checksum__", npzContentChecksum(arrays.arrays()));
  io::ensureDirectory(dir_);
  // A writer killed before its rename leaves its temporary file behind (e.g. a batch worker);
  // an hour is far longer than any entry takes to write.
  io::removeStaleTemporaries(dir_, kStaleTemporarySeconds);
  out.save(path);
}

}  // namespace flsh
