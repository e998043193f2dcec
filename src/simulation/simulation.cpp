#include "zsculpt/simulation/simulation.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <iterator>
#include <optional>
#include <sstream>
#include <string>

#include "zsculpt/core/errors.h"
#include "zsculpt/core/parts.h"

namespace zsculpt {

Simulation::Simulation(Model model, const SimulationSettings& settings)
    : model_(std::move(model)), settings_(settings) {
  model_.properties.validate(model_.mesh, model_.angles);
  if (settings_.constraintSteps < 1)
    throw InvalidInputError("constraint steps " + std::to_string(settings_.constraintSteps) +
                            " must be at least 1");
  state_ = State::atRest(model_.mesh);
  lastGood_ = state_;
  // Every cycle's diagnostics read the energy the step takes on the way (diagnostics()).
  settings_.stepper.measureEnergy = true;
  stepper_ = std::make_unique<Stepper>(model_, settings.scheme, settings.period, settings_.stepper);
  cyclePeriod_ = stepper_->period();
  notePeriodShare();
  const Index n = model_.mesh.numVertices();
  for (Points* p : {&external_, &constraintForce_, &baseForce_, &totalForce_, &loadForce_,
                    &deformation_, &lastGoodDeformation_})
    p->setZero(n, 3);
  Index maxValence = 0;
  for (Index v = 0; v < n; ++v) maxValence = std::max(maxValence, model_.mesh.valence(v));
  armBuffer_.resize(static_cast<size_t>(maxValence));
  forceBuffer_.resize(static_cast<size_t>(maxValence));
  trial_ = state_;
  elasticStart_ = state_;
  scale_ = std::max(1.0, model_.mesh.boundingBox().diagonal());
  updateRigidity();
  if (rigidActive_) splitVelocity();
}

// ---- state and properties -------------------------------------------------------------------

void Simulation::updateRigidity() {
  const PhysicalProperties& p = model_.properties;
  const Index n = model_.mesh.numVertices();
  chi_.resize(static_cast<size_t>(n));
  sigma_.resize(static_cast<size_t>(n));
  rigidActive_ = false;
  allRigid_ = n > 0;
  bool varied = false;
  for (Index i = 0; i < n; ++i) {
    // Section 4.3: chi_i = 1 - sigma_i, sigma_i = min(kappa_0 / kappa_i, 1), or the painted
    // rigidity where it is larger; the force splits into sigma_i F_i and chi_i F_i.
    const double painted = p.rigidity[i];
    const double automatic = zsculpt::elasticShare(p.stiffness[i], p.stiffnessCap);
    const double sigma = std::min(1.0 - painted, automatic);
    chi_[static_cast<size_t>(i)] = effectiveRigidity(painted, p.stiffness[i], p.stiffnessCap);
    sigma_[static_cast<size_t>(i)] = sigma;
    varied = varied || sigma != sigma_[0];
    rigidActive_ = rigidActive_ || sigma < 1.0;
    allRigid_ = allRigid_ && sigma == 0.0;
  }
  const double mass = p.mass.sum();
  // Damping of the rigid motion: the mass-weighted mean of rho_i / (2 mu_i), exact when
  // damping is proportional to mass (as the exact scheme requires anyway).
  rigidDamping_ = mass > 0.0 ? 0.5 * p.damping.sum() / mass : 0.0;
  responseValid_ = false;
  baseForceValid_ = false;
  elasticEnd_.resize(rigidActive_ && !allRigid_ ? n : 0, 3);
  uniformShare_ = n > 0 && !varied ? sigma_[0] : 1.0;
  someFullyRigid_ = false;
  elasticMass_ = p.mass;
  for (Index i = 0; i < n; ++i)
    if (sigma_[static_cast<size_t>(i)] == 0.0) {
      elasticMass_[i] = 0.0;
      someFullyRigid_ = !allRigid_;
    }
}

void Simulation::holdFullyRigidVertices() {
  // A fully rigid vertex (sigma = 0) feels no elastic force, so a deformation velocity it
  // was left with (the hand-over's mean and rigid motion are taken out of every vertex)
  // would carry it away from the body for ever: a stressed torus rigid on one half ran from
  // 5.9 J to 87,415 J. Take out of the deformation the rigid motion that best fits the
  // elastic vertices alone, and zero it at the fully rigid ones: what is left has no net
  // momentum or angular momentum (the rigid rows are zero, the elastic ones balance), so
  // the body keeps the totals; the kinetic energy of the relative motion dropped is lost,
  // as in an inelastic constraint.
  const MassProperties elastic = massProperties(elasticMass_, trial_.position, stepper_->threads());
  if (!(elastic.mass > 0.0)) return;
  (void)removeRigidMotion(elasticMass_, elastic, trial_.position, deformation_,
                          stepper_->threads());
  for (Index i = 0; i < deformation_.rows(); ++i)
    if (sigma_[static_cast<size_t>(i)] == 0.0) deformation_.row(i).setZero();
}

void Simulation::splitVelocity() {
  // Tisserand split: the rigid body takes the momentum and angular momentum, the elastic
  // part keeps the rest. A fully rigid vertex (sigma = 0) has no elastic degree of freedom:
  // its leftover velocity would drift forever, unresisted, so it is dropped.
  const VectorX& mass = model_.properties.mass;
  start_ = massProperties(mass, state_.position);
  deformation_ = state_.velocity;
  rigidMomentum_ = removeRigidMotion(mass, start_, state_.position, deformation_);
  bool dropped = false;
  for (Index i = 0; i < deformation_.rows(); ++i)
    if (sigma_[static_cast<size_t>(i)] == 0.0 && !deformation_.row(i).isZero(0.0)) {
      deformation_.row(i).setZero();
      dropped = true;
    }
  if (dropped) {
    const RigidMomentum more = removeRigidMotion(mass, start_, state_.position, deformation_);
    rigidMomentum_.linear += more.linear;
    rigidMomentum_.angular += more.angular;
  }
  state_.velocity = deformation_;
  addRigidVelocity(start_, rigidMomentum_, state_.position, state_.velocity);
}

void Simulation::setState(const State& state) {
  if (state.position.rows() != model_.mesh.numVertices() ||
      state.velocity.rows() != model_.mesh.numVertices())
    throw InvalidInputError("state has " + std::to_string(state.position.rows()) +
                            " vertices, the model has " +
                            std::to_string(model_.mesh.numVertices()));
  if (!state.position.allFinite() || !state.velocity.allFinite())
    throw InvalidInputError("state contains a non-finite value");
  state_ = state;
  if (rigidActive_)
    splitVelocity();
  else
    rigidMomentum_ = RigidMomentum{};
  lastGood_ = state_;
  baseForceValid_ = false;
  solver_.forgetTurning();  // the normals' turning was towards where the last state was
  energyAtState_ = false;
  endRateValid_ = false;
  ledger_ = ImpulseLedger{};
  stepper_->invalidate();
}

void Simulation::setTimeStep(Scheme scheme, double period) {
  auto next = std::make_unique<Stepper>(model_, scheme, period, settings_.stepper);
  stepper_ = std::move(next);
  settings_.scheme = scheme;
  settings_.period = period;
  cyclePeriod_ = stepper_->period();
  substeps_ = 1;  // chosen again at the next cycle
  notePeriodShare();
  responseValid_ = false;  // the constraints' response is the step's
  energyAtState_ = false;  // the new stepper has not measured the state's energy
  endRateValid_ = false;
}

void Simulation::propertiesChanged(std::span<const Index> vertices) {
  const PhysicalProperties& p = model_.properties;
  const Index n = model_.mesh.numVertices();
  for (Index v : vertices) {
    if (v < 0 || v >= n)
      throw InvalidInputError("property edit at vertex " + std::to_string(v) +
                              ": no such vertex (the model has " + std::to_string(n) + ")");
    for (Property property : {Property::Mass, Property::Damping, Property::Stiffness,
                              Property::AngularStiffness, Property::Rigidity})
      checkPropertyValue(property, p.vertexValues(property)[v], "vertex " + std::to_string(v));
  }
  stepper_->propertiesChanged(vertices);
  energyAtState_ = false;
  endRateValid_ = false;
  propertiesEdited_ = true;
  const bool wasActive = rigidActive_;
  updateRigidity();
  if (rigidActive_)
    splitVelocity();
  else if (wasActive)
    rigidMomentum_ = RigidMomentum{};  // state_.velocity is already total
}

void Simulation::allPropertiesChanged() {
  model_.properties.validate(model_.mesh, model_.angles);
  stepper_->rebuild();
  energyAtState_ = false;
  endRateValid_ = false;
  propertiesEdited_ = true;
  const bool wasActive = rigidActive_;
  updateRigidity();
  if (rigidActive_)
    splitVelocity();
  else if (wasActive)
    rigidMomentum_ = RigidMomentum{};
}

// ---- loads ----------------------------------------------------------------------------------

namespace {

void checkLoad(const TimedLoad& load, Index n, const char* what) {
  if (load.vertex < 0 || load.vertex >= n)
    throw InvalidInputError(std::string(what) + " at vertex " + std::to_string(load.vertex) +
                            ": no such vertex (the model has " + std::to_string(n) + ")");
  if (!load.value.allFinite()) throw InvalidInputError(std::string(what) + ": not finite");
  if (!(load.end >= load.start))
    throw InvalidInputError(std::string(what) + ": ends before it starts");
}

// Whether every coordinate is finite.
bool allFinite(const Points& x, int threads) {
  const Eigen::Map<const VectorX> flat(x.data(), x.size());
  std::array<std::uint8_t, 8> finite{};
  forEachPart<8>(flat.size(), threads, 100000, [&](int part, Index begin, Index end) {
    finite[static_cast<size_t>(part)] = flat.segment(begin, end - begin).allFinite() ? 1 : 0;
  });
  return std::all_of(finite.begin(), finite.end(), [](std::uint8_t f) { return f != 0; });
}

// to = from.
void copyPoints(const Points& from, Points& to, int threads) {
  to.resize(from.rows(), 3);
  const double* source = from.data();
  double* target = to.data();
  forEachPart<8>(from.size(), threads, 100000, [&](int, Index begin, Index end) {
    std::copy(source + begin, source + end, target + begin);
  });
}

}  // namespace

void Simulation::addForce(const TimedLoad& force) {
  checkLoad(force, model_.mesh.numVertices(), "force");
  forces_.push_back(force);
  reserveLoadRows();
}

void Simulation::addTorque(const TimedLoad& torque) {
  checkLoad(torque, model_.mesh.numVertices(), "torque");
  if (model_.mesh.valence(torque.vertex) == 0)
    throw InvalidInputError("torque at vertex " + std::to_string(torque.vertex) +
                            ": an isolated vertex has no neighbours to carry a torque");
  torques_.push_back(torque);
  reserveLoadRows();
}

void Simulation::reserveLoadRows() {
  size_t rows = forces_.size();
  for (const TimedLoad& torque : torques_)
    rows += 1 + static_cast<size_t>(model_.mesh.valence(torque.vertex));
  externalRows_.reserve(rows);
  loadForceRows_.reserve(rows + solver_.support().size());
}

void Simulation::clearLoads() {
  forces_.clear();
  torques_.clear();
}

void Simulation::gatherLoads(double t, const Points& position, Points& out,
                             std::vector<Index>* rows) {
  if (rows) {
    for (const Index row : *rows) out.row(row).setZero();
    rows->clear();
  } else {
    out.setZero();
  }
  auto wrote = [&](Index row) {
    if (rows) rows->push_back(row);
  };
  const double period = stepper_->period();
  for (const TimedLoad& f : forces_)
    if (const double share = f.shareOf(t, period); share > 0.0) {
      out.row(f.vertex) += share * f.value.transpose();
      wrote(f.vertex);
    }
  const Mesh& mesh = model_.mesh;
  for (const TimedLoad& torque : torques_) {
    const double share = torque.shareOf(t, period);
    if (share <= 0.0) continue;
    // Section 5.3: a torque becomes virtual forces on the neighbours.
    const auto neighbours = mesh.vertexNeighbors(torque.vertex);
    const size_t k = neighbours.size();
    for (size_t q = 0; q < k; ++q) armBuffer_[q] = position.row(neighbours[q]).transpose();
    Vec3 onCentre;
    torqueToForces(position.row(torque.vertex).transpose(),
                   std::span<const Vec3>(armBuffer_.data(), k), share * torque.value,
                   std::span<Vec3>(forceBuffer_.data(), k), onCentre);
    out.row(torque.vertex) += onCentre.transpose();
    wrote(torque.vertex);
    for (size_t q = 0; q < k; ++q) {
      out.row(neighbours[q]) += forceBuffer_[q].transpose();
      wrote(neighbours[q]);
    }
  }
  if (rows) {
    std::sort(rows->begin(), rows->end());
    rows->erase(std::unique(rows->begin(), rows->end()), rows->end());
  }
}

// ---- constraints ----------------------------------------------------------------------------

Index Simulation::addPositionConstraint(Index vertex, std::optional<Vec3> target) {
  const bool exists = vertex >= 0 && vertex < model_.mesh.numVertices();
  for (const Travelling& t : travelling_)
    if (constraints_.get(t.id).vertex == vertex)
      throw InvalidInputError("vertex " + std::to_string(vertex) +
                              " has a pin that travels, which must be its only pin");
  const Vec3 where = target   ? *target
                     : exists ? Vec3(state_.position.row(vertex).transpose())
                              : Vec3::Zero();
  return constraints_.addPosition(model_.mesh, vertex, where);
}

Index Simulation::addPositionConstraint(Index vertex, const Vec3& target, const PinTravel& travel) {
  if (!(std::isfinite(travel.start) && std::isfinite(travel.end) && travel.start >= 0.0 &&
        travel.end > travel.start)) {
    std::ostringstream msg;
    msg.precision(6);
    msg << "a pin's travel must end after it starts, at finite times >= 0 (got " << travel.start
        << " to " << travel.end << " s)";
    throw InvalidInputError(msg.str());
  }
  if (!target.allFinite()) throw InvalidInputError("the pin's target is not finite");
  const bool exists = vertex >= 0 && vertex < model_.mesh.numVertices();
  if (exists && constraints_.find(ConstraintKind::Position, vertex))
    throw InvalidInputError("vertex " + std::to_string(vertex) +
                            " is pinned already: a pin that travels must be its only pin");
  // The way is a function of time alone, from where the vertex is when the travel has yet
  // to start (the state given, which may be displaced), or, for a run resumed mid-way
  // (--state-in with --start-time past the start), from where the model as loaded has it,
  // which is where an uninterrupted run from the loaded shape set off: it then finds the pin
  // where that run has it. A rollback or a reset finds it on its way too.
  const bool begun = state_.time > travel.start;
  const Vec3 from = !exists ? target
                    : begun ? Vec3(model_.mesh.positions().row(vertex).transpose())
                            : Vec3(state_.position.row(vertex).transpose());
  const double share = travel.shareAt(state_.time);
  const Vec3 now = share >= 1.0 ? target : Vec3(from + share * (target - from));
  const Index id = constraints_.addPosition(model_.mesh, vertex, now);
  travelling_.push_back({id, from, target, travel});
  if (begun) {
    // Resumed from a state whose vertex is not on the way (not one this travel made): the
    // first cycle takes it there.
    const double distance = (now - state_.position.row(vertex).transpose()).norm();
    const double edge = model_.mesh.meanEdgeLengthAt(vertex, model_.mesh.positions());
    if (edge > 0.0 && distance > edge) {
      std::ostringstream msg;
      msg.precision(3);
      msg << "position constraint at vertex " << vertex << ": the travel began at " << travel.start
          << " s from where the mesh has the vertex, and the state puts it " << distance
          << " from its way at " << state_.time << " s, which the first cycle closes at once";
      warnings_.push_back(msg.str());
    }
  }
  return id;
}

std::optional<std::pair<Vec3, PinTravel>> Simulation::pinTravel(Index id) const {
  for (const Travelling& t : travelling_)
    if (t.id == id) return std::make_pair(t.to, t.travel);
  return std::nullopt;
}

void Simulation::moveTravellingPins() {
  // The targets at the end of the coming cycle; an arrived pin keeps its target (and its
  // travel, for a rollback and a save).
  const double end = state_.time + cyclePeriod_;
  for (const Travelling& t : travelling_) {
    const double share = t.travel.shareAt(end);
    constraints_.setTarget(t.id, share >= 1.0 ? t.to : Vec3(t.from + share * (t.to - t.from)));
  }
}

Index Simulation::addNormalConstraint(Index vertex, std::optional<Vec3> normal) {
  // Without a normal: the current one (addNormal reports where there is none).
  const Vec3 direction =
      normal ? *normal
             : bestPlaneNormal(model_.mesh, state_.position, vertex).value_or(Vec3::UnitZ());
  const size_t before = constraints_.constraints().size();
  const Index id = constraints_.addNormal(model_.mesh, state_.position, vertex, direction);
  if (constraints_.constraints().size() == before) return id;  // merged: said once already
  // Without angle springs the ring folds freely, and where it folds through a shape with no
  // flattest direction its plane, hence the normal, is undefined: the constraint lets go
  // there and turns the normal back once the ring flattens, up to its turn budget
  // (docs/semi-rigid-and-constraints.md, "A folding ring is let go").
  std::vector<Index> ring;
  normalFitVertices(model_.mesh, vertex, ring);
  const VectorX& angular = model_.properties.angularStiffness;
  if (std::any_of(ring.begin(), ring.end(), [&](Index v) { return !(angular[v] > 0.0); }))
    warnings_.push_back("normal constraint at vertex " + std::to_string(vertex) +
                        ": its ring has no angle springs and may fold and let go; paint "
                        "angular stiffness there to hold it");
  return id;
}

void Simulation::setConstraintTarget(Index id, const Vec3& target) {
  constraints_.setTarget(id, target);
  std::erase_if(travelling_, [&](const Travelling& t) { return t.id == id; });
}

void Simulation::moveConstraint(Index id, Index vertex, const Vec3& target) {
  constraints_.movePosition(model_.mesh, id, vertex, target);
  std::erase_if(travelling_, [&](const Travelling& t) { return t.id == id; });
}

void Simulation::setConstraintNormal(Index id, const Vec3& normal) {
  constraints_.setNormal(id, normal);
}

void Simulation::removeConstraint(Index id) {
  constraints_.remove(id);
  std::erase_if(travelling_, [&](const Travelling& t) { return t.id == id; });
}

void Simulation::clearConstraints() {
  constraints_.clear();
  travelling_.clear();
  constraintForce_.setZero();
  constraintForceZero_ = true;
}

std::vector<std::string> Simulation::takeWarnings() {
  std::vector<std::string> out = constraints_.takeWarnings();
  out.insert(out.end(), warnings_.begin(), warnings_.end());
  warnings_.clear();
  return out;
}

// ---- the cycle ------------------------------------------------------------------------------

namespace {

// Steps of a split cycle for a strain of `strain` over the whole cycle: the least power of
// two n (at most kMaxSubsteps) with strain <= bound n.
int stepsFor(double strain, double bound) {
  int n = 1;
  while (n < kMaxSubsteps && strain > bound * n) n *= 2;
  return n;
}

}  // namespace

bool Simulation::substepping() const {
  return settings_.substepStrain > 0.0 && stepper_->scheme() == Scheme::Default;
}

double Simulation::strainRate2() const {
  const std::vector<std::array<Index, 2>>& edges = model_.mesh.edges();
  const VectorX& rest = model_.properties.restLength;
  const Points& v = state_.velocity;
  const Index m = static_cast<Index>(edges.size());
  // Springs of rest length 0 (equation 1's linear ones) are left out: their stiffness does
  // not depend on the amplitude. As many threads as the step found worth it (a second
  // thread only helps when a core is free).
  double rate2 = 0.0;
  const int threads = stepper_->threads();
  parallelRegion(threads, [&] {
    double local = 0.0;
#pragma omp for schedule(static) nowait
    for (Index e = 0; e < m; ++e) {
      const double lambda = rest[e];
      if (!(lambda > 0.0)) continue;
      const auto [a, b] = edges[static_cast<size_t>(e)];
      const double dx = v(a, 0) - v(b, 0), dy = v(a, 1) - v(b, 1), dz = v(a, 2) - v(b, 2);
      local = std::max(local, (dx * dx + dy * dy + dz * dz) / (lambda * lambda));
    }
#pragma omp critical(zsculpt_strain_rate)
    rate2 = std::max(rate2, local);
  });
  return rate2;
}

void Simulation::setSubsteps(int n) {
  if (n == substeps_) return;
  // The division is exact for powers of two, so n = 1 gives T back bit for bit.
  const double period = cyclePeriod_ / n;
  if (stepper_->scheme() == Scheme::Default)
    stepper_->setPeriod(period);
  else  // the other schemes' matrices are built for one period (kStiffenedStepShare only)
    stepper_ = std::make_unique<Stepper>(model_, stepper_->scheme(), period, settings_.stepper);
  substeps_ = n;
  responseValid_ = false;  // the constraints' response is the step's
}

void Simulation::notePeriodShare() {
  const double tMax = criticalPeriod(stepper_->system());
  periodShare_ = std::isfinite(tMax) && tMax > 0.0 ? cyclePeriod_ / tMax : 0.0;
  // Against the limit when the period was set: a period past the Gershgorin bound (the tight
  // limit allowed it, or --allow-unstable) keeps its share, and one set near it (past
  // kStiffenedTrigger) is split only once past the bound itself.
  const double limit = gershgorinStablePeriodLimit(stepper_->scheme(), stepper_->system());
  startedBeyondBound_ = beyondStableLimit(cyclePeriod_, limit);
  startedNearBound_ = cyclePeriod_ > kStiffenedTrigger * limit;
  stableSubsteps_ = 1;
  propertiesEdited_ = false;
}

void Simulation::chooseStableSubsteps() {
  if (!propertiesEdited_) return;
  propertiesEdited_ = false;
  const SystemMatrices& system = stepper_->system();
  const Scheme scheme = stepper_->scheme();
  const double limit = gershgorinStablePeriodLimit(scheme, system);
  // Exact and implicit Euler are stable at any period; a fully rigid model takes no elastic
  // step.
  if (!std::isfinite(limit) || allRigid_) {
    stableSubsteps_ = 1;
    return;
  }
  const double tMax = criticalPeriod(system);
  const double shareStep = std::isfinite(tMax) ? periodShare_ * tMax : 0.0;
  // The paper scheme's damping limit 1 / gamma (equation 4's 1 - gamma T > 0) is exact, not
  // a bound: no share set past the spring bound is let past it.
  // (stablePeriodLimit without springs: the paper scheme's 1 / gamma, infinite for the others.)
  const double dampingLimit = stablePeriodLimit(scheme, system, 0.0);
  // The steps of a split cycle: as long as the period's share of T_max when it was set, or
  // kStiffenedStepShare, within the limit (the paper scheme's may be its damping's, with
  // T_max infinite or unchanged).
  double longest = std::max(shareStep, std::min(kStiffenedStepShare * tMax, 0.99 * limit));
  if (!startedBeyondBound_) longest = std::min(longest, 0.99 * limit);
  longest = std::min(longest, 0.99 * dampingLimit);
  // Split only once the cycle comes near the limit (a relax that stiffens the model by 1 %
  // must not halve a run's speed), or, for a run set near it already, past it.
  double trigger = startedBeyondBound_ ? longest
                   : startedNearBound_ ? limit * (1.0 - 1e-9)
                                       : kStiffenedTrigger * limit;
  trigger = std::min(trigger, dampingLimit * (1.0 - 1e-9));
  // A function of the properties alone, not of the splits before: a run resumed after
  // several edits (--start-time, which applies them at once) splits as the whole run did.
  int n = 1;
  if (cyclePeriod_ > trigger * (1.0 + 1e-9))
    while (n < kMaxSubsteps && cyclePeriod_ / n > longest * (1.0 + 1e-9)) n *= 2;
  const int before = stableSubsteps_;
  stableSubsteps_ = n;
  if (n <= before) return;
  std::ostringstream msg;
  msg.precision(6);
  // At the cycle after the edit (a resumed run applies the edits before its start at once).
  msg << "at t = " << state_.time << " s, after an edit, the " << schemeName(scheme)
      << " scheme's stable limit is " << limit << " s";
  if (std::isfinite(tMax)) msg << " (T_max " << tMax << " s)";
  msg << ", near or below the cycle of " << cyclePeriod_ << " s: each cycle is now taken in "
      << (substepping() ? "at least " : "") << n << " steps of " << cyclePeriod_ / n << " s";
  if (std::isfinite(tMax)) msg << " (" << cyclePeriod_ / n / tMax << " T_max)";
  if (cyclePeriod_ / n > longest * (1.0 + 1e-9))
    msg << ", still too long: " << kMaxSubsteps
        << " steps are the most a cycle takes; lower the time step";
  warnings_.push_back(msg.str());
}

void Simulation::chooseSubsteps() {
  chooseStableSubsteps();
  if (!substepping()) {
    setSubsteps(stableSubsteps_);
    return;
  }
  // The last cycle's end measured it, unless something changed the state since.
  const double rate2 = endRateValid_ ? endRate2_ : strainRate2();
  const double strain = std::sqrt(rate2) * cyclePeriod_;  // over a whole cycle
  const double limit = settings_.substepStrain;
  int n = substeps_;
  if (const int up = stepsFor(strain, limit); up > n)
    n = up;
  else if (const int down = stepsFor(strain, 0.5 * limit); down < n)
    n = down;
  setSubsteps(std::max(n, stableSubsteps_));
}

Diagnostics Simulation::diagnostics() const {
  if (energyAtState_)
    if (const std::optional<PotentialEnergy> internal = stepper_->internalEnergy())
      return measure(model_, state_, *internal);
  return measure(model_, state_);
}

void Simulation::rewindState(const ImpulseLedger& ledgerBefore) {
  const int threads = stepper_->threads();
  copyPoints(lastGood_.position, state_.position, threads);
  copyPoints(lastGood_.velocity, state_.velocity, threads);
  state_.time = lastGood_.time;
  if (rigidActive_) {
    rigidMomentum_ = lastGoodMomentum_;
    deformation_ = lastGoodDeformation_;
  }
  ledger_ = ledgerBefore;
  baseForceValid_ = false;
  energyAtState_ = false;
  endRateValid_ = false;
  stepper_->invalidate();  // its kept kick and forces are the abandoned cycle's
}

void Simulation::step() {
  energyAtState_ = false;
  retakes_ = 0;
  if (!travelling_.empty()) moveTravellingPins();
  chooseSubsteps();
  endRateValid_ = false;
  copyPoints(state_.position, lastGood_.position, stepper_->threads());
  copyPoints(state_.velocity, lastGood_.velocity, stepper_->threads());
  lastGood_.time = state_.time;
  if (rigidActive_) {
    lastGoodMomentum_ = rigidMomentum_;
    lastGoodDeformation_ = deformation_;
  }
  const ImpulseLedger ledgerBefore = ledger_;
  const bool loaded = !forces_.empty() || !torques_.empty();
  // What a retake puts back besides the state: the normals' turning records and the solve's
  // warm start (set up first for a new support, so that the marks are the set-up's), and
  // the warnings the abandoned cycle gave.
  syncSupport();
  const bool marked = !constraints_.empty();
  if (marked) solver_.markCycle();
  const size_t warningsBefore = warnings_.size();
  const bool warned[3] = {warnedUnmet_, warnedReleased_, warnedYielded_};
  const std::span<const Constraint> items = constraints_.constraints();
  auto setTargets = [&](double share) {
    for (size_t c = 0; c < items.size(); ++c)
      if (items[c].kind == ConstraintKind::Position)
        constraints_.setTarget(
            items[c].id, share >= 1.0
                             ? targetEnd_[c]
                             : Vec3(targetStart_[c] + share * (targetEnd_[c] - targetStart_[c])));
  };
  bool targetsKept = false;
  for (;;) {
    constraintWork_ = 0.0;
    loadWork_ = 0.0;
    // Each step of a split cycle is a cycle of its own (loads, constraints, rigid coupling)
    // at T / n. Position constraints move their targets from where their vertices start to
    // where they are asked to be in n equal parts, so that a drag is as smooth as in one
    // cycle.
    if (substeps_ > 1 && !targetsKept) {
      targetEnd_.resize(items.size());
      targetStart_.resize(items.size());
      for (size_t c = 0; c < items.size(); ++c) {
        targetEnd_[c] = items[c].value;
        targetStart_[c] = items[c].kind == ConstraintKind::Position
                              ? Vec3(state_.position.row(items[c].vertex).transpose())
                              : items[c].value;
      }
      targetsKept = true;
    }
    try {
      for (int k = 1; k <= substeps_; ++k) {
        if (substeps_ > 1) {
          setTargets(static_cast<double>(k) / substeps_);
          if (loaded) subStart_ = state_.position;
        }
        subCycle(substeps_ > 1 && loaded ? subStart_ : lastGood_.position);
      }
    } catch (...) {
      // A divergence, or anything else thrown mid-cycle (the stepper may be inside a begun
      // step): back to where the cycle started.
      if (targetsKept) setTargets(1.0);
      if (marked)
        solver_.rewindCycle();
      else
        solver_.forgetTurning();
      rewindState(ledgerBefore);
      throw;
    }
    // n additions of T / n need not add up to T.
    if (substeps_ > 1) state_.time = lastGood_.time + cyclePeriod_;
    if (!substepping()) break;
    // The end velocities' strain, kept for the next cycle's choice. A cycle whose motion grew
    // within it beyond what its start told (a folding sheet's springs, stiff where it
    // folds, turned 31 J into 2808 J in one) is taken again in as many steps as the end asks.
    endRate2_ = strainRate2();
    endRateValid_ = true;
    const int wanted = stepsFor(std::sqrt(endRate2_) * cyclePeriod_, settings_.substepStrain);
    if (wanted <= kRetakeFactor * substeps_) break;
    if (marked) solver_.rewindCycle();
    rewindState(ledgerBefore);
    warnings_.resize(warningsBefore);
    warnedUnmet_ = warned[0];
    warnedReleased_ = warned[1];
    warnedYielded_ = warned[2];
    setSubsteps(wanted);
    ++retakes_;
  }
}

void Simulation::subCycle(const Points& start) {
  // Without loads external_ stays zero from cycle to cycle (and the constraint forces without
  // constraints): on a large model, clearing them again every cycle was a pass of its own.
  const bool loaded = !forces_.empty() || !torques_.empty();
  if (loaded || !externalZero_) {
    gatherLoads(state_.time, state_.position, external_, &externalRows_);
    externalZero_ = !loaded;
  }
  if (!rigidActive_ && constraints_.empty()) {
    // The plain elastic cycle: nothing is split, nothing is constrained.
    stepper_->step(state_, external_);
    if (!constraintForceZero_) {
      constraintForce_.setZero();
      constraintForceZero_ = true;
    }
    baseForceValid_ = false;
    addToLedger(Vec3::Zero(), velocityDelta_);
  } else {
    coupledStep();
  }
  if (!allFinite(state_.position, stepper_->threads()) ||
      !allFinite(state_.velocity, stepper_->threads()) || !rigidMomentum_.linear.allFinite() ||
      !rigidMomentum_.angular.allFinite())
    throw DivergenceError("the simulation diverged at t = " + std::to_string(state_.time) +
                          " s (the state became non-finite)");
  // The loads are held over the step: their work is F . dx (exact for the scheme's modified
  // energy; against the total energy it is second order: 3 to 5 % apart at 0.5 T_max).
  if (!forces_.empty() || !torques_.empty()) {
    double work = 0.0;
    for (const Index i : externalRows_)
      work += external_.row(i).dot(state_.position.row(i) - start.row(i));
    loadWork_ += work;
  }
  // Without rigid motion the cycle ends where the stepper's last step ended: the plain cycle
  // steps state_ itself, a constrained one takes its last trial's positions (the velocity
  // correction moves no vertex). With it, the stepper's forces are its end forces turned with
  // the rigid motion (finishRigid), whose springs' energy the motion did not change, or
  // those startAt took where the motion ended (a fully rigid model has none; the schemes
  // other than default report none, and measure() takes over).
  energyAtState_ = !allRigid_;
}

void Simulation::computeBaseForce(const Points& position) {
  // The internal forces of a fully rigid model add up to no force and no torque: skip them
  // (their rounding would only stir the rigid body). The others come from the step's own
  // force kernel (vectorised, on the step's threads; the same bits on any thread count),
  // which keeps them for the next elastic step: it starts at `position` (the cycle's start,
  // or the end of this cycle's rigid motion, where the next one starts).
  if (allRigid_)
    baseForce_.setZero();
  else
    copyPoints(stepper_->startAt(position), baseForce_, stepper_->threads());
  accumulateGravity(model_.properties, position, baseForce_);
  baseForceValid_ = true;
}

void Simulation::runTrial(bool constrained, bool first) {
  const double t = stepper_->period();
  const int threads = stepper_->threads();
  // A constrained elastic trial begins from elasticStart_ into trial_ (Stepper::beginStep's
  // out-of-place form, the same bits); the other paths step a copy of it.
  const bool fromStart = constrained && !allRigid_;
  if (!fromStart) {
    copyPoints(elasticStart_.position, trial_.position, threads);
    copyPoints(elasticStart_.velocity, trial_.velocity, threads);
  }
  trial_.time = elasticStart_.time;
  const Points* load = &external_;
  if (constrained) {
    // loadForce_ = external_ + constraintForce_, row by row where either can be nonzero (the
    // loads' rows and the support's): every other row is +0 in both, and is in loadForce_.
    // Both lists are sorted and unique (the solver's support is): their union is too.
    for (const Index row : loadForceRows_) loadForce_.row(row).setZero();
    loadForceRows_.clear();
    const auto support = solver_.support();
    std::set_union(externalRows_.begin(), externalRows_.end(), support.begin(), support.end(),
                   std::back_inserter(loadForceRows_));
    for (const Index row : loadForceRows_)
      loadForce_.row(row) = external_.row(row) + constraintForce_.row(row);
    load = &loadForce_;
  }
  if (allRigid_) {
    // sigma = 0 everywhere: the elastic stepper would receive no force at all.
    trial_.position += t * trial_.velocity;
    trial_.time += t;
  } else {
    // The stepper caches internal forces at its last end positions; with rigid motion, which
    // moved the vertices after that, finishRigid turned them with the motion
    // (Stepper::turnEndForces) or computeBaseForce evaluated them where it ended
    // (Stepper::startAt). A later trial of this cycle starts where the earlier one did, whose
    // start forces the stepper kept (rewind).
    if (!first) stepper_->rewind();
    // A constrained trial is kept only if it meets the constraints, which its end positions
    // tell: the step is finished once one does (finishTrial), and a dropped trial costs the
    // kick and the drift, not the forces at its end and the second kick.
    const std::span<const double> share = stepperShare();
    if (constrained) {
      stepper_->beginStep(elasticStart_, trial_, *load, share);
      // The rigid motion (below) moves the vertices; the step is finished where it ended.
      if (rigidActive_) copyPoints(trial_.position, elasticEnd_, threads);
    } else {
      stepper_->step(trial_, *load, share);
    }
  }
  const auto support = solver_.support();
  if (!rigidActive_) {
    if (constrained)
      for (size_t a = 0; a < support.size(); ++a)
        supportElastic_.row(static_cast<Index>(a)) = trial_.position.row(support[a]);
    return;
  }
  const VectorX& mass = model_.properties.mass;
  Vec3 weighted = Vec3::Zero();
  for (Index i = 0; i < trial_.position.rows(); ++i)
    weighted += mass[i] * trial_.position.row(i).transpose();
  elasticCentre_ = weighted / start_.mass;
  Vec3 force = startRigidForce_, torque = startRigidTorque_;
  if (constrained) {
    // The same sums, in the same order, as StepResponse::rigidMotion, so the response
    // model reproduces this step exactly at its anchor.
    const Points& virtualForce = solver_.forces();
    for (size_t a = 0; a < support.size(); ++a) {
      const Index l = static_cast<Index>(a);
      supportElastic_.row(l) = trial_.position.row(support[a]);
      const Vec3 share = supportChi_[a] * virtualForce.row(l).transpose();
      force += share;
      torque += (supportStart_.row(l).transpose() - start_.centre).cross(share);
    }
  }
  drift_ = rigidDrift(start_, rigidMomentum_, force, torque, t, rigidDamping_);
  applyRigidMotion(elasticCentre_, drift_.translation, drift_.rotation, trial_.position, threads);
}

void Simulation::finishTrial() {
  if (!stepper_->stepBegun()) return;  // fully rigid: no elastic step
  const std::span<const double> share = stepperShare();
  // The second part reads the positions (the forces there) and changes only the velocity:
  // the elastic end positions are swapped in for it and out again (two pointer swaps).
  if (rigidActive_) trial_.position.swap(elasticEnd_);
  stepper_->finishStep(trial_, loadForce_, share);
  if (rigidActive_) trial_.position.swap(elasticEnd_);
}

Vec3 Simulation::elasticInternalShare(const Points& force) const {
  // sum_i sigma_i f_i of the internal forces: `force` holds them plus gravity mu_i g.
  Vec3 share = Vec3::Zero();
  double sigmaMass = 0.0;
  const VectorX& mass = model_.properties.mass;
  for (Index i = 0; i < force.rows(); ++i) {
    const double s = sigma_[static_cast<size_t>(i)];
    share += s * force.row(i).transpose();
    sigmaMass += s * mass[i];
  }
  return share - sigmaMass * model_.properties.gravity;
}

void Simulation::finishRigid() {
  const double t = stepper_->period();
  const VectorX& mass = model_.properties.mass;
  end_ = massProperties(mass, trial_.position, stepper_->threads());
  // Second half kick with the forces at the end of the drift (velocity Verlet); they are
  // also the next cycle's start forces. The rigid motion turned the elastic step's end
  // positions, and their internal forces turn with them: the step's end forces turned by
  // the same rotation are those forces (to rounding), without an evaluation.
  const Points* turned = allRigid_ ? nullptr : stepper_->turnEndForces(drift_.rotation);
  if (turned) {
    copyPoints(*turned, baseForce_, stepper_->threads());
    accumulateGravity(model_.properties, trial_.position, baseForce_);
    baseForceValid_ = true;
  } else {
    computeBaseForce(trial_.position);
  }
  // Point forces are held over the cycle; a torque load stays the same torque, so its
  // virtual forces are laid out again on the moved vertices.
  if (torques_.empty()) {
    totalForce_ = baseForce_ + external_;
  } else {
    gatherLoads(elasticStart_.time, trial_.position, loadForce_, &loadForceRows_);
    totalForce_ = baseForce_ + loadForce_;
  }
  // Pins' virtual forces are held over the cycle like any load; planes' couples act at its
  // start only (see ConstraintSolver::velocityCorrection).
  if (!constraints_.empty()) {
    const auto support = solver_.support();
    const Points& all = solver_.forces();
    const Points& couples = solver_.coupleForces();
    for (size_t a = 0; a < support.size(); ++a)
      totalForce_.row(support[a]) +=
          all.row(static_cast<Index>(a)) - couples.row(static_cast<Index>(a));
  }
  Vec3 force, torque;
  weightedResultant(chi_, trial_.position, totalForce_, end_.centre, force, torque,
                    stepper_->threads());
  rigidMomentum_ = rigidKick(drift_.half, force, torque, t, rigidDamping_);
  deformation_ = trial_.velocity;
  if (allRigid_) {
    deformation_.setZero();
  } else {
    // The deformation started the cycle with no net momentum and no angular momentum; hand
    // what it gained to the rigid body. Its momentum gain is the elastic share of the
    // forces' impulse (every scheme keeps linear momentum exactly), taken before the
    // deformation is turned with the body. Its angular momentum gain is replaced by the
    // impulse of the elastic share's torque (trapezoidal, like the kicks): the elastic
    // schemes do not keep angular momentum exactly, and this way internal forces, whose
    // torque vanishes, leave L exactly unchanged.
    Vec3 gained = Vec3::Zero();
    for (Index i = 0; i < deformation_.rows(); ++i)
      gained += mass[i] * deformation_.row(i).transpose();
    const Eigen::RowVector3d mean = (gained / end_.mass).transpose();
    for (Index i = 0; i < deformation_.rows(); ++i) deformation_.row(i) -= mean;
    // The rigid body's second half kick takes the internal forces at the end turned by the
    // cycle's rotation R, (T / 2) sum chi_i R f_i = -(T / 2) sum sigma_i R f_i. The elastic
    // step took the sigma share otherwise: the default scheme's second half kick at the
    // unturned end forces, the other schemes their whole step at the start forces. Counted
    // the rigid body's way, the two shares' impulses cancel and internal forces keep P
    // whatever chi is: the body gets (T / 2)(sum sigma_i R f_i - what the elastic step took
    // for it), damped as the rigid kick is (zero when chi is uniform: then sum sigma_i f_i
    // = 0 at every position). Gravity's share is the same in both frames and drops out.
    const Vec3 turnedShare = elasticInternalShare(baseForce_);
    const Vec3 elasticTook = settings_.scheme == Scheme::Default
                                 ? Vec3(drift_.rotation.transpose() * turnedShare)
                                 : startElasticShare_;
    const double decay = rigidDamping_ != 0.0 ? std::exp(-rigidDamping_ * t) : 1.0;
    gained += (decay * 0.5 * t) * (turnedShare - elasticTook);
    if (settings_.rigidFrame == RigidFrame::Body)
      for (Index i = 0; i < deformation_.rows(); ++i)
        deformation_.row(i) = (drift_.rotation * deformation_.row(i).transpose()).transpose();
    RigidMomentum moved =
        removeRigidMotion(mass, end_, trial_.position, deformation_, stepper_->threads());
    moved.linear += gained;
    Vec3 unused, endTorque;
    weightedResultant(sigma_, trial_.position, totalForce_, end_.centre, unused, endTorque,
                      stepper_->threads());
    Vec3 startTorque = startElasticTorque_;
    if (!constraints_.empty()) {
      const auto support = solver_.support();
      for (size_t a = 0; a < support.size(); ++a) {
        const Index v = support[a];
        startTorque +=
            (elasticStart_.position.row(v).transpose() - start_.centre)
                .cross(sigma_[static_cast<size_t>(v)] * constraintForce_.row(v).transpose());
      }
    }
    rigidMomentum_.linear += moved.linear;
    rigidMomentum_.angular += (0.5 * t) * (startTorque + endTorque);
    if (someFullyRigid_) holdFullyRigidVertices();
  }
  state_.position = trial_.position;
  state_.velocity = deformation_;
  addRigidVelocity(end_, rigidMomentum_, state_.position, state_.velocity, 1.0,
                   stepper_->threads());
}

void Simulation::syncSupport() {
  if (constraints_.empty() || constraints_.revision() == constraintRevision_) return;
  // The old support's forces go now, with the revision that records the change: the
  // clearing below skips them once the revision is current.
  constraintForce_.setZero();
  constraintForceZero_ = true;
  solver_.setUp(model_.mesh, constraints_);
  reserveLoadRows();
  constraintRevision_ = constraints_.revision();
  responseValid_ = false;
  const Index s = static_cast<Index>(solver_.support().size());
  supportStart_.setZero(s, 3);
  supportElastic_.setZero(s, 3);
  velocityDelta_.setZero(s, 3);
  supportChi_.assign(static_cast<size_t>(s), 0.0);
  warnedUnmet_ = false;
  warnedReleased_ = false;
  warnedYielded_ = false;
}

void Simulation::coupledStep() {
  const double t = stepper_->period();
  const VectorX& mass = model_.properties.mass;
  const bool constrained = !constraints_.empty();
  syncSupport();  // step() did, unless called otherwise
  if (constrained && !responseValid_) {
    response_.buildElastic(*stepper_, model_, stepperShare(), solver_.support());
    responseValid_ = true;
  }

  const int threads = stepper_->threads();
  // Without rigid motion the start state moves into elasticStart_ and the last trial into
  // state_ at the end (pointer swaps, not copies: 4 of the 8 full-model copies of a step
  // with two trials). In between state_ holds no state and nothing reads it; a throw in
  // between is rolled back from lastGood_ (step()).
  if (rigidActive_) {
    copyPoints(state_.position, elasticStart_.position, threads);
    copyPoints(deformation_, elasticStart_.velocity, threads);
  } else {
    elasticStart_.position.swap(state_.position);
    elasticStart_.velocity.swap(state_.velocity);
  }
  elasticStart_.time = state_.time;
  if (rigidActive_) {
    start_ = massProperties(mass, state_.position, threads);
    if (!baseForceValid_) computeBaseForce(state_.position);
    totalForce_ = baseForce_ + external_;
    startElasticShare_ = elasticInternalShare(baseForce_);
    weightedResultant(chi_, state_.position, totalForce_, start_.centre, startRigidForce_,
                      startRigidTorque_, threads);
    Vec3 unused;
    weightedResultant(sigma_, state_.position, totalForce_, start_.centre, unused,
                      startElasticTorque_, threads);
  }
  // The constraint forces are zero outside the support, whose rows every trial writes (below):
  // they need clearing only when the support changed (above), or without constraints.
  if (!constraintForceZero_ && !constrained) {
    constraintForce_.setZero();
    constraintForceZero_ = true;
  }
  report_ = ConstraintReport{};
  if (constrained) {
    const auto support = solver_.support();
    solver_.beginStep(model_.mesh, constraints_, elasticStart_.position, mass,
                      stepper_->system().omega2(), t);
    for (size_t a = 0; a < support.size(); ++a) {
      supportStart_.row(static_cast<Index>(a)) = elasticStart_.position.row(support[a]);
      supportChi_[a] = chi_[static_cast<size_t>(support[a])];
    }
    if (rigidActive_) {
      StepResponse::Rigid rigid;
      rigid.start = start_;
      rigid.momentum = rigidMomentum_;
      rigid.force = startRigidForce_;
      rigid.torque = startRigidTorque_;
      rigid.damping = rigidDamping_;
      rigid.period = t;
      response_.setRigid(rigid, supportStart_, supportChi_);
    } else {
      response_.clearRigid();
    }
    const double positionTolerance = settings_.positionTolerance * scale_;
    // Trials of the step under the solver's forces until the constraints hold, at most
    // constraintSteps of them, or until the solve leaves the forces as they were (the next
    // trial would be the last one again); the first of all computes the step afresh.
    int trials = 0;
    auto solveByTrials = [&] {
      for (int k = 0;; ++k) {
        const Points& virtualForce = solver_.forces();
        for (size_t a = 0; a < support.size(); ++a)
          constraintForce_.row(support[a]) = virtualForce.row(static_cast<Index>(a));
        constraintForceZero_ = false;
        runTrial(true, trials == 0);
        ++trials;
        if (solver_.check(constraints_, trial_.position, positionTolerance,
                          settings_.normalTolerance, report_))
          break;
        if (k + 1 >= settings_.constraintSteps) break;
        response_.anchor(supportElastic_, elasticCentre_, solver_.forces());
        if (!solver_.solve(constraints_, response_, positionTolerance, settings_.normalTolerance))
          break;
      }
    };
    solveByTrials();
    // Positions first. Pins the joint solve with the normals left unmet are solved again
    // without the normals (yieldPlanes), and that cycle is kept when it misfits less: the
    // joint solve fails where large motion makes the response model poor, and a drag flung
    // next to a held ring, left unmet cycle after cycle by more each time, blew the model up.
    // Pins alone are affine in their forces, so that solve holds them.
    if (report_.positionError > positionTolerance && solver_.heldPlanes() > 0) {
      const double jointMisfit = solver_.misfit(constraints_, trial_.position);
      const ConstraintReport joint = report_;
      solver_.save();
      report_.yielded = solver_.yieldPlanes();
      response_.anchor(supportElastic_, elasticCentre_, solver_.forces());
      solver_.solve(constraints_, response_, positionTolerance, settings_.normalTolerance);
      solveByTrials();
      if (!(solver_.misfit(constraints_, trial_.position) < jointMisfit)) {
        // The joint cycle again (its last trial, the same bits).
        solver_.restore();
        report_ = joint;
        const Points& virtualForce = solver_.forces();
        for (size_t a = 0; a < support.size(); ++a)
          constraintForce_.row(support[a]) = virtualForce.row(static_cast<Index>(a));
        runTrial(true, false);
        ++trials;
      }
    }
    report_.steps = trials;
    finishTrial();
    if (!solver_.releasedVertices().empty() && !warnedReleased_) {
      warnings_.push_back("normal constraint at vertex " +
                          std::to_string(solver_.releasedVertices().front()) +
                          " let go at t = " + std::to_string(state_.time) +
                          " s: its ring folded (no normal); it holds again once the ring "
                          "flattens");
      warnedReleased_ = true;
    }
    for (const ConstraintSolver::Stop& stop : solver_.newlyStopped())
      warnings_.push_back("normal constraint at vertex " + std::to_string(stop.vertex) +
                          " stopped at t = " + std::to_string(state_.time) + " s, " +
                          std::to_string(stop.angle) +
                          " rad from its target: the ring keeps turning back; held where it is");
    if (report_.yielded > 0 && !warnedYielded_) {
      warnings_.push_back("normal constraints let go at t = " + std::to_string(state_.time) +
                          " s: they and the pins could not both be met; the pins hold");
      warnedYielded_ = true;
    }
    if (!report_.converged && !warnedUnmet_) {
      warnings_.push_back("constraints not met at t = " + std::to_string(state_.time) +
                          " s (position error " + std::to_string(report_.positionError) +
                          " m, normal error " + std::to_string(report_.normalError) +
                          " rad): they contradict each other or the rigid body");
      warnedUnmet_ = true;
    }
  } else {
    runTrial(false, true);
  }

  const Vec3 centre = rigidActive_ ? start_.centre : Vec3::Zero();
  if (rigidActive_) {
    finishRigid();
  } else {
    state_.position.swap(trial_.position);
    state_.velocity.swap(trial_.velocity);
    baseForceValid_ = false;
  }
  state_.time = trial_.time;
  if (constrained) {
    solver_.velocityCorrection(t, elasticStart_.position, state_.position, state_.velocity, mass,
                               stepperShare(), velocityDelta_);
    const auto support = solver_.support();
    for (size_t a = 0; a < support.size(); ++a) {
      const Index v = support[a];
      // The constraints' work: their virtual forces over the cycle, and the kinetic energy
      // the velocity correction adds or removes.
      const Eigen::RowVector3d before = state_.velocity.row(v);
      const Eigen::RowVector3d after = before + velocityDelta_.row(static_cast<Index>(a));
      constraintWork_ += constraintForce_.row(v).dot(state_.position.row(v) -
                                                     supportStart_.row(static_cast<Index>(a))) +
                         0.5 * mass[v] * (after.squaredNorm() - before.squaredNorm());
      state_.velocity.row(v) += velocityDelta_.row(static_cast<Index>(a));
      if (rigidActive_) deformation_.row(v) += velocityDelta_.row(static_cast<Index>(a));
    }
    if (rigidActive_ && !allRigid_) {
      // The corrections' momentum and angular momentum go to the rigid body at once, so
      // the deformation starts every cycle with none (the vertex velocities are unchanged).
      const RigidMomentum moved =
          removeRigidMotion(mass, end_, state_.position, deformation_, threads);
      rigidMomentum_.linear += moved.linear;
      rigidMomentum_.angular += moved.angular;
    }
  }
  addToLedger(centre, velocityDelta_);
}

void Simulation::addToLedger(const Vec3& centreHint, const Points& velocityDelta) {
  const double t = stepper_->period();
  const VectorX& mass = model_.properties.mass;
  const Points& start = lastGood_.position;
  ledger_.gravity += t * mass.sum() * model_.properties.gravity;
  // Loads are counted where there are any (external_ is known zero otherwise): the centre
  // and the pass over the vertices are for them and for the constraints.
  if (externalZero_ && constraints_.empty()) return;
  const Vec3 centre = rigidActive_ ? centreHint : weightedCentre(mass, start, stepper_->threads());
  // In increasing row order, as a loop over every vertex would add them (the others are +0).
  for (size_t k = 0; k < externalRows_.size() && !externalZero_; ++k) {
    const Index i = externalRows_[k];
    const Vec3 arm = start.row(i).transpose() - centre;
    const Vec3 load = external_.row(i).transpose();
    if (!load.isZero(0.0)) {
      ledger_.loads += t * load;
      ledger_.loadsAngular += t * arm.cross(load);
    }
  }
  if (constraints_.empty()) return;
  const Vec3 endCentre = weightedCentre(mass, state_.position, stepper_->threads());
  const auto support = solver_.support();
  for (size_t a = 0; a < support.size(); ++a) {
    // Pins' forces act over the whole cycle. A couple: the elastic stepper held it (its
    // second half kick is taken back in velocityDelta, counted below), the rigid body got
    // its first half kick.
    const Index v = support[a];
    const double share =
        rigidActive_ ? sigma_[static_cast<size_t>(v)] + 0.5 * chi_[static_cast<size_t>(v)] : 1.0;
    const Vec3 couple = solver_.coupleForces().row(static_cast<Index>(a)).transpose();
    const Vec3 f = Vec3(constraintForce_.row(v).transpose()) - couple + share * couple;
    ledger_.constraints += t * f;
    ledger_.constraintsAngular += t * (Vec3(start.row(v).transpose()) - centre).cross(f);
  }
  for (size_t a = 0; a < support.size(); ++a) {
    const Index v = support[a];
    const Vec3 kick = mass[v] * velocityDelta.row(static_cast<Index>(a)).transpose();
    ledger_.constraints += kick;
    ledger_.constraintsAngular +=
        (Vec3(state_.position.row(v).transpose()) - endCentre).cross(kick);
  }
}

}  // namespace zsculpt
