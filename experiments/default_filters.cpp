// Energy, drift and angular momentum of candidate filters for the default scheme, on the
// paper's small models (docs/solver.md, "Filters measured for the default scheme").
//
//   experiment_default_filters MODEL ANGULAR PERTURB RATIO FILTER [STEPS]
//
// MODEL: dodecahedron, torus or grid (Table 1's mass and stiffness); ANGULAR: angular
// stiffness; PERTURB > 0: random initial velocity of that RMS size (seed 11), < 0: a spin
// -PERTURB * (0.2, 0.3, 0.5) rad/s; RATIO: T / T_max (equation 5). FILTER:
//   kick        the default: v += T/2 phi a, phi = 1 - x/12; r += T v
//   kick2       phi = (1 - x/12)^2
//   kick-cubic  phi = 1 - x/8 + x^2/192
//   kick-low    phi = 1 - 0.182859 x + 0.0100009 x^2 - 6.29554e-5 x^3 (y = x phi <= 1.7)
//   drift       phi = 1 - x/12 and the drift r += T psi v, psi = phi / (1 + x phi^2 / 4)
//   drift-cubic psi = phi (1 - 0.181526 x + 0.0302534 x^2 - 0.00126054 x^3)
//   pkick, pdrift, pdrift-cubic  the same built on W = (I - P) Omega^2 (I - P), P the
//               M-orthogonal projector onto the rest shape's affine fields {1, X, Y, Z}
//               (what --drift-filter runs); TRACE=1 prints L and the conserved
//               sum r x M Phi^-1 v twenty times a run.
// with x = T^2 times an eigenvalue of Omega^2. Filters are applied exactly through a dense
// eigendecomposition (models of a few hundred vertices), so only the filter is measured.
// Prints energy_drift (mean of the last 10 % of steps over the first 10 %, minus 1), the
// largest |L - L0| / |L0|, the range of E / E0 and the mean |L| / |L0| of the last 10 %.
#include <Eigen/Dense>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "zsculpt/mesh/builtin.h"
#include "zsculpt/physics/diagnostics.h"
#include "zsculpt/physics/forces.h"
#include "zsculpt/physics/matrices.h"
#include "zsculpt/physics/properties.h"

using namespace zsculpt;

int main(int argc, char** argv) {
  if (argc < 6) {
    std::fprintf(stderr, "usage: %s MODEL ANGULAR PERTURB RATIO FILTER [STEPS]\n", argv[0]);
    return 2;
  }
  const std::string name = argv[1], filter = argv[5];
  const double angular = std::atof(argv[2]), perturb = std::atof(argv[3]),
               ratio = std::atof(argv[4]);
  const long steps = argc > 6 ? std::atol(argv[6]) : 100000;
  UniformProperties u;
  u.mass = name == "torus" ? 0.1 : name == "grid" ? 0.31 : 0.5;
  u.stiffness = name == "grid" ? 5.16 : 5.0;
  u.angularStiffness = angular;
  const Model model = Model::fromMesh(makeBuiltin("builtin:" + name), u);
  const SystemMatrices system(model);
  const double t = ratio * criticalPeriod(system);
  const Index n = model.mesh.numVertices();
  // Omega^2 = M^-1/2 S M^1/2 with S = M^-1/2 K M^-1/2 = U diag(lambda) U^T.
  const Eigen::VectorXd sqrtMass = system.inverseMass().cwiseInverse().cwiseSqrt();
  const Eigen::VectorXd inverseSqrtMass = sqrtMass.cwiseInverse();
  const Eigen::MatrixXd s = inverseSqrtMass.asDiagonal() * Eigen::MatrixXd(system.stiffness()) *
                            inverseSqrtMass.asDiagonal();
  // Filters prefixed "p" use the stiffness compressed to the complement of the affine
  // fields of the rest shape, (I - Q) S (I - Q) with Q the orthogonal projector onto
  // M^1/2 span{1, X, Y, Z}: it vanishes on translations and rotations of the rest shape.
  const bool projected = filter[0] == 'p';
  const std::string base = projected ? filter.substr(1) : filter;
  Eigen::MatrixXd compressed = s;
  if (projected) {
    Eigen::MatrixXd affine(n, 4);
    affine.col(0).setOnes();
    affine.rightCols(3) = model.mesh.positions();
    affine = sqrtMass.asDiagonal() * affine;
    const Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(affine);
    const Eigen::MatrixXd basis = Eigen::MatrixXd(qr.householderQ()).leftCols(qr.rank());
    const Eigen::MatrixXd complement = Eigen::MatrixXd::Identity(n, n) - basis * basis.transpose();
    compressed = complement * s * complement;
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(compressed);
  Eigen::VectorXd kick(n), drift(n);
  bool drifts = false;
  for (Index k = 0; k < n; ++k) {
    const double x = std::max(0.0, eig.eigenvalues()[k]) * t * t, p = 1.0 - x / 12.0;
    drift[k] = 1.0;
    const std::string& filter = base;
    if (filter == "kick")
      kick[k] = p;
    else if (filter == "kick2")
      kick[k] = p * p;
    else if (filter == "kick-cubic")
      kick[k] = 1.0 - x / 8.0 + x * x / 192.0;
    else if (filter == "kick-low")
      kick[k] = 1.0 - 0.182859 * x + 0.0100009 * x * x - 6.29554e-5 * x * x * x;
    else if (filter == "drift")
      kick[k] = p, drift[k] = p / (1.0 + x * p * p / 4.0), drifts = true;
    else if (filter == "drift-cubic")
      kick[k] = p, drift[k] = p * (1.0 - 0.181526 * x + 0.0302534 * x * x - 0.00126054 * x * x * x),
      drifts = true;
    else {
      std::fprintf(stderr, "experiment: %s: unknown filter\n", filter.c_str());
      return 2;
    }
  }
  auto apply = [&](const Eigen::VectorXd& f, const Points& in) {
    const Eigen::MatrixXd modal = eig.eigenvectors().transpose() * (sqrtMass.asDiagonal() * in);
    return Points(inverseSqrtMass.asDiagonal() * (eig.eigenvectors() * (f.asDiagonal() * modal)));
  };
  auto acceleration = [&](const Points& r) {
    Points f = Points::Zero(n, 3);
    accumulateInternalForces(model, r, f);
    return Points(system.inverseMass().asDiagonal() * f);
  };
  State state = State::atRest(model.mesh);
  if (perturb > 0)
    randomVelocity(model.properties.mass, perturb, 11, state.velocity);
  else
    spinVelocity(model.properties.mass, state.position, Vec3(0.2, 0.3, 0.5) * -perturb,
                 state.velocity);
  const Diagnostics d0 = measure(model, state);
  const long window = steps / 10;
  double first = 0, last = 0, worstL = 0, low = 1, high = 1;
  long firstCount = 0, lastCount = 0;
  Vec3 lastL = Vec3::Zero();
  Points a = acceleration(state.position);
  for (long k = 0; k < steps; ++k) {
    state.velocity += (t / 2) * apply(kick, a);
    state.position += t * (drifts ? apply(drift, state.velocity) : state.velocity);
    a = acceleration(state.position);
    state.velocity += (t / 2) * apply(kick, a);
    if (std::getenv("TRACE") && k % (steps / 20) == 0) {
      Eigen::VectorXd inverseKick = kick.cwiseInverse();
      const Points p =
          system.inverseMass().cwiseInverse().asDiagonal() * apply(inverseKick, state.velocity);
      Vec3 j = Vec3::Zero();
      for (Index i = 0; i < n; ++i) j += Vec3(state.position.row(i)).cross(Vec3(p.row(i)));
      const Diagnostics d = measure(model, state);
      std::printf("step %ld E/E0 %.4f L %.6f %.6f %.6f J~ %.9f %.9f %.9f\n", k,
                  d.total() / d0.total(), d.angularMomentum[0], d.angularMomentum[1],
                  d.angularMomentum[2], j[0], j[1], j[2]);
    }
    if (k % 10 != 0) continue;
    const Diagnostics d = measure(model, state);
    if (!std::isfinite(d.total()) || d.total() > 1e6 * d0.total()) {
      std::printf("diverged at step %ld\n", k);
      return 3;
    }
    low = std::min(low, d.total() / d0.total());
    high = std::max(high, d.total() / d0.total());
    if (k < window) first += d.total(), ++firstCount;
    if (k >= steps - window) last += d.total(), lastL += d.angularMomentum, ++lastCount;
    worstL = std::max(worstL,
                      (d.angularMomentum - d0.angularMomentum).norm() / d0.angularMomentum.norm());
  }
  std::printf(
      "%s angular %g perturb %g T/T_max %g %s: energy_drift %+.4f %% |L-L0|/|L0| max %.4f "
      "E/E0 in [%.3f, %.3f] mean |L|/|L0| of the last tenth %.4f\n",
      name.c_str(), angular, perturb, ratio, filter.c_str(),
      100 *
          ((last / static_cast<double>(lastCount)) / (first / static_cast<double>(firstCount)) - 1),
      worstL, low, high,
      (lastL / static_cast<double>(lastCount)).norm() / d0.angularMomentum.norm());
  return 0;
}
