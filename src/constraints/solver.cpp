#include "zsculpt/constraints/solver.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <numbers>

#include "zsculpt/core/errors.h"

namespace zsculpt {

namespace {

// The angle between unit vectors a and b, accurate near 0 and pi.
double angleBetween(const Vec3& a, const Vec3& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b));
}

// The unit axis of the shortest turn from unit vector `from` to `to`: for opposite ones any
// axis across `from`, for equal ones zero.
Vec3 turnAxis(const Vec3& from, const Vec3& to) {
  const Vec3 axis = from.cross(to);
  if (axis.norm() > 0.0) return axis.normalized();
  if (!(from.dot(to) < 0.0)) return Vec3::Zero();
  Index k = 0;
  from.cwiseAbs().minCoeff(&k);
  return from.cross(Vec3::Unit(k)).normalized();
}

}  // namespace

// ---- StepResponse ---------------------------------------------------------------------------

void StepResponse::buildElastic(const Stepper& stepper, const Model& model,
                                std::span<const double> share, std::span<const Index> support) {
  const Index s = static_cast<Index>(support.size());
  elastic_.setZero(s, s);
  centreShift_.setZero(s);
  anchorPosition_.setZero(s, 3);
  anchorForce_.setZero(s, 3);
  start_.setZero(s, 3);
  elasticWork_.setZero(s, 3);
  chi_.assign(static_cast<size_t>(s), 0.0);
  totalMass_ = model.properties.mass.sum();
  const VectorX& inverseMass = stepper.system().inverseMass();
  auto sigma = [&](Index v) { return share.empty() ? 1.0 : share[static_cast<size_t>(v)]; };
  // The scheme's own response (Stepper::positionResponse), per unit force on the elastic
  // share sigma_l of vertex l.
  std::vector<double> column(static_cast<size_t>(s));
  for (Index b = 0; b < s; ++b) {
    const Index l = support[static_cast<size_t>(b)];
    const double scale = sigma(l) * inverseMass[l];
    stepper.positionResponse(l, support, column);
    for (Index a = 0; a < s; ++a) elastic_(a, b) = column[static_cast<size_t>(a)] * scale;
    centreShift_[b] = stepper.centreResponse(l) * sigma(l);
  }
  // Once per build (O(|S|^3)) rather than a factorisation of 3|S| unknowns every cycle.
  elasticInverse_.resize(s, s);
  if (s > 0) {
    Eigen::CompleteOrthogonalDecomposition<Eigen::MatrixXd> decomposition(s, s);
    decomposition.compute(elastic_);
    elasticInverse_ = decomposition.solve(Eigen::MatrixXd::Identity(s, s));
  }
}

void StepResponse::elasticForceFor(const Points& displacement, Points& force) const {
  force.noalias() = elasticInverse_ * displacement;
}

void StepResponse::elasticDisplacement(const Points& force, Points& displacement) const {
  displacement.noalias() = elastic_ * force;
}

void StepResponse::setRigid(const Rigid& rigid, const Points& startPosition,
                            std::span<const double> rigidShare) {
  rigidActive_ = true;
  rigid_ = rigid;
  start_ = startPosition;
  std::copy(rigidShare.begin(), rigidShare.end(), chi_.begin());
}

void StepResponse::anchor(const Points& elasticPosition, const Vec3& elasticCentre,
                          const Points& force) {
  anchorPosition_ = elasticPosition;
  anchorCentre_ = elasticCentre;
  anchorForce_ = force;
}

void StepResponse::rigidMotion(const Points& force, Vec3& centre, RigidDrift& drift) const {
  // The same sums, in the same order, as the cycle's (Simulation::runTrial).
  Vec3 f = rigid_.force, torque = rigid_.torque, shift = Vec3::Zero();
  for (Index l = 0; l < force.rows(); ++l) {
    const Vec3 share = chi_[static_cast<size_t>(l)] * force.row(l).transpose();
    f += share;
    torque += (start_.row(l).transpose() - rigid_.start.centre).cross(share);
    shift += centreShift_[l] * (force.row(l) - anchorForce_.row(l)).transpose();
  }
  centre = anchorCentre_ + shift / totalMass_;
  drift = rigidDrift(rigid_.start, rigid_.momentum, f, torque, rigid_.period, rigid_.damping);
}

void StepResponse::predict(const Points& force, Points& position) const {
  // r_e = r_e0 + C (f - f0), per coordinate column.
  elasticWork_ = force - anchorForce_;
  position.noalias() = elastic_ * elasticWork_;
  position += anchorPosition_;
  if (!rigidActive_) return;
  Vec3 centre;
  RigidDrift drift;
  rigidMotion(force, centre, drift);
  applyRigidMotion(centre, drift.translation, drift.rotation, position);
}

// ---- ConstraintSolver -----------------------------------------------------------------------

void ConstraintSolver::setUp(const Mesh& mesh, const ConstraintSet& constraints) {
  localOf_.assign(static_cast<size_t>(mesh.numVertices()), -1);
  support_.clear();
  std::vector<Index> fit;
  for (const Constraint& c : constraints.constraints()) {
    if (c.kind == ConstraintKind::Position) {
      support_.push_back(c.vertex);
    } else {
      normalFitVertices(mesh, c.vertex, fit);
      support_.insert(support_.end(), fit.begin(), fit.end());
    }
  }
  std::sort(support_.begin(), support_.end());
  support_.erase(std::unique(support_.begin(), support_.end()), support_.end());
  for (size_t a = 0; a < support_.size(); ++a)
    localOf_[static_cast<size_t>(support_[a])] = static_cast<Index>(a);
  pins_.clear();
  // A plane's turning record (its target, what it lost, whether it stopped) belongs to its
  // constraint, not to this set-up: it carries over when other constraints come and go (a
  // drag in the window adds and removes a pin at each stroke).
  std::vector<Plane> previous;
  previous.swap(planes_);
  size_t largestPlane = 0;
  for (const Constraint& c : constraints.constraints()) {
    if (c.kind == ConstraintKind::Position) {
      pins_.push_back(Pin{c.id, local(c.vertex)});
    } else {
      Plane plane;
      plane.id = c.id;
      normalFitVertices(mesh, c.vertex, fit);
      for (Index v : fit) plane.locals.push_back(local(v));
      plane.gradient.assign(fit.size(), Eigen::Matrix<double, 3, 2>::Zero());
      plane.hint = c.value;
      for (const Plane& before : previous)
        if (before.id == c.id) {
          plane.hint = before.hint;
          plane.turn = before.turn;
        }
      largestPlane = std::max(largestPlane, fit.size());
      planes_.push_back(std::move(plane));
    }
  }
  releasedVertices_.clear();
  newlyStopped_.clear();
  releasedVertices_.reserve(planes_.size());
  newlyStopped_.reserve(planes_.size());
  pinForce_.assign(pins_.size(), Vec3::Zero());
  lambda_.assign(planes_.size(), Eigen::Vector2d::Zero());
  const Index s = static_cast<Index>(support_.size());
  forces_.setZero(s, 3);
  coupleForces_.setZero(s, 3);
  predicted_.setZero(s, 3);
  supportEnd_.setZero(s, 3);
  scratch_.setZero(s, 3);
  endGradient_.assign(largestPlane, Eigen::Matrix<double, 3, 2>::Zero());
  points_.reserve(largestPlane);
  const Index residuals = 3 * static_cast<Index>(pins_.size() + planes_.size());
  const Index unknownCount =
      3 * static_cast<Index>(pins_.size()) + 2 * static_cast<Index>(planes_.size());
  jacobian_.setZero(residuals, unknownCount);
  factor_ = Eigen::CompleteOrthogonalDecomposition<Eigen::MatrixXd>(residuals, unknownCount);
  pinError_.setZero(s, 3);
  pinStep_.setZero(s, 3);
  planeMotion_.setZero(s, 3);
  for (VectorX* v : {&rhs_, &shifted_, &solveWork_}) v->setZero(residuals);
  for (VectorX* v : {&step_, &base_, &trial_, &solveUnpermuted_}) v->setZero(unknownCount);
}

Index ConstraintSolver::local(Index vertex) const {
  if (vertex < 0 || static_cast<size_t>(vertex) >= localOf_.size()) return -1;
  return localOf_[static_cast<size_t>(vertex)];
}

void ConstraintSolver::gatherSupport(const Points& all, Points& out) const {
  for (size_t a = 0; a < support_.size(); ++a)
    out.row(static_cast<Index>(a)) = all.row(support_[a]);
}

void ConstraintSolver::beginStep(const Mesh& mesh, const ConstraintSet& constraints,
                                 const Points& position, const VectorX& mass,
                                 const SparseRowMatrix& omega2, double period) {
  gatherSupport(position, supportEnd_);
  releasedVertices_.clear();
  newlyStopped_.clear();
  for (size_t q = 0; q < planes_.size(); ++q) {
    Plane& plane = planes_[q];
    double total = 0.0;
    Vec3 centre = Vec3::Zero();
    for (size_t k = 0; k < plane.locals.size(); ++k) {
      const Index v = support_[static_cast<size_t>(plane.locals[k])];
      total += mass[v];
      centre += mass[v] * position.row(v).transpose();
    }
    centre /= total;
    plane.radius = 0.0;
    for (size_t k = 0; k < plane.locals.size(); ++k) {
      const Index v = support_[static_cast<size_t>(plane.locals[k])];
      plane.radius +=
          (position.row(v).transpose() - centre).norm() / static_cast<double>(plane.locals.size());
    }
    // Orientation of the fitted plane this step: the faces' where the vertex has faces,
    // else continuity with the last step (a curve), so the normal never flips.
    const Index vertex = constraints.get(plane.id).vertex;
    Vec3 reference = Vec3::Zero();
    for (Index f : mesh.vertexFaces(vertex)) {
      const auto corners = mesh.face(f);
      for (size_t k = 0; k < corners.size(); ++k)
        reference += Vec3(position.row(corners[k]).transpose())
                         .cross(Vec3(position.row(corners[(k + 1) % corners.size()]).transpose()));
    }
    const Vec3 current = planeNormal(plane, supportEnd_);
    if (reference.squaredNorm() > 0.0)
      plane.hint = current.dot(reference) < 0.0 ? -current : current;
    else if (current.squaredNorm() > 0.0)
      plane.hint = current;
    // A ring that does not define its normal is let go for the cycle: no forces, no warm
    // start, and no pursuit of its residual (kMaxPlaneFlatness).
    points_.clear();
    for (Index l : plane.locals) points_.push_back(supportEnd_.row(l).transpose());
    plane.held = current.squaredNorm() > 0.0 && planeFlatness(points_) <= kMaxPlaneFlatness;
    plane.yielded = false;
    if (!plane.held) {
      TurnRecord& turn = plane.turn;
      if (turn.lastOff >= 0.0 && turn.arrived) {  // held at its target, and folded there
        ++turn.foldsAfterArriving;
        turn.arrived = false;
      }
      turn.settled = 0.0;
      turn.lastOff = -1.0;  // the way back from a fold is not lost (kTurnBudget)
      for (auto& g : plane.gradient) g.setZero();
      lambda_[q].setZero();
      releasedVertices_.push_back(vertex);
      continue;
    }
    // The cycle's goal: the target, or the normal turned towards it by as much as the ring
    // may turn in a cycle (kTurnRate), at most kTurnRate a cycle (a ring without springs
    // has no period of its own).
    const Vec3 target = constraints.get(plane.id).value;
    TurnRecord& turn = plane.turn;
    if (target != turn.target) turn = TurnRecord{.target = target};  // a new budget
    double stiffest = 0.0;
    for (Index l : plane.locals)
      stiffest = std::max(stiffest, omega2.coeff(support_[static_cast<size_t>(l)],
                                                 support_[static_cast<size_t>(l)]));
    const double ringPeriod = stiffest > 0.0 ? std::sqrt(6.0 / stiffest) : period;
    const double maxTurn = kTurnRate * std::min(1.0, period / ringPeriod);
    // The most the plane's forces may move a vertex of its ring in the cycle (planesWithinReach).
    plane.reach = std::min(2.0, kReachTurns * maxTurn) * plane.radius;
    const Vec3 from = plane.hint;
    // What the ring lost of its way to the target since the last cycle, if it was held then
    // too (a turn undone by the shape around it), counted until it arrives (kTurnBudget).
    const double fromTarget = angleBetween(from, target);
    if (!turn.stopped) {
      if (turn.lastOff >= 0.0) turn.lost += std::max(0.0, fromTarget - turn.lastOff);
      turn.lastOff = fromTarget;
      if (fromTarget <= maxTurn) {  // arrived
        turn.lost = 0.0;
        turn.arrived = true;
        turn.settled += std::min(1.0, period / ringPeriod);
        if (turn.settled >= kSettledPeriods) turn.foldsAfterArriving = 0;
      } else {
        turn.settled = 0.0;
      }
      if (turn.lost > kTurnBudget || turn.foldsAfterArriving > kFoldBudget) {
        turn.stopped = true;  // the budget is spent: hold the normal where it is
        turn.kept = from;
        newlyStopped_.push_back({vertex, fromTarget});
      }
    }
    // A stopped plane holds what it kept, or where it is if that is a turn away (it was let
    // go since, and moved).
    if (turn.stopped && angleBetween(from, turn.kept) > maxTurn) turn.kept = from;
    const Vec3 aim = turn.stopped ? turn.kept : target;
    plane.goal = angleBetween(from, aim) > maxTurn
                     ? Vec3(Eigen::AngleAxisd(maxTurn, turnAxis(from, aim)) * from)
                     : aim;
    // Two directions across the goal: the components of the normal the forces act on.
    Index axis = 0;
    plane.goal.cwiseAbs().minCoeff(&axis);
    plane.across.col(0) = plane.goal.cross(Vec3::Unit(axis)).normalized();
    plane.across.col(1) = plane.goal.cross(Vec3(plane.across.col(0)));
    normalGradient(plane, supportEnd_, plane.gradient);
  }
  // Warm start: last cycle's unknowns, with this cycle's gradients.
  assembleForces();
}

int ConstraintSolver::yieldPlanes() {
  int yielded = 0;
  for (size_t q = 0; q < planes_.size(); ++q) {
    Plane& plane = planes_[q];
    if (!plane.held) continue;
    plane.held = false;
    plane.yielded = true;
    plane.turn.lastOff = -1.0;
    for (auto& g : plane.gradient) g.setZero();
    lambda_[q].setZero();
    ++yielded;
  }
  assembleForces();
  return yielded;
}

int ConstraintSolver::heldPlanes() const {
  return static_cast<int>(
      std::count_if(planes_.begin(), planes_.end(), [](const Plane& p) { return p.held; }));
}

double ConstraintSolver::misfit(const ConstraintSet& constraints, const Points& endPosition) {
  gatherSupport(endPosition, supportEnd_);
  double worst = 0.0;
  for (const Pin& pin : pins_)
    worst = std::max(
        worst, (supportEnd_.row(pin.local).transpose() - constraints.get(pin.id).value).norm());
  Vec3 rotation;
  for (const Plane& plane : planes_)
    if (plane.held || plane.yielded)
      worst = std::max(worst, plane.radius * planeResidual(plane, supportEnd_, rotation));
  return worst;
}

void ConstraintSolver::save() {
  savedUnknowns_.resize(static_cast<Index>(3 * pins_.size() + 2 * planes_.size()));
  unknowns(savedUnknowns_);
  savedHeld_.resize(planes_.size());
  savedGradient_.resize(planes_.size());
  for (size_t q = 0; q < planes_.size(); ++q) {
    savedHeld_[q] = planes_[q].held ? 1 : 0;
    savedGradient_[q] = planes_[q].gradient;
  }
}

void ConstraintSolver::restore() {
  for (size_t q = 0; q < planes_.size(); ++q) {
    planes_[q].held = savedHeld_[q] != 0;
    planes_[q].yielded = false;
    planes_[q].gradient = savedGradient_[q];
  }
  setUnknowns(savedUnknowns_);
  assembleForces();
}

void ConstraintSolver::forgetTurning() {
  for (Plane& plane : planes_) plane.turn = TurnRecord{};
}

void ConstraintSolver::markCycle() {
  markedTurn_.resize(planes_.size());
  markedHint_.resize(planes_.size());
  for (size_t q = 0; q < planes_.size(); ++q) {
    markedTurn_[q] = planes_[q].turn;
    markedHint_[q] = planes_[q].hint;
  }
  markedUnknowns_.resize(static_cast<Index>(3 * pins_.size() + 2 * planes_.size()));
  unknowns(markedUnknowns_);
}

void ConstraintSolver::rewindCycle() {
  ZSCULPT_ASSERT(markedTurn_.size() == planes_.size(), "rewindCycle() without its markCycle()");
  for (size_t q = 0; q < planes_.size(); ++q) {
    planes_[q].turn = markedTurn_[q];
    planes_[q].hint = markedHint_[q];
  }
  setUnknowns(markedUnknowns_);  // beginStep assembles the forces with its gradients
  newlyStopped_.clear();
}

Vec3 ConstraintSolver::planeNormal(const Plane& plane, const Points& supportPosition) const {
  points_.clear();
  for (Index l : plane.locals) points_.push_back(supportPosition.row(l).transpose());
  const std::optional<Vec3> normal = fitPlaneNormal(points_);
  if (!normal) return Vec3::Zero();
  return normal->dot(plane.hint) < 0.0 ? Vec3(-*normal) : *normal;
}

void ConstraintSolver::normalGradient(const Plane& plane, Points& supportPosition,
                                      std::vector<Eigen::Matrix<double, 3, 2>>& out) const {
  // The fitted normal is smooth where the ring's flattest direction is distinct; a step of
  // 1e-6 of the ring's radius resolves it to about 1e-10 relative.
  const double h = 1e-6 * plane.radius;
  for (size_t k = 0; k < plane.locals.size(); ++k) {
    const Index l = plane.locals[k];
    for (int d = 0; d < 3; ++d) {
      const double kept = supportPosition(l, d);
      supportPosition(l, d) = kept + h;
      const Vec3 plus = planeNormal(plane, supportPosition);
      supportPosition(l, d) = kept - h;
      const Vec3 minus = planeNormal(plane, supportPosition);
      supportPosition(l, d) = kept;
      out[k].row(d) = ((plus - minus).transpose() * plane.across) / (2.0 * h);
    }
  }
}

double ConstraintSolver::planeResidual(const Plane& plane, const Points& supportPosition,
                                       Vec3& rotation) const {
  const Vec3& target = plane.goal;
  const Vec3 normal = planeNormal(plane, supportPosition);
  if (normal.squaredNorm() == 0.0) {
    // The plane collapsed to a line: no normal; report the largest error.
    rotation.setZero();
    return std::numbers::pi;
  }
  // The rotation taking the current normal to the target.
  const double angle = angleBetween(normal, target);
  rotation = angle * turnAxis(normal, target);
  return angle;
}

void ConstraintSolver::assembleForces() {
  coupleForces_.setZero();
  for (size_t q = 0; q < planes_.size(); ++q) {
    const Plane& plane = planes_[q];
    for (size_t k = 0; k < plane.locals.size(); ++k)
      coupleForces_.row(plane.locals[k]) += (plane.gradient[k] * lambda_[q]).transpose();
  }
  forces_ = coupleForces_;
  for (size_t k = 0; k < pins_.size(); ++k) forces_.row(pins_[k].local) += pinForce_[k].transpose();
}

bool ConstraintSolver::check(const ConstraintSet& constraints, const Points& endPosition,
                             double positionTolerance, double normalTolerance,
                             ConstraintReport& report) {
  gatherSupport(endPosition, supportEnd_);
  report.positionError = 0.0;
  report.normalError = 0.0;
  for (const Pin& pin : pins_) {
    const Vec3 target = constraints.get(pin.id).value;
    report.positionError =
        std::max(report.positionError, (supportEnd_.row(pin.local).transpose() - target).norm());
  }
  Vec3 rotation;
  report.released = static_cast<int>(releasedVertices_.size());
  report.stopped = 0;
  report.turning = 0;
  report.targetError = 0.0;
  for (const Plane& plane : planes_) {
    // A stop lasts until the target changes, through cycles in which the ring is let go.
    if (plane.turn.stopped) ++report.stopped;
    if (plane.held) {
      report.normalError =
          std::max(report.normalError, planeResidual(plane, supportEnd_, rotation));
      const Vec3 target = constraints.get(plane.id).value;
      report.targetError =
          std::max(report.targetError, angleBetween(planeNormal(plane, supportEnd_), target));
      if (!plane.turn.stopped && plane.goal != target) ++report.turning;
    }
  }
  report.converged =
      report.positionError <= positionTolerance && report.normalError <= normalTolerance;
  return report.converged;
}

double ConstraintSolver::residual(const ConstraintSet& constraints, const StepResponse& response,
                                  VectorX& out, double& positionError, double& normalError) {
  // Pins: target - predicted position (m). Planes held this cycle: the turn taking the
  // predicted normal to the cycle's goal, times the plane's radius (m), so that both weigh
  // alike in least squares; planes let go: nothing.
  assembleForces();
  response.predict(forces_, predicted_);
  positionError = 0.0;
  normalError = 0.0;
  Index row = 0;
  for (const Pin& pin : pins_) {
    const Vec3 e = constraints.get(pin.id).value - predicted_.row(pin.local).transpose();
    positionError = std::max(positionError, e.norm());
    out.segment<3>(row) = e;
    row += 3;
  }
  Vec3 rotation;
  for (const Plane& plane : planes_) {
    if (plane.held) {
      normalError = std::max(normalError, planeResidual(plane, predicted_, rotation));
      out.segment<3>(row) = plane.radius * rotation;
    } else {
      out.segment<3>(row).setZero();
    }
    row += 3;
  }
  return out.squaredNorm();
}

bool ConstraintSolver::planesWithinReach(const StepResponse& response) {
  response.elasticDisplacement(coupleForces_, planeMotion_);
  for (const Plane& plane : planes_)
    if (plane.held)
      for (Index l : plane.locals)
        if (!(planeMotion_.row(l).norm() <= plane.reach)) return false;
  return true;
}

void ConstraintSolver::unknowns(VectorX& x) const {
  // Pin forces (3 each), then each plane's two weights, for the components of its normal
  // across the target (the component along it only changes to second order: leaving it
  // out keeps the problem well-posed).
  Index row = 0;
  for (const Vec3& f : pinForce_) {
    x.segment<3>(row) = f;
    row += 3;
  }
  for (size_t q = 0; q < planes_.size(); ++q) {
    x.segment<2>(row) = lambda_[q];
    row += 2;
  }
}

void ConstraintSolver::setUnknowns(const VectorX& x) {
  Index row = 0;
  for (Vec3& f : pinForce_) {
    f = x.segment<3>(row);
    row += 3;
  }
  for (size_t q = 0; q < planes_.size(); ++q) {
    lambda_[q] = x.segment<2>(row);
    row += 2;
  }
}

bool ConstraintSolver::solve(const ConstraintSet& constraints, const StepResponse& response,
                             double positionTolerance, double normalTolerance) {
  // Damped Newton on all unknowns at once (pin forces and plane weights), with the Jacobian
  // of the response model by forward differences: the elastic part is affine, so its
  // columns are exact to rounding, and the pins' pull on a plane's vertices (which decides
  // which turns of the plane are reachable at all) is part of it. The least-squares step of
  // minimum norm leaves unreachable directions alone instead of letting their forces grow.
  constexpr int kIterations = 20;
  const Index n = static_cast<Index>(3 * pins_.size() + 2 * planes_.size());
  if (n == 0) return false;
  initial_.resize(n);
  unknowns(initial_);
  auto changed = [&] {
    unknowns(base_);
    return base_ != initial_;
  };
  double positionError = 0.0, normalError = 0.0;
  double cost = residual(constraints, response, rhs_, positionError, normalError);
  if (planes_.empty() && response.affine() && pins_.size() == support_.size()) {
    // Pins alone on an affine response: the residual target - (r0 + C (f - f0)) is linear in
    // the forces, and its Jacobian is -C, constant while the response is. The Newton step is
    // then exact with the pseudo-inverse built with the response; a second one refines what
    // rounding left (a state far from the model's scale, as in a divergence). A
    // finite-difference Jacobian could do no better.
    constexpr int kRefinements = 3;
    for (int k = 0; k < kRefinements && positionError > positionTolerance; ++k) {
      for (size_t pin = 0; pin < pins_.size(); ++pin)
        pinError_.row(pins_[pin].local) = rhs_.segment<3>(3 * static_cast<Index>(pin)).transpose();
      response.elasticForceFor(pinError_, pinStep_);
      unknowns(base_);
      trial_ = base_;
      for (size_t pin = 0; pin < pins_.size(); ++pin)
        trial_.segment<3>(3 * static_cast<Index>(pin)) +=
            pinStep_.row(pins_[pin].local).transpose();
      setUnknowns(trial_);
      double p = 0.0, q = 0.0;
      const double trialCost = residual(constraints, response, shifted_, p, q);
      if (!(trialCost < cost)) {
        setUnknowns(base_);
        break;
      }
      cost = trialCost;
      rhs_ = shifted_;
      positionError = p;
    }
    assembleForces();
    return changed();
  }
  for (int iteration = 0; iteration < kIterations; ++iteration) {
    if (positionError <= positionTolerance && normalError <= normalTolerance) break;
    unknowns(base_);
    const double scale = base_.cwiseAbs().maxCoeff();
    for (Index c = 0; c < n; ++c) {
      const double h = 1e-7 * std::max(1.0, scale);
      trial_ = base_;
      trial_[c] += h;
      setUnknowns(trial_);
      double unusedP = 0.0, unusedN = 0.0;
      residual(constraints, response, shifted_, unusedP, unusedN);
      jacobian_.col(c) = (shifted_ - rhs_) / h;
    }
    factor_.compute(jacobian_);
    leastNormSolve(factor_, rhs_, solveWork_, solveUnpermuted_, step_);
    // Backtracking: halve the step until the residual shrinks, with every held plane's forces
    // moving its ring by at most its reach in the cycle (kReachTurns; at most its diameter,
    // the most any turn of it needs).
    // Where a ring folds through a shape with no flattest direction its fitted normal jumps,
    // and the residual can fall by a hair for forces that grow without bound along
    // directions that hardly turn the plane (1e40 within one cycle, and a state of 1e73 J
    // after it, on unbraced Torus-II before this bound); a target beyond reach is left
    // unmet for the cycle (ConstraintReport::converged) instead.
    bool improved = false;
    for (double fraction = 1.0; fraction > 1e-3; fraction *= 0.5) {
      trial_ = base_ - fraction * step_;
      setUnknowns(trial_);
      double p = 0.0, q = 0.0;
      const double trialCost = residual(constraints, response, shifted_, p, q);
      if (trialCost < cost && (planes_.empty() || planesWithinReach(response))) {
        cost = trialCost;
        rhs_ = shifted_;
        positionError = p;
        normalError = q;
        improved = true;
        break;
      }
    }
    if (!improved) {
      setUnknowns(base_);
      break;
    }
  }
  assembleForces();
  return changed();
}

void ConstraintSolver::velocityCorrection(double period, const Points& startPosition,
                                          const Points& endPosition, const Points& velocity,
                                          const VectorX& mass, std::span<const double> share,
                                          Points& delta) const {
  const double t = period;
  delta.setZero(static_cast<Index>(support_.size()), 3);
  auto sigma = [&](Index v) { return share.empty() ? 1.0 : share[static_cast<size_t>(v)]; };
  // 1. A plane's forces act as an impulse at the start of the cycle: the stepper held them
  // over the whole cycle, and their second half kick, along the start's gradient, which
  // has turned since, would push the plane's vertices outwards; take it back.
  for (size_t a = 0; a < support_.size(); ++a) {
    const Index v = support_[a];
    delta.row(static_cast<Index>(a)) =
        (-0.5 * t * sigma(v) / mass[v]) * coupleForces_.row(static_cast<Index>(a));
  }
  auto current = [&](Index l) -> Vec3 {
    return (velocity.row(support_[static_cast<size_t>(l)]) + delta.row(l)).transpose();
  };
  // 2. A constrained normal does not move: with G_k = d (n . across) / d r_k at the end of
  // the cycle, the ring's velocities are projected onto those with sum_k G_k^T v_k = 0, in
  // the mass-weighted norm (the velocity step of RATTLE): dv_k = -(sigma_k / m_k) G_k mu,
  // mu = A^+ sum_k G_k^T v_k, A = sum_k (sigma_k / m_k) G_k^T G_k. A projection only takes
  // kinetic energy away, and sum_k G_k = 0 (a translation does not turn the plane), so it
  // keeps the momentum. (Until the tenth session this took away the ring's rigid angular
  // velocity across the normal; but a ring's fitted normal also turns as the ring deforms,
  // and on a surface without angle springs, which deforms freely, the leftover made each
  // cycle's correction larger than the last: a perturbed dodecahedron with one normal pin
  // reached 1e300 J within 500 cycles.)
  gatherSupport(endPosition, scratch_);
  for (const Plane& plane : planes_) {
    if (!plane.held) continue;
    normalGradient(plane, scratch_, endGradient_);
    Eigen::Matrix2d a = Eigen::Matrix2d::Zero();
    Eigen::Vector2d b = Eigen::Vector2d::Zero();
    for (size_t k = 0; k < plane.locals.size(); ++k) {
      const Index l = plane.locals[k];
      const Index v = support_[static_cast<size_t>(l)];
      const double weight = sigma(v) / mass[v];
      a += weight * endGradient_[k].transpose() * endGradient_[k];
      b += endGradient_[k].transpose() * current(l);
    }
    const Eigen::Vector2d mu = a.completeOrthogonalDecomposition().solve(b);
    for (size_t k = 0; k < plane.locals.size(); ++k) {
      const Index l = plane.locals[k];
      const Index v = support_[static_cast<size_t>(l)];
      delta.row(l) -= (sigma(v) / mass[v]) * (endGradient_[k] * mu).transpose();
    }
  }
  // 3. A pinned vertex moves as its target did over the cycle.
  for (const Pin& pin : pins_) {
    const Index v = support_[static_cast<size_t>(pin.local)];
    if (!(sigma(v) > 0.0)) continue;
    const Eigen::RowVector3d wanted = (endPosition.row(v) - startPosition.row(v)) / t;
    delta.row(pin.local) = wanted - velocity.row(v);
  }
}

void leastNormSolve(const Eigen::CompleteOrthogonalDecomposition<Eigen::MatrixXd>& factor,
                    const VectorX& b, VectorX& work, VectorX& unpermuted, VectorX& x) {
  // CompleteOrthogonalDecomposition::solve written out over the caller's vectors (Eigen's
  // made 5 to 28 allocations a cycle with a normal pin, in the Newton step).
  // A P = Q [T 0; 0 0] Z: x = P Z^T [T^-1 (Q^T b)_1..r; 0].
  const Eigen::MatrixXd& qtz = factor.matrixQTZ();
  const Index rows = qtz.rows(), cols = qtz.cols(), rank = factor.rank();
  x.setZero();
  if (rank == 0) return;
  // Q^T b: the QR's first `rank` reflectors, H_0 first (v_k = [1; qtz(k+1:, k)]).
  work = b;
  for (Index k = 0; k < rank; ++k) {
    double dot = work[k];
    for (Index i = k + 1; i < rows; ++i) dot += qtz(i, k) * work[i];
    dot *= factor.hCoeffs()[k];
    work[k] -= dot;
    for (Index i = k + 1; i < rows; ++i) work[i] -= dot * qtz(i, k);
  }
  // T z = (Q^T b)_1..r, T upper triangular.
  VectorX& y = unpermuted;
  for (Index i = rank - 1; i >= 0; --i) {
    double sum = work[i];
    for (Index j = i + 1; j < rank; ++j) sum -= qtz(i, j) * y[j];
    y[i] = sum / qtz(i, i);
  }
  for (Index i = rank; i < cols; ++i) y[i] = 0.0;
  // Z^T [z; 0] when J is rank deficient: the reflectors stored right of T, row k's acting on
  // entries k and rank..cols-1 (Eigen's applyZAdjointOnTheLeftInPlace).
  if (rank < cols) {
    for (Index k = 0; k < rank; ++k) {
      if (k != rank - 1) std::swap(y[k], y[rank - 1]);
      double dot = y[rank - 1];
      for (Index j = rank; j < cols; ++j) dot += qtz(k, j) * y[j];
      dot *= factor.zCoeffs()[k];
      y[rank - 1] -= dot;
      for (Index j = rank; j < cols; ++j) y[j] -= dot * qtz(k, j);
      if (k != rank - 1) std::swap(y[k], y[rank - 1]);
    }
  }
  // x = P y.
  const auto& permutation = factor.colsPermutation().indices();
  for (Index i = 0; i < cols; ++i) x[permutation[i]] = y[i];
}

}  // namespace zsculpt
