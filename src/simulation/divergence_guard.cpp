#include "zsculpt/simulation/divergence_guard.h"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace zsculpt {

namespace {

void copyInto(State& slot, const State& state) {
  slot.position = state.position;  // same size after the first copy: no allocation
  slot.velocity = state.velocity;
  slot.time = state.time;
}

}  // namespace

DivergenceGuard::DivergenceGuard(const Simulation& sim) {
  restart(sim);
}

double DivergenceGuard::energyOf(const Simulation& sim, const Diagnostics& diagnostics) {
  const PotentialEnergy& v = diagnostics.potential;
  const double share = sim.uniformElasticShare();
  const double springs = v.radial + v.angular;
  return diagnostics.kinetic + v.gravity + share * springs;  // 1 x springs is exact
}

void DivergenceGuard::restart(const Simulation& sim) {
  const Diagnostics d = sim.diagnostics();
  start_ = energyOf(sim, d);
  inflow_ = 0.0;
  maxKinetic_ = d.kinetic;
  lastEnergy_ = start_;
  rebase_ = false;
  editPending_ = false;
  copyInto(slots_[0], sim.state());
  copyInto(slots_[1], sim.state());
  slotCycle_[0] = slotCycle_[1] = 0;
  newest_ = 0;
  reason_.clear();
}

void DivergenceGuard::addEnergy(double joules) {
  inflow_ += std::abs(joules);
}

void DivergenceGuard::measureEdit(const Simulation& sim) {
  const double energy = energyOf(sim, sim.diagnostics());
  if (!std::isfinite(energy)) return;  // the step's check will say so
  inflow_ += std::abs(energy - lastEnergy_);
  lastEnergy_ = energy;
  editPending_ = false;
}

void DivergenceGuard::beforeStep(const Simulation& sim, std::uint64_t cycle) {
  if (cycle == 0 || cycle % kCheckpointEvery != 0) return;
  newest_ = 1 - newest_;
  copyInto(slots_[newest_], sim.state());
  slotCycle_[newest_] = cycle;
}

bool DivergenceGuard::afterStep(const Simulation& sim, const Diagnostics& diagnostics) {
  const double energy = energyOf(sim, diagnostics);
  if (!std::isfinite(energy)) {
    reason_ = "the energy became non-finite";
    return false;
  }
  if (rebase_) {
    start_ = lastEnergy_ = energy;
    inflow_ = 0.0;
    maxKinetic_ = diagnostics.kinetic;
    rebase_ = editPending_ = false;
    return true;
  }
  if (editPending_) {
    inflow_ += std::abs(energy - lastEnergy_);
    editPending_ = false;
  }
  lastEnergy_ = energy;
  // Work of the loads and of the constraints over this cycle, counted in absolute value: the
  // scale of energy moved in and out.
  inflow_ += std::abs(sim.loadWork()) + std::abs(sim.constraintWork());
  const double bound = start_ + kEnergyFactor * (std::abs(start_) + inflow_) + maxKinetic_ + 1e-12;
  maxKinetic_ = std::max(maxKinetic_, diagnostics.kinetic);
  if (!(energy <= bound)) {
    std::ostringstream msg;
    msg.precision(4);
    msg << "the energy ran away: " << energy << " J";
    if (sim.uniformElasticShare() < 1.0)
      msg << " (the kinetic energy plus " << sim.uniformElasticShare() << " times the springs')";
    msg << ", more than " << kEnergyFactor << " times the start energy " << start_
        << " J plus the work put in, " << inflow_
        << " J, plus the largest kinetic energy before it";
    // A known way to get here, said where it applies: painted rigidity that varies heats an
    // undamped model (Torus-I half at 0.99, gently shaken: stopped at step 12; with damping
    // 0.05 kg/s it settles).
    if (sim.elasticShareVaries()) {
      const bool damped = sim.model().properties.damping.maxCoeff() > 0.0;
      msg << "; rigidity that varies from vertex to vertex can feed energy in faster than "
          << (damped ? "the damping takes it out: more damping" : "anything takes it out: damping")
          << " helps (--damping, or Damping in the Simulation panel)";
    }
    reason_ = msg.str();
    return false;
  }
  return true;
}

}  // namespace zsculpt
