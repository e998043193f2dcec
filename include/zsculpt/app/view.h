#pragma once
// From a published Snapshot to a render::Frame: what the window draws each frame and what
// a replay writes as PNG. Keeps the subdivision stencil of the current level (built once
// per level) and the frame's vectors, so a frame allocates nothing once warmed up.

#include <memory>
#include <optional>

#include "zsculpt/app/session.h"
#include "zsculpt/io/scene.h"
#include "zsculpt/render/frame.h"
#include "zsculpt/subdivision/subdivision.h"

namespace zsculpt::app {

struct ViewSettings {
  bool surface = true;
  bool wireframe = false;         ///< control mesh edges
  bool surfaceWireframe = false;  ///< refined mesh edges
  bool points = false;            ///< control vertices
  bool glyphs = true;             ///< pins, normal pins, forces, torques, drag
  int levels = 2;                 ///< subdivision levels of the drawn surface (0: control mesh)
  /// Colour the surface by the snapshot's scalar (its property).
  bool colourByProperty = false;
  render::ColorMap colorMap = render::ColorMap::Viridis;
  bool autoRange = true;
  double rangeMin = 0.0, rangeMax = 1.0;
};

/// The largest level (at most `wanted`) whose refined mesh has at most `maxRefinedVertices`
/// vertices: a closed quad mesh grows about 4x per level.
int affordableLevels(const Mesh& mesh, int wanted, Index maxRefinedVertices = 400000);

/// The level for an image of `width` x `height` pixels with the model framed to fill it (the
/// shorter side, which the framing fits): from 2
/// (the default look) up to 5 until the refined edges span about 8 pixels or less (each
/// level about halves them; a 4K frame of a coarse model at level 2 showed a polygonal
/// silhouette), within affordableLevels' budget.
int levelsForImage(const Mesh& mesh, int width, int height, Index maxRefinedVertices = 400000);

/// Applies a scene's camera settings over `camera` (absent values keep it).
void applyCameraSettings(const io::CameraSettings& settings, render::Camera& camera);
/// The camera as a scene stores it (every field given): what "save scene" writes.
io::CameraSettings cameraSettingsOf(const render::Camera& camera);

class FrameBuilder {
 public:
  /// `mesh` must outlive the builder (the frame points at it).
  explicit FrameBuilder(const Mesh& mesh);

  /// Builds the stencil for `levels` when it changes (levels clamped to [0, 10]). Throws
  /// InvalidInputError when the refinement would be too large.
  void setLevels(int levels);
  [[nodiscard]] int levels() const { return levels_; }
  [[nodiscard]] const SubdivisionStencil* stencil() const { return stencil_.get(); }

  /// The frame for `snapshot` (its positions and scalar are referenced, not copied: keep
  /// the snapshot alive and unchanged while drawing).
  render::Frame& build(const Snapshot& snapshot, const ViewSettings& view,
                       const render::Camera& camera);
  [[nodiscard]] render::Frame& frame() { return frame_; }

 private:
  const Mesh& mesh_;
  int levels_ = -1;
  std::unique_ptr<SubdivisionStencil> stencil_;
  std::uint64_t topologyVersion_ = 0;
  render::Frame frame_;
  std::optional<Property> labelled_;  // the property frame_.scalar.name is the label of
};

}  // namespace zsculpt::app
