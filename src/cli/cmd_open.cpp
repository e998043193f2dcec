// zsculpt open [MESH|SCENE]: the interactive window (cli.md; docs/user-guide.md). With no
// model (and for `zsculpt` without a subcommand) it opens the default scene.

#include <iostream>
#include <memory>

#include "commands.h"
#include "console.h"
#include "model_options.h"
#include "zsculpt/app/application.h"
#include "zsculpt/core/errors.h"
#include "zsculpt/io/atomic_file.h"
#include "zsculpt/io/state_io.h"
#include "zsculpt/render/renderer.h"

namespace zsculpt::cli {

namespace {

struct OpenOptions {
  ModelOptions model;
  RunOptions run;  // scheme and time step only (resolve())
  std::optional<double> perturb;
  std::optional<unsigned> seed;
  std::string stateIn;
  std::vector<std::string> forces, torques;
  std::vector<long> pins, normalPins;
  app::WindowOptions window;
  std::string size = "1280x800";
  bool paused = false;
};

app::SessionSetup makeSetup(const OpenOptions& o) {
  ModelOptions model = o.model;
  if (model.source.empty()) model.source = app::defaultScenePath();
  const LoadedModel loaded = model.load();
  checkOutputsSpareInputs({{"--record", &o.window.recordPath}, {"--state-out", &o.window.stateOut}},
                          loaded, o.stateIn, o.window.scriptPath);
  io::SceneDescription scene;
  if (loaded.scene) {
    scene = *loaded.scene;
  } else {
    scene.mesh = loaded.source;
    // The uniform values the flags gave, so the recorded scene stays small.
    const PhysicalProperties& p = loaded.model.properties;
    if (p.mass.size() > 0) {
      scene.properties.mass = p.mass[0];
      scene.properties.damping = p.damping[0];
      scene.properties.stiffness = p.stiffness[0];
      scene.properties.angularStiffness = p.angularStiffness[0];
      scene.properties.rigidity = p.rigidity[0];
    }
    scene.properties.stiffnessCap = p.stiffnessCap;
    scene.properties.gravity = p.gravity;
  }
  // The axis the mesh was turned by (--up, the scene's, or its format's), so that a recording
  // replays and a saved scene reopens the mesh as the window showed it.
  scene.up = loaded.report.up;
  // Whatever the flags did to the model is now in the scene, as values or full arrays.
  io::recordProperties(scene, loaded.model);
  // A scene's own step above the stable limit (the window allows one, in red, and saves
  // it) opens with a warning: refused, the saved session could not be opened again. A step
  // that flags ask for or make unstable (--dt, --stiffness ...) is still refused without
  // --allow-unstable.
  RunOptions run = o.run;
  const ModelOptions& m = o.model;
  const bool sceneAsSaved = !m.mass && !m.damping && !m.stiffness && !m.angularStiffness &&
                            !m.rigidity && !m.stiffnessCap && !m.restLengthScale &&
                            m.gravity.empty();
  if (!run.dt && !run.dtRatio && sceneAsSaved) run.allowUnstable = true;
  const RunOptions::Resolved resolved = run.resolve(loaded);
  if (!resolved.aboveStableLimit.empty() && !o.run.allowUnstable)
    warn(resolved.aboveStableLimit + "; it will diverge: lower it in the Simulation panel");
  if (o.perturb) {
    if (!(*o.perturb >= 0.0) || !std::isfinite(*o.perturb))
      throw InvalidInputError("--perturb: must be a finite number >= 0");
    scene.simulation.perturb = *o.perturb;
  }
  if (o.seed) scene.simulation.seed = *o.seed;
  for (const std::string& f : o.forces) {
    const TimedLoad l = parseTimedLoad(f, "--force");
    scene.forces.push_back({l.vertex, l.value, l.start, l.end});
  }
  for (const std::string& t : o.torques) {
    const TimedLoad l = parseTimedLoad(t, "--torque");
    scene.torques.push_back({l.vertex, l.value, l.start, l.end});
  }
  const Index n = loaded.model.mesh.numVertices();
  auto vertex = [n](long v, const char* flag) {
    if (v < 0 || v >= n)
      throw InvalidInputError(std::string(flag) + " " + std::to_string(v) +
                              ": no such vertex (the model has " + std::to_string(n) + ")");
    return static_cast<Index>(v);
  };
  for (long v : o.pins)
    scene.constraints.push_back({io::ConstraintType::Position, vertex(v, "--pin"), {}, {}, {}, {}});
  for (long v : o.normalPins)
    scene.constraints.push_back(
        {io::ConstraintType::Normal, vertex(v, "--pin-normal"), {}, {}, {}, {}});
  io::validateScene(scene, loaded.model.mesh);

  app::SessionSetup setup;
  setup.mesh = loaded.model.mesh;
  setup.scheme = resolved.settings.scheme;
  setup.period = resolved.settings.period;
  if (!o.stateIn.empty()) {
    State state = io::loadState(o.stateIn, n);
    // As simulate: only an explicit --perturb is added to a given state.
    if (o.perturb && scene.simulation.perturb > 0.0) {
      Points kick;
      randomVelocity(loaded.model.properties.mass, scene.simulation.perturb,
                     static_cast<unsigned>(scene.simulation.seed), kick);
      state.velocity += kick;
    }
    setup.initial = std::move(state);
  }
  setup.scene = std::move(scene);
  return setup;
}

int runOpen(const OpenOptions& options) {
  app::WindowOptions window = options.window;
  // A mesh opened later from the File panel gets the same flags as the first.
  window.meshDefaults.properties = options.model.withFlags(UniformProperties{});
  if (!options.run.scheme.empty())
    window.meshDefaults.simulation.scheme =
        io::schemeFromName(schemeName(schemeOption(options.run.scheme)));
  window.meshDefaults.simulation.dtRatio = options.run.dtRatio;
  render::parseImageSize(options.size, window.width, window.height, "--size");
  window.startRunning = !options.paused;
  if (!(window.speed > 0.0) || !std::isfinite(window.speed))
    throw InvalidInputError("--speed: must be a positive number");
  // What is written when the window closes is checked now: a session is not to be lost to
  // a path that could never be written.
  for (const std::string* path : {&window.recordPath, &window.stateOut})
    if (!path->empty()) io::checkOutputFile(*path);
  // And the folder screenshots and a script's log go to (a QA pass: a script ran whole, then
  // failed on /proc/script_log.json).
  if (!window.screenshotDir.empty()) {
    try {
      io::checkCreatableDirectory(window.screenshotDir);
    } catch (const Error& e) {
      throw InvalidInputError(std::string("--screenshot-out: ") + e.what());
    }
  }
  checkDistinctOutputs({{"--record", &window.recordPath}, {"--state-out", &window.stateOut}});
  // From before the model loads (a large import takes seconds): a signal then ended the
  // process by its default action, without the recording and --state-out. Now it is noted,
  // and the window closes as soon as it opens, writing them (a QA pass).
  const Interruptions signals;
  app::SessionSetup setup = makeSetup(options);
  return app::runWindow(std::move(setup), window);
}

}  // namespace

void addOpenCommand(CLI::App& root, CommandList& commands) {
  auto* app = root.add_subcommand(
      "open", "open the window on a model (no model: the default scene); see docs/user-guide.md");
  auto o = std::make_shared<OpenOptions>();
  o->model.addTo(app, /*sourceOptional=*/true);
  app->add_option("--scheme", o->run.scheme,
                  "default | paper | exact | symplectic-euler | implicit-euler");
  auto* dt = app->add_option("--dt", o->run.dt, "time step, seconds");
  app->add_option("--dt-ratio", o->run.dtRatio,
                  "time step as a fraction of equation 5's T_max (default 0.5)")
      ->excludes(dt);
  app->add_flag("--allow-unstable", o->run.allowUnstable,
                "accept a time step above the scheme's stable limit");
  app->add_option("--perturb", o->perturb,
                  "random initial velocity of this size, zero net momentum");
  app->add_option("--seed", o->seed, "seed of --perturb, 0 to 4294967295 (default 0)")
      ->check(CLI::Range(0U, 4294967295U));
  app->add_option("--state-in", o->stateIn, "initial state (CSV x,y,z,vx,vy,vz)");
  app->add_option("--force", o->forces, "I:FX,FY,FZ[:T0:T1] force at vertex I (repeatable)");
  app->add_option("--torque", o->torques, "I:TX,TY,TZ[:T0:T1] torque at vertex I (repeatable)");
  app->add_option("--pin", o->pins, "pin vertex I where it is (repeatable)");
  app->add_option("--pin-normal", o->normalPins, "hold the normal at vertex I (repeatable)");
  app->add_option("--record", o->window.recordPath,
                  "record the session (every command with its cycle) to FILE");
  app->add_option("--script", o->window.scriptPath,
                  "run a scripted session (a recording, plus \"ui\" lines)");
  app->add_option("--screenshot-out", o->window.screenshotDir,
                  "folder for screenshots (F12, scripts)");
  app->add_option("--state-out", o->window.stateOut,
                  "write the final state here when the window closes");
  app->add_option("--size", o->size, "window size WxH (default 1280x800)");
  app->add_option("--speed", o->window.speed, "simulated seconds per wall second (default 1)");
  app->add_flag("--paused", o->paused, "start paused (Space plays)");
  commands.push_back({app, [o]() { return runOpen(*o); }});
}

}  // namespace zsculpt::cli
