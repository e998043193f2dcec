#pragma once
// Built-in models (see ../shared/notes/cli.md and docs/scene-format.md). Vertex order is
// part of the contract: scripts pin and push vertices by index.

#include <string>
#include <string_view>

#include "zsculpt/mesh/mesh.h"

namespace zsculpt {

/// Regular dodecahedron, edge length 1, centred at the origin: 20 / 30 / 12 (Table 1).
Mesh makeDodecahedron();
/// U x V quads, major radius 2, minor radius 1, axis z. Vertex (u, v) is u + U v at
/// angle 2 pi u / U around the axis and 2 pi v / V around the tube; faces face outwards.
Mesh makeTorus(Index u = 10, Index v = 10);
/// N x N vertices at (i, j, 0), vertex (i, j) is i + N j; (N-1)^2 quads facing +z.
Mesh makeGrid(Index n = 18);
/// A curve: N vertices on a helix of radius 1 (16 vertices per turn, pitch 1), N-1 edges.
Mesh makeHelix(Index n = 64);
/// A solid: N^3 unit-spaced vertices, vertex (i, j, k) is i + N j + N^2 k; all 3N^2(N-1)
/// lattice edges (interior ones included) and the 6(N-1)^2 boundary quads, facing outwards.
Mesh makeLattice(Index n);
/// Three unit quads sharing the edge (0,0,0)-(0,0,1): a non-manifold surface, 8 / 10 / 3.
Mesh makeFins();

/// True when the name starts with "builtin:".
bool isBuiltinName(std::string_view name);
/// Parses "builtin:NAME[:ARGS]"; throws InvalidInputError naming the model on a bad name.
Mesh makeBuiltin(std::string_view name);

}  // namespace zsculpt
