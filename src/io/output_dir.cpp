#include "flsh/io/output_dir.h"

#include <fcntl.h>
#include <signal.h>
#include <unistd.h>

#include <atomic>
#include <cctype>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <system_error>

#include "flsh/core/error.h"

namespace flsh::io {

namespace fs = std::filesystem;

namespace {

/// The absolute, normalized form of `path` without a trailing separator.
fs::path normalized(const std::string& path) {
  fs::path p = fs::absolute(fs::path(path)).lexically_normal();
  if (p.filename().empty() && p.has_parent_path() && p != p.root_path()) p = p.parent_path();
  return p;
}

/// The deepest ancestor of `path` (or `path` itself) that exists.
fs::path nearestExisting(const fs::path& path) {
  fs::path p = path;
  std::error_code ec;
  while (!fs::exists(fs::symlink_status(p, ec)) && p.has_parent_path() && p != p.root_path())
    p = p.parent_path();
  return p;
}

/// Throws InputError unless the nearest existing ancestor of `path` is a writable folder.
void checkCreatable(const fs::path& path, const std::string& what, const std::string& shown) {
  const fs::path existing = nearestExisting(path.parent_path());
  std::error_code ec;
  if (!fs::is_directory(existing, ec))
    throw InputError(what + ": cannot create '" + shown + "': '" + existing.string() +
                     "' is a file, expected a folder");
  if (::access(existing.c_str(), W_OK | X_OK) != 0)
    throw InputError(what + ": cannot create '" + shown + "': folder '" + existing.string() +
                     "' is not writable (" + std::strerror(errno) + ")");
}

/// Files that flsh's atomic writes leave when killed: ".NAME.tmp.PID.N" (atomic_file.cpp).
bool isAtomicWriteLeftover(const std::string& name) {
  return name.size() > 1 && name[0] == '.' && name.find(".tmp.") != std::string::npos;
}

/// The PID of a staging or moved-aside folder's name after its prefix ("PID-N"), or −1 if the
/// rest is not exactly that (then the folder is not flsh's and is left alone).
long leftoverPid(const std::string& rest) {
  const size_t dash = rest.find('-');
  if (dash == 0 || dash == std::string::npos || dash + 1 == rest.size()) return -1;
  for (size_t k = 0; k < rest.size(); ++k)
    if (k != dash && !std::isdigit(static_cast<unsigned char>(rest[k]))) return -1;
  return std::atol(rest.substr(0, dash).c_str());
}

bool processAlive(long pid) {
  if (pid <= 0) return false;
  return ::kill(pid_t(pid), 0) == 0 || errno == EPERM;
}

std::string entryList(const std::vector<OutputEntry>& entries) {
  std::string list;
  for (const auto& e : entries) list += (list.empty() ? "" : ", ") + e.name + (e.folder ? "/" : "");
  return list;
}

}  // namespace

void checkOutputFile(const std::string& path, const std::string& what) {
  if (path.empty()) throw InputError(what + ": expected a file path, got an empty string");
  const fs::path p = normalized(path);
  std::error_code ec;
  if (fs::is_directory(p, ec))
    throw InputError(what + ": '" + path + "' is a folder, expected a file path");
  checkCreatable(p, what, path);
}

StagedOutputDir::StagedOutputDir(const std::string& target, std::vector<OutputEntry> entries,
                                 std::string what)
    : what_(std::move(what)), entries_(std::move(entries)) {
  if (target.empty()) throw InputError(what_ + ": expected a folder, got an empty string");
  fs::path p = normalized(target);
  std::error_code ec;
  if (fs::is_symlink(p, ec) && fs::is_directory(p, ec)) p = fs::canonical(p, ec);
  const std::string name = p.filename().string();
  if (name.empty() || name == "." || name == ".." || !p.has_parent_path())
    throw InputError(what_ + ": '" + target + "' has no folder name to write to");
  target_ = p.string();
  parent_ = p.parent_path().string();
  name_ = name;

  // Leftovers of runs that no longer exist: their staging folders go; an output folder that
  // one of them had moved aside (commit's fallback) comes back if nothing took its place.
  const std::string tmp_prefix = "." + name_ + ".tmp-", old_prefix = "." + name_ + ".old-";
  for (fs::directory_iterator it(parent_, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string entry = it->path().filename().string();
    const bool tmp = entry.rfind(tmp_prefix, 0) == 0, old = entry.rfind(old_prefix, 0) == 0;
    if (!tmp && !old) continue;
    // Both prefixes are as long.
    const long pid = leftoverPid(entry.substr(tmp_prefix.size()));
    if (pid <= 0 || pid == long(::getpid()) || processAlive(pid)) continue;
    std::error_code ignored;
    if (old && !fs::exists(fs::symlink_status(p, ignored)))
      fs::rename(it->path(), p, ignored);
    else
      fs::remove_all(it->path(), ignored);
  }

  checkTarget();
  checkCreatable(p, what_, target);
  for (fs::path a = p.parent_path(); !fs::exists(fs::symlink_status(a, ec)); a = a.parent_path())
    created_parents_.push_back(a.string());
  static std::atomic<unsigned> counter{0};
  staging_ = (fs::path(parent_) /
              (tmp_prefix + std::to_string(::getpid()) + "-" + std::to_string(counter++)))
                 .string();
  std::string failure;
  fs::create_directories(parent_, ec);
  if (ec)
    failure = "cannot create folder '" + parent_ + "': " + ec.message();
  else if (!fs::create_directory(staging_, ec) || ec)
    failure = "cannot create the staging folder '" + staging_ + "' beside the output folder: " +
              (ec ? ec.message() : std::string("it exists already"));
  if (!failure.empty()) {
    for (const auto& dir : created_parents_) fs::remove(dir, ec);  // only if still empty
    throw FileError(what_ + ": " + failure);
  }
}

StagedOutputDir::~StagedOutputDir() {
  if (committed_) return;
  std::error_code ec;
  fs::remove_all(staging_, ec);
  for (const auto& dir : created_parents_) fs::remove(dir, ec);  // only if still empty
}

std::string StagedOutputDir::path(const std::string& relative) const {
  return (fs::path(staging_) / relative).string();
}

void StagedOutputDir::checkTarget() const {
  std::error_code ec;
  const fs::file_status status = fs::status(target_, ec);
  if (!fs::exists(status)) return;
  if (!fs::is_directory(status))
    throw InputError(what_ + ": '" + target_ + "' is a file, expected a folder");
  const std::string expected =
      "; flsh replaces its output folder as a whole, so it writes only to a new or empty "
      "folder or to one holding a previous run's outputs (" +
      entryList(entries_) + ")";
  for (fs::directory_iterator it(target_, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (isAtomicWriteLeftover(name)) continue;
    const OutputEntry* entry = nullptr;
    for (const auto& e : entries_)
      if (e.name == name) entry = &e;
    if (!entry)
      throw InputError(what_ + ": folder '" + target_ + "' holds '" + name +
                       "', which flsh does not write there" + expected);
    std::error_code kind_ec;
    if (!entry->folder) {
      if (!fs::is_regular_file(it->path(), kind_ec))
        throw InputError(what_ + ": '" + it->path().string() + "' is not a file, expected " +
                         "the file " + name + " of a previous run" + expected);
      continue;
    }
    if (!fs::is_directory(it->path(), kind_ec))
      throw InputError(what_ + ": '" + it->path().string() + "' is not a folder, expected the " +
                       "folder " + name + "/ of a previous run" + expected);
    for (fs::recursive_directory_iterator f(it->path(), kind_ec), fend; !kind_ec && f != fend;
         f.increment(kind_ec)) {
      const std::string file = f->path().filename().string();
      if (f->is_directory(kind_ec) || isAtomicWriteLeftover(file)) continue;
      if (f->path().extension() != entry->extension)
        throw InputError(what_ + ": folder '" + target_ + "' holds '" +
                         fs::relative(f->path(), target_, kind_ec).string() + "', but " + name +
                         "/ holds only " + entry->extension + " files of flsh" + expected);
    }
  }
  if (ec) throw FileError(what_ + ": cannot list folder '" + target_ + "': " + ec.message());
}

void StagedOutputDir::commit() {
  if (committed_) throw Error("StagedOutputDir::commit: already committed");
  try {
    checkTarget();
  } catch (const InputError& e) {
    committed_ = true;  // keep the new outputs
    throw FileError(std::string(e.what()) +
                    " (it changed during the run; this run's outputs "
                    "are in '" +
                    staging_ + "')");
  }
  std::error_code ec;
  if (!fs::exists(fs::symlink_status(target_, ec))) {
    fs::rename(staging_, target_, ec);
    if (ec)
      throw FileError(what_ + ": cannot move '" + staging_ + "' to '" + target_ +
                      "': " + ec.message());
    committed_ = true;
    return;
  }
  if (::renameat2(AT_FDCWD, staging_.c_str(), AT_FDCWD, target_.c_str(), RENAME_EXCHANGE) == 0) {
    committed_ = true;
    fs::remove_all(staging_, ec);  // the previous outputs; a leftover goes with the next run
    return;
  }
  const int exchange_errno = errno;
  if (exchange_errno != EINVAL && exchange_errno != ENOSYS && exchange_errno != ENOTSUP)
    throw FileError(what_ + ": cannot exchange '" + staging_ + "' with '" + target_ +
                    "': " + std::strerror(exchange_errno));
  // No atomic exchange here: move the previous outputs aside, then the new ones in.
  std::string aside = staging_;
  aside.replace(aside.rfind(".tmp-"), 5, ".old-");
  fs::rename(target_, aside, ec);
  if (ec)
    throw FileError(what_ + ": cannot move the previous outputs '" + target_ +
                    "' aside: " + ec.message());
  fs::rename(staging_, target_, ec);
  if (ec) {
    std::error_code ignored;
    fs::rename(aside, target_, ignored);
    throw FileError(what_ + ": cannot move '" + staging_ + "' to '" + target_ +
                    "': " + ec.message());
  }
  committed_ = true;
  fs::remove_all(aside, ec);
}

}  // namespace flsh::io
