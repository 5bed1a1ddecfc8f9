// libFuzzer target: the avatar-cache loader on arbitrary bytes (fuzz_inputs.h,
// readAvatarCacheInput).
#include "fuzz_inputs.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  flsh::fuzz::readAvatarCacheInput(data, size);
  return 0;
}
