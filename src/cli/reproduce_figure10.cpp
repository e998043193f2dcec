// Figure 10 of the paper: "Torsional forces on a planar mesh under multiple constraints. The
// torque (tau_ext = 1.3 J/rad) is applied near the central region of the mesh. The first
// image shows the mesh for an anti-clockwise torque. The second image is due to a clockwise
// torque."
//
// Table 1's open surface (builtin:grid, 18 x 18, mu 0.31, kappa 5.16) with angle springs
// 1.0 (a torque in the plane is resisted by them alone: quads have no diagonal springs) and
// damping 0.3 so that it settles. Its four corners are pinned. A torque of 1.3 N m about
// +z (anticlockwise seen from above) acts at vertex (8, 8) until the mesh is at rest, then
// -1.3 N m (clockwise) until it is at rest again (default scheme, T = 0.5 T_max). Written:
// figure10_positions.csv (rest and both final shapes), figure10.json (summary) and
// figure10.png: the rest shape, the shape at rest under the anticlockwise torque and under
// the clockwise one, side by side from one camera looking down on the mesh, the pinned
// corners as red cubes, the torque as a purple axis arrow with a ring arc turning its way,
// the surface coloured by the displacement along the turn (red anticlockwise, blue
// clockwise; the shapes differ by centimetres on a 17 m mesh).

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iomanip>
#include <iostream>
#include <nlohmann/json.hpp>
#include <numbers>
#include <sstream>

#include "reproduce.h"
#include "zsculpt/io/atomic_file.h"
#include "zsculpt/mesh/builtin.h"
#include "zsculpt/physics/matrices.h"
#include "zsculpt/render/renderer.h"
#include "zsculpt/simulation/simulation.h"
#include "zsculpt/subdivision/subdivision.h"

namespace zsculpt::cli {

namespace {

// The mean turn (rad, about +z) of the vertex's one-ring about it, from `rest` to `now`.
double ringTurn(const Mesh& mesh, const Points& rest, const Points& now, Index centre) {
  double sum = 0.0;
  for (Index w : mesh.vertexNeighbors(centre)) {
    const Vec3 a = (rest.row(w) - rest.row(centre)).transpose();
    const Vec3 b = (now.row(w) - now.row(centre)).transpose();
    sum += std::atan2(a.cross(b).z(), a.head<2>().dot(b.head<2>()));
  }
  return sum / static_cast<double>(mesh.valence(centre));
}

}  // namespace

int reproduceFigure10(const ReproduceOptions& options) {
  io::ensureWritableDirectory(options.out);
  render::OffscreenRenderer renderer;  // IOError when OSMesa cannot give a context
  renderer.checkSize(kPanelWidth, kPanelHeight);
  UniformProperties values;
  values.mass = 0.31;
  values.stiffness = 5.16;
  values.angularStiffness = 1.0;
  values.damping = 0.3;
  const Index n = 18;
  Model model = Model::fromMesh(makeGrid(n), values);
  const double tMax = criticalPeriod(SystemMatrices(model));
  SimulationSettings settings;
  settings.period = 0.5 * tMax;
  const Index centre = 8 + n * 8;
  const std::vector<Index> pins = {0, n - 1, n * (n - 1), n * n - 1};
  const double torque = 1.3;
  Simulation sim(std::move(model), settings);
  const Mesh& mesh = sim.model().mesh;
  const Points rest = mesh.positions();
  for (Index v : pins) sim.addPositionConstraint(v);

  const double phaseTime = options.quick ? 30.0 : 120.0;
  struct Phase {
    Points position;
    double start = 0.0, end = 0.0, turn = 0.0, maxDisplacement = 0.0, outOfPlane = 0.0;
    bool settled = false;
  };
  auto runPhase = [&](double sign) {
    Phase phase;
    phase.start = sim.time();
    sim.clearLoads();
    sim.addTorque(TimedLoad{centre, Vec3(0.0, 0.0, sign * torque), sim.time()});
    while (sim.time() < phase.start + phaseTime) {
      sim.step();
      if (sim.time() > phase.start + 5.0 && sim.diagnostics().kinetic < 1e-16) {
        phase.settled = true;
        break;
      }
    }
    phase.end = sim.time();
    phase.position = sim.state().position;
    phase.turn = ringTurn(mesh, rest, phase.position, centre);
    phase.maxDisplacement = (phase.position - rest).rowwise().norm().maxCoeff();
    phase.outOfPlane = phase.position.col(2).cwiseAbs().maxCoeff();
    return phase;
  };
  const Phase anticlockwise = runPhase(+1.0);
  const Phase clockwise = runPhase(-1.0);
  double pinError = 0.0;
  for (Index v : pins)
    pinError = std::max(pinError, (clockwise.position.row(v) - rest.row(v)).norm());

  std::ostringstream csv;
  csv << std::setprecision(12) << "shape,vertex,pinned,torqued,x,y,z\n";
  for (const auto& [name, p] : {std::pair<const char*, const Points*>{"rest", &rest},
                                {"anticlockwise", &anticlockwise.position},
                                {"clockwise", &clockwise.position}})
    for (Index v = 0; v < mesh.numVertices(); ++v)
      csv << name << ',' << v << ',' << (std::find(pins.begin(), pins.end(), v) != pins.end())
          << ',' << (v == centre) << ',' << (*p)(v, 0) << ',' << (*p)(v, 1) << ',' << (*p)(v, 2)
          << '\n';

  auto phaseJson = [](const Phase& p, double sign) {
    nlohmann::ordered_json j;
    j["torque_z"] = sign * 1.3;
    j["start"] = p.start;
    j["end"] = p.end;
    j["settled"] = p.settled;
    j["ring_turn_rad"] = p.turn;
    j["max_displacement"] = p.maxDisplacement;
    j["max_out_of_plane"] = p.outOfPlane;
    return j;
  };
  nlohmann::ordered_json json;
  json["model"] = "builtin:grid";
  json["mass"] = 0.31;
  json["stiffness"] = 5.16;
  json["angular_stiffness"] = 1.0;
  json["damping"] = 0.3;
  json["dt"] = settings.period;
  json["pinned"] = pins;
  json["torque_vertex"] = centre;
  json["anticlockwise"] = phaseJson(anticlockwise, +1.0);
  json["clockwise"] = phaseJson(clockwise, -1.0);
  json["max_pin_error"] = pinError;
  const std::string csvPath = options.out + "/figure10_positions.csv";
  const std::string jsonPath = options.out + "/figure10.json";
  io::writeFileAtomically(csvPath, [&](std::ostream& out) { out << csv.str(); });
  io::writeFileAtomically(jsonPath, [&](std::ostream& out) { out << json.dump(2) << '\n'; });

  // The image: rest, anticlockwise, clockwise, from one camera above the mesh. The largest
  // displacement is about 3 cm on a 17 m mesh, too small to see as a shape: the surface is
  // coloured by each vertex's displacement along the turn about the torqued vertex
  // (anticlockwise positive, red; clockwise negative, blue), on one range for all panels.
  const double degrees = 180.0 / std::numbers::pi;
  const SubdivisionStencil stencil(mesh, SubdivisionOptions{});
  auto tangential = [&](const Points& p) {
    VectorX t = VectorX::Zero(mesh.numVertices());
    for (Index v = 0; v < mesh.numVertices(); ++v) {
      const Vec3 arm = (rest.row(v) - rest.row(centre)).transpose();
      if (arm.norm() == 0.0) continue;
      const Vec3 along = Vec3::UnitZ().cross(arm).normalized();
      t[v] = 1000.0 * along.dot((p.row(v) - rest.row(v)).transpose());  // mm
    }
    return t;
  };
  const VectorX restTurn = VectorX::Zero(mesh.numVertices());
  const VectorX anticlockwiseTurn = tangential(anticlockwise.position);
  const VectorX clockwiseTurn = tangential(clockwise.position);
  const double range = std::max(
      {anticlockwiseTurn.cwiseAbs().maxCoeff(), clockwiseTurn.cwiseAbs().maxCoeff(), 1e-9});
  render::Frame frame;
  frame.mesh = &mesh;
  frame.stencil = &stencil;
  frame.display.controlWireframe = true;
  frame.pins = pins;
  frame.scalar.name = "displacement along the turn (mm)";
  frame.scalar.autoRange = false;
  frame.scalar.min = -range;
  frame.scalar.max = range;
  frame.scalar.map = render::ColorMap::Diverging;
  frame.camera.yawDegrees = -90.0;
  frame.camera.pitchDegrees = 75.0;
  frame.positions = &rest;
  frame.scalar.values = &restTurn;
  frame.torques.push_back({centre, Vec3(0.0, 0.0, torque)});
  render::frameScene(frame, static_cast<double>(kPanelWidth) / kPanelHeight, 1.45);
  frame.camera.target.x() +=
      0.05 * frame.camera.distance;  // clear of the legend (view's right: +x)
  std::vector<render::Image> panels;
  char text[2][96];
  std::snprintf(text[0], sizeof text[0], "+%.1f N m (anticlockwise): ring turns %+.1f deg", torque,
                anticlockwise.turn * degrees);
  std::snprintf(text[1], sizeof text[1], "-%.1f N m (clockwise): ring turns %+.1f deg", torque,
                clockwise.turn * degrees);
  frame.torques.clear();
  frame.caption = "rest, four corners pinned";
  panels.push_back(renderPanel(renderer, frame));
  frame.positions = &anticlockwise.position;
  frame.scalar.values = &anticlockwiseTurn;
  frame.torques = {{centre, Vec3(0.0, 0.0, torque)}};
  frame.caption = text[0];
  panels.push_back(renderPanel(renderer, frame));
  frame.positions = &clockwise.position;
  frame.scalar.values = &clockwiseTurn;
  frame.torques = {{centre, Vec3(0.0, 0.0, -torque)}};
  frame.caption = text[1];
  panels.push_back(renderPanel(renderer, frame));
  const std::string pngPath = options.out + "/figure10.png";
  savePanels(pngPath, panels);

  std::cout << std::setprecision(4) << "figure 10: open surface (18 x 18), corners pinned, "
            << torque << " N m at vertex " << centre << "\n"
            << "  anticlockwise: the ring about it turns " << anticlockwise.turn * degrees
            << " deg (largest displacement " << anticlockwise.maxDisplacement << ")\n"
            << "  clockwise:     the ring about it turns " << clockwise.turn * degrees
            << " deg (largest displacement " << clockwise.maxDisplacement << ")\n"
            << "  pins held to " << pinError << "; the mesh stays in its plane (|z| <= "
            << std::max(anticlockwise.outOfPlane, clockwise.outOfPlane) << ")\n"
            << "wrote " << csvPath << ", " << jsonPath << ", " << pngPath << "\n";
  return 0;
}

}  // namespace zsculpt::cli
