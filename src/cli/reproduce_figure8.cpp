// Figure 8 of the paper: "Editing: the local rest-length (red points) and local rest-angle
// (blue point) for the torus are modified. The total internal stress is non-zero, since the
// restoring forces for the rest-length and rest-angle oppose each other."
//
// Torus-I (10 x 10 quads, Table 1's mu 0.1 and kappa 5) with angle springs and damping.
// Two dabs at t = 0, applied through the editing module as a user would paint them:
//   red:  rest lengths x 1.5 around vertex 0 (vertices 0, 10, 90: surface radius 1,
//         constant falloff; an edge with one end inside gets half the weight, x 1.25),
//   blue: rest angles x 0.8 at vertex 1, next to the red points.
// The model is then simulated (default scheme, 0.5 T_max) until it is at rest. Written:
// figure8_energy.csv (energy over time), figure8_shape.csv (rest and final positions per
// vertex with its role), figure8.json (the summary printed below) and figure8.png: three
// panels, the torus before (rest shape, just edited) and after it came to rest, seen from
// the same oblique camera, then the after shape from the side (as the paper's third image);
// the edited rest lengths' vertices are red points, the edited rest angle's vertex blue,
// on the level-2 surface.

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iomanip>
#include <iostream>
#include <sstream>

#include "reproduce.h"
#include "zsculpt/editing/editor.h"
#include "zsculpt/editing/local_update.h"
#include "zsculpt/io/atomic_file.h"
#include "zsculpt/mesh/builtin.h"
#include "zsculpt/physics/diagnostics.h"
#include "zsculpt/physics/forces.h"
#include "zsculpt/render/renderer.h"
#include "zsculpt/simulation/simulation.h"
#include "zsculpt/subdivision/subdivision.h"

namespace zsculpt::cli {

namespace {

double maxForce(const Model& model, const Points& position) {
  Points force = Points::Zero(position.rows(), 3);
  accumulateInternalForces(model, position, force);
  return force.rowwise().norm().maxCoeff();
}

std::string number(double x) {
  if (!std::isfinite(x)) return "null";
  std::ostringstream s;
  s << std::setprecision(10) << x;
  return s.str();
}

}  // namespace

int reproduceFigure8(const ReproduceOptions& options) {
  io::ensureWritableDirectory(options.out);
  render::OffscreenRenderer renderer;  // IOError when OSMesa cannot give a context
  renderer.checkSize(kPanelWidth, kPanelHeight);
  UniformProperties values;
  values.mass = 0.1;  // Table 1, Torus-I
  values.stiffness = 5.0;
  values.angularStiffness = 0.5;
  values.damping = 0.1;  // gamma = 0.5 / s: settles in tens of seconds
  Model model = Model::fromMesh(makeTorus(10, 10), values);
  const double tMax = criticalPeriod(SystemMatrices(model));
  SimulationSettings settings;
  settings.period = 0.5 * tMax;
  Simulation sim(std::move(model), settings);
  const Points rest = sim.model().mesh.positions();

  // The two dabs, as the paper's user painted them.
  editing::Editor editor(sim.model().mesh, sim.model().angles);
  editing::EditTarget target{sim.model().mesh, sim.model().angles, sim.mutableProperties()};
  editing::Dab red;
  red.brush.property = Property::RestLength;
  red.brush.mode = editing::BrushMode::Multiply;
  red.brush.value = 1.5;
  red.brush.radius = 1.0;
  red.brush.falloff = editing::Falloff::Constant;
  red.centre = editing::BrushCentre::atVertex(0);
  editing::Dab blue;
  blue.brush.property = Property::RestAngle;
  blue.brush.mode = editing::BrushMode::Multiply;
  blue.brush.value = 0.8;
  blue.brush.radius = 0.1;
  blue.brush.falloff = editing::Falloff::Constant;
  blue.centre = editing::BrushCentre::atVertex(1);

  const editing::EditResult redResult = editor.apply(target, sim.state(), red);
  const std::vector<Index> redPoints(editor.lastRegion().vertices().begin(),
                                     editor.lastRegion().vertices().end());
  const Index redEdges = redResult.entriesChanged;
  const size_t redRows = redResult.matrixRows.size();
  sim.propertiesChanged(redResult.matrixRows);
  const editing::EditResult blueResult = editor.apply(target, sim.state(), blue);
  const Index blueAngles = blueResult.entriesChanged;
  const size_t blueRows = blueResult.matrixRows.size();
  sim.propertiesChanged(blueResult.matrixRows);
  const double storedEnergy = redResult.energy.total() + blueResult.energy.total();
  const double tMaxAfter = criticalPeriod(sim.stepper().system());
  const double matrixDifference = editing::verifyAgainstRebuild(sim.model(), sim.stepper().system(),
                                                                sim.stepper().transformation())
                                      .maxAbs();

  // Simulate until at rest.
  const double startForce = maxForce(sim.model(), sim.state().position);
  const double maxTime = options.quick ? 30.0 : 120.0;
  std::ostringstream energyCsv;
  energyCsv << std::setprecision(12) << "step,time,kinetic,radial,angular,total\n";
  long step = 0;
  double settledAt = -1.0;
  Diagnostics d = sim.diagnostics();
  const double startPotential = d.potential.total();
  auto row = [&]() {
    energyCsv << step << ',' << sim.time() << ',' << d.kinetic << ',' << d.potential.radial << ','
              << d.potential.angular << ',' << d.total() << '\n';
  };
  row();
  while (sim.time() < maxTime) {
    sim.step();
    ++step;
    d = sim.diagnostics();
    if (step % 5 == 0) row();
    const double force = maxForce(sim.model(), sim.state().position);
    if (d.kinetic < 1e-14 * startPotential && force < 1e-6 * startForce) {
      settledAt = sim.time();
      row();
      break;
    }
  }
  const Points& final = sim.state().position;
  const double endForce = maxForce(sim.model(), final);

  // Where the stress sits: the springs of the red points and the blue point.
  const Model& m = sim.model();
  std::vector<char> role(static_cast<size_t>(m.mesh.numVertices()), 0);
  for (Index v : redPoints) role[static_cast<size_t>(v)] = 'r';
  role[1] = 'b';
  double radialNearRed = 0.0, angularAtBlue = 0.0;
  for (Index e = 0; e < m.mesh.numEdges(); ++e) {
    const auto [i, j] = m.mesh.edge(e);
    if (!role[static_cast<size_t>(i)] && !role[static_cast<size_t>(j)]) continue;
    const double stretch = (final.row(i) - final.row(j)).norm() - m.properties.restLength[e];
    radialNearRed += 0.5 * edgeStiffness(m.properties.stiffness[i], m.properties.stiffness[j]) *
                     stretch * stretch;
  }
  for (Index k = m.angles.vertexOffsets[1]; k < m.angles.vertexOffsets[2]; ++k) {
    const auto [c, a, b] = m.angles.angles[static_cast<size_t>(k)];
    angularAtBlue += angleSpringEnergy(angleAt(final.row(c), final.row(a), final.row(b)),
                                       m.properties.restAngle[k], m.properties.angularStiffness[c]);
  }
  double redDisplacement = 0.0;
  for (Index v : redPoints)
    redDisplacement = std::max(redDisplacement, (final.row(v) - rest.row(v)).norm());
  const double blueDisplacement = (final.row(1) - rest.row(1)).norm();
  double farDisplacement = 0.0;  // the far side of the torus (u = 5)
  for (Index v = 0; v < 10; ++v)
    farDisplacement =
        std::max(farDisplacement, (final.row(5 + 10 * v) - rest.row(5 + 10 * v)).norm());

  std::ostringstream shape;
  shape << std::setprecision(12) << "vertex,x0,y0,z0,x,y,z,displacement,role\n";
  for (Index v = 0; v < m.mesh.numVertices(); ++v) {
    const char r = role[static_cast<size_t>(v)];
    shape << v << ',' << rest(v, 0) << ',' << rest(v, 1) << ',' << rest(v, 2) << ',' << final(v, 0)
          << ',' << final(v, 1) << ',' << final(v, 2) << ',' << (final.row(v) - rest.row(v)).norm()
          << ','
          << (r == 'r'   ? "rest_length"
              : r == 'b' ? "rest_angle"
                         : "")
          << '\n';
  }
  std::ostringstream json;
  json << "{\n"
       << "  \"model\": \"builtin:torus\",\n"
       << "  \"mass\": 0.1, \"stiffness\": 5, \"angular_stiffness\": 0.5, \"damping\": 0.1,\n"
       << "  \"dt\": " << number(settings.period) << ",\n"
       << "  \"t_max_before\": " << number(tMax) << ",\n"
       << "  \"t_max_after\": " << number(tMaxAfter) << ",\n"
       << "  \"red_points\": [";
  for (size_t k = 0; k < redPoints.size(); ++k) json << (k ? ", " : "") << redPoints[k];
  json << "],\n"
       << "  \"red_edges_changed\": " << redEdges << ",\n"
       << "  \"blue_point\": 1,\n"
       << "  \"blue_angles_changed\": " << blueAngles << ",\n"
       << "  \"matrix_rows_updated\": " << redRows + blueRows << ",\n"
       << "  \"matrix_update_max_abs_diff\": " << number(matrixDifference) << ",\n"
       << "  \"energy_stored_by_edits\": " << number(storedEnergy) << ",\n"
       << "  \"settled\": " << (settledAt >= 0.0 ? "true" : "false") << ",\n"
       << "  \"settled_at\": " << number(settledAt >= 0.0 ? settledAt : NAN) << ",\n"
       << "  \"steps\": " << step << ",\n"
       << "  \"max_force_start\": " << number(startForce) << ",\n"
       << "  \"max_force_end\": " << number(endForce) << ",\n"
       << "  \"radial_energy_end\": " << number(d.potential.radial) << ",\n"
       << "  \"angular_energy_end\": " << number(d.potential.angular) << ",\n"
       << "  \"radial_energy_near_red\": " << number(radialNearRed) << ",\n"
       << "  \"angular_energy_at_blue\": " << number(angularAtBlue) << ",\n"
       << "  \"red_displacement\": " << number(redDisplacement) << ",\n"
       << "  \"blue_displacement\": " << number(blueDisplacement) << ",\n"
       << "  \"far_side_displacement\": " << number(farDisplacement) << "\n"
       << "}\n";
  const std::string energyPath = options.out + "/figure8_energy.csv";
  const std::string shapePath = options.out + "/figure8_shape.csv";
  const std::string jsonPath = options.out + "/figure8.json";
  io::writeFileAtomically(energyPath, [&](std::ostream& out) { out << energyCsv.str(); });
  io::writeFileAtomically(shapePath, [&](std::ostream& out) { out << shape.str(); });
  io::writeFileAtomically(jsonPath, [&](std::ostream& out) { out << json.str(); });

  // The image: before and after from one camera, then after from the side.
  const SubdivisionStencil stencil(m.mesh, SubdivisionOptions{});
  render::Frame frame;
  frame.mesh = &m.mesh;
  frame.stencil = &stencil;
  for (Index v : redPoints) frame.markers.push_back({v, render::Color::hex(0xd62728)});
  frame.markers.push_back({1, render::Color::hex(0x1f5fd6)});
  frame.positions = &final;
  frame.camera.yawDegrees = 5.0;  // facing the red (azimuth 0) and blue (36 deg) points
  frame.camera.pitchDegrees = 35.0;
  const double aspect = static_cast<double>(kPanelWidth) / kPanelHeight;
  render::frameScene(frame, aspect, 1.15);
  std::vector<render::Image> panels;
  frame.positions = &rest;
  frame.caption = "before: rest lengths x1.5 (red), rest angle x0.8 (blue)";
  panels.push_back(renderPanel(renderer, frame));
  frame.positions = &final;
  char caption[96];
  std::snprintf(caption, sizeof caption, "after: at rest, t = %.1f s", sim.time());
  frame.caption = caption;
  panels.push_back(renderPanel(renderer, frame));
  frame.camera.yawDegrees = -25.0;
  frame.camera.pitchDegrees = 0.0;
  render::frameScene(frame, aspect, 1.15);
  frame.caption = "after, from the side";
  panels.push_back(renderPanel(renderer, frame));
  const std::string pngPath = options.out + "/figure8.png";
  savePanels(pngPath, panels);

  std::cout << std::setprecision(4) << "figure 8: Torus-I, rest lengths x1.5 at the red points {";
  for (size_t k = 0; k < redPoints.size(); ++k) std::cout << (k ? ", " : "") << redPoints[k];
  std::cout << "} (" << redEdges << " edges), rest angles x0.8 at the blue point 1 (" << blueAngles
            << " angles)\n"
            << "  matrix rows updated by the edits: " << redRows + blueRows
            << " (a rest length enters K only where shorter than as loaded); T_max " << tMax
            << " -> " << tMaxAfter << " s\n"
            << "  energy stored by the edits at the rest shape: " << storedEnergy << " J\n"
            << "  " << (settledAt >= 0.0 ? "at rest after " : "not at rest after ")
            << (settledAt >= 0.0 ? settledAt : sim.time()) << " s (" << step
            << " steps); largest force " << startForce << " -> " << endForce << " N\n"
            << "  internal stress at rest: radial " << d.potential.radial << " J (" << radialNearRed
            << " J at the red points' edges), angular " << d.potential.angular << " J ("
            << angularAtBlue << " J at the blue point)\n"
            << "  paper: the stress stays non-zero because the rest-length and rest-angle "
               "springs oppose each other: "
            << (d.potential.radial > 0.0 && d.potential.angular > 0.0 ? "reproduced"
                                                                      : "NOT reproduced")
            << "\n"
            << "  displacement: red " << redDisplacement << ", blue " << blueDisplacement
            << ", far side " << farDisplacement << " m\n"
            << "wrote " << energyPath << ", " << shapePath << ", " << jsonPath << ", " << pngPath
            << "\n";
  return 0;
}

}  // namespace zsculpt::cli
