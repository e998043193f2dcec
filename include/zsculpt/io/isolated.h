#pragma once
// Work that may crash the process, run in a child process instead. Assimp 5.2 has faults
// that the preflight checks of mesh_io.cpp do not catch yet (docs/reliability.md lists the
// ones the fuzzer found): a user's session must not be lost to one of them. The child is forked
// (copy-on-write: nothing to load again), does the work and sends back its bytes or its
// error; a crash or a hang in it becomes an IOError naming the file.

#include <chrono>
#include <cstdint>
#include <functional>
#include <string>

namespace zsculpt::io {

struct IsolationLimits {
  /// The child is killed after this long (a reader stuck on a damaged file).
  std::chrono::milliseconds timeout{std::chrono::seconds(120)};
  /// Address space the child may take beyond what it starts with (0: no limit), so that a
  /// reader that believes a damaged count allocates, fails fast with bad_alloc instead of
  /// eating the machine's memory. Not applied in sanitizer builds (their shadow memory).
  std::uint64_t memoryBytes = 0;
};

/// Whether IsolationLimits::memoryBytes is applied in this build.
bool isolationLimitsMemory();

/// Runs `work` in a forked child and returns the bytes it returned. An Error it throws is
/// thrown again here with the same type (IOError, InvalidInputError, TopologyError,
/// SolverError; other exceptions as IOError) and message. A child killed by a signal, one
/// that exits without an answer, or one that takes longer than `limits.timeout` gives
/// IOError "<name>: ...". When no child can be started (fork fails), `work` runs here.
/// The child must not rely on other threads of this process (they do not exist in it).
std::string runIsolated(const std::string& name, const std::function<std::string()>& work,
                        const IsolationLimits& limits = {});

}  // namespace zsculpt::io
