// Reading input files whole, regular files only (input_file.h).
#include "flsh/io/input_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "flsh/core/error.h"

namespace flsh::io {

namespace {

std::string kindOf(mode_t mode) {
  if (S_ISREG(mode)) return "";
  if (S_ISDIR(mode)) return "a directory";
  if (S_ISFIFO(mode)) return "a FIFO (named pipe)";
  if (S_ISCHR(mode)) return "a character device";
  if (S_ISBLK(mode)) return "a block device";
  if (S_ISSOCK(mode)) return "a socket";
  return "not a regular file";
}

[[noreturn]] void refuse(const std::string& path, const std::string& kind,
                         const std::string& what) {
  throw InputError(path + ": is " + kind + ", expected " + what + " (a regular file)");
}

/// Reads the regular file `path` into `out` (a byte container: std::string or vector<uint8_t>).
template <class Buffer>
void readInto(const std::string& path, const std::string& what, Buffer& out) {
  requireRegularFile(path, what);
  // O_NONBLOCK: if a FIFO replaced the file since the check, open() returns at once instead of
  // waiting for a writer (for a regular file the flag changes nothing).
  const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) throw FileError(path + ": cannot open for reading: " + std::strerror(errno));
  struct Closer {
    int fd;
    ~Closer() { ::close(fd); }
  } closer{fd};
  struct stat st;
  if (::fstat(fd, &st) != 0) throw FileError(path + ": cannot examine: " + std::strerror(errno));
  if (!S_ISREG(st.st_mode)) refuse(path, kindOf(st.st_mode), what);
  // Straight into a buffer of the announced size; then whatever a growing file appended.
  out.resize(size_t(st.st_size));
  size_t filled = 0;
  while (true) {
    char more[1 << 14];
    const bool room = filled < out.size();
    const ssize_t got =
        room ? ::read(fd, &out[filled], out.size() - filled) : ::read(fd, more, sizeof(more));
    if (got < 0) {
      if (errno == EINTR) continue;
      throw FileError(path + ": read error: " + std::strerror(errno));
    }
    if (got == 0) break;
    if (!room) out.insert(out.end(), more, more + got);
    filled += size_t(got);
  }
  out.resize(filled);
}

}  // namespace

std::string nonRegularFileKind(const std::string& path) {
  struct stat st;
  if (::stat(path.c_str(), &st) != 0) {
    if (errno == ENOENT || errno == ENOTDIR) throw FileError(path + ": no such file");
    throw FileError(path + ": cannot examine: " + std::strerror(errno));
  }
  return kindOf(st.st_mode);
}

void requireRegularFile(const std::string& path, const std::string& what) {
  const std::string kind = nonRegularFileKind(path);
  if (!kind.empty()) refuse(path, kind, what);
}

std::vector<uint8_t> readRegularFileBytes(const std::string& path, const std::string& what) {
  std::vector<uint8_t> bytes;
  readInto(path, what, bytes);
  return bytes;
}

std::string readRegularFileText(const std::string& path, const std::string& what) {
  std::string text;
  readInto(path, what, text);
  return text;
}

}  // namespace flsh::io
