#include "glyph_meshes.h"

#include <cmath>
#include <numbers>

namespace zsculpt::render::detail {
namespace {

void vertex(GlyphMesh& m, float x, float y, float z, float nx, float ny, float nz) {
  m.vertices.insert(m.vertices.end(), {x, y, z, nx, ny, nz});
}
std::uint32_t count(const GlyphMesh& m) {
  return static_cast<std::uint32_t>(m.vertices.size() / 6);
}

// Disc at height z facing down (-z) or up, radius 1.
void disc(GlyphMesh& m, int segments, float z, bool up) {
  const std::uint32_t centre = count(m);
  const float nz = up ? 1.0f : -1.0f;
  vertex(m, 0, 0, z, 0, 0, nz);
  for (int i = 0; i <= segments; ++i) {
    const float a = 2.0f * std::numbers::pi_v<float> * static_cast<float>(i) / segments;
    vertex(m, std::cos(a), std::sin(a), z, 0, 0, nz);
  }
  for (int i = 0; i < segments; ++i) {
    const std::uint32_t a = centre + 1 + i;
    if (up) {
      m.indices.insert(m.indices.end(), {centre, a, a + 1});
    } else {
      m.indices.insert(m.indices.end(), {centre, a + 1, a});
    }
  }
}

}  // namespace

GlyphMesh makeCubeMesh() {
  GlyphMesh m;
  // Six faces, each with its own four vertices so normals are flat.
  const float n[6][3] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
  for (const auto& f : n) {
    // Two axes spanning the face, u x v = n.
    float u[3] = {f[1], f[2], f[0]};
    float v[3] = {f[1] * u[2] - f[2] * u[1], f[2] * u[0] - f[0] * u[2], f[0] * u[1] - f[1] * u[0]};
    const std::uint32_t base = count(m);
    const float corners[4][2] = {{-1, -1}, {1, -1}, {1, 1}, {-1, 1}};
    for (const auto& c : corners) {
      vertex(m, f[0] + c[0] * u[0] + c[1] * v[0], f[1] + c[0] * u[1] + c[1] * v[1],
             f[2] + c[0] * u[2] + c[1] * v[2], f[0], f[1], f[2]);
    }
    m.indices.insert(m.indices.end(), {base, base + 1, base + 2, base, base + 2, base + 3});
  }
  return m;
}

GlyphMesh makeCylinderMesh(int segments) {
  GlyphMesh m;
  for (int i = 0; i <= segments; ++i) {
    const float a = 2.0f * std::numbers::pi_v<float> * static_cast<float>(i) / segments;
    const float c = std::cos(a);
    const float s = std::sin(a);
    vertex(m, c, s, 0, c, s, 0);
    vertex(m, c, s, 1, c, s, 0);
  }
  for (int i = 0; i < segments; ++i) {
    const std::uint32_t a = 2 * i;
    m.indices.insert(m.indices.end(), {a, a + 2, a + 1, a + 1, a + 2, a + 3});
  }
  disc(m, segments, 0.0f, false);
  return m;
}

GlyphMesh makeConeMesh(int segments) {
  GlyphMesh m;
  // Side normals tilt up by the cone's half-angle (45 degrees for height 1, radius 1).
  const float k = 1.0f / std::sqrt(2.0f);
  for (int i = 0; i <= segments; ++i) {
    const float a = 2.0f * std::numbers::pi_v<float> * static_cast<float>(i) / segments;
    const float am = 2.0f * std::numbers::pi_v<float> * (static_cast<float>(i) + 0.5f) / segments;
    const float c = std::cos(a);
    const float s = std::sin(a);
    vertex(m, c, s, 0, c * k, s * k, k);
    vertex(m, 0, 0, 1, std::cos(am) * k, std::sin(am) * k, k);
  }
  for (int i = 0; i < segments; ++i) {
    const std::uint32_t a = 2 * i;
    m.indices.insert(m.indices.end(), {a, a + 2, a + 1});
  }
  disc(m, segments, 0.0f, false);
  return m;
}

GlyphMesh makeRingMesh(int segments, int sides, float tube, float sweep) {
  GlyphMesh m;
  for (int i = 0; i <= segments; ++i) {
    const float a = sweep * static_cast<float>(i) / segments;
    const float ca = std::cos(a);
    const float sa = std::sin(a);
    for (int j = 0; j <= sides; ++j) {
      const float b = 2.0f * std::numbers::pi_v<float> * static_cast<float>(j) / sides;
      const float cb = std::cos(b);
      const float sb = std::sin(b);
      // Normal: radial in the tube's cross-section.
      const float nx = cb * ca;
      const float ny = cb * sa;
      const float nz = sb;
      vertex(m, ca + tube * nx, sa + tube * ny, tube * nz, nx, ny, nz);
    }
  }
  const auto row = static_cast<std::uint32_t>(sides + 1);
  for (int i = 0; i < segments; ++i) {
    for (int j = 0; j < sides; ++j) {
      const std::uint32_t a = i * row + j;
      const std::uint32_t b = a + row;
      m.indices.insert(m.indices.end(), {a, b, a + 1, a + 1, b, b + 1});
    }
  }
  return m;
}

}  // namespace zsculpt::render::detail
