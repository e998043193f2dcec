#include "zsculpt/app/session.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <sstream>

#include "zsculpt/constraints/constraints.h"
#include "zsculpt/core/errors.h"
#include "zsculpt/core/overloaded.h"
#include "zsculpt/io/mesh_io.h"
#include "zsculpt/io/scene_edits.h"
#include "zsculpt/physics/matrices.h"
#include "zsculpt/physics/stepper.h"
#include "zsculpt/render/frame.h"

namespace zsculpt::app {

namespace {

Scheme toScheme(io::SimulationScheme s) {
  return schemeFromName(io::schemeName(s));
}
io::SimulationScheme toSceneScheme(Scheme s) {
  return io::schemeFromName(schemeName(s));
}

// FNV-1a over raw bytes: states equal bit for bit hash equal.
void fnv(std::uint64_t& h, const void* data, size_t bytes) {
  const auto* p = static_cast<const unsigned char*>(data);
  for (size_t i = 0; i < bytes; ++i) {
    h ^= p[i];
    h *= 1099511628211ull;
  }
}

std::string vertexText(Index v) {
  return "vertex " + std::to_string(v);
}

}  // namespace

std::uint64_t stateHash(const State& state) {
  std::uint64_t h = 1469598103934665603ull;
  fnv(h, state.position.data(), sizeof(double) * static_cast<size_t>(state.position.size()));
  fnv(h, state.velocity.data(), sizeof(double) * static_cast<size_t>(state.velocity.size()));
  fnv(h, &state.time, sizeof(double));
  return h;
}

std::uint64_t meshHash(const Mesh& mesh) {
  std::uint64_t h = 1469598103934665603ull;
  const Points& p = mesh.positions();
  fnv(h, p.data(), sizeof(double) * static_cast<size_t>(p.size()));
  const CsrIndex& f = mesh.faces();
  fnv(h, f.offsets.data(), sizeof(Index) * f.offsets.size());
  fnv(h, f.indices.data(), sizeof(Index) * f.indices.size());
  for (const auto& e : mesh.edges()) fnv(h, e.data(), sizeof(Index) * 2);
  return h;
}

double resolvePeriod(const io::SceneDescription& scene, const Model& model) {
  const double tMax = criticalPeriod(SystemMatrices(model));
  double period = 0.0;
  if (scene.simulation.dt)
    period = *scene.simulation.dt;
  else
    period = scene.simulation.dtRatio.value_or(0.5) * tMax;
  // No stiffness at all (a free particle cloud): any step is stable; 10 ms as the CLI does.
  if (!std::isfinite(period) && !std::isfinite(tMax)) return 0.01;
  // Refused here, naming the file and the setting, rather than by the stepper (the window's
  // Open must learn of it before it stops the session it has).
  const std::string file = scene.sourcePath.empty() ? scene.mesh : scene.sourcePath;
  const std::string where = scene.simulation.dt ? file + ": /simulation/dt"
                            : scene.simulation.dtRatio
                                ? file + ": /simulation/dt_ratio"
                                : file + ": the default time step (0.5 T_max)";
  checkPeriodRange(period, where);
  return period;
}

SessionSetup sessionSetupFromScene(io::SceneDescription scene) {
  SessionSetup setup;
  io::MeshLoadReport report;
  setup.mesh = io::loadMeshSource(scene.mesh, &report, scene.up);
  scene.up = report.up;
  const Model model = io::buildModel(scene, setup.mesh);
  setup.scheme = toScheme(scene.simulation.scheme);
  setup.period = resolvePeriod(scene, model);
  setup.scene = std::move(scene);
  return setup;
}

SessionSetup loadSessionSetup(const std::string& source, io::UpAxis up,
                              const io::SceneDescription* meshDefaults) {
  io::SceneDescription scene;
  if (io::isSceneFileName(source)) {
    scene = io::loadScene(source);
  } else {
    if (meshDefaults) {
      scene.properties = meshDefaults->properties;
      scene.simulation = meshDefaults->simulation;
    }
    scene.mesh = source;
  }
  if (up != io::UpAxis::Auto) scene.up = up;
  return sessionSetupFromScene(std::move(scene));
}

// ---- construction ----------------------------------------------------------------------------

namespace {

std::unique_ptr<Simulation> makeSimulation(const SessionSetup& setup) {
  if (!(setup.period > 0.0) || !std::isfinite(setup.period))
    throw InvalidInputError("time step: must be a positive number of seconds");
  SimulationSettings settings;
  settings.scheme = setup.scheme;
  settings.period = setup.period;
  return std::make_unique<Simulation>(io::buildModel(setup.scene, setup.mesh), settings);
}

}  // namespace

Session::Session(SessionSetup setup)
    : setup_(std::move(setup)),
      sim_(makeSimulation(setup_)),
      editor_(sim_->model().mesh, sim_->model().angles),
      schedule_(io::scheduleFromScene(setup_.scene.edits)) {
  const Mesh& mesh = sim_->model().mesh;
  if (setup_.initial) {
    initial_ = *setup_.initial;
  } else {
    initial_ = State::atRest(mesh);
    const double amplitude = setup_.scene.simulation.perturb;
    if (amplitude > 0.0) {
      Points kick;
      randomVelocity(sim_->model().properties.mass, amplitude,
                     static_cast<unsigned>(setup_.scene.simulation.seed), kick);
      initial_.velocity += kick;
    }
  }
  sim_->setState(initial_);  // checks size and finiteness

  for (const io::TimedLoad& f : setup_.scene.forces) {
    const TimedLoad load{f.vertex, f.value, f.start, f.end};
    sim_->addForce(load);
    baseForces_.push_back(load);
  }
  for (const io::TimedLoad& t : setup_.scene.torques) {
    const TimedLoad load{t.vertex, t.value, t.start, t.end};
    sim_->addTorque(load);
    baseTorques_.push_back(load);
  }
  forces_ = baseForces_;
  torques_ = baseTorques_;

  addConstraints(setup_.scene.constraints);

  guard_ = std::make_unique<DivergenceGuard>(*sim_);
  region_ = editing::BrushRegion(mesh);
  refreshLimits(true);
  if (std::isfinite(tMax_) && tMax_ > 0.0) periodFraction_ = sim_->period() / tMax_;
}

Session::~Session() = default;

void Session::addConstraints(const std::vector<io::ConstraintSpec>& constraints) {
  const Index n = sim_->model().mesh.numVertices();
  for (const io::ConstraintSpec& c : constraints) {
    if (c.vertex < 0 || c.vertex >= n)
      throw InvalidInputError("constraint: " + vertexText(c.vertex) + " is out of range");
    if (c.type == io::ConstraintType::Position && c.target && c.start && c.end)
      sim_->addPositionConstraint(c.vertex, *c.target, PinTravel{*c.start, *c.end});
    else if (c.type == io::ConstraintType::Position)
      sim_->addPositionConstraint(c.vertex, c.target);
    else
      sim_->addNormalConstraint(c.vertex, c.normal);
  }
  for (std::string& w : sim_->takeWarnings()) notices_.push_back(std::move(w));
}

void Session::endDrag() {
  if (dragVertex_ >= 0 && dragOwnsConstraint_) sim_->removeConstraint(dragId_);
  dragVertex_ = -1;
  dragId_ = -1;
  dragOwnsConstraint_ = false;
}

std::vector<Index> Session::pins() const {
  std::vector<Index> out;
  for (const Constraint& c : sim_->constraints().constraints())
    if (c.kind == ConstraintKind::Position && !isDragConstraint(c)) out.push_back(c.vertex);
  return out;
}

// ---- commands -------------------------------------------------------------------------------

void Session::refreshLimits(bool tight) {
  const SystemMatrices& system = sim_->stepper().system();
  tMax_ = criticalPeriod(system);
  const Scheme scheme = sim_->stepper().scheme();
  stableLimit_ = gershgorinStablePeriodLimit(scheme, system);
  // The period from Gershgorin's bound (which is never below lambda_0) is never above the
  // tight limit. For a period above it the largest
  // eigenvalue gives the tight one, as `zsculpt simulate` does, so that both give one limit;
  // but only when the period or the model is set (`tight`): an edit keeps to the bound, since
  // the eigenvalue costs about half a second at 100k vertices and a dab must not.
  stableLimitTight_ = !beyondStableLimit(sim_->period(), stableLimit_);
  if (tight && !stableLimitTight_) {
    stableLimit_ = stablePeriodLimit(scheme, system, largestEigenvalue(system));
    stableLimitTight_ = true;
  }
  scalarStale_ = true;
}

void Session::keepPeriodFraction() {
  const double wanted = periodFraction_ * tMax_;
  if (!std::isfinite(wanted) || !(wanted > 0.0) || !(sim_->period() > wanted * (1.0 + 1e-9)))
    return;
  const double before = sim_->period();
  changeTimeStep(sim_->stepper().scheme(), wanted);
  refreshLimits();
  // Said from a tenth of a percent: a relax's change read "0.01789 s -> 0.01789 s" at the
  // notice's four digits (a QA pass); smaller changes are made without a word.
  if (!(before > wanted * 1.001)) return;
  std::ostringstream msg;
  msg.precision(4);
  msg << "the edit lowered T_max to " << tMax_ << " s: time step " << before << " s -> " << wanted
      << " s (" << periodFraction_ << " T_max)";
  notices_.push_back(msg.str());
}

void Session::changeTimeStep(Scheme scheme, double period) {
  if (!(period > 0.0) || !std::isfinite(period))
    throw InvalidInputError("time step: must be a positive number of seconds, got " +
                            std::to_string(period));
  // In place: the constraints keep their ids (the drag's, and a normal's record of how far
  // it turned), and the momentum ledger its account.
  sim_->setTimeStep(scheme, period);
}

void Session::reloadLoads() {
  sim_->clearLoads();
  for (const TimedLoad& f : forces_) sim_->addForce(f);
  for (const TimedLoad& t : torques_) sim_->addTorque(t);
}

bool Session::takeStepRequest() {
  const bool r = stepRequest_;
  stepRequest_ = false;
  return r;
}

void Session::apply(const Command& command) {
  diagnosticsFresh_ = false;
  const Index n = sim_->model().mesh.numVertices();
  auto checkVertex = [n](Index v, const char* what) {
    if (v < 0 || v >= n)
      throw InvalidInputError(std::string(what) + ": " + vertexText(v) + " is out of range [0, " +
                              std::to_string(n) + ")");
  };
  auto checkFinite = [](const Vec3& v, const char* what) {
    if (!v.allFinite()) throw InvalidInputError(std::string(what) + ": not finite");
  };
  const double now = sim_->time();
  std::visit(Overloaded{
                 [&](const Play&) { running_ = true; },
                 [&](const Pause&) { running_ = false; },
                 [&](const StepOnce&) { stepRequest_ = true; },
                 [&](const Reset&) {
                   // Back to the start as a save and a reopen would have it: the pins as
                   // they stand now (the user's too: they are part of the scene a save
                   // writes, and went without a word before), the painted properties, the
                   // scene's loads on their schedule; the forces and torques added with the
                   // tools were impulses of the run and go, with a notice.
                   const std::vector<io::ConstraintSpec> pins = currentScene().constraints;
                   const int added = toolLoads_;
                   toolLoads_ = 0;
                   endDrag();
                   sim_->setState(initial_);
                   forces_ = baseForces_;
                   torques_ = baseTorques_;
                   reloadLoads();
                   sim_->clearConstraints();
                   addConstraints(pins);
                   guard_->restart(*sim_);
                   if (added > 0)  // the pins said only where there are some (a QA pass)
                     notices_.push_back(std::string("reset: back to the start; ") +
                                        (pins.empty() ? "the " : "the pins stay, and the ") +
                                        std::to_string(added) +
                                        (added == 1 ? " force or torque" : " forces and torques") +
                                        " added with the tools went with the run");
                 },
                 [&](const SetTimeStep& s) {
                   if (s.scheme == sim_->stepper().scheme() && s.period == sim_->period()) return;
                   changeTimeStep(s.scheme, s.period);
                   refreshLimits(true);
                   if (std::isfinite(tMax_) && tMax_ > 0.0) periodFraction_ = s.period / tMax_;
                   unsaved_ = true;
                 },
                 [&](const SetGravity& g) {
                   checkFinite(g.gravity, "gravity");
                   sim_->mutableProperties().gravity = g.gravity;
                   sim_->propertiesChanged({});
                   guard_->editChangedEnergy();  // the gravity's potential energy changed
                   unsaved_ = true;
                 },
                 [&](const SetStiffnessCap& c) {
                   if (!(c.cap > 0.0))
                     throw InvalidInputError("stiffness cap: must be positive (infinity: none)");
                   sim_->mutableProperties().stiffnessCap = c.cap;
                   sim_->allPropertiesChanged();
                   guard_->editChangedEnergy();
                   refreshLimits();
                   keepPeriodFraction();
                   unsaved_ = true;
                 },
                 [&](const Edit& e) {
                   const editing::EditTarget target{sim_->model().mesh, sim_->model().angles,
                                                    sim_->mutableProperties()};
                   // The simulation takes the new values before the edit enters the history; if it
                   // refuses them (the exact scheme and a mass or damping no longer proportional),
                   // the editor writes the old ones back and the simulation is brought back to
                   // them: the command changes nothing.
                   bool whole = false;
                   std::vector<Index> rows;
                   auto update = [&] {
                     if (whole)
                       sim_->allPropertiesChanged();
                     else
                       sim_->propertiesChanged(rows);
                   };
                   const editing::Editor::Acceptance accept = [&](const editing::EditResult& r) {
                     whole = r.wholeModel;
                     rows.assign(r.matrixRows.begin(), r.matrixRows.end());
                     update();
                     // The time step the edit would bring (the same share of the new T_max)
                     // must be one the stepper takes: stiffness painted to 1e300 was refused
                     // by the step's range after the values were in, so the "refused" edit
                     // stayed, unrecorded, and the replay differed (a QA pass).
                     refreshLimits();
                     const double wanted = periodFraction_ * tMax_;
                     if (std::isfinite(wanted) && wanted > 0.0 && sim_->period() > wanted) {
                       std::ostringstream why;
                       why.precision(4);
                       why << "time step (the edit would lower T_max to " << tMax_ << " s)";
                       checkPeriodRange(wanted, why.str());
                     }
                   };
                   editing::EditResult result;
                   try {
                     result = editor_.apply(target, sim_->state(), e.command, accept);
                   } catch (...) {
                     if (whole || !rows.empty()) {
                       update();
                       refreshLimits();
                     }
                     throw;
                   }
                   if (!result.changed) return;
                   guard_->editChangedEnergy();  // a property edit changes the stored energy
                   keepPeriodFraction();         // the limits were refreshed in `accept`
                   unsaved_ = true;
                 },
                 [&](const AddLoad& l) {
                   const char* what = l.kind == LoadKind::Force ? "force" : "torque";
                   if (!(l.duration > 0.0))
                     throw InvalidInputError(std::string(what) + ": duration must be positive");
                   // Everything is checked before anything changes (a refused command is not
                   // recorded, so it must leave no trace).
                   checkVertex(l.vertex, what);
                   checkFinite(l.value, what);
                   if (l.kind == LoadKind::Torque && sim_->model().mesh.valence(l.vertex) == 0)
                     throw InvalidInputError("torque: " + vertexText(l.vertex) +
                                             " has no neighbours to carry a torque");
                   const TimedLoad load{l.vertex, l.value, now, now + l.duration};
                   // Simulation validates (vertex, finiteness, a torque needs neighbours) and
                   // appends; expired loads are dropped first so the lists stay short.
                   auto expired = [now](const TimedLoad& t) { return t.end <= now; };
                   std::erase_if(forces_, expired);
                   std::erase_if(torques_, expired);
                   reloadLoads();
                   ++toolLoads_;
                   if (l.kind == LoadKind::Force) {
                     sim_->addForce(load);
                     forces_.push_back(load);
                   } else {
                     sim_->addTorque(load);
                     torques_.push_back(load);
                   }
                 },
                 [&](const ClearLoads&) {
                   toolLoads_ = 0;
                   forces_.clear();
                   torques_.clear();
                   sim_->clearLoads();
                 },
                 [&](const Pin& p) {
                   checkVertex(p.vertex, "pin");
                   if (p.target) checkFinite(*p.target, "pin target");
                   const auto id = sim_->constraints().find(ConstraintKind::Position, p.vertex);
                   if (id && !(dragOwnsConstraint_ && *id == dragId_)) {
                     if (p.target) sim_->setConstraintTarget(*id, *p.target);
                   } else if (id) {
                     // Pinning the dragged vertex: its drag constraint becomes the pin.
                     dragOwnsConstraint_ = false;
                     if (p.target) sim_->setConstraintTarget(*id, *p.target);
                   } else {
                     sim_->addPositionConstraint(p.vertex, p.target);
                   }
                   unsaved_ = true;  // the pins are part of the scene a save writes
                 },
                 [&](const Unpin& p) {
                   checkVertex(p.vertex, "unpin");
                   const auto id = sim_->constraints().find(ConstraintKind::Position, p.vertex);
                   if (!id || (dragOwnsConstraint_ && *id == dragId_)) return;
                   if (p.vertex == dragVertex_)
                     dragOwnsConstraint_ = true;  // the drag keeps holding it until released
                   else
                     sim_->removeConstraint(*id);
                   unsaved_ = true;
                 },
                 [&](const PinBrush& p) {
                   region_.compute(sim_->model().mesh, sim_->state().position, p.centre, p.radius,
                                   editing::Falloff::Constant, editing::DistanceKind::Surface);
                   // All or nothing: a pin refused part way (it would contradict a normal pin)
                   // takes the ones this brush added with it.
                   std::vector<Index> added;
                   try {
                     for (Index v : region_.vertices()) {
                       if (v == dragVertex_) continue;
                       const auto id = sim_->constraints().find(ConstraintKind::Position, v);
                       if (p.pin && !id)
                         added.push_back(sim_->addPositionConstraint(v, std::nullopt));
                       else if (!p.pin && id)
                         sim_->removeConstraint(*id);
                     }
                   } catch (...) {
                     for (Index id : added) sim_->removeConstraint(id);
                     throw;
                   }
                   unsaved_ = true;
                 },
                 [&](const UnpinAll&) {
                   const bool dragging = dragVertex_ >= 0;
                   const Index vertex = dragVertex_;
                   const Vec3 target = dragTarget_;
                   dragVertex_ = -1;
                   sim_->clearConstraints();
                   if (dragging) {
                     dragVertex_ = vertex;
                     dragId_ = sim_->addPositionConstraint(vertex, target);
                     dragOwnsConstraint_ = true;
                   }
                   unsaved_ = true;
                 },
                 [&](const PinNormal& p) {
                   checkVertex(p.vertex, "normal pin");
                   if (p.normal) checkFinite(*p.normal, "normal pin");
                   const auto id = sim_->constraints().find(ConstraintKind::Normal, p.vertex);
                   if (id) {
                     if (p.normal) sim_->setConstraintNormal(*id, *p.normal);
                   } else {
                     if (!p.normal &&
                         !bestPlaneNormal(sim_->model().mesh, sim_->state().position, p.vertex))
                       throw InvalidInputError("normal pin: " + vertexText(p.vertex) +
                                               " has no normal (too few or collinear neighbours)");
                     sim_->addNormalConstraint(p.vertex, p.normal);
                   }
                   unsaved_ = true;
                 },
                 [&](const UnpinNormal& p) {
                   checkVertex(p.vertex, "unpin normal");
                   if (const auto id = sim_->constraints().find(ConstraintKind::Normal, p.vertex)) {
                     sim_->removeConstraint(*id);
                     unsaved_ = true;
                   }
                 },
                 [&](const DragStart& d) {
                   checkVertex(d.vertex, "drag");
                   checkFinite(d.target, "drag target");
                   // Refused (the new drag would contradict a normal pin), nothing changes: the
                   // current drag goes on. Its own constraint moves to the new vertex in one step,
                   // checked without it where it was.
                   const auto pinned = sim_->constraints().find(ConstraintKind::Position, d.vertex);
                   const bool ownDrag = dragVertex_ >= 0 && dragOwnsConstraint_;
                   if (pinned && !(ownDrag && *pinned == dragId_)) {
                     // A pinned vertex is dragged by its pin (which stays where it is released).
                     endDrag();
                     dragId_ = *pinned;
                     dragOwnsConstraint_ = false;
                     sim_->setConstraintTarget(dragId_, d.target);
                     unsaved_ = true;  // the pin's target is saved with the scene
                   } else if (ownDrag) {
                     sim_->moveConstraint(dragId_, d.vertex, d.target);
                   } else {
                     const Index id = sim_->addPositionConstraint(d.vertex, d.target);
                     endDrag();  // a drag that held a pin leaves it where it is
                     dragId_ = id;
                     dragOwnsConstraint_ = true;
                   }
                   dragVertex_ = d.vertex;
                   dragTarget_ = d.target;
                 },
                 [&](const DragMove& d) {
                   checkFinite(d.target, "drag target");
                   if (dragVertex_ < 0) return;
                   dragTarget_ = d.target;
                   sim_->setConstraintTarget(dragId_, d.target);
                   if (!dragOwnsConstraint_) unsaved_ = true;  // a pin moved
                 },
                 [&](const DragEnd&) {
                   endDrag();
                   guard_->rebase();  // the drag's work no longer loosens the bound
                 },
                 [&](const MarkSaved&) { unsaved_ = false; },
             },
             command);
}

// ---- the cycle --------------------------------------------------------------------------------

Session::Outcome Session::advance() {
  guard_->beforeStep(*sim_, cycle_);
  const double now = sim_->time();
  // Timed edits of the scene that are due (a millionth of a period absorbs the rounding of
  // the accumulated time, as the command line does).
  for (const editing::TimedEdit& e : schedule_.due(now, 1e-6 * sim_->period())) {
    try {
      apply(Edit{e.command});
    } catch (const InvalidInputError& error) {
      notices_.push_back(std::string("scene edit at t = ") + std::to_string(e.time) +
                         " s: " + error.what());
    }
  }
  // An edit's change of the stored energy, measured before the step moves the state.
  if (guard_->editPending()) guard_->measureEdit(*sim_);
  bool diverged = false;
  std::string reason;
  try {
    sim_->step();
  } catch (const DivergenceError& e) {
    diverged = true;
    reason = "the state became non-finite";
  }
  ++cycle_;
  for (std::string& w : sim_->takeWarnings()) notices_.push_back(std::move(w));
  if (!diverged) {
    diagnostics_ = sim_->diagnostics();
    diagnosticsFresh_ = true;
    if (!guard_->afterStep(*sim_, diagnostics_)) {
      diverged = true;
      reason = guard_->reason();
    }
  }
  if (!diverged) return Outcome::Stepped;

  // Roll back to the older checkpoint: the newer one may already be on its way out.
  const double at = sim_->time();
  sim_->setState(guard_->lastGood());
  diagnosticsFresh_ = false;
  guard_->restart(*sim_);
  const State& good = sim_->state();
  endDrag();
  running_ = false;
  ++divergences_;
  std::ostringstream msg;
  msg.precision(4);
  msg << "the simulation diverged at t = " << at << " s (" << reason
      << "); rolled back to t = " << good.time
      << " s and paused. Lower the time step (Simulation panel) or the stiffness.";
  divergence_ = Divergence{cycle_, at, good.time, msg.str()};
  notices_.push_back(msg.str());
  return Outcome::Diverged;
}

void Session::takeNotices(std::vector<std::string>& out) {
  for (std::string& n : notices_) out.push_back(std::move(n));
  notices_.clear();
}

// ---- outputs ----------------------------------------------------------------------------------

void Session::fill(Snapshot& out, Property scalarProperty) {
  const State& s = sim_->state();
  const Model& model = sim_->model();
  out.cycle = cycle_;
  out.time = s.time;
  out.position = s.position;
  out.velocity = s.velocity;
  if (scalarStale_ || scalarProperty != scalarProperty_) {
    render::propertyAsVertexScalar(model.mesh, model.angles, model.properties, scalarProperty,
                                   scalar_);
    scalarProperty_ = scalarProperty;
    scalarStale_ = false;
  }
  out.scalarProperty = scalarProperty_;
  out.scalar = scalar_;
  if (!diagnosticsFresh_) {
    diagnostics_ = sim_->diagnostics();
    diagnosticsFresh_ = true;
  }
  out.diagnostics = diagnostics_;
  out.pins.clear();
  out.normalPins.clear();
  for (const Constraint& c : sim_->constraints().constraints()) {
    if (isDragConstraint(c)) continue;
    if (c.kind == ConstraintKind::Position)
      out.pins.push_back(c.vertex);
    else
      out.normalPins.emplace_back(c.vertex, c.value);
  }
  out.forces.clear();
  for (const TimedLoad& f : forces_)
    if (f.activeAt(s.time)) out.forces.emplace_back(f.vertex, f.value);
  out.torques.clear();
  for (const TimedLoad& t : torques_)
    if (t.activeAt(s.time)) out.torques.emplace_back(t.vertex, t.value);
  out.dragVertex = dragVertex_;
  out.dragTarget = dragTarget_;
  out.running = running_;
  out.scheme = sim_->stepper().scheme();
  out.period = sim_->period();
  out.tMax = tMax_;
  out.stableLimit = stableLimit_;
  out.stableLimitTight = stableLimitTight_;
  out.substeps = sim_->substeps();
  out.stableSubsteps = sim_->stableSubsteps();
  out.gravity = model.properties.gravity;
  out.stiffnessCap = model.properties.stiffnessCap;
  const VectorX& damping = model.properties.damping;
  out.meanDamping = damping.size() > 0 ? damping.mean() : 0.0;
  out.minDamping = damping.size() > 0 ? damping.minCoeff() : 0.0;
  out.maxDamping = damping.size() > 0 ? damping.maxCoeff() : 0.0;
  out.undoDepth = editor_.undoDepth();
  out.redoDepth = editor_.redoDepth();
  out.unsaved = unsaved_;
  out.divergences = divergences_;
}

io::SceneDescription Session::currentScene() const {
  io::SceneDescription scene = setup_.scene;
  const Model& model = sim_->model();
  io::recordProperties(scene, model);
  scene.constraints.clear();
  for (const Constraint& c : sim_->constraints().constraints()) {
    if (isDragConstraint(c)) continue;
    io::ConstraintSpec spec;
    spec.vertex = c.vertex;
    if (c.kind == ConstraintKind::Position) {
      spec.type = io::ConstraintType::Position;
      spec.target = c.value;
      // A pin on its way keeps its way (its target and times), not where it is now.
      if (const auto travel = sim_->pinTravel(c.id)) {
        spec.target = travel->first;
        spec.start = travel->second.start;
        spec.end = travel->second.end;
      }
    } else {
      spec.type = io::ConstraintType::Normal;
      spec.normal = c.value;
    }
    scene.constraints.push_back(spec);
  }
  // Timed edits already applied live on in the painted arrays; keep the ones still to come
  // (by the schedule, not by the clock: after a Reset or a rollback the applied ones stay
  // applied and do not come again).
  std::vector<bool> pending(scene.edits.size(), false);
  for (const editing::TimedEdit& e : schedule_.pending())
    if (e.source < pending.size()) pending[e.source] = true;
  size_t index = 0;
  std::erase_if(scene.edits, [&](const io::SceneEdit&) { return !pending[index++]; });
  scene.simulation.scheme = toSceneScheme(sim_->stepper().scheme());
  scene.simulation.dt = sim_->period();
  scene.simulation.dtRatio.reset();
  return scene;
}

Mesh Session::currentMesh() const {
  Mesh mesh = setup_.mesh;
  mesh.setPositions(sim_->state().position);
  return mesh;
}

}  // namespace zsculpt::app
