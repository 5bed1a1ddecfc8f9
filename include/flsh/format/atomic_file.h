// Atomic file output: write to a temporary file next to the target, rename on success.
// A reader never sees a half-written file, and a failed write leaves no file behind.
#pragma once

#include <functional>
#include <ostream>
#include <string>

namespace flsh::io {

/// Holds a temporary path beside `target`; commit() renames it onto `target`. If the
/// object is destroyed without commit() (e.g. an exception), the temporary file is removed.
class AtomicPath {
 public:
  explicit AtomicPath(std::string target);
  ~AtomicPath();
  AtomicPath(const AtomicPath&) = delete;
  AtomicPath& operator=(const AtomicPath&) = delete;

  const std::string& tempPath() const { return temp_; }
  const std::string& target() const { return target_; }
  /// Renames the temporary file onto the target (throws FileError on failure).
  void commit();

 private:
  std::string target_;
  std::string temp_;
  bool committed_ = false;
};

/// Writes a file atomically through a stream callback (binary mode). Creates missing
/// parent directories. Throws FileError naming the path on failure.
void writeFileAtomically(const std::string& path, const std::function<void(std::ostream&)>& write);

/// Creates `dir` and its parents if missing (throws FileError on failure).
void ensureDirectory(const std::string& dir);

/// Removes the temporary files AtomicPath leaves in `dir` when its process is killed before
/// commit (".NAME.tmp.PID.N") that were last written more than `min_age_seconds` ago: on a
/// folder shared by several machines a process id says nothing, an age does. Entries it cannot
/// remove are left alone. Returns how many it removed.
int removeStaleTemporaries(const std::string& dir, double min_age_seconds);

}  // namespace flsh::io
