// libFuzzer target: see fuzz_entries.h and docs/reliability.md.
#include "fuzz_entries.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  zsculpt::fuzz::scene(data, size);
  return 0;
}
