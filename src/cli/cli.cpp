#include "zsculpt/cli/cli.h"

#include <CLI/CLI.hpp>
#include <cerrno>
#include <charconv>
#include <csignal>
#include <cstring>
#include <iostream>
#include <regex>
#include <string>

#include "commands.h"
#include "console.h"
#include "model_options.h"
#include "zsculpt/core/errors.h"

namespace zsculpt::cli {

namespace {

// cli.md reads every value as written: none is empty, and whole numbers are decimal (CLI11
// alone would read 010 as octal and 0x10 as hexadecimal, turn a count too large for its type
// into the largest one, and take an empty value as no value). Attached to every option of
// every command, it runs before the conversion.
void checkValues(CLI::App& app) {
  for (CLI::Option* option : app.get_options()) {
    if (option->get_type_size_max() == 0) continue;  // a flag
    const std::string type = option->get_type_name();
    const bool unsignedWhole = type.rfind("UINT", 0) == 0;
    const bool whole = type.rfind("INT", 0) == 0 || unsignedWhole;
    option->transform(CLI::Validator(
        [whole, unsignedWhole](std::string& value) -> std::string {
          if (value.empty()) return "the value must not be empty";
          if (!whole) return {};
          // An unsigned count takes no sign at all ("-1" is not converted to 2^64 - 1).
          auto parse = [&value](auto parsed) -> std::string {
            const char* end = value.data() + value.size();
            const auto [ptr, ec] = std::from_chars(value.data(), end, parsed);
            if (ec == std::errc::result_out_of_range) return "'" + value + "' is out of range";
            if (ec != std::errc() || ptr != end)
              return "'" + value + "' is not a whole number in decimal";
            value = std::to_string(parsed);  // 010 is ten, not CLI11's octal eight
            return {};
          };
          return unsignedWhole ? parse(0ULL) : parse(0LL);
        },
        ""));
  }
  for (CLI::App* command : app.get_subcommands([](CLI::App*) { return true; }))
    checkValues(*command);
}

// An error as one printable line whatever text it quotes (a damaged file's bytes, a line
// break, a NUL): cli.md promises one line.
std::string oneLine(std::string text) {
  for (char& c : text)
    if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) c = '?';
  return text;
}

}  // namespace

int run(int argc, char** argv) {
  // A reader that closed its end (`zsculpt info M | head -1`, `| true`) killed the process by
  // SIGPIPE (exit 141, no word): ignored, the write fails with EPIPE and is said as any failed
  // write to standard output is (`delivered` below, or the file's IOError), exit 2.
  std::signal(SIGPIPE, SIG_IGN);
  CLI::App app{"zsculpt: physics-based sculpting with the z-domain solver of Ray and Qin"};
  app.require_subcommand(0, 1);
  app.set_version_flag("--version", std::string("zsculpt ") + ZSCULPT_VERSION);
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
  checkValues(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::Success& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    // One line, as cli.md asks: `zsculpt: error: <argument>: <reason>`, in the words of the
    // other messages (CLI11's "At least 3 required but received 2" for `--gravity 0,0`).
    static const std::regex count("At least ([0-9]+) required but received ([0-9]+)");
    const std::string text =
        std::regex_replace(e.what(), count, "expected $1 comma-separated values, got $2");
    std::cerr << "zsculpt: error: " << oneLine(text) << "\n";
    return 2;
  }
  // What went to standard output must have arrived: a full disk or a closed pipe under
  // `--json > file` is an error, not a silent success with a truncated file.
  auto delivered = [](int status) {
    errno = 0;
    std::cout.flush();
    if (std::cout.good()) return status;
    std::cerr << "zsculpt: error: standard output: "
              << (errno != 0 ? std::strerror(errno) : "the write failed") << "\n";
    return status == 0 ? 2 : status;
  };
  try {
    for (const Command& command : commands)
      if (command.app->parsed()) return delivered(command.action());
    // No subcommand: the window on the default scene (the open command's default).
    for (const Command& command : commands)
      if (command.app->get_name() == "open") return delivered(command.action());
    std::cout << app.help();
    return delivered(0);
  } catch (const DivergenceError& e) {
    std::cerr << "zsculpt: error: " << oneLine(e.what()) << "\n";
    return 3;
  } catch (const InterruptedError& e) {
    // Said, then ended by the signal itself, as the shell and `timeout` expect.
    std::cerr << "zsculpt: error: " << oneLine(e.what()) << "\n";
    std::cerr.flush();
    std::signal(e.signal(), SIG_DFL);
    std::raise(e.signal());
    return 128 + e.signal();
  } catch (const Error& e) {
    std::cerr << "zsculpt: error: " << oneLine(e.what()) << "\n";
    return 2;
  } catch (const std::bad_alloc&) {
    const std::string& model = modelInWork();
    std::cerr << "zsculpt: error: " << (model.empty() ? std::string() : oneLine(model) + ": ")
              << "out of memory\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "zsculpt: error: " << oneLine(e.what()) << "\n";
    return 2;
  }
}

}  // namespace zsculpt::cli
