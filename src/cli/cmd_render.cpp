// zsculpt render MESH|SCENE --out DIR [--frames N] [--every K] [--size WxH] [--property NAME]
// [--levels L] (cli.md): simulate offscreen and write PNG frames, the diagnostics CSV and
// the energy and momentum plot (see render_job.h).

#include <memory>

#include "commands.h"
#include "render_job.h"

namespace zsculpt::cli {

void addRenderCommand(CLI::App& root, CommandList& commands) {
  auto* app = root.add_subcommand(
      "render", "simulate offscreen (OSMesa) to PNG frames, diagnostics and plots");
  app->footer(
      "The camera is framed on the start. It stays put for a model held by pins and follows the "
      "centre of mass of a free one (the caption says how far it went); it backs away when the "
      "model would leave the view. A scene's camera sets the angles (and a fixed distance).");
  auto o = std::make_shared<RenderJobOptions>();
  o->model.addTo(app);
  o->run.addTo(app);
  app->add_option("--out", o->out, "output folder (created when missing)")->required();
  app->add_option("--frames", o->frames,
                  "frames to write (default 30), evenly spaced from the start to the end of "
                  "the run; one frame shows the end");
  app->add_option("--every", o->every,
                  "steps between frames, from step 0; with --frames N at most N frames (and "
                  "with no run length, a run just long enough for them)");
  app->add_option("--size", o->size, "image size WxH (default 1280x720)");
  app->add_option("--property", o->property,
                  "colour the surface by a property: mass, damping, stiffness, angular_stiffness, "
                  "rigidity, rest_length, rest_angle (default: none)");
  app->add_option("--levels", o->levels,
                  "Doo-Sabin levels of the drawn surface, 0 to 8 as far as they fit, as for "
                  "subdivide (default: 2 to 5, by the image size)");
  app->add_flag("--classic", o->classic,
                "draw classic Doo-Sabin (CGAL's masks), which does not interpolate the mesh");
  app->add_flag_callback(
      "--no-progress", [o] { o->progress = false; }, "no progress bar on standard error");
  app->add_flag("--verify-matrices", o->verifyMatrices,
                "after every edit, compare the locally updated matrices with a full rebuild");
  commands.push_back({app, [o]() {
                        const RenderJobResult r = runRenderJob(*o);
                        return reportRenderJob(*o, r, o->model.source);
                      }});
}

}  // namespace zsculpt::cli
