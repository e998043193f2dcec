// libFuzzer target: the command line (see fuzz_entries.h and docs/reliability.md). Runs in
// a fresh temporary folder so that whatever --state-out or --csv names lands there.
#include <cstdlib>

#include "fuzz_entries.h"

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  char folder[] = "/tmp/zsculpt_fuzz_cli_XXXXXX";
  if (::mkdtemp(folder) == nullptr || ::chdir(folder) != 0) std::abort();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const zsculpt::fuzz::QuietStreams quiet;
  const int status = zsculpt::fuzz::commandLine(data, size);
  // The contract's exit codes only (cli.md): anything else is a bug.
  if (status != -1 && status != 0 && status != 2 && status != 3) std::abort();
  return 0;
}
