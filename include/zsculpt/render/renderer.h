#pragma once
// The OpenGL 3.3 core renderer, independent of the window system (see docs/rendering.md).
//
// Every frame is drawn into the renderer's own multisampled framebuffer and resolved into
// the target (the window's framebuffer, or a single-sample one that is read back), so
// windowed and offscreen images are antialiased alike. Index buffers are built once per
// topology; per frame only positions, normals and scalar values are uploaded, into
// buffers allocated on the first frame.

#include <array>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include "zsculpt/render/context.h"
#include "zsculpt/render/frame.h"
#include "zsculpt/render/image.h"

namespace zsculpt::render {

struct RendererOptions {
  /// MSAA samples, clamped to GL_MAX_SAMPLES; below 2 (or no MSAA available) the frame is
  /// rendered at twice the size and filtered down instead.
  int samples = 4;
  /// Folder with the GLSL files; empty: $ZSCULPT_SHADER_DIR, else <source tree>/shaders.
  std::string shaderDir;
};

/// What the current context allows.
struct RenderLimits {
  int maxWidth = 0;   ///< min(GL_MAX_VIEWPORT_DIMS, GL_MAX_RENDERBUFFER_SIZE), halved when
  int maxHeight = 0;  ///< supersampling instead of MSAA
  int samples = 0;    ///< MSAA samples in use (0: 2x2 supersampling)
  std::string version;
  std::string renderer;
};

class Renderer {
 public:
  /// Needs a current OpenGL 3.3+ core context. Loads the GL functions through `loader`,
  /// compiles the shaders and creates the fixed GPU objects. Throws IOError naming a shader
  /// file that is missing or fails to compile, or a GL function that is missing.
  explicit Renderer(const GlLoader& loader, const RendererOptions& options = {});
  /// Deletes the GL objects: the context must still be current.
  ~Renderer();
  Renderer(const Renderer&) = delete;
  Renderer& operator=(const Renderer&) = delete;

  [[nodiscard]] const RenderLimits& limits() const;
  /// Throws InvalidInputError "<what> WxH: <reason>" for a size below 1 or beyond limits().
  void checkSize(int width, int height, std::string_view what = "image size") const;

  /// Draws the frame into `targetFramebuffer` (0: the default framebuffer, e.g. a window)
  /// over its region [0, width) x [0, height).
  void draw(const Frame& frame, int width, int height, unsigned targetFramebuffer = 0);
  /// Draws the frame and reads it back into `image` (resized; top row first, opaque).
  void drawToImage(const Frame& frame, int width, int height, Image& image);

  /// Forces the index buffers to be rebuilt on the next frame.
  void invalidateTopology();

  /// Where the last frame drew its legend: x0, y0, x1, y1 in the target's pixels (origin top
  /// left, as draw's width and height count them); none when it drew none.
  [[nodiscard]] std::optional<std::array<int, 4>> legendRect() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// An OSMesa context with a renderer: frames to memory or PNG without any display.
class OffscreenRenderer {
 public:
  /// Throws IOError when OSMesa cannot create a context, or as Renderer does.
  explicit OffscreenRenderer(const RendererOptions& options = {});
  ~OffscreenRenderer();
  OffscreenRenderer(const OffscreenRenderer&) = delete;
  OffscreenRenderer& operator=(const OffscreenRenderer&) = delete;

  [[nodiscard]] const RenderLimits& limits() const;
  /// Cheap: call it before any expensive work (see Renderer::checkSize).
  void checkSize(int width, int height, std::string_view what = "image size") const;
  /// The frame as an image; the reference stays valid until the next render.
  const Image& render(const Frame& frame, int width, int height);
  /// Renders and writes a PNG atomically (whole or absent). Throws IOError "<path>: ...".
  void renderPng(const Frame& frame, int width, int height, const std::string& path);

  [[nodiscard]] Renderer& renderer() { return *renderer_; }
  [[nodiscard]] GlContext& context() { return *context_; }

 private:
  std::unique_ptr<OsMesaContext> context_;
  std::unique_ptr<Renderer> renderer_;
  Image image_;
};

/// Frames the camera on what `frame` draws: the surface (refined through the stencil when
/// there is one), the control vertices and the arrows of forces and torques at the
/// renderer's automatic scale (Style::forceScale). Keeps the camera's orientation.
void frameScene(Frame& frame, double aspect, double margin = 1.2);

/// Moves the camera back, never closer, until what `frame` draws (as frameScene counts it)
/// is in view from its target; `all` and `refined` hold the points counted, so that a frame
/// after the first of a run allocates nothing. Returns whether it moved.
bool keepSceneInView(Frame& frame, double aspect, double margin, Points& all, Points& refined);

/// Parses "WxH" (e.g. "1280x720"); throws InvalidInputError "<what> TEXT: ..." otherwise.
void parseImageSize(std::string_view text, int& width, int& height,
                    std::string_view what = "--size");

}  // namespace zsculpt::render
