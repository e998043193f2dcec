#include "zsculpt/cli/cli.h"

#include <CLI/CLI.hpp>
#include <iostream>

#include "commands.h"
#include "zsculpt/core/errors.h"

namespace zsculpt::cli {

int run(int argc, char** argv) {
  CLI::App app{"zsculpt: physics-based sculpting with the z-domain solver of Ray and Qin"};
  app.require_subcommand(0, 1);
  CommandList commands;
  addInfoCommand(app, commands);
  addSimulateCommand(app, commands);
  addReproduceCommand(app, commands);
  addBenchCommand(app, commands);
  addSubdivideCommand(app, commands);
  addRenderCommand(app, commands);
  addDemoCommand(app, commands);
  addOpenCommand(app, commands);
  addReplayCommand(app, commands);
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::Success& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    // One line, as cli.md asks: `zsculpt: error: <argument>: <reason>`.
    std::cerr << "zsculpt: error: " << e.what() << "\n";
    return 2;
  }
  try {
    for (const Command& command : commands)
      if (command.app->parsed()) return command.action();
    // No subcommand: the window on the default scene (the open command's default).
    for (const Command& command : commands)
      if (command.app->get_name() == "open") return command.action();
    std::cout << app.help();
    return 0;
  } catch (const DivergenceError& e) {
    std::cerr << "zsculpt: error: " << e.what() << "\n";
    return 3;
  } catch (const Error& e) {
    std::cerr << "zsculpt: error: " << e.what() << "\n";
    return 2;
  } catch (const std::bad_alloc&) {
    std::cerr << "zsculpt: error: out of memory\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "zsculpt: error: " << e.what() << "\n";
    return 2;
  }
}

}  // namespace zsculpt::cli
