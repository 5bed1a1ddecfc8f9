// libFuzzer target: the .npz/.npy reader on arbitrary bytes (fuzz_inputs.h, readNpzInput).
#include "fuzz_inputs.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  flsh::fuzz::readNpzInput(data, size);
  return 0;
}
