// Reading input files whole, safely: only regular files are opened. A FIFO would block the
// open (or the read) forever, a directory or a device has no content to read; each is refused
// with an InputError naming the path and what it is. Also the nesting bound every JSON reader
// applies to the text before parsing it.
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

/// "line L, column C" (1-based) of the 1-based byte position `byte` of `text`, for editors
/// (clamped to the text's end).
std::string lineColumn(const std::string& text, size_t byte);

/// How deep JSON input files may nest arrays and objects. flsh's files nest a few levels; 64 is
/// far beyond any of them and far below what overflows a stack: nlohmann's dump() and copies
/// recurse once per level, and 200 000 nested '[' crashed the readers.
constexpr int kMaxJsonDepth = 64;

/// Throws InputError("ORIGIN: JSON nested deeper than 64 levels at byte B (line L, column C);
/// HINT") when arrays and objects in `text` nest deeper than `max_depth`: a scan of the brackets
/// outside strings, to run before a parser builds (and later prints or copies) the tree.
/// Unbalanced closing brackets are left for the parser to report. `hint` says how deep such
/// files normally nest, e.g. "scene files nest a few levels".
void checkJsonNesting(const std::string& text, const std::string& origin, const std::string& hint,
                      int max_depth = kMaxJsonDepth);

}  // namespace flsh::io
