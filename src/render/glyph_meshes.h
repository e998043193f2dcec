#pragma once
// Internal: unit meshes for glyphs (position and normal interleaved, triangle indices).

#include <cstdint>
#include <vector>

namespace zsculpt::render::detail {

struct GlyphMesh {
  std::vector<float> vertices;  // x y z nx ny nz
  std::vector<std::uint32_t> indices;
};

/// Cube [-1, 1]^3 with flat faces.
GlyphMesh makeCubeMesh();
/// Cylinder of radius 1 along z from 0 to 1, capped at z = 0.
GlyphMesh makeCylinderMesh(int segments);
/// Cone of base radius 1 at z = 0 and apex at z = 1, with its base disc.
GlyphMesh makeConeMesh(int segments);
/// Arc of a torus about z: centre-line radius 1, tube radius `tube`, from angle 0 to
/// `sweep` radians (anticlockwise seen from +z), open ends.
GlyphMesh makeRingMesh(int segments, int sides, float tube, float sweep);

}  // namespace zsculpt::render::detail
