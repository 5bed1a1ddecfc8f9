#include "flsh/core/error.h"

#include <sstream>

namespace flsh {

std::string shapeString(const std::vector<long>& shape) {
  std::ostringstream out;
  out << "(";
  for (size_t i = 0; i < shape.size(); ++i) {
    out << (i ? ", " : "") << shape[i];
  }
  if (shape.size() == 1) out << ",";
  out << ")";
  return out.str();
}

}  // namespace flsh
