// Figure 6 of the paper: "The dodecahedron under external stress (F_ext = 1.153 N). The
// force is applied at the red point. The second image shows the model recoiling after the
// force is removed. The time difference between the two images is three seconds."
//
// Table 1's dodecahedron (mu 0.5, kappa 5, gamma 0) with weak angle springs (0.5 N m/rad^2:
// Table 1 gives none, and without any the pentagons fold freely under a point load).
// 1.153 N pulls vertex 0 radially outwards for 3 s and is then released; the model is
// followed for 3 s more (default scheme, T = 0.1 T_max). The model is free, so the force
// also accelerates it as a whole (F / M = 0.115 m/s^2); shapes are reported about the
// centre of mass. Written: figure6_positions.csv (every vertex at every step),
// figure6_energy.csv, figure6.json (the summary printed below) and figure6.png: three
// instants side by side (the rest shape as the load starts, the stretched shape at release
// 3 s later, the recoiling shape at the end), the loaded vertex as a red point and the
// force as an orange arrow while it acts. The camera follows the centre of mass at one
// distance and orientation, so that the panels compare shapes, not the drift.

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

Vec3 centreOfMass(const VectorX& mass, const Points& p) {
  Vec3 c = Vec3::Zero();
  for (Index i = 0; i < p.rows(); ++i) c += mass[i] * p.row(i).transpose();
  return c / mass.sum();
}

// Largest relative change of an edge's length from its rest length.
double maxStrain(const Model& model, const Points& p) {
  double worst = 0.0;
  for (Index e = 0; e < model.mesh.numEdges(); ++e) {
    const auto [i, j] = model.mesh.edge(e);
    const double rest = model.properties.restLength[e];
    worst = std::max(worst, std::abs((p.row(i) - p.row(j)).norm() - rest) / rest);
  }
  return worst;
}

}  // namespace

int reproduceFigure6(const ReproduceOptions& options) {
  io::ensureWritableDirectory(options.out);
  render::OffscreenRenderer renderer;  // IOError when OSMesa cannot give a context
  renderer.checkSize(kPanelWidth, kPanelHeight);
  UniformProperties values;
  values.mass = 0.5;
  values.stiffness = 5.0;
  values.angularStiffness = 0.5;
  Model model = Model::fromMesh(makeDodecahedron(), values);
  const double tMax = criticalPeriod(SystemMatrices(model));
  SimulationSettings settings;
  settings.period = 0.1 * tMax;
  const Index loaded = 0;
  const double force = 1.153;
  const double release = 3.0, end = options.quick ? 4.0 : 6.0;
  const Vec3 direction = model.mesh.positions().row(loaded).normalized().transpose();
  Simulation sim(std::move(model), settings);
  sim.addForce(TimedLoad{loaded, force * direction, 0.0, release});
  const VectorX& mass = sim.model().properties.mass;
  const Points rest = sim.model().mesh.positions();
  const double restRadius = (rest.row(loaded).transpose() - centreOfMass(mass, rest)).norm();

  std::ostringstream positions, energy;
  positions << std::setprecision(12) << "step,time,loaded,vertex,x,y,z\n";
  energy << std::setprecision(12) << "step,time,loaded,kinetic,potential,total,px,py,pz\n";
  long step = 0;
  auto record = [&]() {
    const bool on = sim.time() < release;
    const Points& p = sim.state().position;
    for (Index v = 0; v < p.rows(); ++v)
      positions << step << ',' << sim.time() << ',' << on << ',' << v << ',' << p(v, 0) << ','
                << p(v, 1) << ',' << p(v, 2) << '\n';
    const Diagnostics d = sim.diagnostics();
    energy << step << ',' << sim.time() << ',' << on << ',' << d.kinetic << ','
           << d.potential.total() << ',' << d.total() << ',' << d.momentum.x() << ','
           << d.momentum.y() << ',' << d.momentum.z() << '\n';
  };
  // The loaded vertex's distance from the centre of mass: its stretch under the load.
  auto radius = [&]() {
    const Points& p = sim.state().position;
    return (p.row(loaded).transpose() - centreOfMass(mass, p)).norm();
  };
  record();
  double peakRadius = restRadius, peakStrain = 0.0, releasedRadius = 0.0, releasedStrain = 0.0;
  double minAfter = INFINITY, maxAfter = 0.0;
  Diagnostics atRelease;
  Points atReleasePosition = rest;
  double atReleaseTime = 0.0;
  while (sim.time() < end - 0.5 * settings.period) {
    const bool wasOn = sim.time() < release;
    sim.step();
    ++step;
    record();
    const double r = radius();
    if (sim.time() <= release + 0.5 * settings.period) {
      peakRadius = std::max(peakRadius, r);
      peakStrain = std::max(peakStrain, maxStrain(sim.model(), sim.state().position));
    }
    if (wasOn && sim.time() >= release - 0.5 * settings.period) {
      releasedRadius = r;
      releasedStrain = maxStrain(sim.model(), sim.state().position);
      atRelease = sim.diagnostics();
      atReleasePosition = sim.state().position;
      atReleaseTime = sim.time();
    }
    if (!wasOn) {
      minAfter = std::min(minAfter, r);
      maxAfter = std::max(maxAfter, r);
    }
  }
  const Diagnostics last = sim.diagnostics();
  const double finalRadius = radius();

  nlohmann::ordered_json json;
  json["model"] = "builtin:dodecahedron";
  json["mass"] = 0.5;
  json["stiffness"] = 5.0;
  json["angular_stiffness"] = 0.5;
  json["damping"] = 0.0;
  json["dt"] = settings.period;
  json["t_max"] = tMax;
  json["loaded_vertex"] = loaded;
  json["force"] = {force * direction.x(), force * direction.y(), force * direction.z()};
  json["release_time"] = release;
  json["end_time"] = sim.time();
  json["rest_radius"] = restRadius;
  json["peak_radius_under_load"] = peakRadius;
  json["peak_strain_under_load"] = peakStrain;
  json["radius_at_release"] = releasedRadius;
  json["strain_at_release"] = releasedStrain;
  json["recoil_radius_range"] = {minAfter, maxAfter};
  json["radius_at_end"] = finalRadius;
  json["energy_at_release"] = atRelease.total();
  json["energy_at_end"] = last.total();
  json["momentum_at_end"] = {last.momentum.x(), last.momentum.y(), last.momentum.z()};
  json["momentum_expected"] = force * release;  // the load's impulse, along the force
  const std::string positionsPath = options.out + "/figure6_positions.csv";
  const std::string energyPath = options.out + "/figure6_energy.csv";
  const std::string jsonPath = options.out + "/figure6.json";
  io::writeFileAtomically(positionsPath, [&](std::ostream& out) { out << positions.str(); });
  io::writeFileAtomically(energyPath, [&](std::ostream& out) { out << energy.str(); });
  io::writeFileAtomically(jsonPath, [&](std::ostream& out) { out << json.dump(2) << '\n'; });

  // The image: the three instants, the camera framed on the stretched shape with its arrow.
  const SubdivisionStencil stencil(sim.model().mesh, SubdivisionOptions{});
  render::Frame frame;
  frame.mesh = &sim.model().mesh;
  frame.stencil = &stencil;
  frame.markers.push_back({loaded, render::Color::hex(0xd62728)});
  frame.positions = &atReleasePosition;
  frame.forces.push_back({loaded, force * direction});
  // From beside the force, a little in front of the loaded vertex and above it: the arrow
  // lies nearly in the picture and the red point faces the camera.
  const Vec3 side = direction.cross(Vec3::UnitZ()).norm() > 1e-6
                        ? direction.cross(Vec3::UnitZ()).normalized()
                        : Vec3::UnitX();
  const Vec3 eye = (side + 0.7 * direction + 0.3 * Vec3::UnitZ()).normalized();
  frame.camera.yawDegrees = std::atan2(eye.y(), eye.x()) * 180.0 / std::numbers::pi;
  frame.camera.pitchDegrees =
      std::clamp(std::asin(eye.z()) * 180.0 / std::numbers::pi, -80.0, 80.0);
  render::frameScene(frame, static_cast<double>(kPanelWidth) / kPanelHeight, 1.3);
  const Vec3 offset = frame.camera.target - centreOfMass(mass, atReleasePosition);
  const Points& endPosition = sim.state().position;
  struct Instant {
    const Points* position;
    bool loadOn;
    std::string caption;
  };
  char text[3][96];
  std::snprintf(text[0], sizeof text[0], "t = 0 s: %.3f N applied at the red point", force);
  std::snprintf(text[1], sizeof text[1], "t = %.2f s: under load, released", atReleaseTime);
  std::snprintf(text[2], sizeof text[2], "t = %.2f s: recoiling, %.2f s after release", sim.time(),
                sim.time() - atReleaseTime);
  std::vector<render::Image> panels;
  for (const Instant& instant :
       {Instant{&rest, true, text[0]}, Instant{&atReleasePosition, true, text[1]},
        Instant{&endPosition, false, text[2]}}) {
    frame.positions = instant.position;
    frame.forces.clear();
    if (instant.loadOn) frame.forces.push_back({loaded, force * direction});
    frame.camera.target = centreOfMass(mass, *instant.position) + offset;
    frame.caption = instant.caption;
    panels.push_back(renderPanel(renderer, frame));
  }
  const std::string pngPath = options.out + "/figure6.png";
  savePanels(pngPath, panels);

  std::cout << std::setprecision(4) << "figure 6: dodecahedron (mu 0.5, kappa 5), " << force
            << " N outwards at vertex " << loaded << " for " << release << " s, then released\n"
            << "  loaded vertex from the centre of mass: rest " << restRadius
            << ", under load up to " << peakRadius << " (strain " << peakStrain << "), "
            << releasedRadius << " at release\n"
            << "  after release it recoils between " << minAfter << " and " << maxAfter << " ("
            << finalRadius << " after " << sim.time() - release << " s); energy "
            << atRelease.total() << " J at release, " << last.total()
            << " J at the end (no damping)\n"
            << "  momentum " << last.momentum.norm() << " kg m/s = the load's impulse "
            << force * release << " N s\n"
            << "wrote " << positionsPath << ", " << energyPath << ", " << jsonPath << ", "
            << pngPath << "\n";
  return 0;
}

}  // namespace zsculpt::cli
