// libFuzzer target: the PLY and OBJ readers on arbitrary bytes (fuzz_inputs.h, readMeshInput).
#include "fuzz_inputs.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  flsh::fuzz::readMeshInput(data, size);
  return 0;
}
