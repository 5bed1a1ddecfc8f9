// The joint tree given by a `parents` array (parents[b] = −1 for a root, else a joint below b),
// as the volume functions take it: one check and one child list for all of them.
#pragma once

#include <string>
#include <vector>

#include "flsh/core/error.h"

namespace flsh::detail {

/// Throws InputError, prefixed by `fn`, unless `parents` has `num_joints` entries, each −1 or a
/// joint index below its own.
inline void checkParents(const std::vector<int>& parents, int num_joints, const std::string& fn) {
  if (int(parents.size()) != num_joints)
    throw InputError(fn + "parents has " + std::to_string(parents.size()) + " entries, expected " +
                     std::to_string(num_joints) + " (one per joint)");
  for (int b = 0; b < num_joints; ++b)
    if (parents[b] >= b || parents[b] < -1)
      throw InputError(fn + "parents[" + std::to_string(b) + "] = " + std::to_string(parents[b]) +
                       ", expected −1 or a joint index below " + std::to_string(b));
}

/// children[b]: the joints whose parent is b, in increasing order (parents checked).
inline std::vector<std::vector<int>> jointChildren(const std::vector<int>& parents) {
  std::vector<std::vector<int>> children(parents.size());
  for (size_t b = 1; b < parents.size(); ++b)
    if (parents[b] >= 0) children[size_t(parents[b])].push_back(int(b));
  return children;
}

}  // namespace flsh::detail
