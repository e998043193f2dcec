// Figure 5 of the paper: the dodecahedron and the interpolating Doo-Sabin surface, whose
// weights depend on the physical properties (here a non-uniform mass). Data: the control
// points, the surface at the default level as OBJ, and the interpolation error per level.
// Written: figure5_surface.obj, figure5_control.csv, figure5_convergence.csv and
// figure5.png (two panels: the original mesh, faces flat with its edges and red control
// vertices; the interpolating Doo-Sabin surface at level 2, mass-weighted, passing through
// the same red control vertices, with the control mesh's edges over it).

#include <iomanip>
#include <iostream>
#include <sstream>

#include "reproduce.h"
#include "zsculpt/io/atomic_file.h"
#include "zsculpt/io/mesh_io.h"
#include "zsculpt/mesh/builtin.h"
#include "zsculpt/physics/properties.h"
#include "zsculpt/render/renderer.h"
#include "zsculpt/subdivision/subdivision.h"

namespace zsculpt::cli {

int reproduceFigure5(const ReproduceOptions& options) {
  io::ensureWritableDirectory(options.out);
  render::OffscreenRenderer renderer;  // IOError when OSMesa cannot give a context
  renderer.checkSize(kPanelWidth, kPanelHeight);
  UniformProperties u;
  u.mass = 0.5;
  u.stiffness = 5.0;
  Model model = Model::fromMesh(makeDodecahedron(), u);
  // "The subdivision weights are functions of the physical properties": a heavier half.
  for (Index v = 0; v < model.mesh.numVertices(); ++v)
    if (model.mesh.positions()(v, 2) > 0) model.properties.mass[v] = 1.0;
  const Mesh& control = model.mesh;
  const double diagonal = control.boundingBox().diagonal();

  std::ostringstream convergence;
  convergence << std::setprecision(10)
              << "level,vertices,faces,max_interpolation_error,relative_to_bbox_diagonal,"
                 "total_mass_error\n";
  std::cout << "figure 5: the dodecahedron (its upper half twice as heavy) and the modified "
               "Doo-Sabin surface that interpolates it\n";
  std::cout << "level  vertices  faces  max interpolation error / bbox diagonal\n";
  for (int level = 1; level <= (options.quick ? 3 : 5); ++level) {
    SubdivisionOptions sub;
    sub.levels = level;
    sub.mass = &model.properties.mass;
    const SubdivisionStencil stencil(control, sub);
    Points refined(stencil.numRefinedVertices(), 3);
    stencil.apply(control.positions(), refined);
    const double error = maxInterpolationError(stencil, control.positions(), refined);
    const double massError =
        std::abs(stencil.refinedMass(model.properties.mass).sum() - model.properties.mass.sum());
    convergence << level << "," << stencil.numRefinedVertices() << ","
                << stencil.refinedFaces().rows() << "," << error << "," << error / diagonal << ","
                << massError << "\n";
    std::cout << std::setw(5) << level << std::setw(10) << stencil.numRefinedVertices()
              << std::setw(7) << stencil.refinedFaces().rows() << "  " << error / diagonal << "\n";
  }
  SubdivisionOptions sub;
  sub.mass = &model.properties.mass;
  const std::string objPath = options.out + "/figure5_surface.obj";
  io::saveMesh(subdivide(control, sub), objPath);
  std::ostringstream points;
  points << std::setprecision(17) << "x,y,z,mass\n";
  for (Index v = 0; v < control.numVertices(); ++v)
    points << control.positions()(v, 0) << "," << control.positions()(v, 1) << ","
           << control.positions()(v, 2) << "," << model.properties.mass[v] << "\n";
  const std::string controlPath = options.out + "/figure5_control.csv";
  io::writeFileAtomically(controlPath, [&](std::ostream& out) { out << points.str(); });
  const std::string convergencePath = options.out + "/figure5_convergence.csv";
  io::writeFileAtomically(convergencePath, [&](std::ostream& out) { out << convergence.str(); });

  // The image: the original mesh beside the interpolating surface, control vertices in red.
  SubdivisionOptions shown;
  shown.levels = 2;
  shown.mass = &model.properties.mass;
  const SubdivisionStencil stencil(control, shown);
  render::Frame frame;
  frame.mesh = &control;
  frame.display.controlPoints = true;
  frame.display.controlWireframe = true;
  frame.camera.pitchDegrees = 25.0;
  render::frameScene(frame, static_cast<double>(kPanelWidth) / kPanelHeight, 1.3);
  frame.caption = "original mesh";
  frame.display.flatShading = true;  // the facets as they are
  std::vector<render::Image> panels;
  panels.push_back(renderPanel(renderer, frame));
  frame.stencil = &stencil;
  frame.display.flatShading = false;
  // The surface passes through the control vertices, not along the cage's edges: drawn
  // with it, the cage showed only as stubs poking through the surface.
  frame.display.controlWireframe = false;
  frame.caption = "interpolating Doo-Sabin surface (level 2)";
  panels.push_back(renderPanel(renderer, frame));
  const std::string pngPath = options.out + "/figure5.png";
  savePanels(pngPath, panels);
  std::cout << "wrote " << objPath << ", " << controlPath << ", " << convergencePath << ", "
            << pngPath << "\n";
  return 0;
}

}  // namespace zsculpt::cli
