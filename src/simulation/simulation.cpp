#include "zsculpt/simulation/simulation.h"

#include <string>

#include "zsculpt/core/errors.h"

namespace zsculpt {

Simulation::Simulation(Model model, const SimulationSettings& settings)
    : model_(std::move(model)) {
  model_.properties.validate(model_.mesh, model_.angles);
  state_ = State::atRest(model_.mesh);
  lastGood_ = state_;
  stepper_ = std::make_unique<Stepper>(model_, settings.scheme, settings.period, settings.stepper);
  external_.setZero(model_.mesh.numVertices(), 3);
  Index maxValence = 0;
  for (Index v = 0; v < model_.mesh.numVertices(); ++v)
    maxValence = std::max(maxValence, model_.mesh.valence(v));
  armBuffer_.resize(static_cast<size_t>(maxValence));
  forceBuffer_.resize(static_cast<size_t>(maxValence));
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
  lastGood_ = state;
  stepper_->invalidate();
}

namespace {

void checkLoad(const TimedLoad& load, Index n, const char* what) {
  if (load.vertex < 0 || load.vertex >= n)
    throw InvalidInputError(std::string(what) + " at vertex " + std::to_string(load.vertex) +
                            ": no such vertex (the model has " + std::to_string(n) + ")");
  if (!load.value.allFinite()) throw InvalidInputError(std::string(what) + ": not finite");
  if (!(load.end >= load.start))
    throw InvalidInputError(std::string(what) + ": ends before it starts");
}

}  // namespace

void Simulation::addForce(const TimedLoad& force) {
  checkLoad(force, model_.mesh.numVertices(), "force");
  forces_.push_back(force);
}

void Simulation::addTorque(const TimedLoad& torque) {
  checkLoad(torque, model_.mesh.numVertices(), "torque");
  if (model_.mesh.valence(torque.vertex) == 0)
    throw InvalidInputError("torque at vertex " + std::to_string(torque.vertex) +
                            ": an isolated vertex has no neighbours to carry a torque");
  torques_.push_back(torque);
}

void Simulation::clearLoads() {
  forces_.clear();
  torques_.clear();
}

void Simulation::gatherLoads(double t) {
  external_.setZero();
  for (const TimedLoad& f : forces_)
    if (f.activeAt(t)) external_.row(f.vertex) += f.value.transpose();
  const Mesh& mesh = model_.mesh;
  for (const TimedLoad& torque : torques_) {
    if (!torque.activeAt(t)) continue;
    // Section 5.3: a torque becomes virtual forces on the neighbours.
    const auto neighbours = mesh.vertexNeighbors(torque.vertex);
    const size_t k = neighbours.size();
    for (size_t q = 0; q < k; ++q) armBuffer_[q] = state_.position.row(neighbours[q]).transpose();
    Vec3 onCentre;
    torqueToForces(state_.position.row(torque.vertex).transpose(),
                   std::span<const Vec3>(armBuffer_.data(), k), torque.value,
                   std::span<Vec3>(forceBuffer_.data(), k), onCentre);
    external_.row(torque.vertex) += onCentre.transpose();
    for (size_t q = 0; q < k; ++q) external_.row(neighbours[q]) += forceBuffer_[q].transpose();
  }
}

void Simulation::step() {
  gatherLoads(state_.time);
  lastGood_.position = state_.position;
  lastGood_.velocity = state_.velocity;
  lastGood_.time = state_.time;
  stepper_->step(state_, external_);
  if (!state_.position.allFinite() || !state_.velocity.allFinite()) {
    const double t = state_.time;
    state_ = lastGood_;
    stepper_->invalidate();
    throw DivergenceError("the simulation diverged at t = " + std::to_string(t) +
                          " s (the state became non-finite)");
  }
}

void Simulation::propertiesChanged(std::span<const Index> vertices) {
  stepper_->propertiesChanged(vertices);
}

void Simulation::allPropertiesChanged() { stepper_->rebuild(); }

}  // namespace zsculpt
