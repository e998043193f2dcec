#pragma once
// What to draw in one frame: plain data that the interactive window and the command line
// both fill in. The renderer reads it and keeps nothing but GPU copies, so a Frame may be
// reused from frame to frame (clear() its vectors: their capacity is kept).

#include <cstdint>
#include <string>
#include <vector>

#include "zsculpt/core/types.h"
#include "zsculpt/mesh/mesh.h"
#include "zsculpt/physics/properties.h"
#include "zsculpt/render/camera.h"
#include "zsculpt/render/color.h"

namespace zsculpt {
class SubdivisionStencil;
}

namespace zsculpt::render {

/// How vertex normals of the drawn surface are computed each frame.
enum class NormalMode {
  BestPlane,     ///< least-squares plane of the one-ring (paper section 3; subdivision module)
  AreaWeighted,  ///< sum of the incident faces' area vectors
};

/// A per-control-vertex scalar drawn as a colour map, with a legend.
struct ScalarField {
  const VectorX* values = nullptr;  ///< one value per control vertex; null: no colour map
  std::string name;                 ///< legend title, e.g. "stiffness (N/m)"
  bool autoRange = true;            ///< range from the values' finite min and max
  double min = 0.0;                 ///< used when autoRange is false
  double max = 1.0;
  ColorMap map = ColorMap::Viridis;
};

struct NormalPin {
  Index vertex = 0;
  Vec3 normal = Vec3::UnitZ();
};

/// A force or a torque applied at a vertex (newtons, or newton metres).
struct VertexVector {
  Index vertex = 0;
  Vec3 vector = Vec3::Zero();
};

/// A highlighted vertex (e.g. Figure 8's edited rest lengths in red, rest angle in blue).
struct Marker {
  Index vertex = 0;
  Color color = Color::hex(0xd62728);
};

/// The sculpting brush: a circle of `radius` around `center` in the plane normal to `normal`.
struct Brush {
  bool visible = false;
  Vec3 center = Vec3::Zero();
  Vec3 normal = Vec3::UnitZ();
  double radius = 0.5;
};

struct DisplayFlags {
  bool surface = true;            ///< the (subdivided) surface, lit
  bool controlWireframe = false;  ///< edges of the control mesh
  bool controlPoints = false;     ///< control vertices as small red spheres (Figure 5)
  bool surfaceWireframe = false;  ///< edges of the drawn (refined) surface
  bool glyphs = true;             ///< pins, normal pins, forces, torques, markers, brush
  bool legend = true;             ///< colour bar with the scalar's name and range
  /// The legend drawn this opaque, in [0, 1] (the window fades it while the cursor is over
  /// it, so that a spot painted under it shows).
  float legendOpacity = 1.0f;
  bool backgroundGradient = true;
  /// Each polygon lit by its own plane (the control mesh as the facets it is, Figure 5's
  /// original mesh), not by smoothed vertex normals.
  bool flatShading = false;
};

struct Style {
  Color surface = Color::hex(0xc9b8a6);      ///< soft clay
  Color backSurface = Color::hex(0x8f8ab0);  ///< inside of open surfaces
  Color wireframe = Color::hex(0x2b2f3a);
  Color controlPoint = Color::hex(0xd62728);
  Color pin = Color::hex(0xe0402a);
  Color normalPin = Color::hex(0x2a6fdb);
  Color force = Color::hex(0xff8c1a);
  Color torque = Color::hex(0x9b4fd1);
  Color brush = Color::hex(0xffffff);
  Color curve = Color::hex(0x3b6ea8);  ///< edges with no face (curves, solids' inner edges)
  Color backgroundTop = Color::hex(0xf4f6fa);
  Color backgroundBottom = Color::hex(0xc5ccd8);
  Color text = Color::hex(0x1d2230);
  /// Line width in pixels for a 720-pixel-high image (scaled with the image height).
  float lineWidth = 1.6f;
  /// Multiplies the automatic glyph size (derived from the mean control edge length).
  double glyphScale = 1.0;
  /// World length of an arrow per newton (or newton metre); 0: the largest force or torque
  /// of the frame is drawn a fifth of the model's bounding-box diagonal long.
  double forceScale = 0.0;
};

struct Frame {
  /// The control mesh (topology, and positions unless `positions` is given). Required.
  const Mesh* mesh = nullptr;
  /// Refinement of `mesh` to draw as the smooth surface; null draws the control mesh.
  const SubdivisionStencil* stencil = nullptr;
  /// Current control positions (numVertices x 3); null uses mesh->positions().
  const Points* positions = nullptr;
  /// Change it when a new topology is built at the same addresses; GPU index buffers are
  /// rebuilt when it (or the mesh, stencil or their sizes) changes.
  std::uint64_t topologyVersion = 0;
  NormalMode normals = NormalMode::BestPlane;

  ScalarField scalar;
  std::vector<Index> pins;            ///< position constraints
  std::vector<NormalPin> normalPins;  ///< normal constraints (drawn as arrows)
  std::vector<VertexVector> forces;   ///< drawn as straight arrows
  std::vector<VertexVector> torques;  ///< drawn as a ring arrow about the torque's axis
  std::vector<Marker> markers;
  Brush brush;
  /// One line of text in the bottom-left corner (e.g. "t = 1.25 s"); empty: none.
  std::string caption;

  DisplayFlags display;
  Style style;
  Camera camera;
};

/// Any property as one value per vertex, for a ScalarField: per-vertex properties as they
/// are, rest lengths averaged over each vertex's edges, rest angles over the angles centred
/// at the vertex (vertices with none get 0). `out` is resized to the vertex count.
void propertyAsVertexScalar(const Mesh& mesh, const AngleTable& angles,
                            const PhysicalProperties& properties, Property property, VectorX& out);

}  // namespace zsculpt::render
