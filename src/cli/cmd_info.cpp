// zsculpt info MESH|SCENE [--json]: topology, properties and critical sampling period.

#include <cctype>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

#include "commands.h"
#include "model_options.h"
#include "zsculpt/physics/matrices.h"

namespace zsculpt::cli {

namespace {

std::string vec(const Vec3& v) {
  return "[" + jsonNumber(v.x()) + ", " + jsonNumber(v.y()) + ", " + jsonNumber(v.z()) + "]";
}

int runInfo(const ModelOptions& options, bool json) {
  const LoadedModel loaded = options.load();
  const Model& model = loaded.model;
  const Mesh& mesh = model.mesh;
  const BoundingBox box = mesh.boundingBox();
  const SystemMatrices matrices(model);
  const double tMax = criticalPeriod(matrices);
  const double tTight = tightCriticalPeriod(matrices);
  const auto boundary = static_cast<long>(mesh.boundaryEdges().size());
  const auto nonManifold = static_cast<long>(mesh.nonManifoldEdges().size());
  const auto isolated = static_cast<long>(mesh.isolatedVertices().size());
  const Index components = mesh.numComponents();
  const PhysicalProperties& p = model.properties;
  const double restMin = p.restLength.size() ? p.restLength.minCoeff() : 0.0;
  const double restMax = p.restLength.size() ? p.restLength.maxCoeff() : 0.0;
  // What a scene sets besides the properties: its constraints, loads, edits and run.
  const std::optional<io::SceneDescription>& scene = loaded.scene;
  // Its constraints are added as a run adds them (the same function, on a simulation of the
  // model at rest), so that info refuses what simulate, render and open refuse: a QA pass
  // found a normal pin where the mesh has no normal accepted here and refused by every run.
  if (scene && !scene->constraints.empty()) {
    SimulationSettings settings;
    settings.scheme = Scheme::SymplecticEuler;  // the cheapest to set up; constraints are
    settings.period = std::isfinite(tMax) && tMax > 0.0 ? 0.5 * tMax : 0.01;  // any scheme's
    Simulation check(model, settings);
    addSceneConstraints(loaded, check);
  }
  long pins = 0, travelling = 0, normals = 0;
  if (scene)
    for (const io::ConstraintSpec& c : scene->constraints) {
      if (c.type == io::ConstraintType::Normal) {
        ++normals;
      } else {
        ++pins;
        if (c.start) ++travelling;
      }
    }
  auto optionalNumber = [](const std::optional<double>& v) {
    return v ? jsonNumber(*v) : std::string("null");
  };
  if (json) {
    std::cout << "{\n"
              << "  \"source\": " << jsonString(loaded.source) << ",\n"
              << "  \"vertices\": " << mesh.numVertices() << ",\n"
              << "  \"edges\": " << mesh.numEdges() << ",\n"
              << "  \"faces\": " << mesh.numFaces() << ",\n"
              << "  \"boundary_edges\": " << boundary << ",\n"
              << "  \"non_manifold_edges\": " << nonManifold << ",\n"
              << "  \"isolated_vertices\": " << isolated << ",\n"
              << "  \"components\": " << components << ",\n"
              << "  \"angle_springs\": " << model.angles.size() << ",\n"
              << "  \"bbox_min\": " << vec(box.min) << ",\n"
              << "  \"bbox_max\": " << vec(box.max) << ",\n"
              << "  \"mass_total\": " << jsonNumber(p.mass.sum()) << ",\n"
              << "  \"degenerate_faces_dropped\": " << loaded.report.degenerateFacesDropped << ",\n"
              << "  \"points_and_lines_dropped\": " << loaded.report.pointsAndLinesDropped << ",\n"
              << "  \"unused_vertices_dropped\": " << loaded.report.unusedVerticesDropped << ",\n"
              << "  \"vertices_welded\": " << loaded.report.verticesWelded << ",\n"
              << "  \"faces_reversed\": " << loaded.report.facesReversed << ",\n"
              << "  \"non_orientable_components\": " << loaded.report.nonOrientableComponents
              << ",\n"
              << "  \"up_axis\": \"" << io::upAxisName(loaded.report.up) << "\",\n"
              << "  \"rigidity\": [" << jsonNumber(p.rigidity.minCoeff()) << ", "
              << jsonNumber(p.rigidity.maxCoeff()) << "],\n"
              << "  \"stiffness_cap\": " << jsonNumber(p.stiffnessCap) << ",\n"
              << "  \"gravity\": " << vec(p.gravity) << ",\n"
              << "  \"rest_length\": [" << jsonNumber(restMin) << ", " << jsonNumber(restMax)
              << "],\n";
    if (scene)
      std::cout << "  \"scene\": {\"pins\": " << pins << ", \"travelling_pins\": " << travelling
                << ", \"normal_pins\": " << normals << ", \"forces\": " << scene->forces.size()
                << ", \"torques\": " << scene->torques.size()
                << ", \"edits\": " << scene->edits.size()
                << ", \"scheme\": " << jsonString(io::schemeName(scene->simulation.scheme))
                << ", \"dt\": " << optionalNumber(scene->simulation.dt)
                << ", \"dt_ratio\": " << optionalNumber(scene->simulation.dtRatio)
                << ", \"steps\": "
                << (scene->simulation.steps ? std::to_string(*scene->simulation.steps) : "null")
                << ", \"time\": " << optionalNumber(scene->simulation.time)
                << ", \"perturb\": " << jsonNumber(scene->simulation.perturb) << "},\n";
    std::cout << "  \"t_max\": " << jsonNumber(tMax) << ",\n"
              << "  \"t_max_tight\": " << jsonNumber(tTight) << "\n"
              << "}\n";
    return 0;
  }
  std::cout << loaded.source << "\n"
            << "  vertices " << mesh.numVertices() << ", edges " << mesh.numEdges() << ", faces "
            << mesh.numFaces() << "\n"
            << "  boundary edges " << boundary << ", non-manifold edges " << nonManifold
            << ", isolated vertices " << isolated << ", components " << components << "\n"
            << "  angle springs " << model.angles.size() << "\n"
            << "  bounding box [" << box.min.transpose() << "] .. [" << box.max.transpose()
            << "]\n";
  // What the import changed, the parts that are not zero. The merged copies are every vertex
  // that came to a position another had: OBJ and STL readers give each face corner its own,
  // so there they count the shared corners of a clean file too (a QA pass read "400 vertices
  // welded" as 400 duplicates in the file).
  {
    std::vector<std::string> parts;
    if (loaded.report.verticesWelded)
      parts.push_back(std::to_string(loaded.report.verticesWelded) +
                      " vertex copies merged by position (the reader's per-corner copies too)");
    if (loaded.report.degenerateFacesDropped)
      parts.push_back(std::to_string(loaded.report.degenerateFacesDropped) +
                      " degenerate faces dropped");
    // A vertex that only a point or a line of zero length used (no spring) was dropped
    // without a word (a QA pass). Points on vertices that faces use lose nothing, and are
    // not said (zsculpt's own OBJ files list every vertex as a point): their count is in
    // the JSON.
    if (loaded.report.unusedVerticesDropped)
      parts.push_back(std::to_string(loaded.report.unusedVerticesDropped) +
                      (loaded.report.unusedVerticesDropped == 1
                           ? " vertex that no face or line uses dropped (a point, or the end of a "
                             "zero-length line)"
                           : " vertices that no face or line uses dropped (points, or the ends of "
                             "zero-length lines)"));
    if (loaded.report.facesReversed)
      parts.push_back(std::to_string(loaded.report.facesReversed) +
                      " faces reversed to wind as their neighbours (a closed sheet outward)");
    for (size_t k = 0; k < parts.size(); ++k)
      std::cout << (k == 0 ? "  import: " : ", ") << parts[k]
                << (k + 1 == parts.size() ? "\n" : "");
  }
  if (loaded.report.up != io::UpAxis::PlusZ) {
    std::string extension = std::filesystem::path(loaded.source).extension().string();
    for (char& c : extension) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    const bool collada = extension == ".dae";
    std::cout << "  up axis " << io::upAxisName(loaded.report.up)
              << " as read, turned to +z (--up z keeps the coordinates as read"
              << (collada ? "; assimp reads a Collada file Y-up whatever its <up_axis>" : "")
              << ")\n";
  }
  if (loaded.report.nonOrientableComponents)
    std::cout << "  " << loaded.report.nonOrientableComponents
              << " non-orientable component(s): no winding agrees across every edge\n";
  std::cout << "  mass " << p.mass.minCoeff() << " .. " << p.mass.maxCoeff() << " (total "
            << p.mass.sum() << "), stiffness " << p.stiffness.minCoeff() << " .. "
            << p.stiffness.maxCoeff() << ", angular stiffness " << p.angularStiffness.minCoeff()
            << " .. " << p.angularStiffness.maxCoeff() << ", damping " << p.damping.minCoeff()
            << " .. " << p.damping.maxCoeff() << ", rigidity " << p.rigidity.minCoeff() << " .. "
            << p.rigidity.maxCoeff() << ", rest lengths " << restMin << " .. " << restMax << " m\n";
  if (std::isfinite(p.stiffnessCap)) std::cout << "  stiffness cap " << p.stiffnessCap << " N/m\n";
  if (!p.gravity.isZero()) std::cout << "  gravity [" << p.gravity.transpose() << "] m/s^2\n";
  if (scene) {
    auto count = [](size_t n, const char* one, const char* many) {
      return std::to_string(n) + " " + (n == 1 ? one : many);
    };
    std::cout << "  scene: " << count(static_cast<size_t>(pins), "pin", "pins") << " ("
              << travelling << " travelling), "
              << count(static_cast<size_t>(normals), "normal pin", "normal pins") << ", "
              << count(scene->forces.size(), "force", "forces") << ", "
              << count(scene->torques.size(), "torque", "torques") << ", "
              << count(scene->edits.size(), "timed edit", "timed edits") << "; scheme "
              << io::schemeName(scene->simulation.scheme);
    if (scene->simulation.dt) std::cout << ", dt " << *scene->simulation.dt << " s";
    if (scene->simulation.dtRatio) std::cout << ", dt_ratio " << *scene->simulation.dtRatio;
    if (scene->simulation.steps) std::cout << ", " << *scene->simulation.steps << " steps";
    if (scene->simulation.time) std::cout << ", " << *scene->simulation.time << " s";
    if (scene->simulation.perturb > 0.0) std::cout << ", perturb " << scene->simulation.perturb;
    std::cout << "\n";
  }
  std::cout << "  critical sampling period T_max (equation 5, the bound --dt-ratio scales) " << tMax
            << " s; the default scheme's linear stability limit sqrt(12 / lambda_max) " << tTight
            << " s\n";
  return 0;
}

}  // namespace

void addInfoCommand(CLI::App& root, CommandList& commands) {
  auto* app = root.add_subcommand("info", "topology, properties and critical sampling period");
  auto options = std::make_shared<ModelOptions>();
  auto json = std::make_shared<bool>(false);
  options->addTo(app);
  app->add_flag("--json", *json, "a JSON summary on standard output");
  commands.push_back({app, [options, json]() { return runInfo(*options, *json); }});
}

}  // namespace zsculpt::cli
