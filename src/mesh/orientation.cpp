#include "zsculpt/mesh/orientation.h"

#include <algorithm>
#include <array>
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
  std::vector<int> turn(static_cast<size_t>(numFaces), -1);
  std::vector<Index> sheet, queue;
  for (Index start = 0; start < numFaces; ++start) {
    if (turn[static_cast<size_t>(start)] >= 0) continue;
    sheet.clear();
    queue.assign(1, start);
    turn[static_cast<size_t>(start)] = 0;
    bool orientable = true, closed = true;
    while (!queue.empty()) {
      const Index f = queue.back();
      queue.pop_back();
      sheet.push_back(f);
      closed = closed && closedEdge[static_cast<size_t>(f)];
      for (const Link& link : links[static_cast<size_t>(f)]) {
        // Agreeing neighbours run the shared edge opposite ways once both are turned.
        const int wanted = turn[static_cast<size_t>(f)] ^ (link.sameWay ? 1 : 0);
        int& other = turn[static_cast<size_t>(link.other)];
        if (other < 0) {
          other = wanted;
          queue.push_back(link.other);
        } else if (other != wanted) {
          orientable = false;
        }
      }
    }
    if (!orientable) ++report.nonOrientableComponents;
    Index turned = 0;
    for (Index f : sheet) turned += turn[static_cast<size_t>(f)];
    bool flipAll = false;
    if (closed && orientable) {
      // Signed volume of the sheet as it would be wound (fans from each face's first corner).
      double volume = 0.0;
      for (Index f : sheet) {
        const auto& face = faces[static_cast<size_t>(f)];
        const bool reversed = turn[static_cast<size_t>(f)] == 1;
        const Vec3 p0 = positions.row(face[0]).transpose();
        for (size_t k = 1; k + 1 < face.size(); ++k) {
          Vec3 p1 = positions.row(face[k]).transpose();
          Vec3 p2 = positions.row(face[k + 1]).transpose();
          if (reversed) std::swap(p1, p2);
          volume += p0.dot(p1.cross(p2));
        }
      }
      flipAll = volume < 0.0;
    } else {
      flipAll = 2 * turned > static_cast<Index>(sheet.size());
    }
    for (Index f : sheet) {
      const bool reverse = (turn[static_cast<size_t>(f)] == 1) != flipAll;
      if (reverse) {
        reverseFace(faces[static_cast<size_t>(f)]);
        ++report.facesReversed;
      }
    }
  }
  return report;
}

}  // namespace zsculpt
