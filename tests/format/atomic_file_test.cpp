// Atomic file output (format/atomic_file.h): a committed file appears whole, an abandoned one
// leaves nothing, and the temporaries of killed writers are removed once they are old enough
// (also by the avatar cache's store).
#include "flsh/format/atomic_file.h"

#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <set>

#include "flsh/core/error.h"
#include "flsh/format/npz.h"
#include "flsh/volume/avatar_cache.h"
#include "support/test_support.h"

namespace flsh {
namespace {

namespace fs = std::filesystem;

std::set<std::string> filesIn(const std::string& dir) {
  std::set<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) names.insert(e.path().filename().string());
  return names;
}

void touch(const fs::path& path, double age_seconds) {
  std::ofstream(path) << "partial";
  fs::last_write_time(path, fs::file_time_type::clock::now() -
                                std::chrono::duration_cast<fs::file_time_type::duration>(
                                    std::chrono::duration<double>(age_seconds)));
}

TEST(AtomicFile, CommittedAppearsWholeAbandonedLeavesNothing) {
  const std::string dir = test::freshTempDir("atomic_file_commit");
  io::writeFileAtomically(dir + "/a.txt", [](std::ostream& out) { out << "hello"; });
  EXPECT_EQ(filesIn(dir), std::set<std::string>{"a.txt"});
  EXPECT_THROW(io::writeFileAtomically(dir + "/b.txt",
                                       [](std::ostream& out) {
                                         out << "half";
                                         throw FileError("disk full");
                                       }),
               FileError);
  EXPECT_EQ(filesIn(dir), std::set<std::string>{"a.txt"});
}

TEST(AtomicFile, StaleTemporariesAreRemovedFreshOnesAndOtherFilesKept) {
  const std::string dir = test::freshTempDir("atomic_file_stale");
  touch(fs::path(dir) / ".entry.npz.tmp.4242.0", 7200.0);  // a writer killed two hours ago
  touch(fs::path(dir) / ".entry.npz.tmp.4243.1", 10.0);    // one writing now
  touch(fs::path(dir) / "old_entry.npz", 7200.0);          // an entry, however old
  touch(fs::path(dir) / ".hidden", 7200.0);                // not a temporary
  EXPECT_EQ(io::removeStaleTemporaries(dir, 3600.0), 1);
  EXPECT_EQ(filesIn(dir), (std::set<std::string>{".entry.npz.tmp.4243.1", "old_entry.npz",
                                                 ".hidden"}));
  EXPECT_EQ(io::removeStaleTemporaries(dir + "/missing", 3600.0), 0);
  // The avatar cache's store cleans its folder the same way.
  touch(fs::path(dir) / ".killed.npz.tmp.99.3", 7200.0);
  AvatarCache cache(dir);
  io::NpzWriter arrays;
  arrays.addScalar("value", 1.0);
  cache.store(std::string(64, 'a'), arrays);
  EXPECT_EQ(filesIn(dir).count(".killed.npz.tmp.99.3"), 0u);
  EXPECT_EQ(filesIn(dir).count(".entry.npz.tmp.4243.1"), 1u);
}

}  // namespace
}  // namespace flsh
