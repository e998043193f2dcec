#pragma once
// The thin context layer. The renderer never calls a gl* symbol directly: it loads every
// GL 3.3 core function through a GlLoader (OSMesaGetProcAddress here, glfwGetProcAddress
// for the window). The final executable links both libGL (GLFW) and libOSMesa, and a
// direct call would bind to whichever library the linker saw first (anchors.md: -lGL
// before -lOSMesa sends OSMesa's calls to glvnd, where no context is current).
//
// A new backend (EGL surfaceless, for Mesa >= 25.1 where OSMesa is gone) implements
// GlContext: create a 3.3+ core context, make it current, return its proc addresses.

#include <functional>
#include <memory>

namespace zsculpt::render {

using GlProc = void (*)();
/// Returns the address of a GL function by name, or null.
using GlLoader = std::function<GlProc(const char* name)>;

class GlContext {
 public:
  virtual ~GlContext() = default;
  /// Makes the context current on the calling thread.
  virtual void makeCurrent() = 0;
  [[nodiscard]] virtual GlProc getProcAddress(const char* name) const = 0;
  /// Size of the default framebuffer (the renderer draws into its own framebuffers).
  [[nodiscard]] virtual int width() const = 0;
  [[nodiscard]] virtual int height() const = 0;
  /// A loader bound to this context (valid while the context lives).
  [[nodiscard]] GlLoader loader() const {
    return [this](const char* name) { return getProcAddress(name); };
  }
};

/// Offscreen OpenGL through OSMesa (llvmpipe): a core-profile context requested as 3.3
/// (Mesa 22 gives 4.5 core). No display is needed.
class OsMesaContext final : public GlContext {
 public:
  /// Throws IOError "OSMesa: ..." when no core 3.3 context can be created.
  explicit OsMesaContext(int width = 16, int height = 16);
  ~OsMesaContext() override;
  OsMesaContext(const OsMesaContext&) = delete;
  OsMesaContext& operator=(const OsMesaContext&) = delete;

  void makeCurrent() override;
  [[nodiscard]] GlProc getProcAddress(const char* name) const override;
  [[nodiscard]] int width() const override { return width_; }
  [[nodiscard]] int height() const override { return height_; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  int width_;
  int height_;
};

}  // namespace zsculpt::render
