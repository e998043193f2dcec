#include "zsculpt/render/frame.h"

#include "zsculpt/core/errors.h"

namespace zsculpt::render {

void propertyAsVertexScalar(const Mesh& mesh, const AngleTable& angles,
                            const PhysicalProperties& properties, Property property, VectorX& out) {
  const Index n = mesh.numVertices();
  out.resize(n);
  const VectorX& values = properties.values(property);
  switch (propertyDomain(property)) {
    case PropertyDomain::Vertex:
      if (values.size() != n) {
        throw InvalidInputError(std::string(propertyName(property)) +
                                ": one value per vertex expected");
      }
      out = values;
      return;
    case PropertyDomain::Edge: {
      if (values.size() != mesh.numEdges()) {
        throw InvalidInputError(std::string(propertyName(property)) +
                                ": one value per edge expected");
      }
      for (Index v = 0; v < n; ++v) {
        const auto edges = mesh.vertexEdges(v);
        double sum = 0.0;
        for (Index e : edges) sum += values[e];
        out[v] = edges.empty() ? 0.0 : sum / static_cast<double>(edges.size());
      }
      return;
    }
    case PropertyDomain::Angle: {
      if (values.size() != angles.size() ||
          static_cast<Index>(angles.vertexOffsets.size()) != n + 1) {
        throw InvalidInputError(std::string(propertyName(property)) +
                                ": one value per angle expected");
      }
      for (Index v = 0; v < n; ++v) {
        const Index begin = angles.vertexOffsets[v];
        const Index end = angles.vertexOffsets[v + 1];
        double sum = 0.0;
        for (Index a = begin; a < end; ++a) sum += values[a];
        out[v] = end > begin ? sum / static_cast<double>(end - begin) : 0.0;
      }
      return;
    }
  }
}

}  // namespace zsculpt::render
