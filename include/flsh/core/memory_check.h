// Refusing work that cannot fit in memory, up front, with a message saying what to change.
#pragma once

#include <string>

namespace flsh {

/// Physical memory of this machine, bytes (0 if unknown).
double physicalMemoryBytes();

/// Throws InputError naming `what` unless about `bytes` of memory fit in half of this
/// machine's; `advice` says what to change.
void checkMemory(const std::string& what, double bytes, const std::string& advice);

}  // namespace flsh
