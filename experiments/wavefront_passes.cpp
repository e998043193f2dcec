// Would the drift filter's passes run faster as one sweep? (docs/performance.md, "Fifteenth
// session"). The drift of stepDriftFiltered is D + 1 passes over the rows, each a product
// with the sparse Omega^2 that needs the whole previous pass:
//
//   stage 0       v = v e + k                         (row-local)
//   stage 1..D-1  y_s = a_s v + s W y_{s-1}           (y_0 = v)
//   stage D       r += t (v + s W y_{D-1})
//
// On a mesh numbered so that neighbours are close (the builtin grid: at most one row of
// the grid apart), stage s of a block of rows needs stage s - 1 only on the blocks within
// that distance, so all stages can run as one wavefront: each thread walks its blocks and
// does stage s one lag behind stage s - 1, while the rows it needs are still in cache. That
// reads Omega^2, B, Omega^2 B, v and the y's from memory once instead of D times. (W's
// coefficients come from global sums over the previous pass; a real sweep would first have
// to move them out of the way, with bases Omega^{2j} B stored for j <= D.)
//
//   experiment_wavefront_passes SIDE THREADS BLOCK [D]
//
// The stages are the step's own row passes (filter_rows.h: velocity, horner, drift) with the
// coefficients held fixed. Times both forms on the builtin SIDE x SIDE grid (quads, Omega^2 from
// SystemMatrices; the torus would do the same work, but its wrap-around makes the first rows need
// the last), medians of 15 sweeps, and checks on one thread that the wavefront gives the passes'
// positions bit for bit. With two threads each takes half of the blocks and the seams between the
// halves are not synchronised: the timing favours the wavefront.
#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include "../src/physics/filter_rows.h"
#include "zsculpt/mesh/builtin.h"
#include "zsculpt/physics/matrices.h"

using namespace zsculpt;

namespace {

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 4) {
    std::fprintf(stderr, "usage: %s SIDE THREADS BLOCK [D]\n", argv[0]);
    return 2;
  }
  const Index side = std::atoi(argv[1]);
  const int threads = std::atoi(argv[2]);
  const Index block = std::atoi(argv[3]);
  const int degree = argc > 4 ? std::atoi(argv[4]) : 3;
  if (side < 3 || threads < 1 || block < 1 || degree < 1) {
    std::fprintf(stderr, "%s: SIDE >= 3, THREADS >= 1, BLOCK >= 1, D >= 1\n", argv[0]);
    return 2;
  }
  UniformProperties u;
  u.mass = 0.01;
  u.stiffness = 9.5;
  const Model model = Model::fromMesh(makeGrid(side), u);
  const SystemMatrices system(model);
  const SparseRowMatrix& o2 = system.omega2();
  const Index n = model.mesh.numVertices();
  const Index* outer = o2.outerIndexPtr();
  const Index* inner = o2.innerIndexPtr();
  const double* value = o2.valuePtr();
  // How far (in rows) a row's neighbours reach: the wavefront's lag.
  Index reach = 0;
  for (Index i = 0; i < n; ++i)
    for (Index p = outer[i]; p < outer[i + 1]; ++p) reach = std::max(reach, std::abs(inner[p] - i));
  const int stages = degree + 1;
  const size_t rows = static_cast<size_t>(n);
  // The step's own row kernels (src/physics/filter_rows.h), on made-up bases and
  // coefficients: the work per row is what matters here, not the values.
  std::vector<double> velocity(3 * rows), kick(3 * rows, 1e-4), damp(rows, 0.999);
  std::vector<double> position(3 * rows), basis(4 * rows, 0.25), omegaBasis(4 * rows, 0.5),
      massBases(8 * rows, 0.125), mass(rows, u.mass), coefficient(24, 1e-6);
  std::vector<std::vector<double>> y(static_cast<size_t>(std::max(degree - 1, 1)),
                                     std::vector<double>(3 * rows));
  const filter_rows::Kernels& kernels = filter_rows::kernels(true);
  const filter_rows::Inputs in{outer,
                               inner,
                               value,
                               basis.data(),
                               omegaBasis.data(),
                               massBases.data(),
                               mass.data(),
                               coefficient.data(),
                               damp.data()};
  const double t = 1e-3, t2 = 1e-4;
  auto reset = [&] {
    for (size_t k = 0; k < 3 * rows; ++k) {
      velocity[k] = 0.01 * static_cast<double>(k % 17);
      position[k] = static_cast<double>(k % 29);
    }
  };
  const Index blocks = (n + block - 1) / block;
  const Index lag = (reach + block - 1) / block + 1;
  // 24 sums per block, as the step's passes write them (unused: the coefficients are fixed).
  std::vector<double> partial(24 * static_cast<size_t>(blocks), 0.0);
  auto stageRows = [&](int stage, Index b, Index begin, Index end) {
    double* sums = partial.data() + 24 * static_cast<size_t>(b);
    if (stage == 0) {
      kernels.velocity(in, begin, end, velocity.data(), kick.data(), sums);
    } else if (stage < degree) {
      const double* from = stage == 1 ? velocity.data() : y[static_cast<size_t>(stage - 2)].data();
      kernels.horner(in, begin, end, from, velocity.data(),
                     y[static_cast<size_t>(stage - 1)].data(), 0.1 * stage, t2, sums);
    } else {
      const double* from =
          degree == 1 ? velocity.data() : y[static_cast<size_t>(degree - 2)].data();
      kernels.drift(in, begin, end, from, velocity.data(), position.data(), t, t2);
    }
  };
  auto passes = [&] {
#pragma omp parallel num_threads(threads)
    for (int stage = 0; stage < stages; ++stage) {
#pragma omp for schedule(static)
      for (Index b = 0; b < blocks; ++b)
        stageRows(stage, b, b * block, std::min(n, (b + 1) * block));
    }
  };
  auto wavefront = [&] {
#pragma omp parallel num_threads(threads)
    {
      const int count = omp_get_num_threads(), me = omp_get_thread_num();
      const Index b0 = blocks * me / count, b1 = blocks * (me + 1) / count;
      for (Index front = b0; front < b1 + (stages - 1) * lag; ++front)
        for (int stage = 0; stage < stages; ++stage) {
          const Index b = front - stage * lag;
          if (b >= b0 && b < b1) stageRows(stage, b, b * block, std::min(n, (b + 1) * block));
        }
    }
  };
  // One thread: the wavefront must give the passes' positions bit for bit.
  bool same = true;
  if (threads == 1) {
    reset();
    passes();
    const std::vector<double> expected = position;
    reset();
    wavefront();
    same = position == expected;
  }
  std::vector<double> timePasses, timeWavefront;
  reset();
  for (int r = 0; r < 15; ++r) {
    auto start = std::chrono::steady_clock::now();
    passes();
    timePasses.push_back(
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
    start = std::chrono::steady_clock::now();
    wavefront();
    timeWavefront.push_back(
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
  }
  const double p = median(timePasses), w = median(timeWavefront);
  std::printf(
      "grid %dx%d (%d rows, reach %d rows), %d threads, blocks of %d rows, lag %d blocks, "
      "%d stages: passes %.3f ms, wavefront %.3f ms, passes / wavefront %.2f%s\n",
      side, side, n, reach, threads, block, lag, stages, 1e3 * p, 1e3 * w, p / w,
      threads == 1 ? (same ? " (same bits)" : " (BITS DIFFER)") : "");
  return same ? 0 : 1;
}
