// Reading input files whole, safely: only regular files are opened. A FIFO would block the
// open (or the read) forever, a directory or a device has no content to read; each is refused
// with an InputError naming the path and what it is.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace flsh::io {

/// What `path` is when it is not a regular file ("a directory", "a FIFO (named pipe)", …),
/// or "" for a regular file (symbolic links followed). Throws FileError when it does not exist
/// or cannot be examined.
std::string nonRegularFileKind(const std::string& path);

/// Throws InputError("PATH: is a FIFO (named pipe), expected WHAT (a regular file)") unless
/// `path` is a regular file; FileError when it does not exist. `what` names the expected
/// content, e.g. "an .npz file".
void requireRegularFile(const std::string& path, const std::string& what);

/// The whole content of the regular file `path` (checked as requireRegularFile, and again on
/// the opened descriptor, which is opened non-blocking so that a FIFO swapped in between cannot
/// block). Throws FileError when it cannot be opened or read.
std::vector<uint8_t> readRegularFileBytes(const std::string& path, const std::string& what);
/// As readRegularFileBytes, as text.
std::string readRegularFileText(const std::string& path, const std::string& what);

}  // namespace flsh::io
