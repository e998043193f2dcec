#pragma once
// The `zsculpt` command line (contract: ../shared/notes/cli.md).

namespace zsculpt::cli {

/// Parses the arguments, runs the subcommand, and returns the exit status:
/// 0 success, 2 usage error or invalid input, 3 the simulation diverged.
int run(int argc, char** argv);

}  // namespace zsculpt::cli
