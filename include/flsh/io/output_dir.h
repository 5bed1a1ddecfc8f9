// Output paths of the command line, checked before any work, and output folders written as a
// whole: a command writes into a staging folder beside its output folder, which replaces the
// output folder in one rename at the end. A reader (or a later run) sees either the previous
// outputs or the new ones, never a mix; a failed or killed run leaves the previous outputs as
// they were (docs/scene_format.md, "Outputs").
#pragma once

#include <string>
#include <vector>

namespace flsh::io {

/// A top-level name a command writes in its output folder: a file ("states.npz") or a folder
/// whose files, at any depth, all end in `extension` ("meshes", ".ply").
struct OutputEntry {
  std::string name;
  bool folder = false;
  std::string extension;  ///< folders only

  static OutputEntry file(const std::string& name) { return {name, false, ""}; }
  static OutputEntry folderOf(const std::string& name, const std::string& extension) {
    return {name, true, extension};
  }
};

/// Checks, without writing anything, that a file can be written at `path`: `path` is not a
/// folder and its nearest existing ancestor is a writable folder. Throws InputError naming
/// `what` (e.g. "--out") and the path.
void checkOutputFile(const std::string& path, const std::string& what);

/// An output folder written as a whole through a staging folder beside it.
class StagedOutputDir {
 public:
  /// Checks `target`: missing, or a folder holding only `entries` (of the right kinds; a
  /// previous run's outputs) and flsh's own temporary files. Then removes the staging folders
  /// that runs no longer alive left beside it (putting back an output folder that such a run
  /// had moved aside, see commit()) and creates this run's empty staging folder
  /// `.NAME.tmp-PID-N` beside it, with missing parents. Throws InputError (wrong kind of path,
  /// foreign content) or FileError (cannot create), naming `what` and the path.
  StagedOutputDir(const std::string& target, std::vector<OutputEntry> entries, std::string what);
  /// Removes the staging folder (and the parents the constructor created) unless committed.
  ~StagedOutputDir();
  StagedOutputDir(const StagedOutputDir&) = delete;
  StagedOutputDir& operator=(const StagedOutputDir&) = delete;

  /// The output folder, absolute.
  const std::string& target() const { return target_; }
  /// The staging folder, absolute: write every output below it.
  const std::string& staging() const { return staging_; }
  /// `relative` below the staging folder.
  std::string path(const std::string& relative) const;

  /// Puts the staging folder in the output folder's place. A missing target: one rename.
  /// An existing one: one atomic exchange of the two folders (renameat2 RENAME_EXCHANGE),
  /// then the previous outputs are deleted; on a filesystem without the exchange, the target
  /// is first renamed to `.NAME.old-PID-N` (a kill between the two renames leaves the previous
  /// outputs there, and the next run puts them back). Checks the target again first: if
  /// something else appeared in it, throws FileError and keeps the staging folder (the message
  /// names it).
  void commit();

 private:
  void checkTarget() const;
  std::string target_, parent_, name_, staging_, what_;
  std::vector<OutputEntry> entries_;
  std::vector<std::string> created_parents_;  ///< deepest first
  bool committed_ = false;
};

}  // namespace flsh::io
