#include "zsculpt/physics/stepper.h"

#include <cmath>
#include <limits>
#include <unsupported/Eigen/MatrixFunctions>

#include "zsculpt/core/errors.h"

namespace zsculpt {

std::string_view schemeName(Scheme scheme) {
  switch (scheme) {
    case Scheme::Default: return "default";
    case Scheme::Paper: return "paper";
    case Scheme::Exact: return "exact";
    case Scheme::SymplecticEuler: return "symplectic-euler";
    case Scheme::ImplicitEuler: return "implicit-euler";
  }
  return "?";
}

Scheme schemeFromName(std::string_view name) {
  for (Scheme s : {Scheme::Default, Scheme::Paper, Scheme::Exact, Scheme::SymplecticEuler,
                   Scheme::ImplicitEuler})
    if (schemeName(s) == name) return s;
  throw InvalidInputError("unknown scheme '" + std::string(name) +
                          "' (valid: default, paper, exact, symplectic-euler, implicit-euler)");
}

double stablePeriodLimit(Scheme scheme, double lambda0) {
  constexpr double inf = std::numeric_limits<double>::infinity();
  if (!(lambda0 > 0.0)) return inf;
  switch (scheme) {
    case Scheme::Default:
    case Scheme::Paper: return std::sqrt(12.0 / lambda0);
    case Scheme::SymplecticEuler: return std::sqrt(4.0 / lambda0);
    case Scheme::Exact:
    case Scheme::ImplicitEuler: return inf;
  }
  return inf;
}

struct Stepper::Implicit {
  Eigen::SparseMatrix<double> a;
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver;
  VectorX rhs, dv, flat;
};

Stepper::Stepper(const Model& model, Scheme scheme, double period, const StepperOptions& options)
    : model_(model), scheme_(scheme), period_(period), options_(options), system_(model) {
  if (!(period > 0.0) || !std::isfinite(period))
    throw InvalidInputError("time step " + std::to_string(period) + " must be positive");
  const Index n = model.mesh.numVertices();
  for (Points* p : {&internal_, &totalForce_, &acceleration_, &work1_, &work2_, &work3_, &work4_})
    p->setZero(n, 3);
  if (scheme_ == Scheme::Paper)
    transformation_ = std::make_unique<TransformationMatrices>(system_, period_);
  if (scheme_ == Scheme::Exact) setUpExact();
  if (scheme_ == Scheme::ImplicitEuler) implicit_ = std::make_unique<Implicit>();
}

Stepper::~Stepper() = default;

void Stepper::propertiesChanged(std::span<const Index> vertices) {
  system_.updateVertices(model_, vertices);
  if (transformation_) transformation_->updateVertices(system_, vertices);
  if (scheme_ == Scheme::Exact) setUpExact();
  cacheValid_ = false;
}

void Stepper::rebuild() {
  system_ = SystemMatrices(model_);
  if (transformation_) *transformation_ = TransformationMatrices(system_, period_);
  if (scheme_ == Scheme::Exact) setUpExact();
  cacheValid_ = false;
}

void Stepper::step(State& state, const Points& external, std::span<const double> share) {
  switch (scheme_) {
    case Scheme::Default: stepDefault(state, external, share); break;
    case Scheme::Paper: stepPaper(state, external, share); break;
    case Scheme::Exact: stepExact(state, external, share); break;
    case Scheme::SymplecticEuler: stepSymplecticEuler(state, external, share); break;
    case Scheme::ImplicitEuler: stepImplicitEuler(state, external, share); break;
  }
  state.time += period_;
}

void Stepper::computeAcceleration(const Points& position, const Points& external,
                                  std::span<const double> share, bool reuseInternal) {
  if (!reuseInternal) {
    internal_.setZero();
    accumulateInternalForces(model_, position, internal_);
  }
  totalForce_ = internal_ + external;
  accumulateGravity(model_.properties, position, totalForce_);
  const VectorX& inverseMass = system_.inverseMass();
  for (Index i = 0; i < acceleration_.rows(); ++i) {
    const double scale = share.empty() ? inverseMass[i] : share[i] * inverseMass[i];
    acceleration_.row(i) = scale * totalForce_.row(i);
  }
}

void Stepper::stepDefault(State& s, const Points& external, std::span<const double> share) {
  const double t = period_;
  const VectorX& g = system_.dampingCoefficient();
  auto filteredKick = [&]() {
    // v += (T/2) Phi a, Phi = I - T^2 Omega^2 / 12 = 2 H / T^2 truncated after Omega^2.
    multiply(system_.omega2(), acceleration_, work1_);
    s.velocity += (0.5 * t) * acceleration_ - (t * t * t / 24.0) * work1_;
  };
  auto dampHalfStep = [&]() {
    // mu v' = -rho v over T/2 is exactly v *= exp(-2 G T / 2).
    for (Index i = 0; i < s.velocity.rows(); ++i)
      if (g[i] != 0.0) s.velocity.row(i) *= std::exp(-g[i] * t);
  };
  computeAcceleration(s.position, external, share, cacheValid_);
  dampHalfStep();
  filteredKick();
  s.position += t * s.velocity;
  computeAcceleration(s.position, external, share, false);
  filteredKick();
  dampHalfStep();
  cacheValid_ = true;
}

void Stepper::stepPaper(State& s, const Points& external, std::span<const double> share) {
  const double t = period_, t2 = t * t, t3 = t2 * t, t4 = t2 * t2, t5 = t4 * t, t6 = t4 * t2;
  computeAcceleration(s.position, external, share, false);
  const Points& a = acceleration_;
  Points& v = s.velocity;
  if (options_.storedMatrices) {
    // Equation 3 with the stored two-ring matrices.
    const TransformationMatrices& m = *transformation_;
    multiply(m.hPrime(), v, work1_);
    multiply(m.h(), a, work2_);
    multiply(m.xPrime(), v, work3_);
    multiply(m.x(), a, work4_);
    s.position += work1_ + work2_;
    v = work3_ + work4_;
    return;
  }
  // Equation 3 with the polynomials in Omega^2 applied to the state: four one-ring products
  // instead of four two-ring ones.
  const SparseRowMatrix& o2 = system_.omega2();
  multiply(o2, v, work1_);
  multiply(o2, work1_, work2_);
  multiply(o2, a, work3_);
  multiply(o2, work3_, work4_);
  const VectorX& g = system_.dampingCoefficient();
  for (Index i = 0; i < v.rows(); ++i) {
    const Eigen::RowVector3d hpv = t * v.row(i) - t3 / 6.0 * work1_.row(i) + t5 / 120.0 * work2_.row(i);
    const Eigen::RowVector3d hppv = v.row(i) - t2 / 2.0 * work1_.row(i) + t4 / 24.0 * work2_.row(i);
    const Eigen::RowVector3d ha =
        t2 / 2.0 * a.row(i) - t4 / 24.0 * work3_.row(i) + t6 / 720.0 * work4_.row(i);
    const Eigen::RowVector3d hpa = t * a.row(i) - t3 / 6.0 * work3_.row(i) + t5 / 120.0 * work4_.row(i);
    s.position.row(i) += hpv + ha;
    v.row(i) = (hppv - g[i] * hpv) + (hpa - g[i] * ha);
  }
}

void Stepper::setUpExact() {
  const Index n = model_.mesh.numVertices();
  if (n > options_.exactMaxVertices)
    throw InvalidInputError("scheme exact: the model has " + std::to_string(n) +
                            " vertices, more than the dense eigendecomposition's limit of " +
                            std::to_string(options_.exactMaxVertices));
  const VectorX& g = system_.dampingCoefficient();
  const double gamma = g.minCoeff();
  if (g.maxCoeff() - gamma > 1e-12 * std::max(1.0, std::abs(gamma)))
    throw InvalidInputError(
        "scheme exact: needs damping proportional to mass (the same rho / mu at every vertex)");
  sqrtMass_ = system_.inverseMass().cwiseInverse().cwiseSqrt();
  const VectorX scale = sqrtMass_.cwiseInverse();
  const Eigen::MatrixXd symmetric =
      scale.asDiagonal() * Eigen::MatrixXd(system_.stiffness()) * scale.asDiagonal();
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(symmetric);
  if (eig.info() != Eigen::Success) throw SolverError("scheme exact: eigendecomposition failed");
  modes_ = eig.eigenvectors();
  propagator_.resize(n, 6);
  for (Index k = 0; k < n; ++k) {
    // x'' + 2 gamma x' + w^2 x = b (b constant over the step), as a 3 x 3 exponential.
    const double w2 = std::max(0.0, eig.eigenvalues()[k]);
    Mat3 generator;
    generator << 0, 1, 0, -w2, -2 * gamma, 1, 0, 0, 0;
    const Mat3 e = (generator * period_).exp();
    propagator_.row(k) << e(0, 0), e(0, 1), e(0, 2), e(1, 0), e(1, 1), e(1, 2);
  }
  modal1_.setZero(n, 3);
  modal2_.setZero(n, 3);
  modal3_.setZero(n, 3);
}

void Stepper::stepExact(State& s, const Points& external, std::span<const double> share) {
  computeAcceleration(s.position, external, share, false);
  // What the linear model -Omega^2 r does not capture, held over the step.
  multiply(system_.omega2(), s.position, work1_);
  work1_ += acceleration_;
  work2_ = sqrtMass_.asDiagonal() * s.position;
  modal1_.noalias() = modes_.transpose() * work2_;
  work2_ = sqrtMass_.asDiagonal() * s.velocity;
  modal2_.noalias() = modes_.transpose() * work2_;
  work2_ = sqrtMass_.asDiagonal() * work1_;
  modal3_.noalias() = modes_.transpose() * work2_;
  for (Index k = 0; k < modal1_.rows(); ++k) {
    const auto p = propagator_.row(k);
    const Eigen::RowVector3d r = modal1_.row(k), v = modal2_.row(k), b = modal3_.row(k);
    modal1_.row(k) = p[0] * r + p[1] * v + p[2] * b;
    modal2_.row(k) = p[3] * r + p[4] * v + p[5] * b;
  }
  const VectorX inverseSqrtMass = sqrtMass_.cwiseInverse();
  work2_.noalias() = modes_ * modal1_;
  s.position = inverseSqrtMass.asDiagonal() * work2_;
  work2_.noalias() = modes_ * modal2_;
  s.velocity = inverseSqrtMass.asDiagonal() * work2_;
}

void Stepper::stepSymplecticEuler(State& s, const Points& external, std::span<const double> share) {
  const double t = period_;
  const VectorX& g = system_.dampingCoefficient();
  computeAcceleration(s.position, external, share, false);
  s.velocity += t * acceleration_;
  for (Index i = 0; i < s.velocity.rows(); ++i)
    if (g[i] != 0.0) s.velocity.row(i) *= std::exp(-2.0 * g[i] * t);
  s.position += t * s.velocity;
}

namespace {

// d theta / d(c, a, b) of the angle at c between arms to a and b (zero when degenerate).
bool angleGradient(const Vec3& c, const Vec3& a, const Vec3& b, Vec3& gc, Vec3& ga, Vec3& gb) {
  Vec3 fc, fa, fb;
  // angleSpringForce with kappa = 1 and rest angle theta - 1 returns -grad(theta).
  const Vec3 u = a - c, w = b - c;
  if (u.norm() == 0.0 || w.norm() == 0.0) return false;
  const double theta = std::atan2(u.cross(w).norm(), u.dot(w));
  angleSpringForce(c, a, b, 1.0, theta - 1.0, fc, fa, fb);
  gc = -fc;
  ga = -fa;
  gb = -fb;
  return true;
}

}  // namespace

void Stepper::stepImplicitEuler(State& s, const Points& external, std::span<const double> share) {
  // Baraff and Witkin 1998: (M + h D - h^2 J) dv = h (f0 - D v0 + h J v0), J the force
  // Jacobian: exact for radial springs with the compressive transverse term clamped at zero
  // (so the matrix stays positive definite), Gauss-Newton for angle springs.
  const double h = period_;
  const Index n = model_.mesh.numVertices();
  const Mesh& mesh = model_.mesh;
  const PhysicalProperties& p = model_.properties;
  Implicit& im = *implicit_;
  computeAcceleration(s.position, external, share, false);

  auto addBlock = [&](Index bi, Index bj, const Mat3& block, bool assemble) {
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) {
        if (assemble)
          im.a.coeffRef(3 * bi + r, 3 * bj + c) += block(r, c);
        else
          im.a.insert(3 * bi + r, 3 * bj + c) = 0.0;  // pattern pass (first step only)
      }
  };
  auto forEachContribution = [&](bool assemble) {
    for (Index e = 0; e < mesh.numEdges(); ++e) {
      const auto [i, j] = mesh.edge(e);
      const double kappa = edgeStiffness(p.stiffness[i], p.stiffness[j]);
      Mat3 b = Mat3::Zero();
      if (assemble && kappa != 0.0) {
        const Vec3 d = s.position.row(i) - s.position.row(j);
        const double len = d.norm();
        const Vec3 u = len > 0.0 ? Vec3(d / len) : Vec3::UnitX();
        const double transverse = len > 0.0 ? std::max(0.0, 1.0 - p.restLength[e] / len) : 0.0;
        const Mat3 uu = u * u.transpose();
        b = kappa * h * h * (transverse * (Mat3::Identity() - uu) + uu);
      }
      addBlock(i, i, b, assemble);
      addBlock(j, j, b, assemble);
      addBlock(i, j, -b, assemble);
      addBlock(j, i, -b, assemble);
    }
    for (size_t k = 0; k < model_.angles.angles.size(); ++k) {
      const auto [c, a, b] = model_.angles.angles[k];
      const double kappa = p.angularStiffness[c];
      if (kappa == 0.0) continue;
      std::array<Vec3, 3> grad{Vec3::Zero(), Vec3::Zero(), Vec3::Zero()};
      if (assemble)
        angleGradient(s.position.row(c), s.position.row(a), s.position.row(b), grad[0], grad[1],
                      grad[2]);
      const std::array<Index, 3> ids{c, a, b};
      for (int q = 0; q < 3; ++q)
        for (int r = 0; r < 3; ++r)
          addBlock(ids[q], ids[r], (kappa * h * h) * grad[q] * grad[r].transpose(), assemble);
    }
    for (Index i = 0; i < n; ++i)
      addBlock(i, i, (p.mass[i] + h * p.damping[i]) * Mat3::Identity(), assemble);
  };

  if (im.a.rows() != 3 * n) {
    // Pattern: sum duplicates through triplets once, then analyse.
    std::vector<Eigen::Triplet<double>> triplets;
    im.a.resize(3 * n, 3 * n);
    Eigen::SparseMatrix<double, Eigen::RowMajor> scratch(3 * n, 3 * n);
    (void)scratch;
    auto collect = [&](Index bi, Index bj) {
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) triplets.emplace_back(3 * bi + r, 3 * bj + c, 0.0);
    };
    for (Index e = 0; e < mesh.numEdges(); ++e) {
      const auto [i, j] = mesh.edge(e);
      collect(i, j);
      collect(j, i);
    }
    for (const auto& [c, a, b] : model_.angles.angles) {
      collect(c, a), collect(a, c), collect(c, b), collect(b, c), collect(a, b), collect(b, a);
    }
    for (Index i = 0; i < n; ++i) collect(i, i);
    im.a.setFromTriplets(triplets.begin(), triplets.end());
    im.a.makeCompressed();
    im.solver.analyzePattern(im.a);
    im.rhs.resize(3 * n);
    im.dv.resize(3 * n);
    im.flat.resize(3 * n);
  }
  im.a.coeffs().setZero();
  forEachContribution(true);
  im.solver.factorize(im.a);
  if (im.solver.info() != Eigen::Success) throw DivergenceError("implicit-euler: factorisation failed");
  // -J v0 = (A - M - h D) v0 / h^2.
  for (Index i = 0; i < n; ++i) im.flat.segment<3>(3 * i) = s.velocity.row(i).transpose();
  im.rhs.noalias() = im.a * im.flat;
  for (Index i = 0; i < n; ++i) {
    const Vec3 v = s.velocity.row(i).transpose();
    const Vec3 minusJv = (im.rhs.segment<3>(3 * i) - (p.mass[i] + h * p.damping[i]) * v) / (h * h);
    const double sh = share.empty() ? 1.0 : share[i];
    im.rhs.segment<3>(3 * i) =
        h * (sh * totalForce_.row(i).transpose() - p.damping[i] * v - h * minusJv);
  }
  im.dv = im.solver.solve(im.rhs);
  for (Index i = 0; i < n; ++i) s.velocity.row(i) += im.dv.segment<3>(3 * i).transpose();
  s.position += h * s.velocity;
}

}  // namespace zsculpt
