// zsculpt subdivide MESH|SCENE --levels L --out FILE: the smooth surface of the modified
// Doo-Sabin scheme (paper section 3), written in any format assimp exports.

#include <iostream>
#include <new>
#include <utility>

#include "commands.h"
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
  if (options.levels < 0 || options.levels > 8)
    throw InvalidInputError("--levels: " + std::to_string(options.levels) + " is outside [0, 8]");
  io::checkMeshOutput(options.out);  // before the work, not after it
  const LoadedModel loaded = options.model.load();
  SubdivisionOptions sub;
  sub.levels = options.levels;
  sub.interpolate = !options.classic;
  sub.mass = &loaded.model.properties.mass;
  const Mesh& control = loaded.model.mesh;
  // The stencil refuses levels the memory cannot take; said of the flag that asked for them.
  // The estimate (subdivision.h) refuses what would not fit before any work; memory that
  // runs out anyway (a smaller machine) is said of the flag.
  const SubdivisionStencil stencil = [&] {
    try {
      return SubdivisionStencil(control, sub);
    } catch (const InvalidInputError& e) {
      const std::string what = e.what();
      throw InvalidInputError(what.rfind("levels: ", 0) == 0 ? "--" + what : what);
    } catch (const std::bad_alloc&) {
      throw InvalidInputError("--levels: out of memory building " + std::to_string(options.levels) +
                              " levels of this " + std::to_string(control.numVertices()) +
                              "-vertex mesh (about " +
                              std::to_string(static_cast<long long>(
                                  estimatedRefinedVertices(control, options.levels))) +
                              " vertices); try fewer levels");
    }
  }();
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
    std::cout << "wrote " << options.out << ": " << result.numVertices() << " vertices, "
              << result.numEdges() << " edges, " << result.numFaces()
              << " faces; max interpolation error " << error
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
