// libFuzzer target: the scene-file parser on arbitrary bytes (fuzz_inputs.h, readSceneInput).
#include "fuzz_inputs.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  flsh::fuzz::readSceneInput(data, size);
  return 0;
}
