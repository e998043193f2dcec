// zsculpt bench [MESH|SCENE] [model flags] [--scheme S] [--steps N] [--threads T] [--json]
//               [--table1] [--scaling] [--roofline] [--peers] [--quick]
//
// Performance figures (docs/performance.md): for a model, the precompute time, the step
// time (median of repeats), vertex-steps per second and memory; --table1 the paper's four
// models beside Table 1's Init and Solv columns; --scaling tori from 1k to 1M vertices with
// radial and angle springs; --roofline a STREAM-style triad in the same run and the 1M
// step's effective bandwidth as a fraction of it; --peers the wall time of each scheme to
// simulate 10 s at a trajectory error of 1e-3.

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <functional>
#include <iomanip>
#include <iostream>
#include <limits>
#include <memory>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "commands.h"
#include "model_options.h"
#include "zsculpt/core/errors.h"
#include "zsculpt/mesh/builtin.h"
#include "zsculpt/physics/diagnostics.h"
#include "zsculpt/physics/matrices.h"
#include "zsculpt/physics/stepper.h"
#include "zsculpt/subdivision/subdivision.h"

namespace zsculpt::cli {

namespace {

// After a row shown as it comes: a reader that went away (`bench --scaling | head -3`) ends
// the run here, not minutes later (SIGPIPE is ignored: cli.cpp).
void checkShown() {
  if (std::cout.good()) return;
  const int error = errno;
  throw IOError(std::string("standard output: ") +
                (error != 0 ? std::strerror(error) : "the write failed"));
}

using Clock = std::chrono::steady_clock;

double since(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

double median(std::vector<double> values) {
  if (values.empty()) return 0.0;
  std::sort(values.begin(), values.end());
  const size_t n = values.size();
  return n % 2 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

// ---- memory (Linux /proc) -------------------------------------------------------------------

// VmRSS and VmHWM of this process, bytes (0 where /proc is unavailable).
struct Memory {
  double resident = 0.0, peak = 0.0;
};

Memory readMemory() {
  Memory m;
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line)) {
    auto value = [&](const char* key, double& out) {
      if (line.rfind(key, 0) == 0) out = 1024.0 * std::atof(line.c_str() + std::string(key).size());
    };
    value("VmRSS:", m.resident);
    value("VmHWM:", m.peak);
  }
  return m;
}

// Resets VmHWM to the current resident size (Linux 4.0+), so that the next peak is this
// model's own.
void resetPeak() {
  std::ofstream clear("/proc/self/clear_refs");
  clear << "5";
}

std::string loadAverage() {
  std::ifstream in("/proc/loadavg");
  std::string one;
  in >> one;
  return one.empty() ? "?" : one;
}

// ---- one model ------------------------------------------------------------------------------

struct Options {
  ModelOptions model;
  std::string scheme = "default";
  double dtRatio = 0.5;
  long steps = 0;
  int threads = 0;
  bool json = false, table1 = false, scaling = false, roofline = false, peers = false;
  bool quick = false;
  bool driftFilter = true;  // StepperOptions::driftFilter (the default scheme on braced models)
  bool drag = false;        // time the step under a load on one vertex, as while a user drags
};

struct ModelBench {
  std::string name;
  Index vertices = 0, edges = 0, angles = 0;
  std::string scheme;
  int threads = 1;
  double period = 0.0;
  double precompute = 0.0;      // Stepper construction: matrices, caches, work space
  double systemMatrices = 0.0;  // SystemMatrices alone
  double transformation = 0.0;  // TransformationMatrices alone (the paper's extra Init)
  double step = 0.0, stepMin = 0.0;
  double stepSerial = 0.0;  // the same with one thread (when asked)
  double residentPerVertex = 0.0, peakPerVertex = 0.0, stepperPerVertex = 0.0;
  double bytesPerStep = 0.0;  // compulsory traffic of the default step (roofline)
  long stepsTimed = 0;
  bool drag = false;      // timed under a load on one vertex
  int driftProducts = 0;  // products with W in the filtered drift (0: not filtered)
};

// Median seconds per step: blocks of k steps (k such that a block lasts >= 10 ms), repeats
// until `steps` steps or about `budget` seconds, at least 5 blocks.
std::pair<double, double> timeSteps(Stepper& stepper, State& state, const Points& external,
                                    long steps, double budget, long* stepsTimed) {
  auto start = Clock::now();
  stepper.step(state, external);
  stepper.step(state, external);
  const double first = std::max(1e-7, since(start) / 2.0);
  const long block = std::max(1L, static_cast<long>(std::ceil(0.01 / first)));
  long repeats = steps > 0 ? std::max(5L, steps / block)
                           : std::clamp(static_cast<long>(budget / (first * block)), 5L, 51L);
  std::vector<double> times;
  for (long r = 0; r < repeats; ++r) {
    start = Clock::now();
    for (long k = 0; k < block; ++k) stepper.step(state, external);
    times.push_back(since(start) / static_cast<double>(block));
  }
  if (stepsTimed) *stepsTimed = repeats * block;
  return {median(times), *std::min_element(times.begin(), times.end())};
}

// Bytes the default step must move at least: every array it reads or writes, once per pass
// that streams it, for the path bench times (zero loads, the first kick kept from the last
// step). Gathers of neighbours' rows through the CSR indices count once, as if every row
// came from the cache the second time; writes count once (no read for ownership). Each
// pass is listed as stepDefault and stepDriftFiltered run it (docs/performance.md,
// "Roofline").
double compulsoryBytes(const Model& model, const Stepper& stepper) {
  const double n = model.mesh.numVertices(), e = model.mesh.numEdges();
  const double nnz = static_cast<double>(stepper.system().omega2().nonZeros());
  const double perRow = 1.0 / std::max(1.0, n);  // a count over the model, per vertex
  const double point = 24, scalar = 8;
  const double csr = (nnz * 12 + 4 * n) * perRow;  // Omega^2: values, columns, row starts
  // The internal forces (ForceKernel::scatter, then gatherBlock): positions in, forces out;
  // per half-edge its neighbour, edge and target; per edge stiffness and rest length; per
  // vertex its offsets and angular stiffness; per angle spring its rest angle.
  double forces = point + point + (2.0 * e * 12 + 4 * n + e * 16) * perRow + scalar;
  if (model.properties.angularStiffness.maxCoeff() > 0.0)
    forces += (8.0 * static_cast<double>(model.angles.size()) + 4 * n) * perRow;
  const double zeroCheck = point;  // the external forces, read to see they are zero
  double perVertex = zeroCheck + forces;
  if (!stepper.filtersDrift()) {
    // (As where the step stores the accelerations, up to kStoredAccelerationVertices in
    // stepper.cpp; above, the kick makes them on the fly from the forces and inverse
    // masses: 48 bytes fewer.)
    perVertex += 2 * point + point + scalar + 2 * point;    // v = v e^{-GT/2} + kick, r += T v
    perVertex += point + scalar + point;                    // a = M^-1 f
    perVertex += csr + point + point + 2 * point + scalar;  // kick = half a - filter W a, v
    return perVertex * n;
  }
  const double bases = 4 * scalar + 4 * scalar;         // a row of B and of Omega^2 B
  const double massBases = 8 * scalar;                  // m_i B_i and m_i (Omega^2 B)_i
  perVertex += 2 * point + point + scalar + massBases;  // v = v e^{-GT/2} + kick, summed
  // The Horner passes, out = a v + s W u, each summing (Omega^2 B)^T M out: one fewer than
  // Psi's degree (driftProducts: 4 at 0.9 T_max, 2 at the bench's 0.5 T_max); the first
  // has u = v. Then r += T (v + T^2 W w), w = v at degree 1 (an array read once a pass).
  const int horner = stepper.driftProducts() - 1;
  perVertex += horner * (point + point + point + csr + bases + scalar) - (horner > 0 ? point : 0);
  perVertex += (horner > 0 ? point : 0) + point + 2 * point + csr + bases;
  perVertex += point + scalar + point + massBases;                // a = M^-1 f, summed
  perVertex += point + point + 2 * point + csr + bases + scalar;  // the last kick, v
  return perVertex * n;
}

ModelBench benchModel(const std::string& name, const std::function<Model()>& build, Scheme scheme,
                      double dtRatio, int threads, long steps, double budget, bool serialToo,
                      bool transformationToo, bool driftFilter, bool drag = false) {
  ModelBench b;
  b.name = name;
  b.scheme = std::string(schemeName(scheme));
  resetPeak();
  const Memory before = readMemory();
  const Model model = build();
  const Mesh& mesh = model.mesh;
  b.vertices = mesh.numVertices();
  b.edges = mesh.numEdges();
  b.angles = model.angles.size();
  const double tMax = criticalPeriod(SystemMatrices(model));
  b.period = dtRatio * (std::isfinite(tMax) ? tMax : 0.02);
  StepperOptions options;
  options.threads = threads;
  options.driftFilter = driftFilter;
  auto stepper = std::make_unique<Stepper>(model, scheme, b.period, options);
  b.threads = stepper->threads();
  State state = State::atRest(mesh);
  randomVelocity(model.properties.mass, 0.01, 1, state.velocity);
  // A drag (cli drag, the app's drag tool) is a load on one vertex: with it the step cannot
  // keep its first kick from the last step (stepper.cpp), so it takes the loaded path.
  Points external = Points::Zero(mesh.numVertices(), 3);
  b.drag = drag;
  if (drag && mesh.numVertices() > 0) external(0, 2) = 1e-3 * model.properties.mass[0];
  const auto [step, stepMin] = timeSteps(*stepper, state, external, steps, budget, &b.stepsTimed);
  b.step = step;
  b.stepMin = stepMin;
  const Memory after = readMemory();
  const double n = std::max<double>(1.0, b.vertices);
  b.residentPerVertex = (after.resident - before.resident) / n;
  b.peakPerVertex = (after.peak - before.resident) / n;
  b.stepperPerVertex = static_cast<double>(stepper->bytes()) / n;
  b.bytesPerStep = compulsoryBytes(model, *stepper);
  if (scheme == Scheme::Default && stepper->filtersDrift())
    b.driftProducts = stepper->driftProducts();
  stepper.reset();
  if (serialToo) {
    StepperOptions one = options;
    one.threads = 1;
    Stepper serial(model, scheme, b.period, one);
    b.stepSerial = timeSteps(serial, state, external, steps, budget, nullptr).first;
  }
  // Precompute: medians of repeated constructions (fewer for big models).
  const int repeats = b.vertices > 200000 ? 3 : b.vertices > 20000 ? 5 : 15;
  std::vector<double> pre, sys, tra;
  for (int r = 0; r < repeats; ++r) {
    auto start = Clock::now();
    { const Stepper s(model, scheme, b.period, options); }
    pre.push_back(since(start));
    start = Clock::now();
    const SystemMatrices system(model);
    sys.push_back(since(start));
    if (transformationToo) {
      start = Clock::now();
      const TransformationMatrices t(system, b.period);
      tra.push_back(since(start));
    }
  }
  b.precompute = median(pre);
  b.systemMatrices = median(sys);
  b.transformation = median(tra);
  return b;
}

Model uniformModel(Mesh mesh, double mass, double stiffness, double angular) {
  UniformProperties u;
  u.mass = mass;
  u.stiffness = stiffness;
  u.angularStiffness = angular;
  return Model::fromMesh(std::move(mesh), u);
}

Mesh torusII() {
  // Table 1: "the twice Doo-Sabin subdivided Torus-I", 1600 / 3200 / 1600.
  SubdivisionOptions sub;
  sub.levels = 2;
  Mesh mesh = subdivide(makeTorus(10, 10), sub);
  if (mesh.numVertices() != 1600 || mesh.numEdges() != 3200) mesh = makeTorus(40, 40);
  return mesh;
}

// ---- output helpers -------------------------------------------------------------------------

std::string num(double v) {
  return jsonNumber(v);
}

std::string modelJson(const ModelBench& b, const std::string& indent) {
  std::ostringstream o;
  o << indent << "{\"model\": " << jsonString(b.name) << ", \"vertices\": " << b.vertices
    << ", \"edges\": " << b.edges << ", \"angle_springs\": " << b.angles << ", \"scheme\": \""
    << b.scheme << "\", \"threads\": " << b.threads << ", \"dt\": " << num(b.period)
    << ", \"precompute_seconds\": " << num(b.precompute)
    << ", \"system_matrices_seconds\": " << num(b.systemMatrices);
  if (b.transformation > 0.0) o << ", \"transformation_seconds\": " << num(b.transformation);
  o << ", \"step_seconds\": " << num(b.step) << ", \"step_seconds_min\": " << num(b.stepMin)
    << ", \"steps_timed\": " << b.stepsTimed << ", \"steps_per_second\": " << num(1.0 / b.step)
    << ", \"vertex_steps_per_second\": " << num(b.vertices / b.step)
    << ", \"drag\": " << (b.drag ? "true" : "false") << ", \"drift_products\": " << b.driftProducts;
  if (b.stepSerial > 0.0)
    o << ", \"step_seconds_one_thread\": " << num(b.stepSerial)
      << ", \"thread_speedup\": " << num(b.stepSerial / b.step);
  o << ", \"peak_bytes_per_vertex\": " << num(b.peakPerVertex)
    << ", \"resident_bytes_per_vertex\": " << num(b.residentPerVertex)
    << ", \"stepper_bytes_per_vertex\": " << num(b.stepperPerVertex) << "}";
  return o.str();
}

void printModelHeader() {
  std::cout << std::left << std::setw(22) << "model" << std::right << std::setw(9) << "V"
            << std::setw(4) << "thr" << std::setw(12) << "precompute" << std::setw(12) << "step"
            << std::setw(11) << "steps/s" << std::setw(13) << "vertex-st/s" << std::setw(11)
            << "peak B/V" << std::setw(10) << "held B/V"
            << "\n";
}

void printModelRow(const ModelBench& b) {
  std::cout << std::left << std::setw(22) << b.name << std::right << std::setw(9) << b.vertices
            << std::setw(4) << b.threads << std::setw(12) << std::setprecision(4) << b.precompute
            << std::setw(12) << b.step << std::setw(11) << std::setprecision(5) << 1.0 / b.step
            << std::setw(13) << std::setprecision(4) << b.vertices / b.step << std::setw(11)
            << std::setprecision(4) << b.peakPerVertex << std::setw(10) << b.residentPerVertex;
  if (b.stepSerial > 0.0)
    std::cout << "   (1 thread " << std::setprecision(4) << b.stepSerial << " s, x"
              << std::setprecision(3) << b.stepSerial / b.step << ")";
  std::cout << std::endl;  // the scaling series runs for minutes: each row as it comes
  checkShown();
}

// ---- --table1 ---------------------------------------------------------------------------------

struct PaperRow {
  const char* name;
  double mu, kappa, init, solv;
};
// Table 1 as printed (Pentium II 450 MHz).
constexpr PaperRow kPaper[] = {
    {"Dodecahedron", 0.50, 5.00, 0.097, 0.013},
    {"Torus-I", 0.10, 5.00, 0.281, 0.036},
    {"Open surface", 0.31, 5.16, 0.842, 0.085},
    {"Torus-II", 0.01, 9.50, 9.723, 0.393},
};

std::string runTable1(const Options& o) {
  std::ostringstream json;
  json << "  \"table1\": [\n";
  if (!o.json) {
    std::cout << "Table 1 (paper: Pentium II 450 MHz; ours: medians, this machine)\n"
              << std::left << std::setw(14) << "model" << std::right << std::setw(6) << "V"
              << std::setw(11) << "Init" << std::setw(11) << "paper" << std::setw(10) << "ratio"
              << std::setw(11) << "Solv eq.3" << std::setw(11) << "default" << std::setw(9)
              << "paper" << std::setw(10) << "ratio"
              << "\n";
  }
  for (int k = 0; k < 4; ++k) {
    const PaperRow& row = kPaper[k];
    auto build = [k, &row]() {
      Mesh meshes[] = {makeDodecahedron(), makeTorus(10, 10), makeGrid(18), Mesh()};
      Mesh mesh = k == 3 ? torusII() : meshes[k];
      return uniformModel(std::move(mesh), row.mu, row.kappa, 0.0);
    };
    const double budget = o.quick ? 0.05 : 0.5;
    const ModelBench paper = benchModel(row.name, build, Scheme::Paper, 0.5, o.threads, o.steps,
                                        budget, false, true, o.driftFilter);
    const ModelBench ours = benchModel(row.name, build, Scheme::Default, 0.5, o.threads, o.steps,
                                       budget, false, false, o.driftFilter);
    // The paper's Init: Omega^2, Omega^4, H, H', H'' (section 6), i.e. both matrix sets.
    const double init = paper.systemMatrices + paper.transformation;
    if (o.json) {
      json << "    {\"model\": " << jsonString(row.name) << ", \"vertices\": " << paper.vertices
           << ", \"edges\": " << paper.edges << ", \"init_seconds\": " << num(init)
           << ", \"paper_init_seconds\": " << num(row.init)
           << ", \"init_ratio\": " << num(row.init / init)
           << ", \"solv_paper_scheme_seconds\": " << num(paper.step)
           << ", \"solv_default_seconds\": " << num(ours.step)
           << ", \"paper_solv_seconds\": " << num(row.solv)
           << ", \"solv_ratio\": " << num(row.solv / paper.step)
           << ", \"solv_ratio_default\": " << num(row.solv / ours.step)
           << ", \"default_precompute_seconds\": " << num(ours.precompute) << "}"
           << (k < 3 ? ",\n" : "\n");
    } else {
      std::cout << std::left << std::setw(14) << row.name << std::right << std::setw(6)
                << paper.vertices << std::setw(11) << std::setprecision(3) << init << std::setw(11)
                << row.init << std::setw(10) << std::setprecision(4) << row.init / init
                << std::setw(11) << std::setprecision(3) << paper.step << std::setw(11) << ours.step
                << std::setw(9) << row.solv << std::setw(10) << std::setprecision(4)
                << row.solv / paper.step << "\n";
    }
  }
  if (!o.json)
    std::cout << "(Init: SystemMatrices + TransformationMatrices, the paper's precompute; Solv: "
                 "one step of equation 3 (paper scheme) and of the default scheme; ratio = "
                 "paper / ours, for equation 3)\n";
  json << "  ]";
  return json.str();
}

// ---- --scaling --------------------------------------------------------------------------------

std::vector<ModelBench> runScaling(const Options& o, std::ostringstream& json) {
  const double mass = o.model.mass.value_or(0.01);
  const double stiffness = o.model.stiffness.value_or(9.5);
  const double angular = o.model.angularStiffness.value_or(0.05);
  const std::vector<Index> sides =
      o.quick ? std::vector<Index>{32, 100} : std::vector<Index>{32, 100, 316, 1000};
  std::vector<ModelBench> rows;
  if (!o.json) {
    std::cout << "Scaling: tori U x U, mu " << mass << ", kappa " << stiffness << ", kappa_theta "
              << angular << " (radial and angle springs), scheme " << o.scheme << "\n";
    printModelHeader();
  }
  json << "  \"scaling\": [\n";
  for (size_t k = 0; k < sides.size(); ++k) {
    const Index u = sides[k];
    const std::string name = "torus " + std::to_string(u) + "x" + std::to_string(u);
    auto build = [=]() { return uniformModel(makeTorus(u, u), mass, stiffness, angular); };
    const ModelBench b = benchModel(name, build, schemeOption(o.scheme), o.dtRatio, o.threads,
                                    o.steps, o.quick ? 0.2 : 2.0, true, false, o.driftFilter);
    rows.push_back(b);
    if (!o.json) printModelRow(b);
    json << modelJson(b, "    ") << (k + 1 < sides.size() ? ",\n" : "\n");
  }
  json << "  ]";
  return rows;
}

// ---- --roofline -------------------------------------------------------------------------------

// STREAM's triad a = b + s c over arrays much larger than the last-level cache, best of
// several passes, on `threads` threads (each its own contiguous part, touched first by the
// thread that uses it). Bytes counted as STREAM does: 3 x 8 per element.
double triadBandwidth(size_t elements, int threads, int passes) {
  std::vector<double> a(elements), b(elements), c(elements);
  auto parallel = [&](auto&& body) {
    std::vector<std::thread> team;
    for (int t = 0; t < threads; ++t)
      team.emplace_back([&, t]() {
        const size_t begin = elements * static_cast<size_t>(t) / static_cast<size_t>(threads);
        const size_t end = elements * static_cast<size_t>(t + 1) / static_cast<size_t>(threads);
        body(begin, end);
      });
    for (std::thread& t : team) t.join();
  };
  parallel([&](size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i) {
      a[i] = 0.0;
      b[i] = 1.0;
      c[i] = 2.0;
    }
  });
  double best = 0.0;
  const double s = 3.0;
  for (int p = 0; p < passes; ++p) {
    const auto start = Clock::now();
    parallel([&](size_t begin, size_t end) {
      double* __restrict x = a.data();
      const double* __restrict y = b.data();
      const double* __restrict z = c.data();
      for (size_t i = begin; i < end; ++i) x[i] = y[i] + s * z[i];
    });
    best = std::max(best, 24.0 * static_cast<double>(elements) / since(start));
  }
  if (!(a[elements / 2] == 7.0)) throw SolverError("bench: triad check failed");
  return best;
}

std::string runRoofline(const Options& o) {
  const int threads = o.threads > 0 ? o.threads : automaticThreads(1000000);
  // 3 arrays of 64 Mi doubles: 1.5 GiB, several times any last-level cache.
  const size_t elements = o.quick ? (size_t{1} << 22) : (size_t{1} << 26);
  const double triad = triadBandwidth(elements, threads, o.quick ? 3 : 10);
  const double triadOne = triadBandwidth(elements, 1, o.quick ? 2 : 5);
  const Index side = o.quick ? 100 : 1000;
  const double angular = o.model.angularStiffness.value_or(0.05);
  auto build = [=]() { return uniformModel(makeTorus(side, side), 0.01, 9.5, angular); };
  const ModelBench b = benchModel("torus " + std::to_string(side) + "x" + std::to_string(side),
                                  build, Scheme::Default, o.dtRatio, o.threads, o.steps,
                                  o.quick ? 0.2 : 3.0, false, false, o.driftFilter);
  const double effective = b.bytesPerStep / b.step;
  if (!o.json) {
    std::cout << "Roofline: triad " << std::setprecision(4) << triad / 1e9 << " GB/s with "
              << threads << " threads (" << triadOne / 1e9 << " GB/s with one); default step of "
              << b.name << " (" << b.vertices << " vertices, angle springs on): " << b.step
              << " s, moves at least " << b.bytesPerStep / 1e6 << " MB: " << effective / 1e9
              << " GB/s = " << std::setprecision(3) << effective / triad
              << " of the triad bandwidth\n";
  }
  std::ostringstream json;
  json << "  \"roofline\": {\"triad_bytes_per_second\": " << num(triad)
       << ", \"triad_bytes_per_second_one_thread\": " << num(triadOne)
       << ", \"triad_array_bytes\": " << num(8.0 * static_cast<double>(elements))
       << ", \"threads\": " << threads << ", \"model\": " << jsonString(b.name)
       << ", \"vertices\": " << b.vertices << ", \"step_seconds\": " << num(b.step)
       << ", \"step_bytes\": " << num(b.bytesPerStep)
       << ", \"step_bytes_per_second\": " << num(effective)
       << ", \"fraction_of_triad\": " << num(effective / triad) << "}";
  return json.str();
}

// ---- --peers ----------------------------------------------------------------------------------

struct Trajectory {
  std::vector<Points> samples;
  double seconds = 0.0;
  long steps = 0;
  bool finite = true;
};

// Simulates `horizon` seconds at period interval / k from `start`, sampling the positions
// every `interval` seconds.
Trajectory simulateTrajectory(const Model& model, Scheme scheme, const State& start,
                              double interval, long k, double horizon, int threads,
                              bool driftFilter) {
  Trajectory t;
  StepperOptions options;
  options.threads = threads;
  options.driftFilter = driftFilter;
  const double period = interval / static_cast<double>(k);
  Stepper stepper(model, scheme, period, options);
  State s = start;
  const Points external = Points::Zero(model.mesh.numVertices(), 3);
  const long samples = std::lround(horizon / interval);
  const auto begin = Clock::now();
  for (long q = 0; q < samples && t.finite; ++q) {
    for (long i = 0; i < k; ++i) stepper.step(s, external);
    t.steps += k;
    t.finite = s.position.allFinite();
    t.samples.push_back(s.position);
  }
  t.seconds = since(begin);
  return t;
}

// max over samples of the RMS distance to the reference, over the max RMS displacement of
// the reference from the rest shape.
double trajectoryError(const Trajectory& t, const Trajectory& reference, const Points& rest) {
  if (!t.finite || t.samples.size() != reference.samples.size())
    return std::numeric_limits<double>::infinity();
  double error = 0.0, motion = 0.0;
  const double n = static_cast<double>(rest.rows());
  for (size_t q = 0; q < t.samples.size(); ++q) {
    error = std::max(error, std::sqrt((t.samples[q] - reference.samples[q]).squaredNorm() / n));
    motion = std::max(motion, std::sqrt((reference.samples[q] - rest).squaredNorm() / n));
  }
  return error / motion;
}

struct PeerResult {
  std::string model, scheme;
  Index vertices = 0;
  double dt = 0.0, tMax = 0.0, error = 0.0, seconds = 0.0, stepSeconds = 0.0;
  double referenceError = 0.0, stableLimit = 0.0;
  // Wall time for the horizon at 0.95 of the stable limit, whatever the error there (what
  // an interactive session runs at): the steps that takes times the time per step measured.
  double stableStepSeconds = 0.0;
  long steps = 0;
  bool reached = true;
  std::string note;
};

// The initial state of a peers run: a poke (a smooth bump of velocity along z, 0.05 m/s at
// vertex 0, width an eighth of the model's extent), what a drag gives the surface. A
// per-vertex random velocity instead fills the highest modes, whose phase every explicit
// scheme gets wrong at its stable step; there, default and symplectic Euler both need
// about a sixteenth of it (docs/performance.md, "Peers").
State peersStart(const Model& model) {
  State start = State::atRest(model.mesh);
  const Points& rest = model.mesh.positions();
  const double extent = (rest.colwise().maxCoeff() - rest.colwise().minCoeff()).maxCoeff();
  pokeVelocity(model.properties.mass, rest, 0, extent / 8.0, 0.05, Vec3(0.0, 0.0, 1.0),
               start.velocity);
  return start;
}

std::vector<PeerResult> runPeersOn(const std::string& name, const Model& model, const Options& o,
                                   double horizon, double interval, double budget) {
  const double target = 1e-3;
  const Points& rest = model.mesh.positions();
  const State start = peersStart(model);
  const SystemMatrices system(model);
  const double tMax = criticalPeriod(system);
  const double lambda = largestEigenvalue(system);
  // The reference: the default scheme, from a sixteenth of its stable step, halved until
  // its own error (a second-order scheme's: a third of the change on halving) is a tenth
  // of the target, or the budget is spent.
  long kRef =
      static_cast<long>(std::ceil(interval / (stablePeriodLimit(Scheme::Default, lambda) / 16.0)));
  Trajectory reference = simulateTrajectory(model, Scheme::Default, start, interval, kRef, horizon,
                                            o.threads, o.driftFilter);
  double referenceSpent = reference.seconds, referenceError = 0.0;
  for (;;) {
    Trajectory finer = simulateTrajectory(model, Scheme::Default, start, interval, 2 * kRef,
                                          horizon, o.threads, o.driftFilter);
    referenceSpent += finer.seconds;
    referenceError = trajectoryError(reference, finer, rest) / 3.0;
    reference = std::move(finer);
    kRef *= 2;
    if (referenceError <= target / 10.0 || referenceSpent + 2.0 * reference.seconds > budget) break;
  }
  if (!o.json)
    std::cout << name << " (" << model.mesh.numVertices() << " vertices, T_max " << tMax
              << " s): reference = default at dt " << interval / static_cast<double>(kRef)
              << " s, its own error estimate " << std::setprecision(3) << referenceError
              << (referenceError <= target / 10.0 ? "" : " (NOT converged within the budget)")
              << std::endl;
  checkShown();
  std::vector<PeerResult> results;
  for (Scheme scheme :
       {Scheme::Default, Scheme::Paper, Scheme::SymplecticEuler, Scheme::ImplicitEuler}) {
    PeerResult r;
    r.model = name;
    r.scheme = std::string(schemeName(scheme));
    r.vertices = model.mesh.numVertices();
    r.tMax = tMax;
    r.referenceError = referenceError;
    const double limit = stablePeriodLimit(scheme, system, lambda);
    r.stableLimit = limit;
    // Explicit schemes start at 0.95 of their stable limit; implicit Euler, which has none,
    // at the default's (from a whole sample interval it spent the 100k torus's budget on
    // two tries: conjugate gradients need hundreds of iterations at 15 T_max).
    const double first =
        0.95 * (std::isfinite(limit) ? limit : stablePeriodLimit(Scheme::Default, lambda));
    long k = std::max(1L, static_cast<long>(std::ceil(interval / first)));
    double spent = 0.0, perStep = 0.0;
    // Never a step beyond the stable limit, even where a run this short would pass with it:
    // a longer one, or one with other initial conditions, would blow up.
    long pass = 0, fail = std::isfinite(limit) ? k - 1 : 0, lastTried = 0;
    double lastError = std::numeric_limits<double>::infinity();
    Trajectory best;
    auto attempt = [&](long kk) {
      const Trajectory t =
          simulateTrajectory(model, scheme, start, interval, kk, horizon, o.threads, o.driftFilter);
      spent += t.seconds;
      perStep = t.seconds / static_cast<double>(std::max(1L, t.steps));
      const double e = trajectoryError(t, reference, rest);
      if (e <= target && (pass == 0 || kk < pass)) {
        pass = kk;
        best = t;
        r.error = e;
      }
      if (e > target) {
        fail = std::max(fail, kk);
        if (kk >= lastTried) {
          lastTried = kk;
          lastError = e;
        }
      }
      return e;
    };
    auto affordable = [&](long kk) {
      const double steps = static_cast<double>(kk) * horizon / interval;
      return perStep == 0.0 || spent + perStep * steps <= budget;
    };
    // Halve the step until the error is met, then bisect between the last failure and the
    // first success.
    while (affordable(k) && attempt(k) > target) k *= 2;
    if (pass > 0)
      while (pass - fail > 1 && pass > 1) {
        const long mid = std::max(fail + 1, (fail + pass) / 2);
        if (!affordable(mid)) break;
        attempt(mid);
      }
    r.stepSeconds = perStep;
    r.stableStepSeconds = std::isfinite(limit)
                              ? perStep * std::ceil(horizon / interval) *
                                    std::max(1.0, std::ceil(interval / (0.95 * limit)))
                              : std::numeric_limits<double>::quiet_NaN();
    if (pass > 0) {
      r.dt = interval / static_cast<double>(pass);
      r.steps = best.steps;
      r.seconds = best.seconds;
    } else {
      // Not reached: say so, with the finest step tried and its error, and the time spent
      // as a lower bound. (Extrapolating error ~ dt^p from two misses gave absurd times
      // whenever p came out small.)
      r.reached = false;
      r.dt = lastTried > 0 ? interval / static_cast<double>(lastTried) : 0.0;
      r.error = lastError;
      r.steps = static_cast<long>(static_cast<double>(lastTried) * horizon / interval);
      r.seconds = spent;
      std::ostringstream note;
      note << "not reached within the " << budget << " s budget";
      if (!std::isfinite(lastError)) note << ": diverged at every step tried";
      r.note = note.str();
    }
    results.push_back(r);
    if (!o.json) {
      std::cout << "  " << std::left << std::setw(17) << r.scheme << std::right << " dt "
                << std::setw(10) << std::setprecision(4) << r.dt << " (" << std::setw(6)
                << std::setprecision(3) << r.dt / tMax << " T_max)  steps " << std::setw(8)
                << r.steps << "  error " << std::setw(9) << std::setprecision(3) << r.error
                << "  wall " << (r.reached ? " " : ">") << std::setw(9) << std::setprecision(4)
                << r.seconds << " s";
      if (std::isfinite(r.stableStepSeconds))
        std::cout << "  (at 0.95 of its stable step: " << std::setprecision(3)
                  << r.stableStepSeconds << " s)";
      if (!r.note.empty()) std::cout << "  [" << r.note << "]";
      std::cout << std::endl;  // a long run: show each row as it comes
      checkShown();
    }
  }
  return results;
}

std::string runPeers(const Options& o) {
  const double horizon = o.quick ? 1.0 : 10.0;
  const double interval = o.quick ? 0.25 : 0.5;
  const double budget = o.quick ? 5.0 : 240.0;
  if (!o.json)
    std::cout << "Peers: wall time to simulate " << horizon
              << " s at a trajectory error of 1e-3 (RMS distance to the reference over the "
                 "RMS motion, worst sample every "
              << interval
              << " s), from the same poke (0.05 m/s along z at vertex 0, Gaussian of width an "
                 "eighth of the model)\n";
  std::vector<PeerResult> all;
  {
    const Model m = uniformModel(torusII(), 0.01, 9.5, 0.0);
    const auto r = runPeersOn("Torus-II", m, o, horizon, interval, budget);
    all.insert(all.end(), r.begin(), r.end());
  }
  {
    // A bigger object at Torus-II's resolution: the torus scaled so that its mean edge is
    // Torus-II's. Unscaled, its edges would be 8 times shorter, its angle springs 64 times
    // stiffer per unit length and T_max 6 times smaller (0.0069 s): 10 s of it would be a
    // reference of hours on this machine.
    const Index side = o.quick ? 40 : 316;
    Mesh torus = makeTorus(side, side);
    torus.setPositions(torus.positions() * (torusII().meanEdgeLength() / torus.meanEdgeLength()));
    const Model m = uniformModel(std::move(torus), 0.01, 9.5, 0.01);
    const auto r = runPeersOn("torus " + std::to_string(side) + "x" + std::to_string(side), m, o,
                              horizon, interval, budget);
    all.insert(all.end(), r.begin(), r.end());
  }
  std::ostringstream json;
  json << "  \"peers\": [\n";
  for (size_t k = 0; k < all.size(); ++k) {
    const PeerResult& r = all[k];
    json << "    {\"model\": " << jsonString(r.model) << ", \"vertices\": " << r.vertices
         << ", \"scheme\": \"" << r.scheme << "\", \"dt\": " << num(r.dt)
         << ", \"dt_over_t_max\": " << num(r.dt / r.tMax)
         << ", \"stable_limit\": " << num(r.stableLimit) << ", \"steps\": " << r.steps
         << ", \"error\": " << num(r.error) << ", \"wall_seconds\": " << num(r.seconds)
         << ", \"step_seconds\": " << num(r.stepSeconds)
         << ", \"wall_seconds_at_stable_step\": " << num(r.stableStepSeconds)
         << ", \"reference_error\": " << num(r.referenceError)
         << ", \"reached\": " << (r.reached ? "true" : "false") << "}"
         << (k + 1 < all.size() ? ",\n" : "\n");
  }
  json << "  ]";
  return json.str();
}

// ---- the command ------------------------------------------------------------------------------

int runBench(const Options& o) {
  std::vector<std::string> sections;
  const bool anySection = o.table1 || o.scaling || o.roofline || o.peers;
  if (!o.json)
    std::cout << "(load average " << loadAverage() << "; times are medians of repeats)\n";
  if (!o.model.source.empty() || !anySection) {
    const Scheme scheme = schemeOption(o.scheme);
    std::string name = o.model.source.empty() ? "Torus-II" : o.model.source;
    std::function<Model()> build;
    if (o.model.source.empty())
      build = [&o]() {
        return uniformModel(torusII(), o.model.mass.value_or(0.01), o.model.stiffness.value_or(9.5),
                            o.model.angularStiffness.value_or(0.0));
      };
    else
      build = [&o]() { return o.model.load().model; };
    const ModelBench b =
        benchModel(name, build, scheme, o.dtRatio, o.threads, o.steps, o.quick ? 0.2 : 2.0, true,
                   scheme == Scheme::Paper, o.driftFilter, o.drag);
    if (o.json) {
      sections.push_back("  \"model\": " + modelJson(b, ""));
    } else {
      std::cout << "scheme " << b.scheme << ", dt " << b.period << " s"
                << (b.drag ? ", under a drag (a load on one vertex)" : "") << "\n";
      printModelHeader();
      printModelRow(b);
      std::cout << "(precompute: building the stepper (matrices, force caches, work space); "
                   "SystemMatrices alone "
                << b.systemMatrices << " s";
      if (b.transformation > 0.0)
        std::cout << ", TransformationMatrices " << b.transformation << " s";
      std::cout << "; peak B/V: peak resident growth per vertex while loading and stepping; "
                   "held B/V: what stays resident; the stepper's own share "
                << std::setprecision(4) << b.stepperPerVertex << " B/V)\n";
    }
  }
  if (o.table1) sections.push_back(runTable1(o));
  if (o.scaling) {
    std::ostringstream json;
    runScaling(o, json);
    sections.push_back(json.str());
  }
  if (o.roofline) sections.push_back(runRoofline(o));
  if (o.peers) sections.push_back(runPeers(o));
  if (o.json) {
    std::cout << "{\n  \"load_average\": " << loadAverage() << ",\n";
    for (size_t k = 0; k < sections.size(); ++k)
      std::cout << sections[k] << (k + 1 < sections.size() ? ",\n" : "\n");
    std::cout << "}\n";
  }
  return 0;
}

}  // namespace

void addBenchCommand(CLI::App& root, CommandList& commands) {
  auto* app = root.add_subcommand(
      "bench", "performance figures: precompute, step, memory; Table 1, scaling, roofline, peers");
  auto o = std::make_shared<Options>();
  o->model.addTo(app, true);
  app->add_option("--scheme", o->scheme,
                  "default | paper | exact | symplectic-euler | implicit-euler (default: default)");
  app->add_option("--dt-ratio", o->dtRatio, "time step as a fraction of T_max (default 0.5)")
      ->check(CLI::Validator(
          [](std::string& text) -> std::string {
            const double value = std::strtod(text.c_str(), nullptr);
            return value > 0.0 && std::isfinite(value) ? "" : "must be a positive, finite number";
          },
          ""));
  app->add_option("--steps", o->steps,
                  "steps to time (default, or 0: about 2 s worth, at least 5 blocks)")
      ->check(CLI::Validator(
          [](std::string& text) -> std::string {
            const double value = std::strtod(text.c_str(), nullptr);
            return value >= 0.0 ? "" : "must be a whole number of steps, 0 or more";
          },
          ""));
  app->add_option("--threads", o->threads, "threads for the step (default: automatic)")
      ->check(CLI::Range(0, kMaxThreads));
  app->add_flag("--json", o->json, "a JSON summary on standard output");
  app->add_flag("--table1", o->table1, "the paper's four models beside Table 1's Init and Solv");
  app->add_flag("--scaling", o->scaling,
                "tori 32^2 .. 1000^2 (1k to 1M vertices) with radial and angle springs");
  app->add_flag("--roofline", o->roofline,
                "STREAM triad bandwidth and the 1M-vertex step's effective bandwidth");
  app->add_flag("--peers", o->peers,
                "wall time of each scheme to simulate 10 s at a trajectory error of 1e-3");
  app->add_flag("--quick", o->quick, "smaller models and shorter runs (for tests)");
  app->add_flag("--drag", o->drag,
                "one model: time the step under a load on one vertex, as while a user drags");
  // Two callbacks, not CLI11's "!" negation, whose help shows "{false}" after the names.
  auto* driftOn = app->add_flag_callback(
      "--drift-filter", [o] { o->driftFilter = true; },
      "default scheme on braced models: filter the drift too (the default; "
      "docs/solver.md, section 6)");
  app->add_flag_callback(
         "--no-drift-filter", [o] { o->driftFilter = false; },
         "default scheme: the kick filter alone")
      ->excludes(driftOn);
  commands.push_back({app, [o]() { return runBench(*o); }});
}

}  // namespace zsculpt::cli
