// Entry point of the flsh._flsh extension module: one binding file per C++ folder.
#include "bindings.h"

PYBIND11_MODULE(_flsh, m) {
  m.doc() = "flsh: differentiable physics of SMPL human bodies (C++ core)";
  flsh::python::bind_core(m);  // first: registers the exception translation
  flsh::python::bind_format(m);
  flsh::python::bind_body(m);
  flsh::python::bind_io(m);
  flsh::python::bind_render(m);
  flsh::python::bind_volume(m);   // before sim: Simulable takes a SoftAvatar
  flsh::python::bind_contact(m);  // before sim and solve: options and colliders
  flsh::python::bind_sim(m);
  flsh::python::bind_solve(m);
  flsh::python::bind_diff(m);  // after sim and solve: Rollout takes a Simulable, NewtonOptions
}
