#include "zsculpt/app/view.h"

#include <algorithm>
#include <cstdio>

#include "zsculpt/core/errors.h"

namespace zsculpt::app {

int affordableLevels(const Mesh& mesh, int wanted, Index maxRefinedVertices) {
  // Estimated without building the stencil (subdivision.h), as the stencil refuses.
  return levelsWithin(mesh, wanted, static_cast<double>(maxRefinedVertices));
}

int levelsForImage(const Mesh& mesh, int width, int height, Index maxRefinedVertices) {
  const int side = std::min(width, height);
  const double diagonal = mesh.boundingBox().diagonal();
  double sum = 0.0;
  for (const auto& [a, b] : mesh.edges())
    sum += (mesh.positions().row(a) - mesh.positions().row(b)).norm();
  const double meanEdge = mesh.numEdges() > 0 ? sum / static_cast<double>(mesh.numEdges()) : 0.0;
  // Framed, the bounding box's diagonal spans about the image's shorter side.
  const double edgePixels = diagonal > 0.0 ? meanEdge / diagonal * side : 0.0;
  int levels = 2;
  while (levels < 5 && edgePixels / static_cast<double>(1 << levels) > 8.0) ++levels;
  return affordableLevels(mesh, levels, maxRefinedVertices);
}

void applyCameraSettings(const io::CameraSettings& s, render::Camera& camera) {
  if (s.target) camera.target = *s.target;
  if (s.distance) camera.distance = *s.distance;
  if (s.yaw) camera.yawDegrees = *s.yaw;
  if (s.pitch) camera.pitchDegrees = std::clamp(*s.pitch, -89.0, 89.0);
  if (s.fov) camera.fovYDegrees = *s.fov;
}

io::CameraSettings cameraSettingsOf(const render::Camera& camera) {
  io::CameraSettings s;
  s.target = camera.target;
  s.distance = camera.distance;
  s.yaw = camera.yawDegrees;
  s.pitch = camera.pitchDegrees;
  s.fov = camera.fovYDegrees;
  return s;
}

FrameBuilder::FrameBuilder(const Mesh& mesh) : mesh_(mesh) {}

void FrameBuilder::setLevels(int levels) {
  levels = std::clamp(levels, 0, 10);
  if (levels == levels_) return;
  if (levels == 0) {
    stencil_.reset();
  } else {
    SubdivisionOptions options;
    options.levels = levels;
    stencil_ = std::make_unique<SubdivisionStencil>(mesh_, options);
  }
  levels_ = levels;
  ++topologyVersion_;
}

render::Frame& FrameBuilder::build(const Snapshot& snapshot, const ViewSettings& view,
                                   const render::Camera& camera) {
  if (levels_ < 0) setLevels(view.levels);
  render::Frame& f = frame_;
  f.mesh = &mesh_;
  f.stencil = stencil_.get();
  f.positions = snapshot.position.rows() == mesh_.numVertices() ? &snapshot.position : nullptr;
  f.topologyVersion = topologyVersion_;
  f.display.surface = view.surface;
  f.display.controlWireframe = view.wireframe;
  f.display.surfaceWireframe = view.surfaceWireframe;
  f.display.controlPoints = view.points;
  f.display.glyphs = view.glyphs;
  f.display.legend = view.colourByProperty;
  f.display.legendOpacity = 1.0f;  // the window fades it for its own frame only
  if (view.colourByProperty && snapshot.scalar.size() == mesh_.numVertices()) {
    f.scalar.values = &snapshot.scalar;
    // The legend's label is made again only when the property changes: no allocation per
    // frame.
    if (!labelled_ || *labelled_ != snapshot.scalarProperty) {
      f.scalar.name = propertyLabel(snapshot.scalarProperty);
      labelled_ = snapshot.scalarProperty;
    }
    f.scalar.autoRange = view.autoRange;
    f.scalar.min = view.rangeMin;
    f.scalar.max = view.rangeMax;
    f.scalar.map = view.colorMap;
  } else {
    f.scalar.values = nullptr;
  }
  f.pins.assign(snapshot.pins.begin(), snapshot.pins.end());
  f.normalPins.clear();
  for (const auto& [v, n] : snapshot.normalPins) f.normalPins.push_back({v, n});
  f.forces.clear();
  for (const auto& [v, value] : snapshot.forces) f.forces.push_back({v, value});
  f.torques.clear();
  for (const auto& [v, value] : snapshot.torques) f.torques.push_back({v, value});
  f.markers.clear();
  if (snapshot.dragVertex >= 0)
    f.markers.push_back({snapshot.dragVertex, render::Color::hex(0xffd400)});
  char caption[64];
  std::snprintf(caption, sizeof caption, "t = %.2f s", snapshot.time);
  f.caption = caption;
  f.camera = camera;
  return f;
}

}  // namespace zsculpt::app
