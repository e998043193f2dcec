// Subdivision: a frame's refresh (one sparse product of new control positions), the
// per-frame best-plane normals, and the stencil build that happens once per topology.
// The target: refreshing two levels of a 100k-face surface in under 5 ms.
//
//   zsculpt_benchmarks --benchmark_filter=Subdivision --benchmark_repetitions=5
//       --benchmark_report_aggregates_only=true    (one command line)
// Argument: U for builtin:torus:U:U (316: 99 856 control faces, 1.6 M refined faces;
// 79: 6 241 control faces, 99 856 refined faces).

#include <benchmark/benchmark.h>

#include <random>

#include "zsculpt/mesh/builtin.h"
#include "zsculpt/subdivision/subdivision.h"

namespace {

using namespace zsculpt;

/// Two sets of control positions to alternate between, so every refresh reads new input.
std::array<Points, 2> controlFrames(const Mesh& mesh) {
  std::mt19937 rng(1);
  std::normal_distribution<double> noise(0.0, 1e-3);
  std::array<Points, 2> frames{mesh.positions(), mesh.positions()};
  for (Index i = 0; i < frames[1].rows(); ++i)
    for (int k = 0; k < 3; ++k) frames[1](i, k) += noise(rng);
  return frames;
}

void setCounters(benchmark::State& state, const Mesh& mesh, const SubdivisionStencil& s) {
  state.counters["control_faces"] = static_cast<double>(mesh.numFaces());
  state.counters["refined_vertices"] = static_cast<double>(s.numRefinedVertices());
  state.counters["refined_faces"] = static_cast<double>(s.refinedFaces().rows());
  state.counters["stencil_nnz"] = static_cast<double>(s.matrix().nonZeros());
}

void BM_SubdivisionRefresh(benchmark::State& state) {
  const Index u = static_cast<Index>(state.range(0));
  const Mesh mesh = makeTorus(u, u);
  const SubdivisionStencil stencil(mesh, SubdivisionOptions{});  // 2 levels, interpolating
  const auto frames = controlFrames(mesh);
  Points refined(stencil.numRefinedVertices(), 3);
  size_t frame = 0;
  for (auto _ : state) {
    stencil.apply(frames[frame++ & 1], refined);
    benchmark::DoNotOptimize(refined.data());
    benchmark::ClobberMemory();
  }
  setCounters(state, mesh, stencil);
}
BENCHMARK(BM_SubdivisionRefresh)->Arg(79)->Arg(316)->Unit(benchmark::kMillisecond);

void BM_SubdivisionNormals(benchmark::State& state) {
  const Index u = static_cast<Index>(state.range(0));
  const Mesh mesh = makeTorus(u, u);
  const SubdivisionStencil stencil(mesh, SubdivisionOptions{});
  Points refined(stencil.numRefinedVertices(), 3);
  stencil.apply(mesh.positions(), refined);
  Points normals(stencil.numRefinedVertices(), 3);
  for (auto _ : state) {
    stencil.refinedNormals(refined, normals);
    benchmark::DoNotOptimize(normals.data());
    benchmark::ClobberMemory();
  }
  setCounters(state, mesh, stencil);
}
BENCHMARK(BM_SubdivisionNormals)->Arg(79)->Arg(316)->Unit(benchmark::kMillisecond);

void BM_SubdivisionStencilBuild(benchmark::State& state) {
  const Index u = static_cast<Index>(state.range(0));
  const bool withMass = state.range(1) != 0;
  const Mesh mesh = makeTorus(u, u);
  VectorX mass = VectorX::Constant(mesh.numVertices(), 0.5);
  SubdivisionOptions options;
  if (withMass) options.mass = &mass;
  for (auto _ : state) {
    SubdivisionStencil stencil(mesh, options);
    benchmark::DoNotOptimize(stencil.matrix().valuePtr());
  }
  const SubdivisionStencil stencil(mesh, options);
  setCounters(state, mesh, stencil);
}
BENCHMARK(BM_SubdivisionStencilBuild)
    ->Args({79, 0})
    ->Args({316, 0})
    ->Args({316, 1})
    ->Unit(benchmark::kMillisecond);

}  // namespace
