#include "flsh/format/atomic_file.h"

#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include "flsh/core/error.h"

namespace flsh::io {

namespace fs = std::filesystem;

void ensureDirectory(const std::string& dir) {
  if (dir.empty()) return;
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) throw FileError("cannot create directory '" + dir + "': " + ec.message());
}

int removeStaleTemporaries(const std::string& dir, double min_age_seconds) {
  std::error_code ec;
  fs::directory_iterator it(dir, ec), end;
  if (ec) return 0;
  const auto now = fs::file_time_type::clock::now();
  int removed = 0;
  for (; it != end; it.increment(ec)) {
    if (ec) break;
    const std::string name = it->path().filename().string();
    if (name.size() < 2 || name[0] != '.' || name.find(".tmp.") == std::string::npos) continue;
    std::error_code stat_ec;
    if (!it->is_regular_file(stat_ec) || stat_ec) continue;
    const auto written = fs::last_write_time(it->path(), stat_ec);
    if (stat_ec) continue;
    const double age = std::chrono::duration<double>(now - written).count();
    if (age > min_age_seconds && fs::remove(it->path(), stat_ec) && !stat_ec) ++removed;
  }
  return removed;
}

AtomicPath::AtomicPath(std::string target) : target_(std::move(target)) {
  static std::atomic<unsigned> counter{0};
  const fs::path p(target_);
  ensureDirectory(p.parent_path().string());
  temp_ = (p.parent_path() / ("." + p.filename().string() + ".tmp." + std::to_string(getpid()) +
                              "." + std::to_string(counter++)))
              .string();
}

AtomicPath::~AtomicPath() {
  if (!committed_) std::remove(temp_.c_str());
}

void AtomicPath::commit() {
  std::error_code ec;
  fs::rename(temp_, target_, ec);
  if (ec) throw FileError("cannot move '" + temp_ + "' to '" + target_ + "': " + ec.message());
  committed_ = true;
}

void writeFileAtomically(const std::string& path, const std::function<void(std::ostream&)>& write) {
  AtomicPath tmp(path);
  {
    std::ofstream out(tmp.tempPath(), std::ios::binary | std::ios::trunc);
    if (!out)
      throw FileError("cannot open '" + tmp.tempPath() + "' for writing (target '" + path + "')");
    write(out);
    out.flush();
    if (!out) throw FileError("write failed for '" + path + "' (disk full?)");
  }
  tmp.commit();
}

}  // namespace flsh::io
