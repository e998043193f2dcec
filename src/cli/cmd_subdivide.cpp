// zsculpt subdivide MESH|SCENE --levels L --out FILE: the smooth surface of the modified
// Doo-Sabin scheme (paper section 3), written in any format assimp exports.

#include <cctype>
#include <filesystem>
#include <iostream>
#include <new>
#include <utility>

#include "commands.h"
#include "console.h"
#include "levels.h"
#include "model_options.h"
#include "zsculpt/core/errors.h"
#include "zsculpt/io/mesh_io.h"
#include "zsculpt/subdivision/subdivision.h"

namespace zsculpt::cli {

namespace {

struct SubdivideOptions {
  ModelOptions model;
  int levels = 2;
  std::string out;
  bool classic = false;
  bool json = false;
};

int runSubdivide(const SubdivideOptions& options) {
  checkLevelsRange(options.levels);
  io::checkMeshOutput(options.out);  // before the work, not after it
  checkOutputsSpareStdout({{"--out", &options.out}}, options.json);
  const LoadedModel loaded = options.model.load();
  checkOutputsSpareInputs({{"--out", &options.out}}, loaded);
  SubdivisionOptions sub;
  sub.levels = options.levels;
  sub.interpolate = !options.classic;
  sub.mass = &loaded.model.properties.mass;
  const Mesh& control = loaded.model.mesh;
  const SubdivisionStencil stencil = stencilForLevels(control, sub);
  Points refined(stencil.numRefinedVertices(), 3);
  stencil.apply(control.positions(), refined);
  const double error = maxInterpolationError(stencil, control.positions(), refined);
  const Mesh result = refinedMesh(stencil, std::move(refined));
  io::saveMesh(result, options.out);
  if (options.json) {
    std::cout << "{\n"
              << "  \"levels\": " << options.levels << ",\n"
              << "  \"vertices\": " << result.numVertices() << ",\n"
              << "  \"edges\": " << result.numEdges() << ",\n"
              << "  \"faces\": " << result.numFaces() << ",\n"
              << "  \"max_interpolation_error\": " << jsonNumber(error) << ",\n"
              << "  \"bbox_diagonal\": " << jsonNumber(control.boundingBox().diagonal()) << "\n"
              << "}\n";
  } else {
    // STL holds triangles only: the file's count, said beside the surface's own.
    std::string triangles;
    std::string extension = std::filesystem::path(options.out).extension().string();
    for (char& c : extension) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    if (extension == ".stl") {
      Index count = 0;
      for (Index f = 0; f < result.numFaces(); ++f)
        count += static_cast<Index>(result.face(f).size()) - 2;
      Index curves = 0;
      for (Index e = 0; e < result.numEdges(); ++e) curves += result.isWireEdge(e) ? 1 : 0;
      triangles = " (" + std::to_string(count) + " triangles in the STL file" +
                  (curves > 0 ? "; its " + std::to_string(curves) +
                                    (curves == 1 ? " curve edge is" : " curve edges are") +
                                    " not: STL holds triangles only"
                              : std::string()) +
                  ")";
    }
    std::cout << "wrote " << options.out << ": " << result.numVertices() << " vertices, "
              << result.numEdges() << " edges, " << result.numFaces() << " faces" << triangles
              << "; max interpolation error " << error
              << " m (each control vertex to the surface inside its vertex face, computed in "
                 "double precision; the file's coordinates are single precision)\n";
  }
  return 0;
}

}  // namespace

void addSubdivideCommand(CLI::App& root, CommandList& commands) {
  auto* app = root.add_subcommand(
      "subdivide", "smooth surface (modified Doo-Sabin, interpolating) to a mesh file");
  auto options = std::make_shared<SubdivideOptions>();
  options->model.addTo(app);
  app->add_option("--levels", options->levels, "subdivision levels (default 2)");
  app->add_option("--out", options->out, "output mesh: .obj .ply .stl .gltf .glb .dae")->required();
  app->add_flag("--classic", options->classic,
                "classic Doo-Sabin (CGAL's masks), which does not interpolate");
  app->add_flag("--json", options->json, "a JSON summary on standard output");
  commands.push_back({app, [options]() { return runSubdivide(*options); }});
}

}  // namespace zsculpt::cli
