#include "zsculpt/physics/forces.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <numbers>

#include "zsculpt/core/parts.h"

#ifdef _OPENMP
#include <omp.h>
#endif

namespace zsculpt {

namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kHalfPi = std::numbers::pi / 2;
constexpr double kQuarterPi = std::numbers::pi / 4;
// pi/2 - kHalfPi: the low bits of pi/2 (Cephes' MOREBITS).
constexpr double kMoreBits = 6.123233995736765886130e-17;

// The angles here come from a branch-free atan2 (below) so that a batch of them vectorises
// (glibc's atan2 is a call the compiler cannot); it is accurate near 0 and pi, like atan2.
// cond ? a : b on the bits, with both operands computed: with trapping math the compiler
// neither speculates a floating-point operation out of a branch nor may it sink one into a
// branch here, so the loops below have no control flow and vectorise.
inline double select(bool cond, double a, double b) {
  const std::uint64_t mask = std::uint64_t{0} - static_cast<std::uint64_t>(cond);
  return std::bit_cast<double>((std::bit_cast<std::uint64_t>(a) & mask) |
                               (std::bit_cast<std::uint64_t>(b) & ~mask));
}

// The kernels below are built three times: for AVX-512 (8 doubles at a time) and AVX2 (4),
// each chosen at load time where the processor has it, and for the x86-64 baseline. None
// contracts to FMA (forces.cpp is built with -ffp-contract=off, as AVX-512F has FMA), and all
// do the same operations in the same order, so they round alike: the forces do not depend
// on the machine's choice. forces.cpp is built without errno for the math functions
// (CMakeLists.txt), so std::sqrt in a loop vectorises; other paths take theirs in a pass of
// Eigen's packet sqrt (the same correctly rounded result).
// Sanitized builds (CMakeLists.txt) define ZSCULPT_NO_TARGET_CLONES: no ifunc resolvers.
#ifdef ZSCULPT_NO_TARGET_CLONES
#define ZSCULPT_KERNEL
#else
#define ZSCULPT_KERNEL __attribute__((target_clones("avx512f", "avx2", "default")))
#endif

// atan2(s, c) for s >= 0 (the angle between two arms from |u x w| and u . w) in parts, so
// that angleBeta can share its one division with 1 / sin: the argument reduced to
// |num / den| <= tan(pi/8) (num / den = min / max of |s|, |c|, or (min - max) / (min + max)
// beyond tan(pi/8)), Cephes' rational atan (S. Moshier, relative error 2e-16 on |x| <= 0.66)
// written homogeneously in (num, den): atan(num / den) = num (qt + n2 pt) / (den qt), pt and
// qt the homogeneous forms of Cephes' P(z) and Q(z) at z = n2 / d2. den^10 must neither
// under- nor overflow: callers pass max(|s|, |c|) near 1.
inline void atanParts(double s, double c, bool& sinLarger, bool& reduce, double& num, double& den,
                      double& n2, double& pt, double& qt) {
  constexpr double p0 = -8.750608600031904122785e-1, p1 = -1.615753718733365076637e1,
                   p2 = -7.500855792314704667340e1, p3 = -1.228866684490136173410e2,
                   p4 = -6.485021904942025371773e1;
  constexpr double q0 = 2.485846490142306297962e1, q1 = 1.650270098316988542046e2,
                   q2 = 4.328810604912902668951e2, q3 = 4.853903996359136964868e2,
                   q4 = 1.945506571482613964425e2;
  const double ac = std::abs(c);
  sinLarger = s > ac;
  const double mx = select(sinLarger, s, ac);
  const double mn = select(sinLarger, ac, s);
  reduce = mn > 0.41421356237309504880 * mx;
  num = select(reduce, mn - mx, mn);
  den = select(reduce, mn + mx, mx);
  n2 = num * num;
  const double d2 = den * den, d4 = d2 * d2, d6 = d4 * d2, d8 = d4 * d4;
  pt = (((p0 * n2 + p1 * d2) * n2 + p2 * d4) * n2 + p3 * d6) * n2 + p4 * d8;
  qt = ((((n2 + q0 * d2) * n2 + q1 * d4) * n2 + q2 * d6) * n2 + q3 * d8) * n2 + q4 * d8 * d2;
}

// The angle in [0, pi] from t0 = atan(num / den) and atanParts' choices.
inline double angleFromAtan(double t0, bool reduce, bool sinLarger, double c) {
  const double t1 = select(reduce, kQuarterPi + (t0 + 0.5 * kMoreBits), t0);
  const double t2 = select(sinLarger, (kHalfPi - t1) + kMoreBits, t1);
  return select(c < 0.0, (kPi - t2) + 2.0 * kMoreBits, t2);
}

// atan2(s, c) for s >= 0, scaled first so that max(s, |c|) is 1 (atanParts' condition for
// arms of any length); 0 when both are 0, as atan2(0, 0).
inline double angleFromSinCos(double s, double c) {
  const double scale = std::max(s, std::abs(c));
  const bool some = scale > 0.0;
  const double safe = select(some, scale, 1.0);
  const double sn = s / safe, cn = c / safe;
  bool sinLarger, reduce;
  double num, den, n2, pt, qt;
  atanParts(sn, cn, sinLarger, reduce, num, den, n2, pt, qt);
  const double t0 = num * (qt + n2 * pt) / select(some, den * qt, 1.0);
  return angleFromAtan(t0, reduce, sinLarger, cn);
}

// radialSpringEnergy: kappa/2 (d - lambda)^2, continued below d = lambda/2 by
// kappa lambda^2/4 - kappa d^2/2 (both computed, one selected, so that a batch vectorises).
inline double radialEnergy(double length, double kappa, double restLength) {
  const double stretch = length - restLength;
  const double stretched = 0.5 * kappa * stretch * stretch;
  const double crushed = 0.25 * kappa * restLength * restLength - 0.5 * kappa * length * length;
  return select(length >= 0.5 * restLength, stretched, crushed);
}

// |u x w|^2 and u . w of two arms, as angleAt and potentialEnergy take them (one expression,
// and a correctly rounded square root after it, so that a rest angle and the energy's angle
// at the rest shape are the same bits).
inline void armsSinCos(double ux, double uy, double uz, double wx, double wy, double wz,
                       double& sineSquared, double& c) {
  const double cx = uy * wz - uz * wy, cy = uz * wx - ux * wz, cz = ux * wy - uy * wx;
  sineSquared = cx * cx + cy * cy + cz * cz;
  c = ux * wx + uy * wy + uz * wz;
}

// angleSpringProfile, branch-free (it vectorises in the kernels): the cap at straight
// (p = pi - theta below eps = min(D / 2, kAngleCapWidth), D = pi - theta_0) or at folded
// (p = theta, D = theta_0), else the plain spring. In a cap E / kappa = a + b p^2 + c p^4,
// the even quartic that meets (p - D)^2 / 2 at p = eps with its value, slope and
// curvature (C2, so that the schemes' error expansions hold through it): c = D / (8 eps^3),
// b = (eps - 3 D / 2) / (2 eps), a = (eps - D)^2 / 2 - b eps^2 - c eps^4. Its curvature
// runs from 2b (>= -2 at eps = D / 2) to 1: the cap is no stiffer than the spring.
inline void angleProfile(double theta, double rest, double& slope, double& twiceEnergy,
                         bool& inCap) {
  const double psi = kPi - theta, toStraight = kPi - rest;
  const double epsStraight = std::min(0.5 * toStraight, kAngleCapWidth);
  const double epsFolded = std::min(0.5 * rest, kAngleCapWidth);
  const bool straight = psi < epsStraight;
  const bool folded = theta < epsFolded;
  const bool capped = straight || folded;
  const double p = select(straight, psi, theta);
  const double eps = select(capped, select(straight, epsStraight, epsFolded), 1.0);
  const double d = select(straight, toStraight, rest);
  const double inv = 1.0 / eps;  // the one division
  const double c = 0.125 * d * inv * inv * inv;
  const double b = 0.5 * (eps - 1.5 * d) * inv;
  const double eps2 = eps * eps;
  const double a = 0.5 * (eps - d) * (eps - d) - b * eps2 - c * eps2 * eps2;
  const double p2 = p * p;
  const double capSlope = p * (2.0 * b + 4.0 * c * p2);  // dE/dp / kappa
  const double capTwice = 2.0 * (a + p2 * (b + c * p2));
  const double excess = theta - rest;
  // d/dtheta = -d/dp at straight, +d/dp at folded.
  slope = select(straight, -capSlope, select(folded, capSlope, excess));
  twiceEnergy = select(capped, capTwice, excess * excess);
  inCap = capped;
}

inline void angleProfile(double theta, double rest, double& slope, double& twiceEnergy) {
  bool inCap;
  angleProfile(theta, rest, slope, twiceEnergy, inCap);
}

// theta = atan2(sin, cos) in [0, pi] and the factor 1 / sin that angleBeta multiplies the
// slope by (1 when the sine is 1e-12 or less, regular false: the caller zeroes the slope). atan x
// and 1 / sin with it cost one division (atanParts). The arms are unit vectors, so max(|sin|,
// |cos|) >= 1/sqrt(2) and nothing under- or overflows.
inline double angleAndInverseSine(double s, double c, double& inverseSine, bool& regular) {
  bool sinLarger, reduce;
  double num, den, n2, pt, qt;
  atanParts(s, c, sinLarger, reduce, num, den, n2, pt, qt);
  regular = s > 1e-12;
  const double safeSine = select(regular, s, 1.0);
  const double denominator = select(regular, den * qt, 1.0);
  const double inv = 1.0 / (denominator * safeSine);
  const double t0 = num * (qt + n2 * pt) * safeSine * inv;
  inverseSine = denominator * inv;
  return angleFromAtan(t0, reduce, sinLarger, c);
}

// beta = slope / sin(theta), slope angleProfile's (theta - theta_0 away from its caps), and
// twiceEnergy (the spring's energy is kappa_theta/2 twiceEnergy); both zero when the sine is
// 1e-12 or less (those angles are the caller's: angleSpringForce handles them); capped where
// the profile took a cap. The profile costs one more division.
inline double angleBeta(double s, double c, double rest, double& twiceEnergy, bool& capped) {
  double inverseSine;
  bool regular, inCap;
  const double theta = angleAndInverseSine(s, c, inverseSine, regular);
  double slope, e2;
  angleProfile(theta, rest, slope, e2, inCap);
  twiceEnergy = select(regular, e2, 0.0);
  capped = regular & inCap;
  return select(regular, slope, 0.0) * inverseSine;
}

inline double angleBeta(double s, double c, double rest, double& twiceEnergy) {
  bool capped;
  return angleBeta(s, c, rest, twiceEnergy, capped);
}

// angleBeta for an angle outside its caps, where the profile is theta - theta_0: the same
// bits as angleBeta's there. capped is set where angleBeta's would be (the profile's tests,
// expression for expression), and there beta and twiceEnergy are not angleBeta's: the caller
// takes those angles again with angleBeta (runAngleRows).
inline double angleBetaUncapped(double s, double c, double rest, double& twiceEnergy,
                                bool& capped) {
  double inverseSine;
  bool regular;
  const double theta = angleAndInverseSine(s, c, inverseSine, regular);
  const bool straight = kPi - theta < std::min(0.5 * (kPi - rest), kAngleCapWidth);
  const bool folded = theta < std::min(0.5 * rest, kAngleCapWidth);
  capped = regular & (straight | folded);
  const double excess = theta - rest;
  twiceEnergy = select(regular, excess * excess, 0.0);
  return select(regular, excess, 0.0) * inverseSine;
}

// potentialEnergy's and gravityEnergy's sums are taken in this many fixed contiguous parts,
// added in part order: the same bits whatever the thread count.
constexpr int kParts = 64;

// potentialEnergy's terms in batches, vectorised (square roots, atan2s), gathered by the
// caller, which adds them in order so that every machine sums alike.
// Angle springs, kappa_theta/2 (theta - theta_0)^2, from |u x w|^2 and u . w (armsSinCos).
ZSCULPT_KERNEL void angleEnergies(Index m, const double* __restrict sineSquared,
                                  const double* __restrict cosine, const double* __restrict kappa,
                                  const double* __restrict rest, double* __restrict energy) {
#pragma omp simd
  for (Index k = 0; k < m; ++k) {
    double slope, twiceEnergy;
    angleProfile(angleFromSinCos(std::sqrt(sineSquared[k]), cosine[k]), rest[k], slope,
                 twiceEnergy);
    energy[k] = 0.5 * kappa[k] * twiceEnergy;
  }
}

// Radial springs from their squared lengths.
ZSCULPT_KERNEL void radialEnergies(Index m, const double* __restrict lengthSquared,
                                   const double* __restrict kappa, const double* __restrict rest,
                                   double* __restrict energy) {
#pragma omp simd
  for (Index k = 0; k < m; ++k)
    energy[k] = radialEnergy(std::sqrt(lengthSquared[k]), kappa[k], rest[k]);
}

}  // namespace

double angleAt(const Vec3& centre, const Vec3& a, const Vec3& b) {
  double s2, c;
  armsSinCos(a.x() - centre.x(), a.y() - centre.y(), a.z() - centre.z(), b.x() - centre.x(),
             b.y() - centre.y(), b.z() - centre.z(), s2, c);
  return angleFromSinCos(std::sqrt(s2), c);
}

double radialSpringForce(const Vec3& ri, const Vec3& rj, double kappa, double restLength,
                         Vec3& forceOnI) {
  const Vec3 d = ri - rj;
  const double length = d.norm();
  if (restLength == 0.0) {
    forceOnI = -kappa * d;
    return 0.5 * kappa * length * length;
  }
  const double stretch = length - restLength;
  if (!(length > 0.0)) {
    forceOnI = Vec3::Zero();
    return radialSpringEnergy(length, kappa, restLength);
  }
  // Equation 1's force per unit of the arm, kappa (l - lambda) / l, is the spring's
  // transverse stiffness; it falls without bound as the edge collapses (l -> 0), far below
  // the -kappa that equation 5's period allows for, so an edge crushed by a storm of loads
  // makes any fixed step blow up (and at l = 0 the direction is undefined). Below half
  // the rest length the spring is continued by E = kappa lambda^2 / 4 - kappa l^2 / 2:
  // the same energy, force and slope at l = lambda / 2, a force kappa (r_i - r_j) that
  // still pushes the ends apart and vanishes smoothly at l = 0, and stiffnesses bounded by
  // kappa. Above lambda / 2 it is equation 1 exactly.
  const double coefficient = std::max(kappa * stretch / length, -kappa);
  forceOnI = -coefficient * d;
  return radialSpringEnergy(length, kappa, restLength);
}

double radialSpringEnergy(double length, double kappa, double restLength) {
  return radialEnergy(length, kappa, restLength);
}

namespace {

// A unit vector perpendicular to v (deterministic).
Vec3 anyPerpendicular(const Vec3& v) {
  Eigen::Index axis = 0;
  v.cwiseAbs().minCoeff(&axis);
  return v.cross(Vec3::Unit(axis)).normalized();
}

}  // namespace

double angleSpringForce(const Vec3& centre, const Vec3& a, const Vec3& b, double kappa,
                        double restAngle, Vec3& forceOnCentre, Vec3& forceOnA, Vec3& forceOnB) {
  Vec3 gc, ga, gb;
  if (kappa == 0.0 || !angleGradient(centre, a, b, gc, ga, gb)) {
    forceOnCentre.setZero();
    forceOnA.setZero();
    forceOnB.setZero();
    return 0.0;
  }
  const Vec3 u = a - centre, w = b - centre;
  const double theta = std::atan2(u.cross(w).norm(), u.dot(w));
  double slope, twiceEnergy;
  angleProfile(theta, restAngle, slope, twiceEnergy);
  forceOnA = (-kappa * slope) * ga;
  forceOnB = (-kappa * slope) * gb;
  forceOnCentre = -(forceOnA + forceOnB);
  return 0.5 * kappa * twiceEnergy;
}

void angleSpringProfile(double theta, double restAngle, double& slope, double& twiceEnergy) {
  angleProfile(theta, restAngle, slope, twiceEnergy);
}

double angleSpringEnergy(double theta, double restAngle, double kappa) {
  double slope, twiceEnergy;
  angleProfile(theta, restAngle, slope, twiceEnergy);
  return 0.5 * kappa * twiceEnergy;
}

bool angleGradient(const Vec3& centre, const Vec3& a, const Vec3& b, Vec3& gradCentre, Vec3& gradA,
                   Vec3& gradB) {
  const Vec3 u = a - centre;
  const Vec3 w = b - centre;
  const double lu = u.norm(), lw = w.norm();
  if (lu == 0.0 || lw == 0.0) {
    gradCentre.setZero();
    gradA.setZero();
    gradB.setZero();
    return false;
  }
  const Vec3 uh = u / lu, wh = w / lw;
  const double sinTheta = uh.cross(wh).norm();
  const double cosTheta = uh.dot(wh);
  // e_a: in the plane of the angle, perpendicular to u, towards w (d theta / d a = -e_a/|u|).
  Vec3 ea, eb;
  if (sinTheta > 1e-12) {
    ea = (wh - cosTheta * uh) / sinTheta;
    eb = (uh - cosTheta * wh) / sinTheta;
  } else {
    ea = anyPerpendicular(uh);
    eb = cosTheta > 0.0 ? Vec3(-ea) : ea;  // theta ~ 0: arms together; theta ~ pi: opposite
  }
  gradA = -ea / lu;
  gradB = -eb / lw;
  gradCentre = -(gradA + gradB);
  return true;
}

Vec3 torqueToForces(const Vec3& centre, std::span<const Vec3> neighbours, const Vec3& torque,
                    std::span<Vec3> forceOnNeighbours, Vec3& forceOnCentre) {
  // sum_k d_k x (lambda x d_k) = A lambda with A = sum_k (|d_k|^2 I - d_k d_k^T).
  Mat3 a = Mat3::Zero();
  for (const Vec3& n : neighbours) {
    const Vec3 d = n - centre;
    a += d.squaredNorm() * Mat3::Identity() - d * d.transpose();
  }
  // Pseudo-inverse: directions the arms cannot turn about (eigenvalue ~ 0) get nothing.
  Eigen::SelfAdjointEigenSolver<Mat3> eig(a);
  const double largest = eig.eigenvalues().cwiseAbs().maxCoeff();
  Vec3 lambda = Vec3::Zero();
  for (int k = 0; k < 3; ++k) {
    const double e = eig.eigenvalues()[k];
    if (e > 1e-12 * largest) {
      const Vec3 axis = eig.eigenvectors().col(k);
      lambda += (axis.dot(torque) / e) * axis;
    }
  }
  forceOnCentre.setZero();
  Vec3 applied = Vec3::Zero();
  for (size_t k = 0; k < neighbours.size(); ++k) {
    const Vec3 d = neighbours[k] - centre;
    forceOnNeighbours[k] = lambda.cross(d);
    forceOnCentre -= forceOnNeighbours[k];
    applied += d.cross(forceOnNeighbours[k]);
  }
  return applied;
}

PotentialEnergy accumulateInternalForces(const Model& model, const Points& position,
                                         Points& force) {
  PotentialEnergy energy;
  const Mesh& mesh = model.mesh;
  const PhysicalProperties& p = model.properties;
  for (Index e = 0; e < mesh.numEdges(); ++e) {
    const auto [i, j] = mesh.edge(e);
    const double kappa = edgeStiffness(p.stiffness[i], p.stiffness[j]);
    if (kappa == 0.0) continue;
    Vec3 fi;
    energy.radial +=
        radialSpringForce(position.row(i), position.row(j), kappa, p.restLength[e], fi);
    force.row(i) += fi.transpose();
    force.row(j) -= fi.transpose();
  }
  const auto& angles = model.angles.angles;
  for (size_t k = 0; k < angles.size(); ++k) {
    const auto [c, a, b] = angles[k];
    const double kappa = p.angularStiffness[c];
    if (kappa == 0.0) continue;
    Vec3 fc, fa, fb;
    energy.angular += angleSpringForce(position.row(c), position.row(a), position.row(b), kappa,
                                       p.restAngle[static_cast<Index>(k)], fc, fa, fb);
    force.row(c) += fc.transpose();
    force.row(a) += fa.transpose();
    force.row(b) += fb.transpose();
  }
  return energy;
}

double accumulateGravity(const PhysicalProperties& properties, const Points& position,
                         Points& force) {
  if (properties.gravity.isZero()) return 0.0;
  double energy = 0.0;
  const Eigen::RowVector3d g = properties.gravity.transpose();
  for (Index i = 0; i < position.rows(); ++i) {
    force.row(i) += properties.mass[i] * g;
    energy -= properties.mass[i] * g.dot(position.row(i));
  }
  return energy;
}

PotentialEnergy potentialEnergy(const Model& model, const Points& position) {
  // Every cycle's diagnostics call this, and on large models a serial pass (a libm atan2 per
  // angle spring) cost more than the step itself (docs/performance.md). So each sum is taken
  // in kParts fixed contiguous parts, the parts on all threads, then added in part order
  // (the same bits whatever the thread count), and within a part in batches whose square
  // roots and atan2s vectorise.
  const Mesh& mesh = model.mesh;
  const PhysicalProperties& p = model.properties;
  const auto& angles = model.angles.angles;
  const std::int64_t edges = mesh.numEdges(), springs = static_cast<std::int64_t>(angles.size());
  std::array<double, kParts> radial{}, angular{};
  auto begin = [](std::int64_t count, int part) { return partBegin(count, part, kParts); };
  int threads = 1;
#ifdef _OPENMP
  if (edges + springs > 50000 && omp_in_parallel() == 0) threads = omp_get_max_threads();
#endif
  parallelRegion(threads, [&] {
#pragma omp for schedule(static)
    for (int part = 0; part < kParts; ++part) {
      // In batches: ends gathered, then the square roots, atan2s and energies vectorised
      // (radialEnergies, angleEnergies), then added in order, term by term.
      constexpr Index kBatch = 64;
      double squared[kBatch], cosine[kBatch], kappa[kBatch], term[kBatch];
      const double* r = position.data();
      double sum = 0.0;
      for (Index e0 = begin(edges, part); e0 < begin(edges, part + 1); e0 += kBatch) {
        const Index m = std::min(kBatch, begin(edges, part + 1) - e0);
        for (Index k = 0; k < m; ++k) {
          const auto [i, j] = mesh.edge(e0 + k);
          // Eigen's expression, as the rest lengths are made (Vec3::norm is its square root).
          squared[k] = (position.row(i) - position.row(j)).squaredNorm();
          kappa[k] = edgeStiffness(p.stiffness[i], p.stiffness[j]);
        }
        radialEnergies(m, squared, kappa, p.restLength.data() + e0, term);
        for (Index k = 0; k < m; ++k) sum += term[k];
      }
      radial[static_cast<size_t>(part)] = sum;
      sum = 0.0;
      for (Index k0 = begin(springs, part); k0 < begin(springs, part + 1); k0 += kBatch) {
        const Index m = std::min(kBatch, begin(springs, part + 1) - k0);
        for (Index j = 0; j < m; ++j) {
          const auto [c, a, b] = angles[static_cast<size_t>(k0 + j)];
          const double *rc = r + 3 * static_cast<size_t>(c), *ra = r + 3 * static_cast<size_t>(a),
                       *rb = r + 3 * static_cast<size_t>(b);
          armsSinCos(ra[0] - rc[0], ra[1] - rc[1], ra[2] - rc[2], rb[0] - rc[0], rb[1] - rc[1],
                     rb[2] - rc[2], squared[j], cosine[j]);
          kappa[j] = p.angularStiffness[c];
        }
        angleEnergies(m, squared, cosine, kappa, p.restAngle.data() + k0, term);
        for (Index j = 0; j < m; ++j) sum += term[j];
      }
      angular[static_cast<size_t>(part)] = sum;
    }
  });
  PotentialEnergy energy;
  for (int part = 0; part < kParts; ++part) {
    energy.radial += radial[static_cast<size_t>(part)];
    energy.angular += angular[static_cast<size_t>(part)];
  }
  energy.gravity = gravityEnergy(p, position);
  return energy;
}

double gravityEnergy(const PhysicalProperties& properties, const Points& position) {
  // Zero gravity gives +0 term by term (0 - (+-0) is +0): skip the pass.
  if (properties.gravity.isZero(0.0)) return 0.0;
  const std::int64_t vertices = position.rows();
  std::array<double, kParts> part{};
  int threads = 1;
#ifdef _OPENMP
  if (vertices > 50000 && omp_in_parallel() == 0) threads = omp_get_max_threads();
#endif
  parallelRegion(threads, [&] {
#pragma omp for schedule(static)
    for (int k = 0; k < kParts; ++k) {
      double sum = 0.0;
      for (Index i = partBegin(vertices, k, kParts); i < partBegin(vertices, k + 1, kParts); ++i)
        sum -= properties.mass[i] * properties.gravity.dot(position.row(i).transpose());
      part[static_cast<size_t>(k)] = sum;
    }
  });
  double energy = 0.0;
  for (double term : part) energy += term;
  return energy;
}

// ---- ForceKernel ------------------------------------------------------------------------------

namespace {

int threadNumber() {
#ifdef _OPENMP
  return omp_get_thread_num();
#else
  return 0;
#endif
}

int availableThreads() {
#ifdef _OPENMP
  return std::max(omp_get_max_threads(), omp_get_num_procs());
#else
  return 1;
#endif
}

bool inParallel() {
#ifdef _OPENMP
  return omp_in_parallel() != 0;
#else
  return false;
#endif
}

// Vertices per block: big enough that the halo (vertices of other blocks reached by an
// angle spring) stays a small fraction on meshes stored in a local order, small enough to
// balance two threads. Depends on nothing but the vertex count (determinism).
constexpr Index kBlockVertices = 8192;
// Shortest run of equal-degree vertices worth the transposed angle path.
constexpr Index kMinRun = 8;
// Vertices per edge group of a block without angle springs: its edges' arms and forces
// (seven arrays of about twice as many doubles) stay in the core's L2 cache.
constexpr Index kGroupVertices = 1024;

// Equation 1's force on v per unit arm (r_w - r_v) of a spring of length l: kappa (l - lambda)
// / l, continued below half the rest length (radialSpringForce says why); kappa for a zero
// rest length; 0 without stiffness or for an arm of zero length. Branch-free, so that a
// batch vectorises.
[[gnu::always_inline]] inline double radialCoefficient(double l, double kappa, double rest) {
  const bool positive = l > 0.0;
  const double safe = select(positive, l, 1.0);
  const double stretched = select(positive, std::max(kappa * (l - rest) / safe, -kappa), 0.0);
  return select(kappa == 0.0, 0.0, select(rest == 0.0, kappa, stretched));
}

// 1 / l, or 0 for an arm of zero length.
[[gnu::always_inline]] inline double inverseLength(double l) {
  const bool positive = l > 0.0;
  return select(positive, 1.0 / select(positive, l, 1.0), 0.0);
}

// A block's energy sums: value j of a batch goes to running sum j mod 8, eight independent
// chains (a vectorised loop) where one sum would wait on every addition before it; laneTotal
// adds the eight in a fixed order. The same bits on any thread count.
constexpr int kLanes = 8;
[[gnu::always_inline]] inline void addToLanes(double* __restrict lanes,
                                              const double* __restrict values, Index count) {
  Index j = 0;
  for (; j + kLanes <= count; j += kLanes)
#pragma omp simd
    for (int q = 0; q < kLanes; ++q) lanes[q] += values[j + q];
  for (int q = 0; j < count; ++j, ++q) lanes[q] += values[j];
}
inline double laneTotal(const double* lanes) {
  return ((lanes[0] + lanes[1]) + (lanes[2] + lanes[3])) +
         ((lanes[4] + lanes[5]) + (lanes[6] + lanes[7]));
}

// One arm j's radial spring (r_w - r_v = u, of length l), as radialRows and
// slotArmsRadialRows write it: the force on v to gx.., the unit arm to ax.., 1 / l to il,
// and with kEnergy the spring's energy to energy[j].
template <bool kEnergy>
[[gnu::always_inline]] inline void radialArm(Index j, double ux, double uy, double uz, double l,
                                             double kappa, double rest, double* __restrict ax,
                                             double* __restrict ay, double* __restrict az,
                                             double* __restrict il, double* __restrict gx,
                                             double* __restrict gy, double* __restrict gz,
                                             double* __restrict energy) {
  const double coefficient = radialCoefficient(l, kappa, rest);
  const double inv = inverseLength(l);
  if constexpr (kEnergy) energy[j] = radialEnergy(l, kappa, rest);
  gx[j] = coefficient * ux;
  gy[j] = coefficient * uy;
  gz[j] = coefficient * uz;
  ax[j] = ux * inv;
  ay[j] = uy * inv;
  az[j] = uz * inv;
  il[j] = inv;
}

// Radial springs and arms of one chunk, per half-edge j (from v to w, edge e), after
// squaredLength[j] = |r_w - r_v|^2 was turned into the length: the force on v,
// kappa (l - lambda) / l (r_w - r_v), which is radialSpringForce's force on v rounding for
// rounding (the reference computes -kappa (l - lambda) / l (r_v - r_w), and IEEE rounding is
// symmetric in the sign); kappa (r_w - r_v) for a zero rest length (equation 1). The arm
// (r_w - r_v) in ax, ay, az becomes its unit vector. With kEnergy the spring's energy goes
// to energy[j]. (Inlined into the kernel below, and so built for its instruction sets, as
// are the other *Rows templates.)
template <bool kEnergy>
[[gnu::always_inline]] inline void radialRows(
    Index count, const Index* __restrict edge, const double* __restrict edgeKappa,
    const double* __restrict restLength, double* __restrict ax, double* __restrict ay,
    double* __restrict az, const double* __restrict length, double* __restrict il,
    double* __restrict gx, double* __restrict gy, double* __restrict gz,
    double* __restrict energy) {
#pragma omp simd
  for (Index j = 0; j < count; ++j) {
    radialArm<kEnergy>(j, ax[j], ay[j], az[j], length[j], edgeKappa[edge[j]], restLength[edge[j]],
                       ax, ay, az, il, gx, gy, gz, energy);
  }
}

// radialRows, with the energies when energy is not null.
ZSCULPT_KERNEL void radialBatch(Index count, const Index* __restrict edge,
                                const double* __restrict edgeKappa,
                                const double* __restrict restLength, double* __restrict ax,
                                double* __restrict ay, double* __restrict az,
                                const double* __restrict length, double* __restrict il,
                                double* __restrict gx, double* __restrict gy, double* __restrict gz,
                                double* __restrict energy) {
  if (energy)
    radialRows<true>(count, edge, edgeKappa, restLength, ax, ay, az, length, il, gx, gy, gz,
                     energy);
  else
    radialRows<false>(count, edge, edgeKappa, restLength, ax, ay, az, length, il, gx, gy, gz,
                      energy);
}

// The angle springs, kappa_theta left out (section 5.2): the forces on the ends of unit arms
// u (inverse length iu) and w (iw) are beta iu (w - cos u) and beta iw (u - cos w), the
// gradient form of angleSpringForce. (A macro: structs or arrays in the loop body keep GCC
// from vectorising it.)
#define ZSCULPT_ANGLE_FORCE(beta, c, ux, uy, uz, iu, wx, wy, wz, iw, FA0, FA1, FA2, FB0, FB1, FB2) \
  do {                                                                                             \
    const double sa_ = (beta) * (iu), sb_ = (beta) * (iw);                                         \
    FA0 = sa_ * ((wx) - (c) * (ux));                                                               \
    FA1 = sa_ * ((wy) - (c) * (uy));                                                               \
    FA2 = sa_ * ((wz) - (c) * (uz));                                                               \
    FB0 = sb_ * ((ux) - (c) * (wx));                                                               \
    FB1 = sb_ * ((uy) - (c) * (wy));                                                               \
    FB2 = sb_ * ((uz) - (c) * (wz));                                                               \
  } while (0)

// radialRows for a chunk without angle springs: the arms stay as they are.
template <bool kEnergy>
[[gnu::always_inline]] inline void radialOnlyRows(
    Index count, const Index* __restrict edge, const double* __restrict edgeKappa,
    const double* __restrict restLength, const double* __restrict ax, const double* __restrict ay,
    const double* __restrict az, const double* __restrict length, double* __restrict gx,
    double* __restrict gy, double* __restrict gz, double* __restrict energy) {
#pragma omp simd
  for (Index j = 0; j < count; ++j) {
    const double kappa = edgeKappa[edge[j]], rest = restLength[edge[j]], l = length[j];
    const double coefficient = radialCoefficient(l, kappa, rest);
    if constexpr (kEnergy) energy[j] = radialEnergy(l, kappa, rest);
    gx[j] = coefficient * ax[j];
    gy[j] = coefficient * ay[j];
    gz[j] = coefficient * az[j];
  }
}

ZSCULPT_KERNEL void radialOnlyBatch(Index count, const Index* __restrict edge,
                                    const double* __restrict edgeKappa,
                                    const double* __restrict restLength,
                                    const double* __restrict ax, const double* __restrict ay,
                                    const double* __restrict az, const double* __restrict length,
                                    double* __restrict gx, double* __restrict gy,
                                    double* __restrict gz, double* __restrict energy) {
  if (energy)
    radialOnlyRows<true>(count, edge, edgeKappa, restLength, ax, ay, az, length, gx, gy, gz,
                         energy);
  else
    radialOnlyRows<false>(count, edge, edgeKappa, restLength, ax, ay, az, length, gx, gy, gz,
                          energy);
}

// The arms r_second - r_first of a group's edges and their lengths (the same sums as
// slotArms', so that the edge's force on its first end is the gather path's bit for bit).
ZSCULPT_KERNEL void edgeArms(Index count, const Index* __restrict first,
                             const Index* __restrict second, const double* __restrict r,
                             double* __restrict ax, double* __restrict ay, double* __restrict az,
                             double* __restrict length) {
#pragma omp simd
  for (Index j = 0; j < count; ++j) {
    const Index v = first[j], w = second[j];
    const double ux = r[3 * w] - r[3 * v], uy = r[3 * w + 1] - r[3 * v + 1],
                 uz = r[3 * w + 2] - r[3 * v + 2];
    ax[j] = ux;
    ay[j] = uy;
    az[j] = uz;
    length[j] = std::sqrt(ux * ux + uy * uy + uz * uz);
  }
}

// Cosine and sine of the angle between the unit arms p[k] and q[k] (the sine as |u x w|, its
// square root taken in this loop, which vectorises, rather than in a pass of its own).
ZSCULPT_KERNEL void angleCosSin(Index m, const Index* __restrict p, const Index* __restrict q,
                                const double* __restrict ax, const double* __restrict ay,
                                const double* __restrict az, double* __restrict cosine,
                                double* __restrict sine) {
#pragma omp simd
  for (Index k = 0; k < m; ++k) {
    const Index i = p[k], j = q[k];
    const double ux = ax[i], uy = ay[i], uz = az[i];
    const double wx = ax[j], wy = ay[j], wz = az[j];
    cosine[k] = ux * wx + uy * wy + uz * wz;
    const double cx = uy * wz - uz * wy, cy = uz * wx - ux * wz, cz = ux * wy - uy * wx;
    sine[k] = std::sqrt(cx * cx + cy * cy + cz * cz);
  }
}

// Forces of a batch of angles with arms p[k], q[k] (indices into the arm arrays); the
// first arm's force goes to fa[k], the second's to fb[k], and with kEnergy the squared
// excess theta - theta_0 to excess2[k]. Returns the smallest sine. (Inlined into the kernel
// below, and so built for its instruction sets.)
template <bool kEnergy>
[[gnu::always_inline]] inline double angleForceRows(
    Index m, const Index* __restrict p, const Index* __restrict q, const double* __restrict ax,
    const double* __restrict ay, const double* __restrict az, const double* __restrict il,
    const double* __restrict sine, const double* __restrict cosine, const double* __restrict rest,
    double* __restrict fax, double* __restrict fay, double* __restrict faz, double* __restrict fbx,
    double* __restrict fby, double* __restrict fbz, double* __restrict excess2) {
  double smallest = 1.0;
#pragma omp simd reduction(min : smallest)
  for (Index k = 0; k < m; ++k) {
    const double s = sine[k], c = cosine[k];
    smallest = std::min(smallest, s);
    double twiceEnergy;
    const double beta = angleBeta(s, c, rest[k], twiceEnergy);
    if constexpr (kEnergy) excess2[k] = twiceEnergy;
    const Index i = p[k], j = q[k];
    ZSCULPT_ANGLE_FORCE(beta, c, ax[i], ay[i], az[i], il[i], ax[j], ay[j], az[j], il[j], fax[k],
                        fay[k], faz[k], fbx[k], fby[k], fbz[k]);
  }
  return smallest;
}

// angleForceRows, with the squared excesses when excess2 is not null.
ZSCULPT_KERNEL double angleForces(Index m, const Index* __restrict p, const Index* __restrict q,
                                  const double* __restrict ax, const double* __restrict ay,
                                  const double* __restrict az, const double* __restrict il,
                                  const double* __restrict sine, const double* __restrict cosine,
                                  const double* __restrict rest, double* __restrict fax,
                                  double* __restrict fay, double* __restrict faz,
                                  double* __restrict fbx, double* __restrict fby,
                                  double* __restrict fbz, double* __restrict excess2) {
  return excess2 ? angleForceRows<true>(m, p, q, ax, ay, az, il, sine, cosine, rest, fax, fay, faz,
                                        fbx, fby, fbz, excess2)
                 : angleForceRows<false>(m, p, q, ax, ay, az, il, sine, cosine, rest, fax, fay, faz,
                                         fbx, fby, fbz, excess2);
}

// One pair of arms (u, w) across a run of L vertices (runAngleRows): the angles' forces
// added to the arms' sums, their sines to si, their squared excesses to excess2 (kEnergy);
// rest angles at rest[pairs i]. With kCaps angleBeta, else angleBetaUncapped. Returns
// whether an angle was in its cap.
template <bool kEnergy, bool kCaps>
[[gnu::always_inline]] inline int anglePairRows(
    Index count, Index pairs, const double* __restrict ux, const double* __restrict uy,
    const double* __restrict uz, const double* __restrict iu, const double* __restrict wx,
    const double* __restrict wy, const double* __restrict wz, const double* __restrict iw,
    const double* __restrict rest, double* __restrict si, double* __restrict gax,
    double* __restrict gay, double* __restrict gaz, double* __restrict gbx, double* __restrict gby,
    double* __restrict gbz, double* __restrict excess2, double& smallest) {
  int capped = 0;
  double least = smallest;
#pragma omp simd reduction(min : least) reduction(| : capped)
  for (Index i = 0; i < count; ++i) {
    const double c = ux[i] * wx[i] + uy[i] * wy[i] + uz[i] * wz[i];
    const double cx = uy[i] * wz[i] - uz[i] * wy[i], cy = uz[i] * wx[i] - ux[i] * wz[i],
                 cz = ux[i] * wy[i] - uy[i] * wx[i];
    const double s = std::sqrt(cx * cx + cy * cy + cz * cz);
    si[i] = s;
    least = std::min(least, s);
    double twiceEnergy;
    bool inCap;
    const double beta = kCaps ? angleBeta(s, c, rest[pairs * i], twiceEnergy, inCap)
                              : angleBetaUncapped(s, c, rest[pairs * i], twiceEnergy, inCap);
    capped |= static_cast<int>(inCap);
    if constexpr (kEnergy) excess2[i] += twiceEnergy;
    double fa0, fa1, fa2, fb0, fb1, fb2;
    ZSCULPT_ANGLE_FORCE(beta, c, ux[i], uy[i], uz[i], iu[i], wx[i], wy[i], wz[i], iw[i], fa0, fa1,
                        fa2, fb0, fb1, fb2);
    gax[i] += fa0;
    gay[i] += fa1;
    gaz[i] += fa2;
    gbx[i] += fb0;
    gby[i] += fb1;
    gbz[i] += fb2;
  }
  smallest = least;
  return capped;
}

// A run of L vertices of one degree with every angle spring on: the arms transposed by slot
// (arm a of the run's vertex i at a L + i), angle (a, b) = pair k of vertex i at k L + i
// (its rest angle at rest[k + pairs i]). Per arm slot a, gx.. (degree L) get the sum of its
// angles' forces (without kappa_theta), vectorised across the vertices without gathers:
// angleCosSin's cosine and sine, angleForceRows' forces, added in angle order k as the
// degree's term table lists them (the forces of each angle summed into its two arms at
// once, rather than stored per angle and summed in a pass of their own). sine gets the
// sines (k L + i), for the degenerate angles' check; with kEnergy excess2[i] the sum of
// vertex i's squared excesses. Returns the smallest sine.
// The cap of an angle spring (angleProfile) costs a division and a polynomial (a fifth of
// the force pass: docs/performance.md) and is reached only within kAngleCapWidth of straight
// or folded. capsTaken[k] (one per pair, kept by the caller from call to call) says whether
// pair k had an angle in its cap the last time; the pairs that had not are taken without
// the cap (angleBetaUncapped, the same bits where no angle is in one), and if one of them now
// has an angle in its cap the whole run is taken again with it. On a fine surface the
// opposite arms are within a few hundredths of straight at rest and reach their caps
// often; the neighbouring ones do not.
template <bool kEnergy>
[[gnu::always_inline]] inline double runAngleRows(
    Index pairs, Index count, Index degree, const Index* __restrict pairA,
    const Index* __restrict pairB, const double* __restrict ax, const double* __restrict ay,
    const double* __restrict az, const double* __restrict il, const double* __restrict rest,
    double* __restrict sine, double* __restrict gx, double* __restrict gy, double* __restrict gz,
    double* __restrict excess2, unsigned char* __restrict capsTaken) {
  double smallest;
  // A second pass, every pair with angleBeta, only when the first took an angle in its cap as
  // if outside it.
  for (bool second = false;; second = true) {
    smallest = 1.0;
    if constexpr (kEnergy)
      for (Index i = 0; i < count; ++i) excess2[i] = 0.0;
    for (Index i = 0; i < degree * count; ++i) gx[i] = gy[i] = gz[i] = 0.0;
    int missedCap = 0;
    for (Index k = 0; k < pairs; ++k) {
      const Index a = pairA[k] * count, b = pairB[k] * count;
      const double* __restrict ux = ax + a;
      const double* __restrict uy = ay + a;
      const double* __restrict uz = az + a;
      const double* __restrict iu = il + a;
      const double* __restrict wx = ax + b;
      const double* __restrict wy = ay + b;
      const double* __restrict wz = az + b;
      const double* __restrict iw = il + b;
      // Arms a and b differ (a < b): their sums do not overlap.
      double* __restrict gax = gx + a;
      double* __restrict gay = gy + a;
      double* __restrict gaz = gz + a;
      double* __restrict gbx = gx + b;
      double* __restrict gby = gy + b;
      double* __restrict gbz = gz + b;
      double* __restrict si = sine + k * count;
      const bool withCaps = second || capsTaken[k] != 0;
      const int capped =
          withCaps
              ? anglePairRows<kEnergy, true>(count, pairs, ux, uy, uz, iu, wx, wy, wz, iw, rest + k,
                                             si, gax, gay, gaz, gbx, gby, gbz, excess2, smallest)
              : anglePairRows<kEnergy, false>(count, pairs, ux, uy, uz, iu, wx, wy, wz, iw,
                                              rest + k, si, gax, gay, gaz, gbx, gby, gbz, excess2,
                                              smallest);
      if (!withCaps) missedCap |= capped;
      capsTaken[k] = static_cast<unsigned char>(capped != 0);
    }
    if (!missedCap) break;
  }
  return smallest;
}

// runAngleRows, with the squared excesses when excess2 is not null.
ZSCULPT_KERNEL double runAngles(Index pairs, Index count, Index degree,
                                const Index* __restrict pairA, const Index* __restrict pairB,
                                const double* __restrict ax, const double* __restrict ay,
                                const double* __restrict az, const double* __restrict il,
                                const double* __restrict rest, double* __restrict sine,
                                double* __restrict gx, double* __restrict gy, double* __restrict gz,
                                double* __restrict excess2, unsigned char* __restrict capsTaken) {
  return excess2 ? runAngleRows<true>(pairs, count, degree, pairA, pairB, ax, ay, az, il, rest,
                                      sine, gx, gy, gz, excess2, capsTaken)
                 : runAngleRows<false>(pairs, count, degree, pairA, pairB, ax, ay, az, il, rest,
                                       sine, gx, gy, gz, excess2, capsTaken);
}

// Arms of a uniform chunk (L = count vertices from c0, of one degree), by slot: arm a of
// vertex i at a L + i is r_w - r_v, its length beside it (the same sums as Vec3::norm's).
ZSCULPT_KERNEL void slotArms(Index degree, Index count, Index c0, const Index* __restrict neighbour,
                             const double* __restrict r, double* __restrict ax,
                             double* __restrict ay, double* __restrict az,
                             double* __restrict length) {
  for (Index a = 0; a < degree; ++a) {
    const Index o = a * count;
#pragma omp simd
    for (Index i = 0; i < count; ++i) {
      const Index w = neighbour[o + i], v = c0 + i;
      const double ux = r[3 * w] - r[3 * v], uy = r[3 * w + 1] - r[3 * v + 1],
                   uz = r[3 * w + 2] - r[3 * v + 2];
      ax[o + i] = ux;
      ay[o + i] = uy;
      az[o + i] = uz;
      length[o + i] = std::sqrt(ux * ux + uy * uy + uz * uz);
    }
  }
}

// slotArms and radialRows in one loop, for a uniform chunk with angle springs: arm j = a L + i
// of half-edge h0 + j (edge[j]) becomes its unit vector in ax.., its inverse length in il,
// the radial spring's force on v in gx.., the same operations as the two passes (the
// length is not stored: nothing after needs it). With kEnergy the spring's energy goes to
// energy[j].
template <bool kEnergy>
[[gnu::always_inline]] inline void slotArmsRadialRows(
    Index degree, Index count, Index c0, const Index* __restrict neighbour,
    const double* __restrict r, const Index* __restrict edge, const double* __restrict edgeKappa,
    const double* __restrict restLength, double* __restrict ax, double* __restrict ay,
    double* __restrict az, double* __restrict il, double* __restrict gx, double* __restrict gy,
    double* __restrict gz, double* __restrict energy) {
  for (Index a = 0; a < degree; ++a) {
    const Index o = a * count;
#pragma omp simd
    for (Index i = 0; i < count; ++i) {
      const Index w = neighbour[o + i], v = c0 + i, j = o + i;
      const double ux = r[3 * w] - r[3 * v], uy = r[3 * w + 1] - r[3 * v + 1],
                   uz = r[3 * w + 2] - r[3 * v + 2];
      const double l = std::sqrt(ux * ux + uy * uy + uz * uz);
      radialArm<kEnergy>(j, ux, uy, uz, l, edgeKappa[edge[j]], restLength[edge[j]], ax, ay, az, il,
                         gx, gy, gz, energy);
    }
  }
}

// slotArmsRadialRows, with the energies when energy is not null.
ZSCULPT_KERNEL void slotArmsRadial(Index degree, Index count, Index c0,
                                   const Index* __restrict neighbour, const double* __restrict r,
                                   const Index* __restrict edge, const double* __restrict edgeKappa,
                                   const double* __restrict restLength, double* __restrict ax,
                                   double* __restrict ay, double* __restrict az,
                                   double* __restrict il, double* __restrict gx,
                                   double* __restrict gy, double* __restrict gz,
                                   double* __restrict energy) {
  if (energy)
    slotArmsRadialRows<true>(degree, count, c0, neighbour, r, edge, edgeKappa, restLength, ax, ay,
                             az, il, gx, gy, gz, energy);
  else
    slotArmsRadialRows<false>(degree, count, c0, neighbour, r, edge, edgeKappa, restLength, ax, ay,
                              az, il, gx, gy, gz, energy);
}

// The slot sums of a run of L vertices scaled by each vertex's kappa_theta (the force on
// the end of each arm), and their sums per vertex in arm order (the reaction on the centre,
// negated by the caller): kappa g and 0 + f_0 + f_1 + ..., rounding for rounding what a
// vertex-by-vertex loop makes, vectorised across the vertices.
ZSCULPT_KERNEL void slotScale(Index degree, Index count, const double* __restrict kappa,
                              double* __restrict gx, double* __restrict gy, double* __restrict gz,
                              double* __restrict cx, double* __restrict cy, double* __restrict cz) {
  for (Index i = 0; i < count; ++i) cx[i] = cy[i] = cz[i] = 0.0;
  for (Index a = 0; a < degree; ++a) {
    double* __restrict x = gx + a * count;
    double* __restrict y = gy + a * count;
    double* __restrict z = gz + a * count;
#pragma omp simd
    for (Index i = 0; i < count; ++i) {
      x[i] = kappa[i] * x[i];
      y[i] = kappa[i] * y[i];
      z[i] = kappa[i] * z[i];
      cx[i] += x[i];
      cy[i] += y[i];
      cz[i] += z[i];
    }
  }
}

}  // namespace

ForceKernel::ForceKernel(const Model& model, int maxThreads) {
  const Mesh& mesh = model.mesh;
  const Index n = mesh.numVertices();
  const CsrIndex& neighbours = mesh.vertexNeighborTable();
  const Index* off = neighbours.offsets.data();
  const Index* nbr = neighbours.indices.data();

  // Blocks of consecutive vertices, an even count when there is more than one (two threads
  // share them evenly); from a thousand vertices on, at least two.
  Index blocks = std::max<Index>(1, (n + kBlockVertices - 1) / kBlockVertices);
  if (n >= 1024 && blocks < 2) blocks = 2;
  if (blocks > 1 && blocks % 2 == 1) ++blocks;
  blockStart_.resize(static_cast<size_t>(blocks) + 1);
  for (Index b = 0; b <= blocks; ++b)
    blockStart_[static_cast<size_t>(b)] =
        static_cast<Index>(static_cast<std::int64_t>(n) * b / blocks);

  // Does the angle table follow buildAngleTable's layout? Otherwise find every angle's arms.
  const AngleTable& angles = model.angles;
  if (static_cast<Index>(angles.vertexOffsets.size()) != n + 1) {
    reference_ = true;
  } else {
    for (Index v = 0; v < n && canonicalAngles_; ++v) {
      const Index degree = off[v + 1] - off[v];
      Index k = angles.vertexOffsets[static_cast<size_t>(v)];
      if (angles.vertexOffsets[static_cast<size_t>(v) + 1] - k != degree * (degree - 1) / 2) {
        canonicalAngles_ = false;
        break;
      }
      for (Index a = 0; a < degree && canonicalAngles_; ++a)
        for (Index b = a + 1; b < degree; ++b, ++k) {
          const auto& angle = angles.angles[static_cast<size_t>(k)];
          const Index na = nbr[off[v] + a], nb = nbr[off[v] + b];
          if (angle[0] != v || angle[1] != std::min(na, nb) || angle[2] != std::max(na, nb)) {
            canonicalAngles_ = false;
            break;
          }
        }
    }
    if (!canonicalAngles_) {
      angleArm_.resize(2 * angles.angles.size());
      for (Index v = 0; v < n && !reference_; ++v)
        for (Index k = angles.vertexOffsets[static_cast<size_t>(v)];
             k < angles.vertexOffsets[static_cast<size_t>(v) + 1]; ++k) {
          const auto& angle = angles.angles[static_cast<size_t>(k)];
          if (angle[0] != v) {
            reference_ = true;
            break;
          }
          for (int arm = 0; arm < 2; ++arm) {
            const Index* begin = nbr + off[v];
            const Index* end = nbr + off[v + 1];
            const Index* it = std::find(begin, end, angle[static_cast<size_t>(arm) + 1]);
            if (it == end) {
              reference_ = true;
              break;
            }
            angleArm_[2 * static_cast<size_t>(k) + static_cast<size_t>(arm)] =
                static_cast<Index>(it - nbr);
          }
        }
    }
  }

  // Halo of every block: the vertices of other blocks next to its vertices, sorted.
  target_.resize(neighbours.indices.size());
  std::vector<Index> stamp(static_cast<size_t>(n), -1), slot(static_cast<size_t>(n), 0);
  std::vector<Index> list;
  std::vector<std::array<Index, 3>> incoming;  // (vertex, halo position, source block)
  haloStart_.assign(1, 0);
  size_t maxAccumulator = 0;
  for (Index b = 0; b < blocks; ++b) {
    const Index v0 = blockStart_[static_cast<size_t>(b)],
                v1 = blockStart_[static_cast<size_t>(b) + 1];
    list.clear();
    for (Index h = off[v0]; h < off[v1]; ++h) {
      const Index w = nbr[h];
      if ((w < v0 || w >= v1) && stamp[static_cast<size_t>(w)] != b) {
        stamp[static_cast<size_t>(w)] = b;
        list.push_back(w);
      }
    }
    std::sort(list.begin(), list.end());
    for (size_t k = 0; k < list.size(); ++k) {
      slot[static_cast<size_t>(list[k])] = static_cast<Index>(k);
      incoming.push_back({list[k], haloStart_.back() + static_cast<Index>(k), b});
    }
    const Index length = v1 - v0;
    for (Index h = off[v0]; h < off[v1]; ++h) {
      const Index w = nbr[h];
      target_[static_cast<size_t>(h)] =
          (w >= v0 && w < v1) ? w - v0 : length + slot[static_cast<size_t>(w)];
    }
    haloStart_.push_back(haloStart_.back() + static_cast<Index>(list.size()));
    maxAccumulator = std::max(maxAccumulator, 3 * (static_cast<size_t>(length) + list.size()));
  }
  halo_.assign(3 * static_cast<size_t>(haloStart_.back()), 0.0);
  blockHasAngles_.assign(static_cast<size_t>(blocks), 0);
  blockEnergy_.assign(2 * static_cast<size_t>(blocks), 0.0);
  // Incoming contributions per receiving block, by row then source block (stable sort: the
  // list is already in source block order).
  std::stable_sort(incoming.begin(), incoming.end(),
                   [](const auto& x, const auto& y) { return x[0] < y[0]; });
  incomingStart_.assign(1, 0);
  incomingRow_.resize(incoming.size());
  incomingHalo_.resize(incoming.size());
  incomingBlock_.resize(incoming.size());
  size_t k = 0;
  for (Index b = 0; b < blocks; ++b) {
    const Index v0 = blockStart_[static_cast<size_t>(b)],
                v1 = blockStart_[static_cast<size_t>(b) + 1];
    for (; k < incoming.size() && incoming[k][0] < v1; ++k) {
      incomingRow_[k] = incoming[k][0] - v0;
      incomingHalo_[k] = incoming[k][1];
      incomingBlock_[k] = incoming[k][2];
    }
    incomingStart_.push_back(static_cast<Index>(k));
  }

  // Chunks: consecutive vertices of a block, at most chunkVertices_ of them; one degree
  // throughout makes a uniform chunk, whose half-edges the kernel keeps by arm slot.
  const bool uniformAllowed = canonicalAngles_ && !reference_;
  blockChunk_.assign(1, 0);
  chunkStart_.clear();
  chunkDegree_.clear();
  size_t maxArms = 0, maxAngles = 0;
  for (Index b = 0; b < blocks; ++b) {
    const Index v0 = blockStart_[static_cast<size_t>(b)],
                v1 = blockStart_[static_cast<size_t>(b) + 1];
    for (Index c0 = v0; c0 < v1; c0 += chunkVertices_) {
      const Index c1 = std::min(c0 + chunkVertices_, v1);
      const Index degree = off[c0 + 1] - off[c0];
      bool uniform = uniformAllowed && degree > 0;
      for (Index v = c0; v < c1 && uniform; ++v) uniform = off[v + 1] - off[v] == degree;
      chunkStart_.push_back(c0);
      chunkDegree_.push_back(uniform ? degree : 0);
      maxArms = std::max(maxArms, static_cast<size_t>(off[c1] - off[c0]));
      if (!reference_)
        maxAngles =
            std::max(maxAngles, static_cast<size_t>(angles.vertexOffsets[static_cast<size_t>(c1)] -
                                                    angles.vertexOffsets[static_cast<size_t>(c0)]));
    }
    blockChunk_.push_back(static_cast<Index>(chunkStart_.size()));
  }
  chunkStart_.push_back(n);
  const Index* meshEdge = mesh.vertexEdgeTable().indices.data();
  neighbour_.resize(neighbours.indices.size());
  edge_.resize(neighbours.indices.size());
  std::vector<Index> meshTarget = std::move(target_);
  target_.resize(meshTarget.size());
  for (size_t c = 0; c < chunkDegree_.size(); ++c) {
    const Index c0 = chunkStart_[c], c1 = chunkStart_[c + 1], degree = chunkDegree_[c];
    const Index h0 = off[c0], count = c1 - c0;
    for (Index h = h0; h < off[c1]; ++h) {
      // Mesh half-edge h is arm a of the chunk's vertex i; uniform chunks store it at a L + i.
      const Index i = degree ? (h - h0) / degree : 0, a = degree ? (h - h0) % degree : 0;
      const size_t to = static_cast<size_t>(degree ? h0 + a * count + i : h);
      neighbour_[to] = nbr[h];
      edge_[to] = meshEdge[h];
      target_[to] = meshTarget[static_cast<size_t>(h)];
    }
  }
  maxAngles_ = static_cast<Index>(maxAngles);
  // Edge groups for blocks without angle springs.
  blockGroup_.assign(1, 0);
  groupStart_.clear();
  groupEdgeStart_.assign(1, 0);
  groupEdge_.clear();
  armSlot_.assign(neighbours.indices.size(), 0);
  size_t maxGroupEdges = 0;
  {
    std::vector<Index> groupSlot(static_cast<size_t>(mesh.numEdges()), -1);
    for (Index b = 0; b < blocks; ++b) {
      const Index v0 = blockStart_[static_cast<size_t>(b)];
      const Index v1 = blockStart_[static_cast<size_t>(b) + 1];
      for (Index g0 = v0; g0 < v1; g0 += kGroupVertices) {
        const Index g1 = std::min(g0 + kGroupVertices, v1);
        const size_t begin = groupEdge_.size();
        groupEdge_.insert(groupEdge_.end(), meshEdge + off[g0], meshEdge + off[g1]);
        std::sort(groupEdge_.begin() + static_cast<std::ptrdiff_t>(begin), groupEdge_.end());
        groupEdge_.erase(
            std::unique(groupEdge_.begin() + static_cast<std::ptrdiff_t>(begin), groupEdge_.end()),
            groupEdge_.end());
        for (size_t k = begin; k < groupEdge_.size(); ++k)
          groupSlot[static_cast<size_t>(groupEdge_[k])] = static_cast<Index>(k - begin);
        for (Index v = g0; v < g1; ++v)
          for (Index h = off[v]; h < off[v + 1]; ++h) {
            const Index e = meshEdge[h];
            const Index slotOfEdge = groupSlot[static_cast<size_t>(e)];
            armSlot_[static_cast<size_t>(h)] = mesh.edge(e)[0] == v ? slotOfEdge : ~slotOfEdge;
          }
        groupStart_.push_back(g0);
        groupEdgeStart_.push_back(static_cast<Index>(groupEdge_.size()));
        maxGroupEdges = std::max(maxGroupEdges, groupEdge_.size() - begin);
      }
      blockGroup_.push_back(static_cast<Index>(groupStart_.size()));
    }
    groupStart_.push_back(n);
  }
  groupFirst_.resize(groupEdge_.size());
  groupSecond_.resize(groupEdge_.size());
  for (size_t k = 0; k < groupEdge_.size(); ++k) {
    const auto ends = mesh.edge(groupEdge_[k]);
    groupFirst_[k] = ends[0];
    groupSecond_[k] = ends[1];
  }
  // Canonical tables for every degree up to the largest.
  Index maxDegree = 0;
  for (Index v = 0; v < n; ++v) maxDegree = std::max(maxDegree, off[v + 1] - off[v]);
  pairStart_.assign(1, 0);
  termStart_.assign(1, 0);
  armTermStart_.assign(1, 0);
  for (Index degree = 0; degree <= maxDegree && canonicalAngles_ && !reference_; ++degree) {
    for (Index a = 0; a < degree; ++a)
      for (Index b = a + 1; b < degree; ++b) {
        pairA_.push_back(a);
        pairB_.push_back(b);
      }
    pairStart_.push_back(static_cast<Index>(pairA_.size()));
    // termStart_[degree] is where this degree's arms start in armTermStart_.
    termStart_.back() = static_cast<Index>(armTermStart_.size()) - 1;
    for (Index arm = 0; arm < degree; ++arm) {
      Index k = 0;
      for (Index a = 0; a < degree; ++a)
        for (Index b = a + 1; b < degree; ++b, ++k) {
          if (a == arm) armTerm_.push_back(k);
          if (b == arm) armTerm_.push_back(k + maxAngles_);
        }
      armTermStart_.push_back(static_cast<Index>(armTerm_.size()));
    }
    termStart_.push_back(0);
  }
  if (canonicalAngles_ && !reference_) capsTaken_.assign(angles.angles.size(), 0);
  const int threads = maxThreads > 0 ? maxThreads : availableThreads();
  scratch_.resize(static_cast<size_t>(threads));
  for (Scratch& s : scratch_) {
    s.acc.resize(maxAccumulator);
    // The arms, lengths and radial forces also serve the edge groups.
    for (auto* v : {&s.ax, &s.ay, &s.az, &s.length, &s.gx, &s.gy, &s.gz, &s.energy})
      v->resize(std::max(maxArms, maxGroupEdges));
    for (auto* v : {&s.invLength, &s.tx, &s.ty, &s.tz, &s.tl}) v->resize(maxArms);
    for (auto* v : {&s.armP, &s.armQ}) v->resize(maxAngles);
    for (auto* v : {&s.rest, &s.cosine, &s.sine, &s.excess2}) v->resize(maxAngles);
    for (auto* v : {&s.fx, &s.fy, &s.fz}) v->resize(2 * maxAngles);
  }
  rebuild(model);
}

void ForceKernel::rebuild(const Model& model) {
  const Mesh& mesh = model.mesh;
  const PhysicalProperties& p = model.properties;
  edgeKappa_.resize(mesh.numEdges());
  for (Index e = 0; e < mesh.numEdges(); ++e) {
    const auto [i, j] = mesh.edge(e);
    edgeKappa_[e] = edgeStiffness(p.stiffness[i], p.stiffness[j]);
  }
}

void ForceKernel::propertiesChanged(const Model& model, std::span<const Index> vertices) {
  const Mesh& mesh = model.mesh;
  const PhysicalProperties& p = model.properties;
  for (Index v : vertices)
    for (Index e : mesh.vertexEdges(v)) {
      const auto [i, j] = mesh.edge(e);
      edgeKappa_[e] = edgeStiffness(p.stiffness[i], p.stiffness[j]);
    }
}

size_t ForceKernel::bytes() const {
  size_t total = 0;
  for (const auto* v :
       {&blockStart_,     &blockChunk_,  &chunkStart_,   &chunkDegree_,   &neighbour_,
        &edge_,           &target_,      &haloStart_,    &blockGroup_,    &groupStart_,
        &groupEdgeStart_, &groupEdge_,   &groupFirst_,   &groupSecond_,   &armSlot_,
        &incomingStart_,  &incomingRow_, &incomingHalo_, &incomingBlock_, &angleArm_,
        &pairStart_,      &pairA_,       &pairB_,        &termStart_,     &armTermStart_,
        &armTerm_})
    total += v->capacity() * sizeof(Index);
  total += (halo_.capacity() + blockEnergy_.capacity()) * sizeof(double) +
           blockHasAngles_.capacity() + capsTaken_.capacity() +
           static_cast<size_t>(edgeKappa_.size()) * sizeof(double);
  for (const Scratch& s : scratch_) {
    for (const auto* v : {&s.acc,    &s.ax,   &s.ay, &s.az, &s.length, &s.invLength, &s.gx,
                          &s.gy,     &s.gz,   &s.tx, &s.ty, &s.tz,     &s.tl,        &s.rest,
                          &s.cosine, &s.sine, &s.fx, &s.fy, &s.fz,     &s.energy,    &s.excess2})
      total += v->capacity() * sizeof(double);
    for (const auto* v : {&s.armP, &s.armQ}) total += v->capacity() * sizeof(Index);
  }
  return total;
}

void ForceKernel::compute(const Model& model, const Points& position, Points& force, int threads,
                          bool withEnergy) {
  if (inParallel()) {
    scatter(model, position, force, withEnergy);
#pragma omp for schedule(static)
    for (Index b = 0; b < numBlocks(); ++b) gatherBlock(b, force);
    return;
  }
  const int team = threads > 0 ? std::min(threads, maxThreads()) : maxThreads();
  (void)team;
  parallelRegion(team, [&] {
    scatter(model, position, force, withEnergy);
#pragma omp for schedule(static)
    for (Index b = 0; b < numBlocks(); ++b) gatherBlock(b, force);
  });
}

void ForceKernel::scatter(const Model& model, const Points& position, Points& force,
                          bool withEnergy) {
  if (reference_) {
#pragma omp single
    {
      force.setZero();
      const PotentialEnergy e = accumulateInternalForces(model, position, force);
      if (withEnergy) {
        std::fill(blockEnergy_.begin(), blockEnergy_.end(), 0.0);
        blockEnergy_[0] = e.radial;
        blockEnergy_[1] = e.angular;
      }
    }
    return;
  }
  Scratch& scratch = scratch_[static_cast<size_t>(threadNumber())];
  const Index blocks = numBlocks();
  if (!inParallel()) {
    // One thread (parallelRegion ran the body directly): a dynamic loop outside a region
    // would make libgomp allocate its work share, every step.
    for (Index b = 0; b < blocks; ++b) scatterBlock(model, position, force, b, scratch, withEnergy);
    return;
  }
#pragma omp for schedule(dynamic, 1)
  for (Index b = 0; b < blocks; ++b) scatterBlock(model, position, force, b, scratch, withEnergy);
}

void ForceKernel::scatterBlock(const Model& model, const Points& position, Points& force,
                               Index block, Scratch& s, bool withEnergy) {
  const Mesh& mesh = model.mesh;
  const PhysicalProperties& prop = model.properties;
  const Index v0 = blockStart_[static_cast<size_t>(block)];
  const Index v1 = blockStart_[static_cast<size_t>(block) + 1];
  const Index length = v1 - v0;
  const double* kappaTheta = prop.angularStiffness.data();
  if (std::all_of(kappaTheta + v0, kappaTheta + v1, [](double k) { return k == 0.0; })) {
    radialOnlyBlock(model, position, force, block, s, withEnergy);
    blockHasAngles_[static_cast<size_t>(block)] = 0;
    return;
  }
  const Index haloBegin = haloStart_[static_cast<size_t>(block)];
  const Index haloLength = haloStart_[static_cast<size_t>(block) + 1] - haloBegin;
  double* acc = s.acc.data();
  std::fill(acc, acc + 3 * static_cast<size_t>(length + haloLength), 0.0);

  const Index* off = mesh.vertexNeighborTable().offsets.data();
  const Index* nbr = neighbour_.data();
  const Index* angleOffsets = model.angles.vertexOffsets.data();
  const double* r = position.data();
  const double* restAngle = prop.restAngle.data();
  double* ax = s.ax.data();
  double* ay = s.ay.data();
  double* az = s.az.data();
  double* il = s.invLength.data();
  double* len = s.length.data();
  const size_t second = static_cast<size_t>(maxAngles_);
  bool anyAngle = false;
  // The block's energies (withEnergy): each radial spring from both of its ends (halved at
  // the end), each angle spring from its centre, in the kernel's order.
  double angularSum = 0.0;
  double radialLanes[kLanes] = {}, angularLanes[kLanes] = {};
  double* excess2 = withEnergy ? s.excess2.data() : nullptr;
  double* energy = withEnergy ? s.energy.data() : nullptr;

  // The degenerate angles of centre v (arms (anti)parallel or of zero length), whose
  // direction angleSpringForce picks, into the accumulator (tc: the centre's row);
  // sineOf(k), armsOf(k): the vertex's angle k.
  auto depositDegenerate = [&](Index v, double kappa, double* tc, auto&& sineOf, auto&& armsOf) {
    const Index count = angleOffsets[v + 1] - angleOffsets[v];
    for (Index k = 0; k < count; ++k) {
      if (sineOf(k) > 1e-12) continue;
      Index hp, hq;
      armsOf(k, hp, hq);
      Vec3 fc, fa, fb;
      angularSum += angleSpringForce(position.row(v), position.row(nbr[hp]), position.row(nbr[hq]),
                                     kappa, restAngle[angleOffsets[v] + k], fc, fa, fb);
      double* ta = acc + 3 * static_cast<size_t>(target_[static_cast<size_t>(hp)]);
      double* tb = acc + 3 * static_cast<size_t>(target_[static_cast<size_t>(hq)]);
      for (int d = 0; d < 3; ++d) {
        ta[d] += fa[d];
        tb[d] += fb[d];
        tc[d] += fc[d];
      }
    }
  };
  // Deposits the angle forces of centre v: kappa_theta times the force on the end of each of
  // its arms (arm a is half-edge slot(a) of the kernel's order), in arm order, minus their
  // sum on the centre, then the degenerate angles. armForce(a, f): the arm's summed force
  // without kappa_theta.
  auto deposit = [&](Index v, double kappa, auto&& slot, auto&& armForce, bool checkDegenerate,
                     auto&& sineOf, auto&& armsOf) {
    double cx = 0.0, cy = 0.0, cz = 0.0;
    for (Index a = 0; a < off[v + 1] - off[v]; ++a) {
      double f[3];
      armForce(a, f);
      const double fx = kappa * f[0], fy = kappa * f[1], fz = kappa * f[2];
      double* t = acc + 3 * static_cast<size_t>(target_[static_cast<size_t>(slot(a))]);
      t[0] += fx;
      t[1] += fy;
      t[2] += fz;
      cx += fx;
      cy += fy;
      cz += fz;
    }
    double* tc = acc + 3 * static_cast<size_t>(v - v0);
    tc[0] -= cx;
    tc[1] -= cy;
    tc[2] -= cz;
    if (checkDegenerate) depositDegenerate(v, kappa, tc, sineOf, armsOf);
  };
  // deposit with the arms' forces already scaled by kappa_theta and summed (slotScale):
  // armForce(a, f) the force on arm a's end, centre(c) their sum.
  auto depositScaled = [&](Index v, auto&& slot, auto&& armForce, auto&& centre,
                           bool checkDegenerate, auto&& sineOf, auto&& armsOf) {
    for (Index a = 0; a < off[v + 1] - off[v]; ++a) {
      double f[3];
      armForce(a, f);
      double* t = acc + 3 * static_cast<size_t>(target_[static_cast<size_t>(slot(a))]);
      t[0] += f[0];
      t[1] += f[1];
      t[2] += f[2];
    }
    double c[3];
    centre(c);
    double* tc = acc + 3 * static_cast<size_t>(v - v0);
    tc[0] -= c[0];
    tc[1] -= c[1];
    tc[2] -= c[2];
    if (checkDegenerate) depositDegenerate(v, kappaTheta[v], tc, sineOf, armsOf);
  };

  // The angles of a run of `count` vertices from v of one degree whose arms are by slot in
  // tx.. (arm a of vertex i at a count + i), rest angles from restAngle + angleOffsets[v];
  // slot(i, a) is the arm's kernel half-edge.
  auto slotAngles = [&](Index v, Index count, Index degree, const double* tx, const double* ty,
                        const double* tz, const double* tl, auto&& slot) {
    const Index pairs = degree * (degree - 1) / 2;
    const Index* pa = pairA_.data() + pairStart_[static_cast<size_t>(degree)];
    const Index* pb = pairB_.data() + pairStart_[static_cast<size_t>(degree)];
    const double smallest = runAngles(
        pairs, count, degree, pa, pb, tx, ty, tz, tl, restAngle + angleOffsets[v], s.sine.data(),
        s.gx.data(), s.gy.data(), s.gz.data(), excess2, capsTaken_.data() + angleOffsets[v]);
    // deposit's products and centre sums for all the run's vertices at once (fx.. are free
    // scratch on this path): the same values, leaving deposit the scattered additions.
    double* cx = s.fx.data();
    double* cy = s.fy.data();
    double* cz = s.fz.data();
    slotScale(degree, count, kappaTheta + v, s.gx.data(), s.gy.data(), s.gz.data(), cx, cy, cz);
    if (withEnergy) {
      for (Index i = 0; i < count; ++i)
        excess2[i] = select(kappaTheta[v + i] != 0.0, 0.5 * kappaTheta[v + i] * excess2[i], 0.0);
      addToLanes(angularLanes, excess2, count);
    }
    for (Index i = 0; i < count; ++i) {
      const Index w = v + i;
      if (kappaTheta[w] == 0.0) continue;
      depositScaled(
          w, [&](Index a) { return slot(i, a); },
          [&](Index a, double* f) {
            const size_t at = static_cast<size_t>(a * count + i);
            f[0] = s.gx[at];
            f[1] = s.gy[at];
            f[2] = s.gz[at];
          },
          [&](double* c) {
            c[0] = cx[i];
            c[1] = cy[i];
            c[2] = cz[i];
          },
          !(smallest > 1e-12), [&](Index k) { return s.sine[static_cast<size_t>(k * count + i)]; },
          [&](Index k, Index& hp, Index& hq) {
            hp = slot(i, pa[k]);
            hq = slot(i, pb[k]);
          });
    }
  };

  for (Index chunk = blockChunk_[static_cast<size_t>(block)];
       chunk < blockChunk_[static_cast<size_t>(block) + 1]; ++chunk) {
    const Index c0 = chunkStart_[static_cast<size_t>(chunk)];
    const Index c1 = chunkStart_[static_cast<size_t>(chunk) + 1];
    const Index uniform = chunkDegree_[static_cast<size_t>(chunk)];
    const Index h0 = off[c0], arms = off[c1] - h0, count = c1 - c0;
    // Arms r_w - r_v and their lengths, then the radial springs (section 5.1) of every arm:
    // the force on v, rounding for rounding radialSpringForce's.
    bool chunkAngles = false;
    for (Index v = c0; v < c1 && !chunkAngles; ++v) chunkAngles = kappaTheta[v] != 0.0;
    if (uniform && chunkAngles) {
      slotArmsRadial(uniform, count, c0, nbr + h0, r, edge_.data() + h0, edgeKappa_.data(),
                     prop.restLength.data(), ax, ay, az, il, s.gx.data(), s.gy.data(), s.gz.data(),
                     energy);
    } else if (uniform) {
      slotArms(uniform, count, c0, nbr + h0, r, ax, ay, az, len);
    } else {
      for (Index v = c0; v < c1; ++v) {
        const double rx = r[3 * v], ry = r[3 * v + 1], rz = r[3 * v + 2];
        for (Index h = off[v]; h < off[v + 1]; ++h) {
          const Index w = nbr[h], j = h - h0;
          const double ux = r[3 * w] - rx, uy = r[3 * w + 1] - ry, uz = r[3 * w + 2] - rz;
          ax[j] = ux;
          ay[j] = uy;
          az[j] = uz;
          len[j] = ux * ux + uy * uy + uz * uz;
        }
      }
      Eigen::Map<Eigen::ArrayXd> lengths(len, arms);
      lengths = lengths.sqrt();
    }
    // (slotArmsRadial took a uniform chunk's radial springs with its arms.)
    if (chunkAngles && !uniform)
      radialBatch(arms, edge_.data() + h0, edgeKappa_.data(), prop.restLength.data(), ax, ay, az,
                  len, il, s.gx.data(), s.gy.data(), s.gz.data(), energy);
    else if (!chunkAngles)
      radialOnlyBatch(arms, edge_.data() + h0, edgeKappa_.data(), prop.restLength.data(), ax, ay,
                      az, len, s.gx.data(), s.gy.data(), s.gz.data(), energy);
    if (withEnergy) addToLanes(radialLanes, energy, arms);
    // Each vertex adds its edges' forces in increasing edge index (Mesh::vertexEdges, the arm
    // order), as accumulateInternalForces does: without angle springs the forces are
    // bit-identical to the reference.
    for (Index v = c0; v < c1; ++v) {
      const Index degree = off[v + 1] - off[v];
      const Index first = uniform ? v - c0 : off[v] - h0, stride = uniform ? count : 1;
      double fx = 0.0, fy = 0.0, fz = 0.0;
      for (Index a = 0; a < degree; ++a) {
        const size_t j = static_cast<size_t>(first + a * stride);
        fx += s.gx[j];
        fy += s.gy[j];
        fz += s.gz[j];
      }
      double* own = acc + 3 * (v - v0);
      own[0] += fx;
      own[1] += fy;
      own[2] += fz;
    }

    // Angle springs (section 5.2), centre by centre. Uniform chunks and runs of one degree
    // take the by-slot path, the others the general one; both do the same arithmetic and
    // deposit in vertex order, so the split changes nothing in the result.
    if (!chunkAngles) continue;
    if (uniform) {
      if (uniform < 2) continue;
      anyAngle = true;
      slotAngles(c0, count, uniform, ax, ay, az, il,
                 [&](Index i, Index a) { return h0 + a * count + i; });
      continue;
    }
    Index v = c0;
    while (v < c1) {
      if (kappaTheta[v] == 0.0) {
        ++v;
        continue;
      }
      const Index degree = off[v + 1] - off[v];
      Index u = v + 1;
      if (canonicalAngles_)
        while (u < c1 && kappaTheta[u] != 0.0 && off[u + 1] - off[u] == degree) ++u;
      else
        while (u < c1 && kappaTheta[u] != 0.0) ++u;
      if (angleOffsets[u] == angleOffsets[v]) {
        v = u;
        continue;
      }
      anyAngle = true;
      if (canonicalAngles_ && u - v >= kMinRun) {
        // A run: arms transposed to slot order.
        const Index run = u - v, base = off[v] - h0;
        for (Index i = 0; i < run; ++i)
          for (Index a = 0; a < degree; ++a) {
            const size_t from = static_cast<size_t>(base + degree * i + a);
            const size_t to = static_cast<size_t>(a * run + i);
            s.tx[to] = ax[from];
            s.ty[to] = ay[from];
            s.tz[to] = az[from];
            s.tl[to] = il[from];
          }
        slotAngles(v, run, degree, s.tx.data(), s.ty.data(), s.tz.data(), s.tl.data(),
                   [&](Index i, Index a) { return off[v + i] + a; });
      } else {
        // General path: a batch of the range's angles with their arms' indices.
        Index m = 0;
        for (Index w = v; w < u; ++w) {
          const Index first = angleOffsets[w], count = angleOffsets[w + 1] - first;
          if (canonicalAngles_) {
            const Index d = off[w + 1] - off[w], b = off[w] - h0;
            const Index* pa = pairA_.data() + pairStart_[static_cast<size_t>(d)];
            const Index* pb = pairB_.data() + pairStart_[static_cast<size_t>(d)];
            for (Index k = 0; k < count; ++k) {
              s.armP[static_cast<size_t>(m + k)] = b + pa[k];
              s.armQ[static_cast<size_t>(m + k)] = b + pb[k];
            }
          } else {
            for (Index k = 0; k < count; ++k) {
              s.armP[static_cast<size_t>(m + k)] =
                  angleArm_[2 * static_cast<size_t>(first + k)] - h0;
              s.armQ[static_cast<size_t>(m + k)] =
                  angleArm_[2 * static_cast<size_t>(first + k) + 1] - h0;
            }
          }
          for (Index k = 0; k < count; ++k)
            s.rest[static_cast<size_t>(m + k)] = restAngle[first + k];
          m += count;
        }
        angleCosSin(m, s.armP.data(), s.armQ.data(), ax, ay, az, s.cosine.data(), s.sine.data());
        const double smallest =
            angleForces(m, s.armP.data(), s.armQ.data(), ax, ay, az, il, s.sine.data(),
                        s.cosine.data(), s.rest.data(), s.fx.data(), s.fy.data(), s.fz.data(),
                        s.fx.data() + second, s.fy.data() + second, s.fz.data() + second, excess2);
        Index k0 = 0;
        for (Index w = v; w < u; ++w) {
          const Index d = off[w + 1] - off[w];
          const Index count = angleOffsets[w + 1] - angleOffsets[w];
          if (withEnergy) {
            double squares = 0.0;
            for (Index k = k0; k < k0 + count; ++k) squares += excess2[k];
            angularSum += 0.5 * kappaTheta[w] * squares;
          }
          auto slot = [&](Index a) { return off[w] + a; };
          auto sineOf = [&](Index k) { return s.sine[static_cast<size_t>(k0 + k)]; };
          auto armsOf = [&](Index k, Index& hp, Index& hq) {
            hp = s.armP[static_cast<size_t>(k0 + k)] + h0;
            hq = s.armQ[static_cast<size_t>(k0 + k)] + h0;
          };
          if (canonicalAngles_) {
            const Index* start = armTermStart_.data() + termStart_[static_cast<size_t>(d)];
            deposit(
                w, kappaTheta[w], slot,
                [&](Index a, double* f) {
                  f[0] = f[1] = f[2] = 0.0;
                  for (Index t = start[a]; t < start[a + 1]; ++t) {
                    const size_t at = static_cast<size_t>(k0 + armTerm_[static_cast<size_t>(t)]);
                    f[0] += s.fx[at];
                    f[1] += s.fy[at];
                    f[2] += s.fz[at];
                  }
                },
                !(smallest > 1e-12), sineOf, armsOf);
          } else {
            // Any table: sum each angle's two arm forces into its arms, in angle order.
            std::fill(s.tx.begin(), s.tx.begin() + d, 0.0);
            std::fill(s.ty.begin(), s.ty.begin() + d, 0.0);
            std::fill(s.tz.begin(), s.tz.begin() + d, 0.0);
            const Index b = off[w] - h0;
            for (Index k = k0; k < k0 + count; ++k) {
              const size_t at = static_cast<size_t>(k);
              const size_t i = static_cast<size_t>(s.armP[at] - b);
              const size_t j = static_cast<size_t>(s.armQ[at] - b);
              s.tx[i] += s.fx[at];
              s.ty[i] += s.fy[at];
              s.tz[i] += s.fz[at];
              s.tx[j] += s.fx[at + second];
              s.ty[j] += s.fy[at + second];
              s.tz[j] += s.fz[at + second];
            }
            deposit(
                w, kappaTheta[w], slot,
                [&](Index a, double* f) {
                  f[0] = s.tx[static_cast<size_t>(a)];
                  f[1] = s.ty[static_cast<size_t>(a)];
                  f[2] = s.tz[static_cast<size_t>(a)];
                },
                !(smallest > 1e-12), sineOf, armsOf);
          }
          k0 += count;
        }
      }
      v = u;
    }
  }
  std::copy(acc, acc + 3 * static_cast<size_t>(length), force.data() + 3 * static_cast<size_t>(v0));
  if (anyAngle)
    std::copy(acc + 3 * static_cast<size_t>(length),
              acc + 3 * static_cast<size_t>(length + haloLength),
              halo_.data() + 3 * static_cast<size_t>(haloBegin));
  blockHasAngles_[static_cast<size_t>(block)] = anyAngle ? 1 : 0;
  if (withEnergy) {
    blockEnergy_[2 * static_cast<size_t>(block)] = 0.5 * laneTotal(radialLanes);
    blockEnergy_[2 * static_cast<size_t>(block) + 1] = angularSum + laneTotal(angularLanes);
  }
}

void ForceKernel::radialOnlyBlock(const Model& model, const Points& position, Points& force,
                                  Index block, Scratch& s, bool withEnergy) {
  // The radial springs (section 5.1) of each edge once: its force on the first end,
  // kappa (l - lambda) / l (r_second - r_first), the gather path's rounding for rounding
  // (and minus it, exactly, on the second end). Each vertex adds its edges' forces in arm
  // order, as accumulateInternalForces does: bit-identical to the reference.
  const Index* off = model.mesh.vertexNeighborTable().offsets.data();
  const double* r = position.data();
  double* f = force.data();
  double* ax = s.ax.data();
  double* ay = s.ay.data();
  double* az = s.az.data();
  double* len = s.length.data();
  const double* gx = s.gx.data();
  const double* gy = s.gy.data();
  const double* gz = s.gz.data();
  double* energy = withEnergy ? s.energy.data() : nullptr;
  double radialLanes[kLanes] = {};  // each spring from both ends, as scatterBlock takes it
  for (Index g = blockGroup_[static_cast<size_t>(block)];
       g < blockGroup_[static_cast<size_t>(block) + 1]; ++g) {
    const Index e0 = groupEdgeStart_[static_cast<size_t>(g)];
    const Index count = groupEdgeStart_[static_cast<size_t>(g) + 1] - e0;
    edgeArms(count, groupFirst_.data() + e0, groupSecond_.data() + e0, r, ax, ay, az, len);
    radialOnlyBatch(count, groupEdge_.data() + e0, edgeKappa_.data(),
                    model.properties.restLength.data(), ax, ay, az, len, s.gx.data(), s.gy.data(),
                    s.gz.data(), energy);
    for (Index v = groupStart_[static_cast<size_t>(g)]; v < groupStart_[static_cast<size_t>(g) + 1];
         ++v) {
      double fx = 0.0, fy = 0.0, fz = 0.0;
      for (Index h = off[v]; h < off[v + 1]; ++h) {
        const Index slot = armSlot_[static_cast<size_t>(h)];
        if (slot >= 0) {
          const size_t j = static_cast<size_t>(slot);
          fx += gx[j];
          fy += gy[j];
          fz += gz[j];
        } else {
          const size_t j = static_cast<size_t>(~slot);
          fx -= gx[j];
          fy -= gy[j];
          fz -= gz[j];
        }
      }
      double* row = f + 3 * static_cast<size_t>(v);
      row[0] = fx;
      row[1] = fy;
      row[2] = fz;
    }
    if (!withEnergy) continue;
    const Index h0 = off[groupStart_[static_cast<size_t>(g)]];
    for (Index h = h0; h < off[groupStart_[static_cast<size_t>(g) + 1]]; ++h) {
      const Index slot = armSlot_[static_cast<size_t>(h)];
      radialLanes[(h - h0) % kLanes] += energy[slot >= 0 ? slot : ~slot];
    }
  }
  if (withEnergy) {
    blockEnergy_[2 * static_cast<size_t>(block)] = 0.5 * laneTotal(radialLanes);
    blockEnergy_[2 * static_cast<size_t>(block) + 1] = 0.0;
  }
}

PotentialEnergy ForceKernel::energy() const {
  PotentialEnergy total;
  for (size_t b = 0; b + 1 < blockEnergy_.size(); b += 2) {
    total.radial += blockEnergy_[b];
    total.angular += blockEnergy_[b + 1];
  }
  return total;
}

Index ForceKernel::uniformVertices() const {
  Index total = 0;
  for (size_t c = 0; c < chunkDegree_.size(); ++c)
    if (chunkDegree_[c]) total += chunkStart_[c + 1] - chunkStart_[c];
  return total;
}

void ForceKernel::gatherBlock(Index block, Points& force) const {
  if (reference_) return;
  const Index v0 = blockStart_[static_cast<size_t>(block)];
  double* f = force.data() + 3 * static_cast<size_t>(v0);
  for (Index k = incomingStart_[static_cast<size_t>(block)];
       k < incomingStart_[static_cast<size_t>(block) + 1]; ++k) {
    const size_t q = static_cast<size_t>(k);
    if (!blockHasAngles_[static_cast<size_t>(incomingBlock_[q])]) continue;
    double* row = f + 3 * static_cast<size_t>(incomingRow_[q]);
    const double* h = halo_.data() + 3 * static_cast<size_t>(incomingHalo_[q]);
    row[0] += h[0];
    row[1] += h[1];
    row[2] += h[2];
  }
}

}  // namespace zsculpt
