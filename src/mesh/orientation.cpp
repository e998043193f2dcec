#include "zsculpt/mesh/orientation.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <tuple>

namespace zsculpt {

namespace {

// One face's use of an undirected edge: the edge (a < b), the face, and whether the face
// runs it from a to b.
struct EdgeUse {
  Index a, b, face;
  bool forward;
};

void reverseFace(std::vector<Index>& face) {
  std::reverse(face.begin() + 1, face.end());
}

/// Calls f(a, b, c) for each triangle of the face's fan from its first corner, as wound
/// (b and c swapped when `reversed`), the corners relative to `origin`.
template <class F>
void forEachFanTriangle(const Points& positions, const std::vector<Index>& face, bool reversed,
                        const Vec3& origin, F&& f) {
  const Vec3 a = positions.row(face[0]).transpose() - origin;
  for (size_t k = 1; k + 1 < face.size(); ++k) {
    Vec3 b = positions.row(face[k]).transpose() - origin;
    Vec3 c = positions.row(face[k + 1]).transpose() - origin;
    if (reversed) std::swap(b, c);
    f(a, b, c);
  }
}

}  // namespace

OrientationReport orientFaces(const Points& positions, std::vector<std::vector<Index>>& faces) {
  OrientationReport report;
  const Index numFaces = static_cast<Index>(faces.size());
  std::vector<EdgeUse> uses;
  for (Index f = 0; f < numFaces; ++f) {
    const auto& face = faces[static_cast<size_t>(f)];
    for (size_t k = 0; k < face.size(); ++k) {
      const Index u = face[k], v = face[(k + 1) % face.size()];
      uses.push_back({std::min(u, v), std::max(u, v), f, u < v});
    }
  }
  std::sort(uses.begin(), uses.end(), [](const EdgeUse& x, const EdgeUse& y) {
    return std::tie(x.a, x.b, x.face) < std::tie(y.a, y.b, y.face);
  });
  // For each face, its neighbours across manifold edges, with whether the two run the
  // shared edge the same way (then one of them must turn).
  struct Link {
    Index other;
    bool sameWay;
  };
  std::vector<std::vector<Link>> links(static_cast<size_t>(numFaces));
  std::vector<char> closedEdge(static_cast<size_t>(numFaces), 1);  // every edge shared by two
  for (size_t i = 0; i < uses.size();) {
    size_t j = i;
    while (j < uses.size() && uses[j].a == uses[i].a && uses[j].b == uses[i].b) ++j;
    if (j - i == 2 && uses[i].face != uses[i + 1].face) {
      const bool same = uses[i].forward == uses[i + 1].forward;
      links[static_cast<size_t>(uses[i].face)].push_back({uses[i + 1].face, same});
      links[static_cast<size_t>(uses[i + 1].face)].push_back({uses[i].face, same});
    } else {
      for (size_t k = i; k < j; ++k) closedEdge[static_cast<size_t>(uses[k].face)] = 0;
    }
    i = j;
  }

  // Sheet by sheet: turn[f] says whether face f must be reversed relative to the sheet's
  // first face.
  struct Sheet {
    std::vector<Index> faces;
    bool closed = true, orientable = true;
    bool flip = false;  // reverse the whole sheet as propagated
    double volume = 0.0;
  };
  std::vector<Sheet> sheets;
  std::vector<int> turn(static_cast<size_t>(numFaces), -1);
  std::vector<Index> queue;
  for (Index start = 0; start < numFaces; ++start) {
    if (turn[static_cast<size_t>(start)] >= 0) continue;
    Sheet sheet;
    queue.assign(1, start);
    turn[static_cast<size_t>(start)] = 0;
    while (!queue.empty()) {
      const Index f = queue.back();
      queue.pop_back();
      sheet.faces.push_back(f);
      sheet.closed = sheet.closed && closedEdge[static_cast<size_t>(f)];
      for (const Link& link : links[static_cast<size_t>(f)]) {
        // Agreeing neighbours run the shared edge opposite ways once both are turned.
        const int wanted = turn[static_cast<size_t>(f)] ^ (link.sameWay ? 1 : 0);
        int& other = turn[static_cast<size_t>(link.other)];
        if (other < 0) {
          other = wanted;
          queue.push_back(link.other);
        } else if (other != wanted) {
          sheet.orientable = false;
        }
      }
    }
    if (!sheet.orientable) {
      ++report.nonOrientableComponents;
      for (Index f : sheet.faces) turn[static_cast<size_t>(f)] = 0;  // left as it is
    } else if (sheet.closed) {
      // Signed volume (x 6) of the sheet as propagated (fans from each face's first corner),
      // about one of its own vertices: a small part far from the origin keeps its sign.
      const Vec3 origin = positions.row(faces[static_cast<size_t>(start)][0]).transpose();
      for (Index f : sheet.faces)
        forEachFanTriangle(positions, faces[static_cast<size_t>(f)],
                           turn[static_cast<size_t>(f)] == 1, origin,
                           [&](const Vec3& a, const Vec3& b, const Vec3& c) {
                             sheet.volume += a.dot(b.cross(c));
                           });
    } else {
      Index turned = 0;
      for (Index f : sheet.faces) turned += turn[static_cast<size_t>(f)];
      sheet.flip = 2 * turned > static_cast<Index>(sheet.faces.size());
    }
    sheets.push_back(std::move(sheet));
  }

  // A closed sheet faces outward (positive volume), unless it lies inside a larger closed
  // sheet: a hollow model's inner wall faces its cavity, and a part inside another is wound
  // outward; neither can be told from the geometry alone, so a nested sheet keeps its winding
  // relative to the sheet around it (turned only if that one is turned: a whole model wound
  // inside out). Nesting: the other's bounding box holds this one's strictly, and the other's
  // winding number is near 1 at three of this sheet's face centroids (a point on the other's
  // surface gives about 1/2, a sheet only overlapping it some 0). Containers are looked for
  // among the 64 largest sheets, so that a model of many parts loads in linear time.
  std::vector<size_t> closedSheets;
  for (size_t k = 0; k < sheets.size(); ++k)
    if (sheets[k].closed && sheets[k].orientable) closedSheets.push_back(k);
  std::sort(closedSheets.begin(), closedSheets.end(), [&](size_t a, size_t b) {
    return std::abs(sheets[a].volume) > std::abs(sheets[b].volume);
  });
  std::vector<Vec3> boxMin(sheets.size()), boxMax(sheets.size());
  for (size_t k : closedSheets) {
    boxMin[k] = Vec3::Constant(std::numeric_limits<double>::infinity());
    boxMax[k] = -boxMin[k];
    for (Index f : sheets[k].faces)
      for (Index v : faces[static_cast<size_t>(f)]) {
        boxMin[k] = boxMin[k].cwiseMin(positions.row(v).transpose());
        boxMax[k] = boxMax[k].cwiseMax(positions.row(v).transpose());
      }
  }
  // Winding number of sheet k (as propagated) at p: its solid angle over 4 pi, by Van
  // Oosterom and Strackee's formula per fan triangle; +-1 inside, 0 outside.
  auto winding = [&](size_t k, const Vec3& p) {
    double total = 0.0;
    for (Index f : sheets[k].faces)
      forEachFanTriangle(
          positions, faces[static_cast<size_t>(f)], turn[static_cast<size_t>(f)] == 1, p,
          [&](const Vec3& a, const Vec3& b, const Vec3& c) {
            const double la = a.norm(), lb = b.norm(), lc = c.norm();
            const double numerator = a.dot(b.cross(c));
            const double denominator = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
            total += 2.0 * std::atan2(numerator, denominator);
          });
    return total / (4.0 * M_PI);
  };
  auto centroid = [&](Index f) {
    const auto& face = faces[static_cast<size_t>(f)];
    Vec3 c = Vec3::Zero();
    for (Index v : face) c += positions.row(v).transpose();
    return Vec3(c / static_cast<double>(face.size()));
  };
  constexpr size_t kContainers = 64;
  for (size_t rank = 0; rank < closedSheets.size(); ++rank) {
    Sheet& sheet = sheets[closedSheets[rank]];
    const size_t k = closedSheets[rank];
    const size_t n = sheet.faces.size();
    const Vec3 samples[3] = {centroid(sheet.faces[0]), centroid(sheet.faces[n / 3]),
                             centroid(sheet.faces[2 * n / 3])};
    // The innermost container: the smallest of the larger sheets that holds this one.
    const Sheet* container = nullptr;
    for (size_t r = std::min(rank, kContainers); r-- > 0;) {
      const size_t other = closedSheets[r];
      if (!(std::abs(sheets[other].volume) > std::abs(sheet.volume)) ||
          !(boxMin[other].array() < boxMin[k].array()).all() ||
          !(boxMax[other].array() > boxMax[k].array()).all())
        continue;
      bool inside = true;
      for (const Vec3& p : samples) inside = inside && std::abs(winding(other, p)) > 0.75;
      if (inside) {
        container = &sheets[other];
        break;
      }
    }
    sheet.flip = container ? container->flip : sheet.volume < 0.0;
  }

  for (const Sheet& sheet : sheets)
    for (Index f : sheet.faces)
      if ((turn[static_cast<size_t>(f)] == 1) != sheet.flip) {
        reverseFace(faces[static_cast<size_t>(f)]);
        ++report.facesReversed;
      }
  return report;
}

}  // namespace zsculpt
