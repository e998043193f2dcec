#include "zsculpt/mesh/builtin.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <numbers>
#include <string>
#include <vector>

#include "zsculpt/core/errors.h"

namespace zsculpt {

Mesh makeDodecahedron() {
  const double phi = std::numbers::phi;
  std::vector<Vec3> p;
  for (int sx : {-1, 1})
    for (int sy : {-1, 1})
      for (int sz : {-1, 1}) p.emplace_back(sx, sy, sz);
  for (int s1 : {-1, 1})
    for (int s2 : {-1, 1}) {
      p.emplace_back(0, s1 / phi, s2 * phi);
      p.emplace_back(s1 / phi, s2 * phi, 0);
      p.emplace_back(s1 * phi, 0, s2 / phi);
    }
  // The canonical coordinates have edge length 2 / phi; scale to edge length 1.
  const double scale = phi / 2.0;
  Points positions(20, 3);
  for (Index i = 0; i < 20; ++i) positions.row(i) = scale * p[i].transpose();

  // Face centres point along the icosahedron's vertices; each face is the five vertices
  // with the largest projection on that direction, ordered counter-clockwise from outside.
  std::vector<Vec3> centres;
  for (int s1 : {-1, 1})
    for (int s2 : {-1, 1}) {
      centres.emplace_back(s1, 0, s2 * phi);
      centres.emplace_back(0, s1 * phi, s2);
      centres.emplace_back(s1 * phi, s2, 0);
    }
  std::vector<std::vector<Index>> faces;
  for (const Vec3& c : centres) {
    const Vec3 n = c.normalized();
    std::vector<std::pair<double, Index>> proj;
    for (Index i = 0; i < 20; ++i) proj.emplace_back(-n.dot(positions.row(i).transpose()), i);
    std::sort(proj.begin(), proj.end());
    std::vector<Index> face;
    for (int k = 0; k < 5; ++k) face.push_back(proj[k].second);
    const Vec3 centre = [&] {
      Vec3 s = Vec3::Zero();
      for (Index v : face) s += positions.row(v).transpose();
      return Vec3(s / 5.0);
    }();
    const Vec3 u = (positions.row(face[0]).transpose() - centre).normalized();
    const Vec3 w = n.cross(u);
    std::sort(face.begin(), face.end(), [&](Index a, Index b) {
      const Vec3 da = positions.row(a).transpose() - centre;
      const Vec3 db = positions.row(b).transpose() - centre;
      return std::atan2(da.dot(w), da.dot(u)) < std::atan2(db.dot(w), db.dot(u));
    });
    faces.push_back(face);
  }
  return Mesh(std::move(positions), faces);
}

Mesh makeTorus(Index nu, Index nv) {
  if (nu < 3 || nv < 3) throw InvalidInputError("builtin:torus: U and V must be at least 3");
  const double major = 2.0, minor = 1.0;
  Points positions(static_cast<Eigen::Index>(nu) * nv, 3);
  for (Index v = 0; v < nv; ++v)
    for (Index u = 0; u < nu; ++u) {
      const double a = 2.0 * std::numbers::pi * u / nu;
      const double b = 2.0 * std::numbers::pi * v / nv;
      positions.row(u + nu * v) << (major + minor * std::cos(b)) * std::cos(a),
          (major + minor * std::cos(b)) * std::sin(a), minor * std::sin(b);
    }
  std::vector<std::vector<Index>> faces;
  faces.reserve(static_cast<size_t>(nu) * nv);
  for (Index v = 0; v < nv; ++v)
    for (Index u = 0; u < nu; ++u) {
      const Index u1 = (u + 1) % nu, v1 = (v + 1) % nv;
      faces.push_back({u + nu * v, u1 + nu * v, u1 + nu * v1, u + nu * v1});
    }
  return Mesh(std::move(positions), faces);
}

Mesh makeGrid(Index n) {
  if (n < 2) throw InvalidInputError("builtin:grid: N must be at least 2");
  Points positions(static_cast<Eigen::Index>(n) * n, 3);
  for (Index j = 0; j < n; ++j)
    for (Index i = 0; i < n; ++i) positions.row(i + n * j) << i, j, 0.0;
  std::vector<std::vector<Index>> faces;
  for (Index j = 0; j + 1 < n; ++j)
    for (Index i = 0; i + 1 < n; ++i)
      faces.push_back({i + n * j, i + 1 + n * j, i + 1 + n * (j + 1), i + n * (j + 1)});
  return Mesh(std::move(positions), faces);
}

Mesh makeHelix(Index n) {
  if (n < 2) throw InvalidInputError("builtin:helix: N must be at least 2");
  Points positions(n, 3);
  std::vector<std::array<Index, 2>> edges;
  for (Index k = 0; k < n; ++k) {
    const double t = 2.0 * std::numbers::pi * k / 16.0;
    positions.row(k) << std::cos(t), std::sin(t), k / 16.0;
    if (k + 1 < n) edges.push_back({k, k + 1});
  }
  return Mesh(std::move(positions), {}, edges);
}

Mesh makeLattice(Index n) {
  if (n < 2) throw InvalidInputError("builtin:lattice: N must be at least 2");
  auto id = [n](Index i, Index j, Index k) { return i + n * j + n * n * k; };
  Points positions(static_cast<Eigen::Index>(n) * n * n, 3);
  for (Index k = 0; k < n; ++k)
    for (Index j = 0; j < n; ++j)
      for (Index i = 0; i < n; ++i) positions.row(id(i, j, k)) << i, j, k;
  std::vector<std::array<Index, 2>> edges;
  for (Index k = 0; k < n; ++k)
    for (Index j = 0; j < n; ++j)
      for (Index i = 0; i < n; ++i) {
        if (i + 1 < n) edges.push_back({id(i, j, k), id(i + 1, j, k)});
        if (j + 1 < n) edges.push_back({id(i, j, k), id(i, j + 1, k)});
        if (k + 1 < n) edges.push_back({id(i, j, k), id(i, j, k + 1)});
      }
  std::vector<std::vector<Index>> faces;
  const Index m = n - 1;
  for (Index a = 0; a < m; ++a)
    for (Index b = 0; b < m; ++b) {
      // z = 0 (normal -z) and z = m (normal +z); likewise for x and y.
      faces.push_back({id(a, b, 0), id(a, b + 1, 0), id(a + 1, b + 1, 0), id(a + 1, b, 0)});
      faces.push_back({id(a, b, m), id(a + 1, b, m), id(a + 1, b + 1, m), id(a, b + 1, m)});
      faces.push_back({id(0, a, b), id(0, a, b + 1), id(0, a + 1, b + 1), id(0, a + 1, b)});
      faces.push_back({id(m, a, b), id(m, a + 1, b), id(m, a + 1, b + 1), id(m, a, b + 1)});
      faces.push_back({id(a, 0, b), id(a + 1, 0, b), id(a + 1, 0, b + 1), id(a, 0, b + 1)});
      faces.push_back({id(a, m, b), id(a, m, b + 1), id(a + 1, m, b + 1), id(a + 1, m, b)});
    }
  return Mesh(std::move(positions), faces, edges);
}

Mesh makeFins() {
  Points positions(8, 3);
  positions.row(0) << 0, 0, 0;
  positions.row(1) << 0, 0, 1;
  std::vector<std::vector<Index>> faces;
  for (Index f = 0; f < 3; ++f) {
    const double a = 2.0 * std::numbers::pi * f / 3.0;
    positions.row(2 + 2 * f) << std::cos(a), std::sin(a), 0;
    positions.row(3 + 2 * f) << std::cos(a), std::sin(a), 1;
    faces.push_back({0, 2 + 2 * f, 3 + 2 * f, 1});
  }
  return Mesh(std::move(positions), faces);
}

bool isBuiltinName(std::string_view name) {
  return name.starts_with("builtin:");
}

namespace {

std::vector<std::string_view> split(std::string_view s, char sep) {
  std::vector<std::string_view> parts;
  size_t start = 0;
  while (true) {
    const size_t pos = s.find(sep, start);
    parts.push_back(s.substr(start, pos == std::string_view::npos ? pos : pos - start));
    if (pos == std::string_view::npos) break;
    start = pos + 1;
  }
  return parts;
}

Index parseCount(std::string_view name, std::string_view text, Index max) {
  Index value = 0;
  const auto [ptr, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc() || ptr != text.data() + text.size() || value <= 0 || value > max)
    throw InvalidInputError(std::string(name) + ": '" + std::string(text) +
                            "' is not a count between 1 and " + std::to_string(max));
  return value;
}

}  // namespace

Mesh makeBuiltin(std::string_view name) {
  if (!isBuiltinName(name))
    throw InvalidInputError(std::string(name) + ": not a built-in model name");
  const auto parts = split(name.substr(8), ':');
  const std::string_view model = parts[0];
  const size_t args = parts.size() - 1;
  auto bad = [&]() {
    return InvalidInputError(
        std::string(name) +
        ": unknown built-in model (try dodecahedron, torus[:U:V], grid[:N], helix[:N], "
        "lattice:N, fins)");
  };
  if (model == "dodecahedron" && args == 0) return makeDodecahedron();
  if (model == "fins" && args == 0) return makeFins();
  if (model == "torus") {
    if (args == 0) return makeTorus(10, 10);
    if (args == 2)
      return makeTorus(parseCount(name, parts[1], 4096), parseCount(name, parts[2], 4096));
    throw bad();
  }
  if (model == "grid") {
    if (args == 0) return makeGrid(18);
    if (args == 1) return makeGrid(parseCount(name, parts[1], 4096));
    throw bad();
  }
  if (model == "helix") {
    if (args == 0) return makeHelix(64);
    if (args == 1) return makeHelix(parseCount(name, parts[1], 1 << 24));
    throw bad();
  }
  if (model == "lattice" && args == 1) return makeLattice(parseCount(name, parts[1], 256));
  throw bad();
}

}  // namespace zsculpt
