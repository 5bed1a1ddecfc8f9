// Entry point of the flsh._flsh extension module: one binding file per C++ folder.
#include <pybind11/pybind11.h>

namespace py = pybind11;

PYBIND11_MODULE(_flsh, m) {
  m.doc() = "flsh: differentiable physics of SMPL human bodies (C++ core)";
}
