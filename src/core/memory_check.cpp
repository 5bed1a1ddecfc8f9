#include "flsh/core/memory_check.h"

#include <unistd.h>

#include <cstdio>

#include "flsh/core/error.h"

namespace flsh {

double physicalMemoryBytes() {
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
  return pages > 0 && page > 0 ? double(pages) * double(page) : 0.0;
}

void checkMemory(const std::string& what, double bytes, const std::string& advice) {
  const double memory = physicalMemoryBytes();
  auto gigabytes = [](double b) {
    char text[32];
    std::snprintf(text, sizeof(text), "%.3g GB", b / 1e9);
    return std::string(text);
  };
  if (memory > 0 && !(bytes <= 0.5 * memory))
    throw InputError(what + ": this needs about " + gigabytes(bytes) +
                     " of memory, expected at most " + gigabytes(0.5 * memory) +
                     " (half of this machine's memory); " + advice);
}

}  // namespace flsh
