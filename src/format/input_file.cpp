// Reading input files whole, regular files only; the JSON nesting bound (input_file.h).
#include "flsh/format/input_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
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

std::string lineColumn(const std::string& text, size_t byte) {
  byte = std::min(byte, text.size());
  size_t line = 1, column = 1;
  for (size_t k = 0; k + 1 < byte; ++k) {
    if (text[k] == '\n') {
      ++line;
      column = 1;
    } else {
      ++column;
    }
  }
  return "line " + std::to_string(line) + ", column " + std::to_string(column);
}

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

void checkJsonNesting(const std::string& text, const std::string& origin, const std::string& hint,
                      int max_depth) {
  int depth = 0;
  bool in_string = false;
  for (size_t k = 0; k < text.size(); ++k) {
    const char c = text[k];
    if (in_string) {
      if (c == '\\')
        ++k;  // the escaped character cannot end the string
      else if (c == '"')
        in_string = false;
    } else if (c == '"') {
      in_string = true;
    } else if (c == '[' || c == '{') {
      if (++depth > max_depth)
        throw InputError(origin + ": JSON nested deeper than " + std::to_string(max_depth) +
                         " levels at byte " + std::to_string(k) + " (" + lineColumn(text, k + 1) +
                         "); " + hint);
    } else if ((c == ']' || c == '}') && depth > 0) {
      --depth;  // unbalanced closers are the parser's to report
    }
  }
}

}  // namespace flsh::io
