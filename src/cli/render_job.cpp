#include "render_job.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <sstream>

#include "console.h"
#include "levels.h"
#include "runaway_guard.h"
#include "timed_edits.h"
#include "zsculpt/app/view.h"
#include "zsculpt/core/errors.h"
#include "zsculpt/io/atomic_file.h"
#include "zsculpt/io/state_io.h"
#include "zsculpt/render/plot.h"
#include "zsculpt/render/renderer.h"
#include "zsculpt/subdivision/subdivision.h"

namespace zsculpt::cli {

namespace {

// The run's own files in --out: its `frames` frames (names `digits` wide), its plot, and its
// diagnostics when --csv names none. None may be another output or an input: the run would
// overwrite the one with the other and say nothing (a --csv named like the plot came out a
// PNG; a --state-in named like the diagnostics was replaced by them).
void checkOwnFilesSpare(const RenderJobOptions& o, const LoadedModel& loaded, size_t frames,
                        int digits) {
  namespace fs = std::filesystem;
  // Resolved where it exists, lexically past that ("out/", "./new/../" name their folder).
  auto canonical = [](const std::string& path) {
    std::error_code ec;
    fs::path p = fs::weakly_canonical(fs::absolute(path, ec), ec).lexically_normal();
    if (!p.has_filename() && p.has_parent_path()) p = p.parent_path();
    return p;
  };
  const fs::path dir = canonical(o.out);
  auto ownFile = [&](const fs::path& file) -> std::string {
    if (file.parent_path() != dir) return {};
    const std::string name = file.filename().string();
    if (name == "energy_momentum.png") return "the run's plot";
    if (o.run.csv.empty() && name == "diagnostics.csv") return "the run's diagnostics";
    const size_t width = static_cast<size_t>(digits);
    if (name.size() != 6 + width + 4 || name.rfind("frame_", 0) != 0 ||
        name.compare(6 + width, 4, ".png") != 0)
      return {};
    size_t index = 0;
    for (size_t k = 6; k < 6 + width; ++k) {
      if (name[k] < '0' || name[k] > '9') return {};
      index = 10 * index + static_cast<size_t>(name[k] - '0');
    }
    return index < frames ? "one of the run's frames" : std::string();
  };
  std::vector<std::pair<std::string, std::string>> named = {
      {"--csv", o.run.csv}, {"--state-out", o.run.stateOut}, {"--state-in", o.run.stateIn}};
  named.emplace_back(loaded.source, loaded.source);
  if (loaded.scene) named.emplace_back(loaded.scene->mesh, loaded.scene->mesh);
  for (const auto& [what, path] : named) {
    if (path.empty()) continue;
    const std::string own = ownFile(canonical(path));
    if (own.empty()) continue;
    const std::string subject = what == path ? path : what + ": " + path;
    throw InvalidInputError(subject + " is " + own + " in --out " + o.out +
                            ", and one would overwrite the other");
  }
}

// A file's bytes (a staged frame, to be written through a link or to a device).
std::string readFileBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream bytes;
  bytes << in.rdbuf();
  if (!in) throw IOError(path + ": cannot read it back");
  return bytes.str();
}

constexpr long kDefaultFrames = 30;
constexpr long kMaxFrames = 100000;
constexpr long kMaxRenderSteps = 1000000000;

/// The steps at which frames are taken: with --every K, 0, K, 2K ... up to the run's end
/// (at most --frames of them); otherwise --frames (default 30) spread evenly over the run,
/// the first at the rest state and the last at its end. Evenly means a whole number of
/// steps apart: a run given as a time takes a step count that the frames divide, with the
/// step shortened to fit (never lengthened, so never past the stable limit), and so ends on
/// that time; a run of the default length is lengthened to the next such count. A step
/// count given explicitly is kept, with a warning when the frames cannot divide it.
std::vector<long> frameSteps(const RenderJobOptions& o, RunOptions::Resolved& run,
                             bool explicitLength) {
  if (o.frames && (*o.frames < 1 || *o.frames > kMaxFrames))
    throw InvalidInputError("--frames: must be between 1 and " + std::to_string(kMaxFrames));
  if (o.every && *o.every < 1) throw InvalidInputError("--every: must be at least 1");
  long& steps = run.steps;
  // A render keeps every step's energy and momenta for its plot and diagnostics (80 bytes a
  // step and a line of text): 1e18 s asked for failed as "vector::reserve", and the frame
  // arithmetic below overflowed (a QA pass).
  auto checkLength = [&](long asked, const std::string& source) {
    if (asked > kMaxRenderSteps)
      throw InvalidInputError(source + ": " + std::to_string(asked) +
                              " steps: a render keeps every step's energy and momentum for its "
                              "plot, so it runs at most " +
                              std::to_string(kMaxRenderSteps) + " steps");
  };
  const std::string length = run.seconds ? "the run's time (--time or the scene's)"
                                         : "the run's steps (--steps or the scene's)";
  checkLength(steps, length);
  if (o.every) checkLength(*o.every, "--every");
  std::vector<long> at;
  if (o.every) {
    const long k = *o.every;
    // --frames N --every K with no run length: the run is just long enough for N frames.
    if (o.frames && !explicitLength) steps = (*o.frames - 1) * k;
    checkLength(steps, explicitLength ? length : "--frames with --every");
    for (long s = 0; s <= steps; s += k) {
      if (o.frames && static_cast<long>(at.size()) >= *o.frames) break;
      at.push_back(s);
      if (static_cast<long>(at.size()) > kMaxFrames)
        throw InvalidInputError("--every: " + std::to_string(k) + " would write more than " +
                                std::to_string(kMaxFrames) + " frames");
    }
    // --frames cut the frames short of the run's end (without it, the frames go on to the
    // end, K steps apart).
    if (o.frames && static_cast<long>(at.size()) == *o.frames && at.back() + k <= steps)
      warn("--every " + std::to_string(k) + " --frames " + std::to_string(*o.frames) +
           ": frames at steps 0 to " + std::to_string(at.back()) + "; the run goes on to step " +
           std::to_string(steps) + " with no more frames");
    return at;
  }
  const long n = o.frames.value_or(kDefaultFrames);
  const long intervals = std::max(1L, n - 1);
  if (run.seconds && *run.seconds > 0.0) {
    // Always fitted, so that the run ends on the time asked for.
    long fitted = std::max(1L, (steps + intervals - 1) / intervals) * intervals;
    while (*run.seconds / static_cast<double>(fitted) > run.settings.period) fitted += intervals;
    const double period = *run.seconds / static_cast<double>(fitted);
    if (!run.explicitPeriod.empty() && period < run.settings.period * (1.0 - 1e-12)) {
      std::ostringstream msg;
      msg.precision(6);
      msg << run.explicitPeriod << ": the step is shortened from " << run.settings.period
          << " s to " << period << " s, so that the frames fall on whole steps and the run "
          << "ends at " << *run.seconds << " s";
      warn(msg.str());
    }
    checkLength(fitted, length);
    steps = fitted;
    run.settings.period = period;
  }
  if (n == 1) return {steps};
  if (steps >= intervals && steps % intervals != 0) {
    if (!run.explicitSteps) {
      steps = (steps + intervals - 1) / intervals * intervals;
    } else {
      const long apart = steps / intervals;
      warn("--frames " + std::to_string(n) + ": " + std::to_string(steps) +
           " steps do not divide into " + std::to_string(intervals) +
           " equal intervals, so frames are " + std::to_string(apart) + " or " +
           std::to_string(apart + 1) + " steps apart (--steps " +
           std::to_string((apart + 1) * intervals) + " or --time would space them evenly)");
    }
  }
  for (long f = 0; f < n; ++f) {
    const long s = static_cast<long>(std::llround(
        static_cast<double>(f) * static_cast<double>(steps) / static_cast<double>(intervals)));
    if (at.empty() || s != at.back()) at.push_back(s);
  }
  // A run of fewer steps than frames asked for has a frame per step and no more.
  if (o.frames && static_cast<long>(at.size()) < *o.frames)
    warn("--frames " + std::to_string(*o.frames) + ": the run has " + std::to_string(steps) +
         (steps == 1 ? " step, so " : " steps, so ") + std::to_string(at.size()) +
         (at.size() == 1 ? " frame (of its one state)" : " frames (one per state)"));
  return at;
}

/// "[#######.........]  42%  frame 12/30" on one terminal line, redrawn in place.
class ProgressBar {
 public:
  explicit ProgressBar(bool enabled) : enabled_(enabled && ::isatty(STDERR_FILENO) == 1) {}
  void update(double fraction, long frame, long frames) {
    if (!enabled_) return;
    const int percent = static_cast<int>(std::floor(100.0 * std::clamp(fraction, 0.0, 1.0)));
    if (percent == last_ && !progressLineCleared()) return;
    last_ = percent;
    constexpr int kWidth = 30;
    const int filled = percent * kWidth / 100;
    std::fprintf(stderr, "\r[%.*s%.*s] %3d%%  frame %ld/%ld", filled,
                 "##############################", kWidth - filled,
                 "..............................", percent, frame, frames);
    std::fflush(stderr);
    progressLineDrawn(true);
  }
  void finish() {
    if (enabled_ && last_ >= 0 && !progressLineCleared()) std::fputc('\n', stderr);
    progressLineDrawn(false);
    last_ = -1;
  }

 private:
  bool enabled_;
  int last_ = -1;
};

}  // namespace

RenderJobResult runRenderJob(const RenderJobOptions& o) {
  namespace fs = std::filesystem;
  const Interruptions interruptions;
  RenderJobResult result;
  // 1. Everything that can be refused, before any simulation work.
  render::parseImageSize(o.size, result.width, result.height, "--size");
  std::optional<Property> property;
  if (!o.property.empty() && o.property != "none") property = propertyOption(o.property);
  if (o.levels) checkLevelsRange(*o.levels);
  if (o.out.empty()) throw InvalidInputError("--out: an output folder is required");
  io::checkCreatableDirectory(o.out);  // made by the first frame written
  // The outermost folder of --out that is not there yet (the first frame makes it and those
  // inside it), so that a run refused part way takes away what it made, and no more.
  fs::path madeFolder;
  {
    std::error_code ec;
    for (fs::path p = fs::absolute(o.out, ec).lexically_normal(); !p.empty(); p = p.parent_path()) {
      if (!p.has_filename()) continue;  // a trailing slash
      if (fs::exists(p, ec)) break;
      madeFolder = p;
      if (p == p.root_path()) break;
    }
  }
  for (const std::string* path : {&o.run.csv, &o.run.stateOut})
    if (!path->empty()) io::checkOutputFile(*path);
  checkDistinctOutputs({{"--csv", &o.run.csv}, {"--state-out", &o.run.stateOut}});
  checkOutputsSpareStdout({{"--csv", &o.run.csv}, {"--state-out", &o.run.stateOut}}, o.run.json);
  render::OffscreenRenderer renderer;  // IOError when OSMesa cannot give a context
  renderer.checkSize(result.width, result.height, "--size");

  const LoadedModel loaded = o.model.load();
  throwIfInterrupted();  // a big model loads for a while: a Ctrl+C then ends it here
  checkOutputsSpareInputs({{"--csv", &o.run.csv}, {"--state-out", &o.run.stateOut}}, loaded,
                          o.run.stateIn);
  RunOptions::Resolved resolved = o.run.resolve(loaded);
  const bool explicitLength =
      o.run.steps || o.run.time ||
      (loaded.scene && (loaded.scene->simulation.steps || loaded.scene->simulation.time));
  const std::vector<long> frameAt = frameSteps(o, resolved, explicitLength);
  const int digits = std::max(4, static_cast<int>(std::to_string(frameAt.size() - 1).size()));
  checkOwnFilesSpare(o, loaded, frameAt.size(), digits);
  const long steps = std::max(resolved.steps, frameAt.back());
  result.steps = steps;
  result.period = resolved.settings.period;
  result.tMax = resolved.tMax;

  const Mesh& mesh = loaded.model.mesh;
  result.levels = o.levels.value_or(app::levelsForImage(mesh, result.width, result.height));
  std::unique_ptr<SubdivisionStencil> stencil;
  if (result.levels > 0) {
    SubdivisionOptions subdivision;
    subdivision.levels = result.levels;
    subdivision.interpolate = !o.classic;
    stencil = std::make_unique<SubdivisionStencil>(stencilForLevels(mesh, subdivision));
  }

  Simulation sim(loaded.model, resolved.settings);
  o.run.prepare(loaded, sim);
  for (const std::string& warning : sim.takeWarnings()) warn(loaded.source + ": " + warning);
  TimedEdits edits(loaded, sim, o.verifyMatrices);
  // A bare model at rest with nothing acting on it renders identical frames: said after the
  // run, with how to set it going (the frames are still written).
  bool nothingActs = false;
  {
    const State rest = State::atRest(sim.model().mesh);
    const bool atRest = sim.state().velocity.isZero(0.0) && sim.state().position == rest.position;
    const bool heldAway =
        std::any_of(sim.constraints().constraints().begin(), sim.constraints().constraints().end(),
                    [&](const Constraint& c) {
                      // (A normal pin may ask for another normal: counted as acting, never warned
                      // of.)
                      return c.kind == ConstraintKind::Normal || sim.pinTravel(c.id) ||
                             c.value != sim.state().position.row(c.vertex).transpose();
                    });
    // Springs away from their rest (rest lengths scaled, rest lengths or angles given by
    // the scene) move the model too: rendered with this warning until a QA pass.
    const Model& model = sim.model();
    const Diagnostics start = sim.diagnostics();
    const bool stressed =
        start.potential.radial + start.potential.angular > 1e-12 * springEnergyScale(model);
    nothingActs = atRest && !stressed && sim.forces().empty() && sim.torques().empty() &&
                  model.properties.gravity.isZero(0.0) && edits.schedule.size() == 0 && !heldAway;
  }
  auto sayNothingActs = [&] {
    if (nothingActs)
      warn(loaded.source +
           ": nothing acts on the model (no load, gravity, perturbation, initial state, pin "
           "target or edit), so it stays at rest and every frame is the same; try --perturb "
           "0.05, --force I:FX,FY,FZ or --gravity 0,0,-9.81");
  };

  // 2. The frame: the camera is framed once on the start (with its arrows), keeps that
  // orientation, and backs away (never closer) when the model would leave the view, so
  // that deformation shows as deformation and a still model gives identical frames. A
  // model held by position pins is watched from a fixed point: the pins stay where they
  // are on screen, and sagging or falling shows. A free model is followed by its centre of
  // mass, so that one set flying by its loads stays in view, and the caption says how far
  // the centre has gone.
  render::Frame frame;
  // Asked for the control mesh itself (--levels 0): its facets, lit flat. (An automatic level
  // 0, for a model too large to refine, keeps the smooth look.)
  frame.display.flatShading = o.levels && *o.levels == 0;
  frame.mesh = &sim.model().mesh;
  frame.stencil = stencil.get();
  frame.positions = &sim.state().position;
  VectorX scalar;
  const VectorX& mass = sim.model().properties.mass;
  auto centreOfMass = [&]() -> Vec3 {
    return (sim.state().position.transpose() * mass) / mass.sum();
  };
  const double diagonal = mesh.boundingBox().diagonal();
  const Vec3 centreAtStart = centreOfMass();
  bool anchored = false;
  for (const Constraint& c : sim.constraints().constraints())
    anchored = anchored || c.kind == ConstraintKind::Position;
  Vec3 targetOffset = Vec3::Zero();
  auto fillFrame = [&]() {
    frame.forces.clear();
    for (const TimedLoad& f : sim.forces())
      if (f.activeAt(sim.time())) frame.forces.push_back({f.vertex, f.value});
    frame.torques.clear();
    for (const TimedLoad& t : sim.torques())
      if (t.activeAt(sim.time())) frame.torques.push_back({t.vertex, t.value});
    frame.pins.clear();
    frame.normalPins.clear();
    for (const Constraint& c : sim.constraints().constraints()) {
      if (c.kind == ConstraintKind::Position)
        frame.pins.push_back(c.vertex);
      else
        frame.normalPins.push_back({c.vertex, c.value});
    }
    if (property) {
      render::propertyAsVertexScalar(sim.model().mesh, sim.model().angles, sim.model().properties,
                                     *property, scalar);
      frame.scalar.values = &scalar;
      frame.scalar.name = propertyLabel(*property);
    }
    frame.display.legend = property.has_value();
    const Vec3 centre = centreOfMass();
    if (!anchored) frame.camera.target = centre + targetOffset;
    const double moved = (centre - centreAtStart).norm();
    char caption[96];
    if (!anchored && moved > 1e-3 * diagonal)
      std::snprintf(caption, sizeof caption, "t = %.2f s, centre of mass %.3g m from its start",
                    sim.time(), moved);
    else
      std::snprintf(caption, sizeof caption, "t = %.2f s", sim.time());
    frame.caption = caption;
  };
  fillFrame();
  if (loaded.scene) app::applyCameraSettings(loaded.scene->camera, frame.camera);
  render::frameScene(frame, static_cast<double>(result.width) / result.height, 1.25);
  if (loaded.scene) {
    // A scene's explicit target and distance win over the automatic framing.
    const io::CameraSettings& c = loaded.scene->camera;
    if (c.target) frame.camera.target = *c.target;
    if (c.distance) frame.camera.distance = *c.distance;
  }
  targetOffset = frame.camera.target - centreOfMass();
  // A scene's explicit distance is kept as given; otherwise the camera may back away.
  const bool backAway = !(loaded.scene && loaded.scene->camera.distance);
  const double aspect = static_cast<double>(result.width) / result.height;
  Points viewPoints, viewRefined;

  // 3. Simulate, render and record.
  render::EnergyMomentumSeries series;
  std::ostringstream csv;
  csv.precision(17);
  csv << "step,time,kinetic,potential,total,px,py,pz,lx,ly,lz\n";
  for (auto* column : {&series.time, &series.kinetic, &series.potential, &series.total, &series.px,
                       &series.py, &series.pz, &series.lx, &series.ly, &series.lz})
    column->reserve(static_cast<size_t>(steps) + 1);
  auto record = [&](long step, const Diagnostics& d) {
    csv << step << ',' << sim.time() << ',' << d.kinetic << ',' << d.potential.total() << ','
        << d.total() << ',' << d.momentum.x() << ',' << d.momentum.y() << ',' << d.momentum.z()
        << ',' << d.angularMomentum.x() << ',' << d.angularMomentum.y() << ','
        << d.angularMomentum.z() << '\n';
    series.time.push_back(sim.time());
    series.kinetic.push_back(d.kinetic);
    series.potential.push_back(d.potential.total());
    series.total.push_back(d.total());
    series.px.push_back(d.momentum.x());
    series.py.push_back(d.momentum.y());
    series.pz.push_back(d.momentum.z());
    series.lx.push_back(d.angularMomentum.x());
    series.ly.push_back(d.angularMomentum.y());
    series.lz.push_back(d.angularMomentum.z());
  };
  // The frames are written to a folder of their own in --out and moved to their names when
  // the run ends (or diverges): a run refused or interrupted part way leaves the frames of
  // an earlier run in --out as they were (it overwrote some, then took them away).
  // Named by the process and the clock, and made new: a folder left by a killed run whose
  // process number came round again is not taken over.
  fs::path staging;
  std::vector<std::string> staged;
  auto writeFrame = [&]() {
    char name[32];
    std::snprintf(name, sizeof name, "frame_%0*zu.png", digits, result.frames.size());
    // The folder the user named is made here, at the first write (checked, not made, before
    // the run), so that its error names it rather than a frame in it.
    if (result.frames.empty()) {
      io::ensureWritableDirectory(o.out);
      const auto ticks = std::chrono::steady_clock::now().time_since_epoch().count();
      for (int attempt = 0;; ++attempt) {
        staging = fs::path(o.out) / (".zsculpt-frames-" + std::to_string(::getpid()) + "-" +
                                     std::to_string(ticks + attempt));
        std::error_code ec;
        if (fs::create_directory(staging, ec)) break;
        if (ec || attempt == 100)
          throw IOError(staging.string() +
                        ": cannot make it: " + (ec ? ec.message() : std::string("it is there")));
      }
    }
    fillFrame();
    if (backAway) render::keepSceneInView(frame, aspect, 1.25, viewPoints, viewRefined);
    staged.push_back((staging / name).string());
    renderer.renderPng(frame, result.width, result.height, staged.back());
    result.frames.push_back((fs::path(o.out) / name).string());
    result.frameTimes.push_back(sim.time());
  };

  ProgressBar progress(o.progress);
  const auto wallStart = std::chrono::steady_clock::now();
  size_t next = 0;
  record(0, sim.diagnostics());
  GuardedRun run(sim, edits);
  try {
    throwIfInterrupted();
    if (frameAt[next] == 0) {
      writeFrame();
      ++next;
    }
    for (long k = 1; k <= steps; ++k) {
      if (!run.step(k)) {
        result.diverged = true;
        result.divergedAt = k;
        result.divergence = run.why();
        break;
      }
      record(k, run.diagnostics());
      if (next < frameAt.size() && frameAt[next] == k) {
        writeFrame();
        ++next;
      }
      progress.update(static_cast<double>(k) / static_cast<double>(steps),
                      static_cast<long>(result.frames.size()), static_cast<long>(frameAt.size()));
    }
    throwIfInterrupted();
    progress.finish();
    result.stepsTaken = result.diverged ? result.divergedAt - 1 : steps;
    result.editsApplied = edits.applied;
    result.matrixDifference = edits.maxDifference;
    sayNothingActs();
    if (!result.diverged) {
      edits.sayWhatIsLeft(sim);
      o.run.sayLoadsLeft(loaded, sim.time());
    }

    // The frames go to their names last, over an earlier run's (its frames up to the last good
    // state when it diverged): every name checked before any output is written, so that a
    // failure leaves no mix. A link or a device of a frame's name is written through (as every
    // save is), not replaced.
    // (saveTarget refuses a folder of that name, follows links, and says a device is written
    // in place.)
    std::vector<io::SaveTarget> targets;
    targets.reserve(staged.size());
    for (const std::string& name : result.frames) targets.push_back(io::saveTarget(name));
    result.diagnostics =
        o.run.csv.empty() ? (fs::path(o.out) / "diagnostics.csv").string() : o.run.csv;
    io::writeFileAtomically(result.diagnostics, [&](std::ostream& out) { out << csv.str(); });
    result.plot = (fs::path(o.out) / "energy_momentum.png").string();
    render::PlotOptions plotOptions;
    plotOptions.title = fs::path(loaded.source).filename().string() + ": energy and momentum";
    // When the loads act, shaded: the energy and the momenta change there (a review).
    std::vector<render::PlotPanel> panels = render::energyMomentumPanels(series);
    const double runStart = series.time.empty() ? 0.0 : series.time.front();
    const double runEnd = series.time.empty() ? 0.0 : series.time.back();
    std::vector<render::Band> loads;
    for (const auto* list : {&sim.forces(), &sim.torques()})
      for (const TimedLoad& load : *list) {
        const double from = std::max(load.start, runStart), to = std::min(load.end, runEnd);
        if (to > from) loads.push_back({from, to});
      }
    for (render::PlotPanel& panel : panels) {
      panel.bands = loads;
      panel.bandLabel = "load";
    }
    render::savePlot(result.plot, panels, plotOptions);
    if (!o.run.stateOut.empty()) {
      io::saveState(run.lastGood(), o.run.stateOut);
      result.stateOut = o.run.stateOut;
    }
    // Last, the frames to their names over an earlier run's (checked before the other
    // outputs were written).
    for (size_t f = 0; f < staged.size(); ++f) {
      std::error_code ec;
      if (targets[f].inPlace) {
        const std::string bytes = readFileBytes(staged[f]);
        io::writeFileAtomically(result.frames[f], [&](std::ostream& out) { out << bytes; });
      } else {
        fs::rename(staged[f], targets[f].path, ec);
        if (ec) throw IOError(result.frames[f] + ": cannot write it: " + ec.message());
      }
    }
    {
      std::error_code ec;
      fs::remove_all(staging, ec);
    }
  } catch (...) {
    // Refused, failed or interrupted part way (a scene's edit out of range where it falls, a
    // full disk, memory, SIGTERM): the run leaves no output behind, so the frames it wrote
    // go, and the folders it made if they are empty. A divergence is not thrown.
    progress.finish();
    std::error_code ec;
    if (!staging.empty()) fs::remove_all(staging, ec);
    if (!madeFolder.empty())
      for (fs::path p = fs::absolute(o.out, ec).lexically_normal();; p = p.parent_path()) {
        if (!p.has_filename()) continue;
        if (!fs::remove(p, ec) || p == madeFolder || !p.has_parent_path()) break;
      }
    throw;
  }
  endIfInterrupted();
  result.wallSeconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - wallStart).count();
  return result;
}

int reportRenderJob(const RenderJobOptions& o, const RenderJobResult& r,
                    const std::string& source) {
  warnAboutOtherFrames(o.out, r.frames.size());
  if (o.run.json) {
    std::cout << "{\n  \"frames\": [";
    for (size_t i = 0; i < r.frames.size(); ++i)
      std::cout << (i ? ", " : "") << jsonString(r.frames[i]);
    std::cout << "],\n  \"frame_times\": [";
    for (size_t i = 0; i < r.frameTimes.size(); ++i)
      std::cout << (i ? ", " : "") << jsonNumber(r.frameTimes[i]);
    std::cout << "],\n"
              << "  \"diagnostics\": " << jsonString(r.diagnostics) << ",\n"
              << "  \"plot\": " << jsonString(r.plot) << ",\n"
              << "  \"width\": " << r.width << ",\n"
              << "  \"height\": " << r.height << ",\n"
              << "  \"levels\": " << r.levels << ",\n"
              << "  \"steps\": " << r.steps << ",\n"
              << "  \"dt\": " << jsonNumber(r.period) << ",\n"
              << "  \"t_max\": " << jsonNumber(r.tMax) << ",\n"
              << "  \"diverged\": " << (r.diverged ? "true" : "false") << ",\n"
              << "  \"diverged_at_step\": " << (r.diverged ? std::to_string(r.divergedAt) : "null")
              << ",\n";
    if (o.verifyMatrices)
      std::cout << "  \"edits_applied\": " << r.editsApplied << ",\n"
                << "  \"matrix_update_max_abs_diff\": " << jsonNumber(r.matrixDifference) << ",\n";
    std::cout << "  \"wall_seconds\": " << jsonNumber(r.wallSeconds) << "\n"
              << "}\n";
  } else {
    std::cout << "frames (" << r.frames.size() << ", " << r.width << "x" << r.height << "):";
    if (!r.frames.empty()) {
      std::cout << " " << r.frames.front();
      if (r.frames.size() > 1) std::cout << " ... " << r.frames.back();
    }
    std::cout << "\ndiagnostics: " << r.diagnostics << "\nplot: " << r.plot << "\n";
    if (!r.stateOut.empty()) std::cout << "state: " << r.stateOut << "\n";
    // Simulated time first: "N steps ... in W s" read as W seconds simulated.
    std::cout << "simulated " << static_cast<double>(r.stepsTaken) * r.period << " s in "
              << r.stepsTaken;
    if (r.stepsTaken != r.steps) std::cout << " of " << r.steps;
    std::cout << " steps of " << r.period << " s (" << shareOfTMax(r.period, r.tMax)
              << "); wall time " << r.wallSeconds << " s\n";
    if (o.verifyMatrices)
      std::cout << "edits applied " << r.editsApplied << ", matrix update max abs diff "
                << r.matrixDifference << "\n";
  }
  if (r.diverged) {
    std::cerr << "zsculpt: error: " << source << ": the simulation diverged at step "
              << r.divergedAt << " (" << r.divergence
              << "); the frames and diagnostics up to it were written"
              << (r.stateOut.empty() ? "" : ", and the last finite state") << "\n";
    return 3;
  }
  return 0;
}

}  // namespace zsculpt::cli
