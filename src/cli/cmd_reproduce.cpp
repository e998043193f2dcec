// zsculpt reproduce WHAT --out DIR: the paper's tables and figures (reproduce.h).

#include <filesystem>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "commands.h"
#include "reproduce.h"
#include "zsculpt/core/errors.h"
#include "zsculpt/io/atomic_file.h"

namespace zsculpt::cli {

namespace {

const std::vector<std::pair<std::string, std::function<int(const ReproduceOptions&)>>>& targets() {
  static const std::vector<std::pair<std::string, std::function<int(const ReproduceOptions&)>>>
      list = {
          {"table1", reproduceTable1},   {"figure3", reproduceFigure3},
          {"figure5", reproduceFigure5}, {"figure6", reproduceFigure6},
          {"figure7", reproduceFigure7}, {"figure8", reproduceFigure8},
          {"figure9", reproduceFigure9}, {"figure10", reproduceFigure10},
      };
  return list;
}

}  // namespace

void addReproduceCommand(CLI::App& root, CommandList& commands) {
  auto* app = root.add_subcommand("reproduce",
                                  "the paper's table 1 (CSV) and figures (data, JSON and images)");
  auto what = std::make_shared<std::string>();
  auto options = std::make_shared<ReproduceOptions>();
  std::string names;
  for (const auto& [name, fn] : targets()) names += (names.empty() ? "" : ", ") + name;
  app->add_option("what", *what,
                  "one of: " + names + ", all (figures 1, 2 and 4 are diagrams, with no results)")
      ->required();
  app->add_option("--out", options->out, "output folder")->required();
  app->add_flag("--quick", options->quick, "shorter runs (for tests)");
  commands.push_back(
      {app, [what, options]() {
         io::checkCreatableDirectory(options->out);
         if (*what == "all") {
           int status = 0;
           for (const auto& [name, fn] : targets()) status = std::max(status, fn(*options));
           return status;
         }
         for (const auto& [name, fn] : targets())
           if (name == *what) return fn(*options);
         std::string valid;
         for (const auto& [name, fn] : targets()) valid += (valid.empty() ? "" : ", ") + name;
         const bool diagram = *what == "figure1" || *what == "figure2" || *what == "figure4";
         throw InvalidInputError("reproduce: " +
                                 (diagram ? *what + " is one of the paper's diagrams (figures 1, 2 "
                                                    "and 4), not a result to reproduce"
                                          : "unknown target '" + *what + "'") +
                                 " (valid: " + valid + ", all)");
       }});
}

}  // namespace zsculpt::cli
