// Figure 9 of the paper: "Constraints: The dodecahedron is under position (red) constraints
// in Image I and under position and normal (blue) constraints in Image II. The same force
// has been applied in both cases. Note that the normals in the two cases are different."
//
// Table 1's dodecahedron (mu 0.5, kappa 5) with weak angle springs (0.5) and damping 0.5 so
// that it settles. Red: the five vertices of face 0 pinned where they are. Blue (case II
// only): the normals at those five vertices held at their rest normals. The same 1.153 N
// force pushes the vertex farthest from face 0 sideways in both cases; each case runs until
// it is at rest (default scheme, T = 0.5 T_max). Written: figure9.csv (final positions and
// best-plane normals of every vertex in both cases), figure9.json (summary) and figure9.png:
// the final shapes of case I and case II side by side from one camera (looking across the
// axis from face 0 to the loaded vertex, so the force lies in the picture), the position
// constraints as red cubes, the normal constraints as blue cubes with arrows along the held
// normals, the force as an orange arrow.

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <iostream>
#include <nlohmann/json.hpp>
#include <numbers>
#include <sstream>

#include "reproduce.h"
#include "zsculpt/constraints/constraints.h"
#include "zsculpt/io/atomic_file.h"
#include "zsculpt/mesh/builtin.h"
#include "zsculpt/physics/matrices.h"
#include "zsculpt/render/renderer.h"
#include "zsculpt/simulation/simulation.h"
#include "zsculpt/subdivision/subdivision.h"

namespace zsculpt::cli {

namespace {

double angleBetween(const Vec3& a, const Vec3& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b));
}

struct CaseResult {
  Points position;
  Points normal;
  double time = 0.0;
  bool settled = false;
  ConstraintReport report;
  Vec3 constraintImpulse = Vec3::Zero();
};

}  // namespace

int reproduceFigure9(const ReproduceOptions& options) {
  io::ensureWritableDirectory(options.out);
  render::OffscreenRenderer renderer;  // IOError when OSMesa cannot give a context
  renderer.checkSize(kPanelWidth, kPanelHeight);
  UniformProperties values;
  values.mass = 0.5;
  values.stiffness = 5.0;
  values.angularStiffness = 0.5;
  values.damping = 0.5;
  const Model model = Model::fromMesh(makeDodecahedron(), values);
  const Mesh& mesh = model.mesh;
  const Points& rest = mesh.positions();
  const double tMax = criticalPeriod(SystemMatrices(model));
  SimulationSettings settings;
  settings.period = 0.5 * tMax;

  const auto face = mesh.face(0);
  const std::vector<Index> red(face.begin(), face.end());
  Vec3 faceCentre = Vec3::Zero();
  for (Index v : red) faceCentre += rest.row(v).transpose();
  faceCentre /= static_cast<double>(red.size());
  Index loaded = 0;
  double farthest = 0.0;
  for (Index v = 0; v < mesh.numVertices(); ++v) {
    const double d = (rest.row(v).transpose() - faceCentre).norm();
    if (d > farthest) {
      farthest = d;
      loaded = v;
    }
  }
  // Sideways: across the axis from face 0 to the loaded vertex.
  const Vec3 axis = (rest.row(loaded).transpose() - faceCentre).normalized();
  Index k = 0;
  axis.cwiseAbs().minCoeff(&k);
  const Vec3 direction = axis.cross(Vec3::Unit(k)).normalized();
  const double force = 1.153;
  std::vector<Vec3> restNormals(static_cast<size_t>(mesh.numVertices()));
  for (Index v = 0; v < mesh.numVertices(); ++v)
    restNormals[static_cast<size_t>(v)] = *bestPlaneNormal(mesh, rest, v);

  const double maxTime = options.quick ? 40.0 : 150.0;
  auto runCase = [&](bool withNormals) {
    Simulation sim(model, settings);
    for (Index v : red) sim.addPositionConstraint(v);
    if (withNormals)
      for (Index v : red) sim.addNormalConstraint(v, restNormals[static_cast<size_t>(v)]);
    sim.addForce(TimedLoad{loaded, force * direction});
    CaseResult result;
    ConstraintReport worst;
    while (sim.time() < maxTime) {
      sim.step();
      const ConstraintReport& r = sim.constraintReport();
      worst.positionError = std::max(worst.positionError, r.positionError);
      worst.normalError = std::max(worst.normalError, r.normalError);
      worst.converged = worst.converged && r.converged;
      worst.steps = std::max(worst.steps, r.steps);
      if (sim.time() > 5.0 && sim.diagnostics().kinetic < 1e-16) {
        result.settled = true;
        break;
      }
    }
    result.time = sim.time();
    result.position = sim.state().position;
    result.normal.resize(mesh.numVertices(), 3);
    for (Index v = 0; v < mesh.numVertices(); ++v)
      result.normal.row(v) = bestPlaneNormal(mesh, result.position, v)->transpose();
    result.report = worst;
    result.constraintImpulse = sim.impulses().constraints;
    return result;
  };
  const CaseResult one = runCase(false);
  const CaseResult two = runCase(true);

  auto isRed = [&](Index v) { return std::find(red.begin(), red.end(), v) != red.end(); };
  std::ostringstream csv;
  csv << std::setprecision(12) << "case,vertex,role,x,y,z,nx,ny,nz,normal_turn_from_rest\n";
  double turnOne = 0.0, turnTwo = 0.0, between = 0.0, loadedMoveOne = 0.0, loadedMoveTwo = 0.0;
  for (const auto& [name, result] : {std::pair<const char*, const CaseResult*>{"I", &one},
                                     std::pair<const char*, const CaseResult*>{"II", &two}}) {
    for (Index v = 0; v < mesh.numVertices(); ++v) {
      const Vec3 n = result->normal.row(v).transpose();
      const double turn = angleBetween(n, restNormals[static_cast<size_t>(v)]);
      const char* role = isRed(v)      ? (result == &two ? "position+normal" : "position")
                         : v == loaded ? "loaded"
                                       : "";
      csv << name << ',' << v << ',' << role << ',' << result->position(v, 0) << ','
          << result->position(v, 1) << ',' << result->position(v, 2) << ',' << n.x() << ',' << n.y()
          << ',' << n.z() << ',' << turn << '\n';
      double& worst = result == &one ? turnOne : turnTwo;
      if (isRed(v)) worst = std::max(worst, turn);
    }
  }
  for (Index v : red)
    between = std::max(between,
                       angleBetween(one.normal.row(v).transpose(), two.normal.row(v).transpose()));
  loadedMoveOne = (one.position.row(loaded) - rest.row(loaded)).norm();
  loadedMoveTwo = (two.position.row(loaded) - rest.row(loaded)).norm();

  auto caseJson = [&](const CaseResult& r, double turn, double move) {
    nlohmann::ordered_json j;
    j["settled"] = r.settled;
    j["time"] = r.time;
    j["max_pin_error"] = r.report.positionError;
    j["max_normal_error"] = r.report.normalError;
    j["max_steps_per_cycle"] = r.report.steps;
    j["max_normal_turn_at_red"] = turn;
    j["loaded_vertex_displacement"] = move;
    j["constraint_impulse"] = {r.constraintImpulse.x(), r.constraintImpulse.y(),
                               r.constraintImpulse.z()};
    return j;
  };
  nlohmann::ordered_json json;
  json["model"] = "builtin:dodecahedron";
  json["mass"] = 0.5;
  json["stiffness"] = 5.0;
  json["angular_stiffness"] = 0.5;
  json["damping"] = 0.5;
  json["dt"] = settings.period;
  json["red_vertices"] = red;
  json["loaded_vertex"] = loaded;
  json["force"] = {force * direction.x(), force * direction.y(), force * direction.z()};
  json["case_I_position"] = caseJson(one, turnOne, loadedMoveOne);
  json["case_II_position_and_normal"] = caseJson(two, turnTwo, loadedMoveTwo);
  json["max_normal_difference_between_cases"] = between;
  const std::string csvPath = options.out + "/figure9.csv";
  const std::string jsonPath = options.out + "/figure9.json";
  io::writeFileAtomically(csvPath, [&](std::ostream& out) { out << csv.str(); });
  io::writeFileAtomically(jsonPath, [&](std::ostream& out) { out << json.dump(2) << '\n'; });

  // The image: both final shapes from one camera, framed on case I with its glyphs.
  const double degrees = 180.0 / std::numbers::pi;
  const SubdivisionStencil stencil(mesh, SubdivisionOptions{});
  render::Frame frame;
  frame.mesh = &mesh;
  frame.stencil = &stencil;
  frame.forces.push_back({loaded, force * direction});
  frame.pins = red;
  const Vec3 across = (axis.cross(direction) - 0.3 * axis).normalized();
  frame.camera.yawDegrees = std::atan2(across.y(), across.x()) * degrees;
  frame.camera.pitchDegrees = std::clamp(std::asin(across.z()) * degrees, -80.0, 80.0);
  frame.positions = &one.position;
  const double aspect = static_cast<double>(kPanelWidth) / kPanelHeight;
  render::frameScene(frame, aspect, 1.3);
  const render::Camera camera = frame.camera;
  frame.positions = &two.position;
  for (Index v : red) frame.normalPins.push_back({v, restNormals[static_cast<size_t>(v)]});
  render::frameScene(frame, aspect, 1.3);
  frame.camera.distance = std::max(frame.camera.distance, camera.distance);
  frame.camera.target = 0.5 * (frame.camera.target + camera.target);
  std::vector<render::Image> panels;
  frame.caption = "II: position (red) and normal (blue) constraints";
  const render::Image caseTwo = renderPanel(renderer, frame);
  frame.positions = &one.position;
  frame.normalPins.clear();
  frame.caption = "I: position (red) constraints";
  panels.push_back(renderPanel(renderer, frame));
  panels.push_back(caseTwo);
  const std::string pngPath = options.out + "/figure9.png";
  savePanels(pngPath, panels);

  std::cout << std::setprecision(4) << "figure 9: dodecahedron, face 0 pinned (red), " << force
            << " N sideways at vertex " << loaded << "\n"
            << "  I  (position):          normals at the red vertices turn up to "
            << turnOne * degrees << " deg; pins held to " << one.report.positionError << "\n"
            << "  II (position + normal): normals at the red vertices turn up to "
            << turnTwo * degrees << " deg; pins held to " << two.report.positionError << "\n"
            << "  the normals of the two cases differ by up to " << between * degrees
            << " deg; the loaded vertex moved " << loadedMoveOne << " (I) and " << loadedMoveTwo
            << " (II)\n"
            << "wrote " << csvPath << ", " << jsonPath << ", " << pngPath << "\n";
  return 0;
}

}  // namespace zsculpt::cli
