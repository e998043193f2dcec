// zsculpt demo [--out DIR] (cli.md): the main job without a display. The default scene
// (assets/scenes/default.json: Torus-I pushed and twisted, then released) to PNG frames,
// the diagnostics CSV and the energy and momentum plot in ./zsculpt-demo/.

#include <memory>

#include "commands.h"
#include "render_job.h"
#include "zsculpt/app/session.h"

namespace zsculpt::cli {

void addDemoCommand(CLI::App& root, CommandList& commands) {
  auto* app = root.add_subcommand(
      "demo", "the main job without a display: the default scene to PNG frames and plots");
  auto o = std::make_shared<RenderJobOptions>();
  o->out = "zsculpt-demo";
  o->frames = 48;
  app->add_option("--out", o->out, "output folder (default ./zsculpt-demo)");
  app->add_option("--frames", o->frames, "frames to write (default 48)");
  app->add_option("--size", o->size, "image size WxH (default 1280x720)");
  app->add_option("--property", o->property, "colour the surface by a property (default: none)");
  app->add_flag("--json", o->run.json, "a JSON summary on standard output");
  app->add_flag_callback(
      "--no-progress", [o] { o->progress = false; }, "no progress bar on standard error");
  commands.push_back({app, [o]() {
                        RenderJobOptions job = *o;
                        job.model.source = app::defaultScenePath();
                        const RenderJobResult r = runRenderJob(job);
                        return reportRenderJob(job, r, job.model.source);
                      }});
}

}  // namespace zsculpt::cli
