// zsculpt replay RECORDING --out DIR: re-runs a recorded interactive session headless
// (cli.md; recording format in include/zsculpt/app/recording.h). Writes final_state.csv,
// diagnostics.csv and PNG frames through OSMesa, and checks the final state against the
// recorded one bit for bit.

#include <chrono>
#include <cstdio>
#include <iostream>
#include <memory>
#include <optional>

#include "commands.h"
#include "console.h"
#include "levels.h"
#include "model_options.h"
#include "zsculpt/app/recording.h"
#include "zsculpt/core/errors.h"
#include "zsculpt/render/renderer.h"

namespace zsculpt::cli {

namespace {

struct ReplayOptions {
  std::string recording;
  std::string out;
  std::optional<long> every;  // none: only the final frame
  std::string size = "1280x720";
  std::string property;
  int levels = 2;
  bool noFrames = false;
  bool json = false;
};

std::string hex(std::uint64_t v) {
  char text[17];
  std::snprintf(text, sizeof text, "%016llx", static_cast<unsigned long long>(v));
  return text;
}

int runReplay(const ReplayOptions& o) {
  app::ReplayOptions options;
  options.outDir = o.out;
  if (o.every && *o.every < 1) throw InvalidInputError("--every: must be at least 1");
  options.frameEvery = o.every ? static_cast<unsigned long>(*o.every) : 0;
  options.frames = !o.noFrames;
  render::parseImageSize(o.size, options.width, options.height, "--size");
  if (!o.property.empty()) options.property = propertyOption(o.property);
  checkLevelsRange(o.levels);
  options.levels = o.levels;
  const app::Recording recording = app::readRecording(o.recording);
  if (!recording.setup)
    throw InvalidInputError(o.recording +
                            ": no header line: a script without a model cannot be replayed "
                            "(run it with `zsculpt open MESH --script FILE`)");
  const auto start = std::chrono::steady_clock::now();
  app::ReplayResult r;
  try {
    r = app::replay(recording, options);
  } catch (const InvalidInputError& e) {
    throw InvalidInputError(o.recording + ": " + e.what());  // which file the command was in
  }
  const double wall =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (options.frames)
    warnAboutOtherFrames(o.out, static_cast<std::size_t>(r.numberedFramesWritten));
  // What the session said, as warnings; a run of the same notice (a model that diverges
  // every cycle) is told once, with its count.
  for (size_t k = 0; k < r.notices.size();) {
    size_t same = k + 1;
    while (same < r.notices.size() && r.notices[same] == r.notices[k]) ++same;
    warn(o.recording + ": " + r.notices[k] +
         (same - k > 1 ? " (" + std::to_string(same - k) + " times)" : std::string()));
    k = same;
  }
  const char* match = !r.matchesRecording ? "null" : (*r.matchesRecording ? "true" : "false");
  if (o.json) {
    std::cout << "{\n"
              << "  \"cycles\": " << r.cycles << ",\n"
              << "  \"commands\": " << r.commands << ",\n"
              << "  \"time\": " << jsonNumber(r.finalState.time) << ",\n"
              << "  \"divergences\": " << r.divergences << ",\n"
              << "  \"state_hash\": \"" << hex(r.stateHash) << "\",\n"
              << "  \"matches_recording\": " << match << ",\n"
              << "  \"frames\": " << r.framesWritten << ",\n"
              << "  \"wall_seconds\": " << jsonNumber(wall) << "\n"
              << "}\n";
  } else {
    std::cout << "replayed " << r.commands << " commands over " << r.cycles
              << " cycles (t = " << r.finalState.time << " s) in " << wall << " s\n"
              << "final state " << o.out << "/final_state.csv, hash " << hex(r.stateHash);
    if (r.matchesRecording)
      std::cout << (*r.matchesRecording ? ": bit-identical to the recorded session"
                                        : ": DIFFERS from the recorded session");
    else
      std::cout << ": not compared (the recording has no footer with a final hash: a script, or "
                   "a session that did not end cleanly)";
    std::cout << "\n";
    if (r.framesWritten > 0) std::cout << r.framesWritten << " frames in " << o.out << "\n";
  }
  if (r.matchesRecording && !*r.matchesRecording) {
    std::cerr << "zsculpt: error: " << o.recording
              << ": the replayed final state differs from the recorded one (hash "
              << hex(r.stateHash) << " vs " << hex(*recording.stateHash) << ")\n";
    return 2;
  }
  if (r.divergences > 0) {
    // cli.md: exit 3 when the simulation diverged, its outputs still written. The session
    // rolled back and paused, as the window did; a pipeline must not take it for a clean run.
    std::cerr << "zsculpt: error: " << o.recording << ": the simulation diverged " << r.divergences
              << (r.divergences == 1 ? " time" : " times")
              << " in the session (each rolled back to its last good state, as in the window); "
              << "the outputs in " << o.out << " are whole\n";
    return 3;
  }
  return 0;
}

}  // namespace

void addReplayCommand(CLI::App& root, CommandList& commands) {
  auto* app = root.add_subcommand("replay", "re-run a recorded interactive session headless");
  auto o = std::make_shared<ReplayOptions>();
  app->add_option("recording", o->recording, "a file written by `zsculpt open --record FILE`")
      ->required();
  app->add_option("--out", o->out, "output folder: final_state.csv, diagnostics.csv, frames")
      ->required();
  app->add_option("--every", o->every,
                  "a PNG frame every K cycles (default: only the final frame)");
  app->add_option("--size", o->size, "frame size WxH (default 1280x720)");
  app->add_option("--property", o->property, "colour the surface by this property");
  app->add_option("--levels", o->levels, "subdivision levels of the drawn surface (default 2)");
  app->add_flag("--no-frames", o->noFrames, "write no PNG frames");
  app->add_flag("--json", o->json, "a JSON summary on standard output");
  commands.push_back({app, [o]() { return runReplay(*o); }});
}

}  // namespace zsculpt::cli
