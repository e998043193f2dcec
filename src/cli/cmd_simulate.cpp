// zsculpt simulate MESH|SCENE: headless simulation with diagnostics (cli.md).

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <optional>
#include <sstream>

#include "commands.h"
#include "console.h"
#include "model_options.h"
#include "runaway_guard.h"
#include "timed_edits.h"
#include "zsculpt/core/errors.h"
#include "zsculpt/io/atomic_file.h"
#include "zsculpt/io/state_io.h"

namespace zsculpt::cli {

namespace {

struct SimulateOptions {
  ModelOptions model;
  RunOptions run;
  bool verifyMatrices = false;
};

int runSimulate(const SimulateOptions& options) {
  const Interruptions interruptions;
  const LoadedModel loaded = options.model.load();
  throwIfInterrupted();  // a big model loads for a while: a Ctrl+C then ends it here
  const RunOptions::Resolved resolved = options.run.resolve(loaded);
  Simulation sim(loaded.model, resolved.settings);
  options.run.prepare(loaded, sim);
  for (const std::string& warning : sim.takeWarnings()) warn(loaded.source + ": " + warning);
  TimedEdits edits(loaded, sim, options.verifyMatrices);
  // Check the output folders before any work.
  for (const std::string* path : {&options.run.csv, &options.run.stateOut})
    if (!path->empty()) io::checkOutputFile(*path);
  checkDistinctOutputs({{"--csv", &options.run.csv}, {"--state-out", &options.run.stateOut}});
  checkOutputsSpareStdout({{"--csv", &options.run.csv}, {"--state-out", &options.run.stateOut}},
                          options.run.json);
  checkOutputsSpareInputs({{"--csv", &options.run.csv}, {"--state-out", &options.run.stateOut}},
                          loaded, options.run.stateIn);

  const long steps = resolved.steps;
  const long window = std::max(1L, steps / 10);
  std::ostringstream csv;
  csv.precision(17);
  const bool wantCsv = !options.run.csv.empty();
  if (wantCsv) csv << "step,time,kinetic,potential,total,px,py,pz,lx,ly,lz\n";
  auto row = [&](long step, const Diagnostics& d) {
    csv << step << ',' << sim.time() << ',' << d.kinetic << ',' << d.potential.total() << ','
        << d.total() << ',' << d.momentum.x() << ',' << d.momentum.y() << ',' << d.momentum.z()
        << ',' << d.angularMomentum.x() << ',' << d.angularMomentum.y() << ','
        << d.angularMomentum.z() << '\n';
  };
  const Diagnostics start = sim.diagnostics();
  if (wantCsv) row(0, start);
  double firstSum = 0.0, lastSum = 0.0;
  long firstCount = 0, lastCount = 0;
  // |L - L0| / |L0| needs an L0 to be relative to: a model that starts without angular
  // momentum has no relative drift (null in the JSON), whatever a torque then puts in.
  const double l0 = start.angularMomentum.norm();
  double momentumDrift = 0.0, angularDrift = l0 > 0.0 ? 0.0 : std::nan("");
  bool diverged = false;
  long divergedAt = -1;
  Diagnostics last = start;
  const auto wallStart = std::chrono::steady_clock::now();
  GuardedRun run(sim, edits);
  long splitCycles = 0, retakenCycles = 0;
  int mostSubsteps = 1;
  for (long k = 1; k <= steps; ++k) {
    if (!run.step(k)) {
      diverged = true;
      divergedAt = k;
      mostSubsteps = std::max(mostSubsteps, sim.substeps());  // the failed cycle's too
      break;
    }
    if (sim.substeps() > 1) ++splitCycles;
    if (sim.retakes() > 0) ++retakenCycles;
    mostSubsteps = std::max(mostSubsteps, sim.substeps());
    const Diagnostics& d = run.diagnostics();
    last = d;
    if (wantCsv) row(k, d);
    if (k <= window) {
      firstSum += d.total();
      ++firstCount;
    }
    if (k > steps - window) {
      lastSum += d.total();
      ++lastCount;
    }
    momentumDrift = std::max(momentumDrift, (d.momentum - start.momentum).norm());
    if (l0 > 0.0)
      angularDrift =
          std::max(angularDrift, (d.angularMomentum - start.angularMomentum).norm() / l0);
  }
  const double wall =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - wallStart).count();
  throwIfInterrupted();
  if (!diverged) {  // a signal in the loading or the last cycle: nothing written yet
    edits.sayWhatIsLeft(sim);
    options.run.sayLoadsLeft(loaded, sim.time());
  }
  if (wantCsv)
    io::writeFileAtomically(options.run.csv, [&](std::ostream& out) { out << csv.str(); });
  if (!options.run.stateOut.empty()) io::saveState(run.lastGood(), options.run.stateOut);
  endIfInterrupted();

  // A relative drift needs an energy to be relative to: a model at rest whose angle springs
  // hold it only to rounding has 1e-28 J, and its "drift" was 25 (a ratio of noise). Below a
  // millionth of a millionth of the springs' energy scale the drift is undefined.
  const double energyScale = springEnergyScale(sim.model());
  const double firstMean = firstCount ? firstSum / firstCount : 0.0;
  const double energyDrift =
      (firstCount && lastCount && !diverged && std::abs(firstMean) > 1e-12 * energyScale)
          ? (lastSum / lastCount) / firstMean - 1.0
          : std::nan("");
  if (options.run.json) {
    std::cout << "{\n"
              << "  \"scheme\": \"" << schemeName(resolved.settings.scheme) << "\",\n"
              << "  \"dt\": " << jsonNumber(resolved.settings.period) << ",\n"
              << "  \"t_max\": " << jsonNumber(resolved.tMax) << ",\n"
              << "  \"steps\": " << steps << ",\n"
              << "  \"diverged\": " << (diverged ? "true" : "false") << ",\n"
              << "  \"diverged_at_step\": " << (diverged ? std::to_string(divergedAt) : "null")
              << ",\n"
              << "  \"energy_start\": " << jsonNumber(start.total()) << ",\n"
              << "  \"energy_end\": " << jsonNumber(last.total()) << ",\n"
              << "  \"energy_drift\": " << jsonNumber(energyDrift) << ",\n"
              << "  \"momentum_drift\": " << jsonNumber(momentumDrift) << ",\n"
              << "  \"angular_momentum_drift\": " << jsonNumber(angularDrift) << ",\n"
              << "  \"split_steps\": " << splitCycles << ",\n"
              << "  \"substeps_max\": " << mostSubsteps << ",\n"
              << "  \"retaken_steps\": " << retakenCycles << ",\n"
              << "  \"time_end\": " << jsonNumber(run.lastGood().time) << ",\n";
    if (edits.schedule.size() || options.verifyMatrices)
      std::cout << "  \"edits_applied\": " << edits.applied << ",\n";
    if (options.verifyMatrices)
      std::cout << "  \"matrix_update_max_abs_diff\": " << jsonNumber(edits.maxDifference) << ",\n";
    if (!sim.constraints().empty()) {
      // Momentum the constraints put in (N s): p_end - p_start = loads + gravity + this.
      const Vec3& j = sim.impulses().constraints;
      std::cout << "  \"constraint_impulse\": [" << jsonNumber(j.x()) << ", " << jsonNumber(j.y())
                << ", " << jsonNumber(j.z()) << "],\n";
    }
    std::cout << "  \"wall_seconds\": " << jsonNumber(wall) << "\n"
              << "}\n";
  } else {
    // A relative drift of nothing (a model at rest) is no number: said so, as JSON's null.
    auto drift = [](double d) {
      std::ostringstream text;
      if (std::isfinite(d))
        text << d;
      else
        text << "undefined";
      return text.str();
    };
    std::cout << "scheme " << schemeName(resolved.settings.scheme) << ", dt "
              << resolved.settings.period << " s ("
              << shareOfTMax(resolved.settings.period, resolved.tMax) << "), " << steps
              << " steps\n";
    const ImpulseLedger& ledger = sim.impulses();
    const bool acted = ledger.loads.norm() > 0.0 || ledger.gravity.norm() > 0.0 ||
                       ledger.constraints.norm() > 0.0 || ledger.loadsAngular.norm() > 0.0 ||
                       ledger.constraintsAngular.norm() > 0.0;
    if (!acted) {
      // The drift compares means, not the ends: the default scheme's energy oscillates
      // about its start (docs/solver.md), so the ends alone can differ either way.
      std::cout << "energy " << start.total() << " -> " << last.total() << " J (drift "
                << drift(energyDrift)
                << ": the mean over the last 10 % of steps against the first 10 %, minus 1)\n"
                << "momentum drift " << drift(momentumDrift) << ", angular momentum drift "
                << drift(angularDrift) << "\n";
    } else {
      // Loads, gravity or constraints put energy and momentum in: what changed is their
      // doing (and the damping's), not a drift of the scheme; the momentum's sources are
      // said beside it (the JSON keeps the contract's drift fields).
      std::cout << "energy " << start.total() << " -> " << last.total()
                << " J (loads, gravity or constraints acted: a change, not a drift)\n"
                << "momentum change " << (last.momentum - start.momentum).norm() << " N s (loads "
                << ledger.loads.norm() << ", gravity " << ledger.gravity.norm() << ", constraints "
                << ledger.constraints.norm() << "), angular momentum change "
                << (last.angularMomentum - start.angularMomentum).norm() << " N m s (loads "
                << ledger.loadsAngular.norm() << ", constraints "
                << ledger.constraintsAngular.norm() << ")\n";
    }
    if (splitCycles > 0)
      std::cout << splitCycles << " steps split (for fast motion, or after an edit that stiffened "
                << "the model), into up to " << mostSubsteps << " substeps\n";
    if (retakenCycles > 0)
      std::cout << retakenCycles
                << " steps taken again in more substeps (their motion grew within them)\n";
    std::cout << "wall " << wall << " s\n";
    if (edits.schedule.size() || options.verifyMatrices) {
      std::cout << "edits applied " << edits.applied;
      if (options.verifyMatrices)
        std::cout << ", matrix update max abs diff " << edits.maxDifference;
      std::cout << "\n";
    }
  }
  if (diverged) {
    std::cerr << "zsculpt: error: " << loaded.source << ": the simulation diverged at step "
              << divergedAt << " (" << run.why() << ")";
    if (!options.run.stateOut.empty())
      std::cerr << "; the last good state (t = " << run.lastGood().time << " s) was written";
    std::cerr << "\n";
    return 3;
  }
  return 0;
}

}  // namespace

void addSimulateCommand(CLI::App& root, CommandList& commands) {
  auto* app = root.add_subcommand("simulate", "headless simulation with diagnostics");
  auto options = std::make_shared<SimulateOptions>();
  options->model.addTo(app);
  options->run.addTo(app);
  app->add_flag("--verify-matrices", options->verifyMatrices,
                "after every edit, compare the locally updated matrices with a full rebuild");
  commands.push_back({app, [options]() { return runSimulate(*options); }});
}

}  // namespace zsculpt::cli
