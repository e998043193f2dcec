#pragma once
// Internal to the cli module: each subcommand lives in its own cmd_<name>.cpp and
// registers itself here. A command's action runs after a successful parse and returns
// the exit status; errors are thrown as zsculpt::Error and reported by run().

#include <CLI/CLI.hpp>
#include <functional>
#include <vector>

namespace zsculpt::cli {

using Action = std::function<int()>;

struct Command {
  CLI::App* app = nullptr;
  Action action;
};

using CommandList = std::vector<Command>;

// One per subcommand of ../shared/notes/cli.md, each defined in its cmd_<name>.cpp and
// called from run() in cli.cpp.
void addInfoCommand(CLI::App& root, CommandList& commands);
void addSimulateCommand(CLI::App& root, CommandList& commands);
void addSubdivideCommand(CLI::App& root, CommandList& commands);
void addRenderCommand(CLI::App& root, CommandList& commands);
void addDemoCommand(CLI::App& root, CommandList& commands);
void addReproduceCommand(CLI::App& root, CommandList& commands);
void addBenchCommand(CLI::App& root, CommandList& commands);
void addOpenCommand(CLI::App& root, CommandList& commands);
void addReplayCommand(CLI::App& root, CommandList& commands);

}  // namespace zsculpt::cli
