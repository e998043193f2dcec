// The Display thread of paper section 6: window, input, tools and scripts. Panels are in
// panels.cpp.

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <map>
#include <utility>
#include <vector>

#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>
#include <backends/imgui_impl_glfw.h>
#include <backends/imgui_impl_opengl3.h>
#include <imgui.h>

#include "window.h"
#include "zsculpt/app/interruptions.h"
#include "zsculpt/core/errors.h"
#include "zsculpt/io/atomic_file.h"
#include "zsculpt/io/state_io.h"

namespace zsculpt::app {

namespace {

namespace fs = std::filesystem;

// The largest vertex number a script line may name (a larger one is no vertex of any mesh).
constexpr std::uint64_t kMaxScriptVertex =
    static_cast<std::uint64_t>(std::numeric_limits<Index>::max());

constexpr unsigned kGlFramebuffer = 0x8D40;
constexpr unsigned kGlBack = 0x0405;
constexpr unsigned kGlRgba = 0x1908;
constexpr unsigned kGlUnsignedByte = 0x1401;
constexpr unsigned kGlPackAlignment = 0x0D05;
constexpr unsigned kGlColorBufferBit = 0x4000;
constexpr unsigned kGlDepthBufferBit = 0x0100;

// GLFW reports errors through a callback; the last one goes into our messages.
std::string& glfwLastError() {
  static std::string error;
  return error;
}
void glfwError(int code, const char* description) {
  glfwLastError() = std::string(description ? description : "unknown error") + " (GLFW error " +
                    std::to_string(code) + ")";
}

template <class F>
void loadGl(F& f, const char* name) {
  f = reinterpret_cast<F>(glfwGetProcAddress(name));
  if (f == nullptr)
    throw IOError(std::string("display: the OpenGL function ") + name + " is missing");
}

constexpr std::pair<const char*, Tool> kToolNames[] = {
    {"orbit", Tool::Orbit},          {"drag", Tool::Drag},
    {"paint", Tool::Paint},          {"pin", Tool::Pin},
    {"normal_pin", Tool::NormalPin}, {"force", Tool::Force},
    {"torque", Tool::Torque}};

Tool toolFromName(const std::string& name) {
  for (const auto& [toolName, tool] : kToolNames)
    if (name == toolName) return tool;
  throw InvalidInputError(
      "tool \"" + name + "\": unknown (valid: orbit, drag, paint, pin, normal_pin, force, torque)");
}

const char* nameOfTool(Tool tool) {
  for (const auto& [toolName, t] : kToolNames)
    if (t == tool) return toolName;
  return "?";
}

}  // namespace

// ---- construction -------------------------------------------------------------------------------

Window::Window(SessionSetup setup, const WindowOptions& options) : options_(options) {
  loadLabels_.reserve(32);
  brush_.property = Property::Stiffness;
  brush_.mode = editing::BrushMode::Set;
  brush_.value = 1.0;
  brush_.strength = 1.0;
  brush_.radius = 1.0;
  if (!options_.scriptPath.empty()) loadScript(options_.scriptPath);

  // X11 sizes windows in 16 bits: a larger one is refused by the server with an error that
  // Xlib's default handler turns into exit(1) with a dump of the request.
  constexpr int kLargestWindowSide = 32767;
  if (options_.width > kLargestWindowSide || options_.height > kLargestWindowSide)
    throw InvalidInputError("--size " + std::to_string(options_.width) + "x" +
                            std::to_string(options_.height) + ": larger than a window may be (" +
                            std::to_string(kLargestWindowSide) + " pixels a side)");
  glfwSetErrorCallback(glfwError);
  if (glfwInit() == GLFW_FALSE)
    throw IOError("display: cannot open a window: " + glfwLastError() +
                  ". Without a display use `zsculpt replay`, `zsculpt render` or `zsculpt demo`");
  glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 3);
  glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 3);
  glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
  glfwWindowHint(GLFW_OPENGL_FORWARD_COMPAT, GLFW_TRUE);
  window_ =
      glfwCreateWindow(options_.width, options_.height, options_.title.c_str(), nullptr, nullptr);
  if (window_ == nullptr) {
    const std::string error = glfwLastError();
    glfwTerminate();
    throw IOError("display: cannot create an OpenGL 3.3 core window: " + error);
  }
  glfwMakeContextCurrent(window_);
  glfwSwapInterval(1);
  try {
    loadGl(gl_.BindFramebuffer, "glBindFramebuffer");
    loadGl(gl_.Viewport, "glViewport");
    loadGl(gl_.ClearColor, "glClearColor");
    loadGl(gl_.Clear, "glClear");
    loadGl(gl_.ReadBuffer, "glReadBuffer");
    loadGl(gl_.PixelStorei, "glPixelStorei");
    loadGl(gl_.ReadPixels, "glReadPixels");
    renderer_ = std::make_unique<render::Renderer>([](const char* name) {
      return reinterpret_cast<render::GlProc>(glfwGetProcAddress(name));
    });
    // The view is drawn offscreen at up to the window's size: a size the context cannot
    // draw is refused here, in one line, not reported at every frame.
    renderer_->checkSize(options_.width, options_.height, "--size");
  } catch (...) {
    renderer_.reset();  // its GL objects go while their context is current
    glfwDestroyWindow(window_);
    window_ = nullptr;
    glfwTerminate();
    throw;
  }

  IMGUI_CHECKVERSION();
  ImGui::CreateContext();
  ImGuiIO& io = ImGui::GetIO();
  io.IniFilename = nullptr;  // never write imgui.ini into the user's folder
  for (const char* font : {"/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
                           "/usr/share/fonts/dejavu/DejaVuSans.ttf"}) {
    std::error_code ec;
    if (fs::exists(font, ec)) {
      io.Fonts->AddFontFromFileTTF(font, 15.0f);
      break;
    }
  }
  ImGui::StyleColorsLight();
  ImGui::GetStyle().WindowRounding = 0.0f;
  // A slider's value is written across its middle, where the handle often is: a lighter
  // handle leaves the digits under it readable (a QA pass read "0.0|485" through it).
  ImGui::GetStyle().Colors[ImGuiCol_SliderGrab].w = 0.35f;
  ImGui::GetStyle().Colors[ImGuiCol_SliderGrabActive].w = 0.6f;
  ImGui_ImplGlfw_InitForOpenGL(window_, true);
  ImGui_ImplOpenGL3_Init("#version 330 core");

  startSession(std::make_unique<Session>(std::move(setup)), !options_.recordPath.empty());
}

Window::~Window() {
  try {
    stopSession();
  } catch (const std::exception&) {
  }
  builder_.reset();
  if (window_ != nullptr) {
    glfwMakeContextCurrent(window_);
    renderer_.reset();
    ImGui_ImplOpenGL3_Shutdown();
    ImGui_ImplGlfw_Shutdown();
    ImGui::DestroyContext();
    glfwDestroyWindow(window_);
  }
  glfwTerminate();
}

void Window::startSession(std::unique_ptr<Session> session, bool record) {
  const SessionSetup& setup = session->setup();
  source_ = setup.scene.sourcePath.empty() ? setup.scene.mesh : setup.scene.sourcePath;
  mesh_ = std::make_unique<Mesh>(setup.mesh);
  uniform_ = setup.scene.properties;
  const io::CameraSettings cameraSettings = setup.scene.camera;
  recorder_.reset();
  if (record) {
    recorder_ = std::make_shared<Recorder>(options_.recordPath, setup);
    if (!recorder_->journalProblem().empty())
      message("recording without a journal (" + recorder_->journalProblem() +
              "): a session killed outright loses its recording");
  }
  const Snapshot* first = nullptr;
  SolverThreadOptions so;
  so.realTime = true;
  so.speed = options_.speed;
  so.startRunning = options_.startRunning && !scripted_;
  solver_ = std::make_unique<SolverThread>(std::move(session), so, recorder_);
  // Script command lines go to the solver at their cycles.
  if (scripted_) {
    std::vector<ScheduledCommand> scheduled;
    const Recording script = readRecording(scriptPath_);
    for (const RecordedCommand& c : script.commands) scheduled.push_back({c.cycle, c.command});
    solver_->schedule(std::move(scheduled));
  }
  solver_->start();
  first = &solver_->latest();
  tMaxAtStart_ = first->tMax;
  dtRatio_ = static_cast<float>(std::isfinite(first->tMax) ? first->period / first->tMax : 0.5);
  schemeIndex_ = static_cast<int>(first->scheme);
  damping_ = static_cast<float>(first->meanDamping);
  // Damping is off unless asked for (cli.md): say what that means for a model pushed about.
  if (!(first->meanDamping > 0.0))
    message(
        "no damping: motion never dies out; set damping in Simulation (or --damping) to let "
        "the model settle");
  gravityOn_ = first->gravity.norm() > 0.0;
  if (gravityOn_)
    for (int c = 0; c < 3; ++c)
      gravity_[static_cast<size_t>(c)] = static_cast<float>(first->gravity[c]);
  capOn_ = std::isfinite(first->stiffnessCap);
  if (capOn_) cap_ = static_cast<float>(first->stiffnessCap);
  pushed_ = 0;
  lastSerial_ = 0;
  plots_.clear();
  hover_.reset();
  gesture_ = Gesture::None;

  builder_ = std::make_unique<FrameBuilder>(*mesh_);
  mostLevels_ = affordableLevels(*mesh_, 4);
  view_.levels = std::min(2, mostLevels_);
  builder_->setLevels(view_.levels);
  refined_.resize(builder_->stencil() ? builder_->stencil()->numRefinedVertices() : 0, 3);
  // A brush about two mean edges wide, in scene units.
  const double edge = mesh_->meanEdgeLength();
  brush_.radius = edge > 0.0 ? 2.0 * edge : 0.1 * std::max(mesh_->boundingBox().diagonal(), 1e-3);
  const double diagonal = std::max(mesh_->boundingBox().diagonal(), 1e-6);
  forceScale_ = 1.0 / diagonal * 4.0;
  torqueScale_ = 1.0 / diagonal;
  camera_ = render::Camera{};
  layout();
  frameModel();
  applyCameraSettings(cameraSettings, camera_);
  if (pathField_.empty()) pathField_ = source_;
  const std::string stem = fs::path(source_).stem().string();
  const std::string base = stem.empty() || stem.find(':') != std::string::npos ? "model" : stem;
  sceneField_ = base + "_sculpted.json";
  meshField_ = base + "_sculpted.obj";
  glfwSetWindowTitle(window_, (options_.title + " - " + source_).c_str());
}

void Window::stopSession() {
  if (!solver_) return;
  solver_->stop();
  Session& session = solver_->sessionWhenStopped();
  for (std::string& m : solver_->takeMessages()) message(std::move(m));
  if (recorder_) {
    recorder_->finish(session.cycle(), session.state());
    message("recorded " + std::to_string(session.cycle()) + " cycles to " + recorder_->path());
    recorder_.reset();
  }
  if (!options_.stateOut.empty()) io::saveState(session.state(), options_.stateOut);
  builder_.reset();
  solver_.reset();
}

void Window::openModel(const std::string& path) {
  // Load and build first: a file that does not load, or a model the stepper refuses (a time
  // step out of range, say), leaves the current session running untouched.
  std::unique_ptr<Session> session;
  try {
    const int choice = std::clamp(upChoice_, 0, static_cast<int>(std::size(kUpChoices)) - 1);
    session = std::make_unique<Session>(
        loadSessionSetup(path, io::parseUpAxis(kUpChoices[choice]), &options_.meshDefaults));
  } catch (const Error& e) {
    message(std::string("cannot open: ") + e.what());
    return;
  } catch (const std::exception& e) {
    message(std::string("cannot open ") + path + ": " + e.what());
    return;
  }
  if (recorder_) message("recording stopped: a recording holds one model");
  stopSession();
  startSession(std::move(session), false);
  message("opened " + path);
}

// ---- the loop -----------------------------------------------------------------------------------

int Window::run() {
  // Killed, a session lost its recording and --state-out (the default action ends the
  // process where it stands): a signal closes the window as its button does.
  const Interruptions signals;
  while (!quit_) {
    if (const int closingSignal = Interruptions::signal(); closingSignal != 0) {
      // As the close button, without the question about unsaved edits (no one may be there
      // to answer): the session stops and what the command line asked for is written.
      if (!scripted_) std::cerr << "zsculpt: closing on signal " << closingSignal << "\n";
      message("closing on signal " + std::to_string(closingSignal));
      break;
    }
    glfwPollEvents();
    if (glfwWindowShouldClose(window_)) {
      glfwSetWindowShouldClose(window_, GLFW_FALSE);
      requestQuit();
    }
    if (!glfwLastError().empty()) {
      message("GLFW: " + glfwLastError());
      glfwLastError().clear();
    }
    drawFrame();
  }
  stopSession();
  if (scripted_ && !options_.screenshotDir.empty()) {
    const fs::path log = fs::path(options_.screenshotDir) / "script_log.json";
    io::ensureWritableDirectory(options_.screenshotDir);
    io::writeFileAtomically(log.string(),
                            [&](std::ostream& out) { out << scriptLog_.dump(2) << "\n"; });
  }
  // The shell's convention for a process ended by a signal, after the outputs are written.
  return Interruptions::signal() != 0 ? 128 + Interruptions::signal() : 0;
}

void Window::layout() {
  int w = 1, h = 1, ww = 1, wh = 1;
  glfwGetFramebufferSize(window_, &w, &h);
  glfwGetWindowSize(window_, &ww, &wh);
  fbWidth_ = std::max(w, 1);
  fbHeight_ = std::max(h, 1);
  pixelScale_ = ww > 0 ? static_cast<double>(fbWidth_) / ww : 1.0;
  sidebarPixels_ = std::min(static_cast<int>(std::lround(360 * pixelScale_)), fbWidth_ / 2);
  viewWidth_ = std::max(fbWidth_ - sidebarPixels_, 1);
  viewHeight_ = fbHeight_;
}

void Window::message(std::string text) {
  if (text.empty()) return;
  // A scripted session has no one watching the panel: messages go to the terminal too.
  if (scripted_) std::cerr << "zsculpt: " << text << "\n";
  log_.push_back(std::move(text));
  while (log_.size() > 200) log_.pop_front();
  lastMessageAt_ = std::chrono::steady_clock::now();
}

void Window::push(Command c) {
  solver_->push(std::move(c));
  ++pushed_;
}

void Window::drawFrame() {
  layout();
  for (std::string& m : solver_->takeMessages()) message(std::move(m));
  const Snapshot& snap = solver_->latest();
  if (snap.serial != lastSerial_) {
    lastSerial_ = snap.serial;
    plots_.push(snap.diagnostics, snap.time);
  }

  ImGui_ImplOpenGL3_NewFrame();
  ImGui_ImplGlfw_NewFrame();
  ImGui::NewFrame();
  followModel(solver_->current());
  if (scripted_) {
    // The script is the only user: the real pointer (Xvfb parks it mid-screen) must not
    // move the tools or the camera.
    stepScript();
  } else {
    readImGuiInput();
    shortcuts();
  }
  panels();
  overlays(solver_->current());
  ImGui::Render();

  const Snapshot& s = solver_->current();
  gl_.BindFramebuffer(kGlFramebuffer, 0);
  gl_.Viewport(0, 0, fbWidth_, fbHeight_);
  gl_.ClearColor(0.93f, 0.94f, 0.96f, 1.0f);
  gl_.Clear(kGlColorBufferBit | kGlDepthBufferBit);
  try {
    render::Frame& frame = builder_->build(s, view_, camera_);
    frame.brush.visible = hover_.has_value() && adjust_ == Adjust::None &&
                          (tool_ == Tool::Paint || (tool_ == Tool::Pin && pinByBrush_));
    if (frame.brush.visible) {
      frame.brush.center = hover_->point;
      frame.brush.normal = hover_->normal;
      frame.brush.radius = brush_.radius;
    }
    // The legend fades while the cursor is over it (where the last frame drew it), so that
    // the model under it, a spot just painted there, can be seen.
    const auto legend = renderer_->legendRect();
    legendFaded_ = legend && cursorX_ >= (*legend)[0] && cursorX_ < (*legend)[2] &&
                   cursorY_ >= (*legend)[1] && cursorY_ < (*legend)[3];
    frame.display.legendOpacity = legendFaded_ ? 0.2f : 1.0f;
    renderer_->draw(frame, viewWidth_, viewHeight_, 0);
  } catch (const Error& e) {
    message(std::string("display: ") + e.what());
    view_.levels = 0;
    builder_->setLevels(0);
  }
  gl_.BindFramebuffer(kGlFramebuffer, 0);
  gl_.Viewport(0, 0, fbWidth_, fbHeight_);
  ImGui_ImplOpenGL3_RenderDrawData(ImGui::GetDrawData());
  if (pendingWindowCapture_) captureWindow();
  glfwSwapBuffers(window_);
  ++scriptFrame_;
}

void Window::captureWindow() {
  const std::string path = *pendingWindowCapture_;
  pendingWindowCapture_.reset();
  render::Image image(fbWidth_, fbHeight_);
  std::vector<std::uint8_t> rows(static_cast<size_t>(fbWidth_) * fbHeight_ * 4);
  gl_.BindFramebuffer(kGlFramebuffer, 0);
  gl_.ReadBuffer(kGlBack);
  gl_.PixelStorei(kGlPackAlignment, 1);
  gl_.ReadPixels(0, 0, fbWidth_, fbHeight_, kGlRgba, kGlUnsignedByte, rows.data());
  const size_t stride = static_cast<size_t>(fbWidth_) * 4;
  for (int y = 0; y < fbHeight_; ++y) {
    std::copy_n(rows.data() + static_cast<size_t>(fbHeight_ - 1 - y) * stride, stride,
                image.rgba.data() + static_cast<size_t>(y) * stride);
  }
  for (size_t i = 3; i < image.rgba.size(); i += 4) image.rgba[i] = 255;
  try {
    render::savePng(path, image);
    message("window saved to " + path);
  } catch (const Error& e) {
    message(e.what());
  }
}

void Window::takeScreenshot(const std::string& name, bool window) {
  // The model alone, rendered offscreen at the view's size (what `zsculpt render` would
  // draw), and optionally the whole window with its panels.
  const fs::path dir =
      options_.screenshotDir.empty() ? fs::path(".") : fs::path(options_.screenshotDir);
  try {
    io::ensureWritableDirectory(dir.string());
    const std::string path = (dir / (name + ".png")).string();
    render::Image image;
    render::Frame& frame = builder_->build(solver_->current(), view_, camera_);
    frame.brush.visible = false;  // the picture shows the model, not the cursor
    renderer_->drawToImage(frame, viewWidth_, viewHeight_, image);
    gl_.BindFramebuffer(kGlFramebuffer, 0);
    render::savePng(path, image);
    message("screenshot saved to " + path);
    if (window) pendingWindowCapture_ = (dir / (name + "_window.png")).string();
  } catch (const Error& e) {
    message(std::string("screenshot: ") + e.what());
  }
}

void Window::requestQuit() {
  if (scripted_ || !solver_ || !solver_->current().unsaved) {
    quit_ = true;
    return;
  }
  confirmQuit_ = true;
}

// ---- input
// ---------------------------------------------------------------------------------------

void Window::readImGuiInput() {
  const ImGuiIO& io = ImGui::GetIO();
  const double x = io.MousePos.x * pixelScale_;
  const double y = io.MousePos.y * pixelScale_;
  // Where the cursor is now, wherever it is (over a panel, out of the window: nowhere), for
  // what follows it without being a gesture (the legend's fade).
  const bool valid = ImGui::IsMousePosValid();
  cursorX_ = valid ? x : -1.0;
  cursorY_ = valid ? y : -1.0;
  const bool inView = x >= 0 && x < viewWidth_ && y >= 0 && y < viewHeight_;
  PointerEvent e;
  e.x = x;
  e.y = y;
  e.shift = io.KeyShift;
  e.ctrl = io.KeyCtrl;
  e.alt = io.KeyAlt;
  // A gesture that started in the view keeps the mouse until the button is released, even
  // over a panel.
  const bool captured = io.WantCaptureMouse && gesture_ == Gesture::None;
  if (!ImGui::IsMousePosValid()) return;
  if (x != lastX_ || y != lastY_) {
    e.kind = PointerEvent::Kind::Move;
    if (!captured || gesture_ != Gesture::None) pointer(e);
  }
  for (int b = 0; b < 3; ++b) {
    if (ImGui::IsMouseClicked(b) && !captured && inView) {
      e.kind = PointerEvent::Kind::Down;
      e.button = b;
      pointer(e);
    }
    if (ImGui::IsMouseReleased(b) && gesture_ != Gesture::None && gestureButton_ == b) {
      e.kind = PointerEvent::Kind::Up;
      e.button = b;
      pointer(e);
    }
  }
  if (io.MouseWheel != 0.0f && !captured && inView) {
    e.kind = PointerEvent::Kind::Wheel;
    e.wheel = io.MouseWheel;
    pointer(e);
  }
  if (!inView && gesture_ == Gesture::None) hover_.reset();
}

void Window::pointer(const PointerEvent& e) {
  cursorX_ = e.x;  // a script's pointer, which readImGuiInput does not see
  cursorY_ = e.y;
  const double dx = e.x - lastX_;
  const double dy = e.y - lastY_;
  switch (e.kind) {
    case PointerEvent::Kind::Wheel:
      camera_.zoom(std::pow(0.88, e.wheel));
      break;
    case PointerEvent::Kind::Down: {
      if (adjust_ != Adjust::None) {
        // Left click confirms the F / Shift+F adjustment, right click cancels it (Blender).
        if (e.button == 1) {
          if (adjust_ == Adjust::Radius)
            brush_.radius = adjustBefore_;
          else
            brush_.strength = adjustBefore_;
        }
        adjust_ = Adjust::None;
        break;
      }
      if (gesture_ != Gesture::None) break;
      gestureButton_ = e.button;
      if (e.button == 1 || (e.button == 0 && e.shift)) {
        gesture_ = Gesture::Pan;
      } else if (e.button == 2 || (e.button == 0 && (e.alt || tool_ == Tool::Orbit))) {
        gesture_ = Gesture::Orbit;
      } else if (e.button == 0) {
        // A tool acts on the model; on the background the left button orbits.
        hover_ = pick(e.x, e.y);
        if (hover_) {
          gesture_ = Gesture::Tool;
          toolDown(e);
        } else {
          gesture_ = Gesture::Orbit;
        }
      }
      break;
    }
    case PointerEvent::Kind::Move: {
      if (adjust_ != Adjust::None) {
        const double r = std::hypot(e.x - adjustCentreX_, e.y - adjustCentreY_);
        if (adjust_ == Adjust::Radius) {
          brush_.radius = std::max(r, 2.0) * worldPerPixel(camera_, viewHeight_, camera_.target);
        } else {
          brush_.strength = std::clamp(r / (200.0 * pixelScale_), 0.0, 1.0);
        }
        break;
      }
      switch (gesture_) {
        case Gesture::Orbit:
          camera_.orbit(-0.3 * dx / pixelScale_, 0.3 * dy / pixelScale_);
          break;
        case Gesture::Pan:
          camera_.pan(-dx / viewHeight_, dy / viewHeight_);
          break;
        case Gesture::Tool:
          toolMove(e);
          break;
        case Gesture::None:
          if (tool_ == Tool::Paint || tool_ == Tool::Pin || tool_ == Tool::Drag ||
              tool_ == Tool::NormalPin || tool_ == Tool::Force || tool_ == Tool::Torque)
            hover_ = pick(e.x, e.y);
          break;
      }
      break;
    }
    case PointerEvent::Kind::Up:
      if (gesture_ == Gesture::Tool) toolUp(e);
      gesture_ = Gesture::None;
      gestureButton_ = -1;
      break;
  }
  lastX_ = e.x;
  lastY_ = e.y;
}

// The keys shortcutKey answers (what the Keys table of docs/user-guide.md lists), with the
// names a script gives them.
namespace {

constexpr std::pair<const char*, int> kShortcutKeys[] = {
    {"z", GLFW_KEY_Z},         {"y", GLFW_KEY_Y},           {"s", GLFW_KEY_S},
    {"space", GLFW_KEY_SPACE}, {"period", GLFW_KEY_PERIOD}, {"home", GLFW_KEY_HOME},
    {"f12", GLFW_KEY_F12},     {"escape", GLFW_KEY_ESCAPE}, {"enter", GLFW_KEY_ENTER},
    {"f", GLFW_KEY_F},         {"q", GLFW_KEY_Q},           {"d", GLFW_KEY_D},
    {"b", GLFW_KEY_B},         {"p", GLFW_KEY_P},           {"n", GLFW_KEY_N},
    {"v", GLFW_KEY_V},         {"t", GLFW_KEY_T},           {"r", GLFW_KEY_R}};

// "a, b, c" of name(item) over a range, for the "(valid: ...)" of an error.
template <class Range, class Name>
std::string joinedNames(const Range& items, Name name) {
  std::string joined;
  for (const auto& item : items) joined += (joined.empty() ? "" : ", ") + std::string(name(item));
  return joined;
}

int shortcutKeyFromName(const std::string& name) {
  for (const auto& [keyName, key] : kShortcutKeys)
    if (name == keyName) return key;
  throw InvalidInputError("key \"" + name + "\": not a shortcut (valid: " +
                          joinedNames(kShortcutKeys, [](const auto& k) { return k.first; }) + ")");
}

}  // namespace

void Window::shortcuts() {
  const ImGuiIO& io = ImGui::GetIO();
  if (io.WantCaptureKeyboard) return;
  for (const auto& [name, key] : kShortcutKeys)
    if (ImGui::IsKeyPressed(key, false))
      shortcutKey(key, io.KeyCtrl, io.KeyShift, io.MousePos.x * pixelScale_,
                  io.MousePos.y * pixelScale_);
}

// One key pressed with its modifiers, the pointer at (x, y) in framebuffer pixels: the live
// window's keys and a script's `key` lines both come here.
void Window::shortcutKey(int key, bool ctrl, bool shift, double x, double y) {
  if (ctrl) {
    if (key == GLFW_KEY_Z)
      push(Edit{shift ? editing::EditCommand(editing::Redo{})
                      : editing::EditCommand(editing::Undo{})});
    if (key == GLFW_KEY_Y) push(Edit{editing::Redo{}});
    if (key == GLFW_KEY_S) saveScene(sceneField_, false);
    return;
  }
  if (key == GLFW_KEY_SPACE) push(solver_->current().running ? Command(Pause{}) : Command(Play{}));
  if (key == GLFW_KEY_PERIOD) push(StepOnce{});
  if (key == GLFW_KEY_HOME) frameModel();
  if (key == GLFW_KEY_F12)
    takeScreenshot("screenshot_" + std::to_string(++screenshotCounter_), true);
  if (key == GLFW_KEY_ESCAPE) {
    if (adjust_ == Adjust::Radius) brush_.radius = adjustBefore_;
    if (adjust_ == Adjust::Strength) brush_.strength = adjustBefore_;
    adjust_ = Adjust::None;
  }
  if (key == GLFW_KEY_ENTER) adjust_ = Adjust::None;
  if (key == GLFW_KEY_F && gesture_ == Gesture::None) {
    // Blender: F then move the mouse sets the radius, Shift+F the strength; click confirms.
    if (shift) {
      adjust_ = Adjust::Strength;
      adjustBefore_ = brush_.strength;
      adjustCentreX_ = x - brush_.strength * 200.0 * pixelScale_;
    } else {
      adjust_ = Adjust::Radius;
      adjustBefore_ = brush_.radius;
      adjustCentreX_ = x - brush_.radius / worldPerPixel(camera_, viewHeight_, camera_.target);
    }
    adjustCentreY_ = y;
  }
  if (shift) return;
  if (key == GLFW_KEY_Q) tool_ = Tool::Orbit;
  if (key == GLFW_KEY_D) tool_ = Tool::Drag;
  if (key == GLFW_KEY_B) tool_ = Tool::Paint;
  if (key == GLFW_KEY_P) tool_ = Tool::Pin;
  if (key == GLFW_KEY_N) tool_ = Tool::NormalPin;
  if (key == GLFW_KEY_V) tool_ = Tool::Force;
  if (key == GLFW_KEY_T) tool_ = Tool::Torque;
  if (key == GLFW_KEY_R) push(Edit{editing::Relax{}});
}

void Window::frameModel() {
  if (!solver_) return;
  render::Frame& f = builder_->build(solver_->current(), view_, camera_);
  render::frameScene(f, static_cast<double>(viewWidth_) / viewHeight_);
  camera_ = f.camera;
}

// ---- tools
// ---------------------------------------------------------------------------------------

std::optional<Pick> Window::pick(double x, double y) {
  const Snapshot& s = solver_->current();
  if (s.position.rows() != mesh_->numVertices()) return std::nullopt;
  const Ray ray = rayThroughPixel(camera_, viewWidth_, viewHeight_, x, y);
  Pick p;
  if (mesh_->numFaces() > 0) {
    const SubdivisionStencil* stencil = builder_->stencil();
    std::optional<SurfaceHit> hit;
    if (stencil != nullptr && view_.surface) {
      if (refined_.rows() != stencil->numRefinedVertices())
        refined_.resize(stencil->numRefinedVertices(), 3);
      stencil->apply(s.position, refined_);
      hit = pickSurface(stencil->refinedFaces(), refined_, ray);
      if (hit) p.vertex = nearestVertex(s.position, hit->point);
    } else {
      hit = pickSurface(mesh_->faces(), s.position, ray);
      if (hit) {
        p.vertex = hit->nearestCorner;
        p.controlFace = hit->face;
      }
    }
    if (hit) {
      p.point = hit->point;
      p.normal = hit->normal;
      return p;
    }
    // Off the surface: a vertex within a few pixels still counts (below), so that a press on
    // a boundary or silhouette vertex, whose pixel straddles the surface's edge, takes it.
  }
  // Curves and point sets, and presses just off a surface: the vertex nearest the ray within
  // a few pixels.
  const double tolerance = 8.0 * pixelScale_ * worldPerPixel(camera_, viewHeight_, camera_.target);
  p.vertex = pickNearestVertex(s.position, ray, tolerance);
  if (p.vertex < 0) return std::nullopt;
  p.point = s.position.row(p.vertex).transpose();
  p.normal = -ray.direction;
  return p;
}

editing::Brush Window::effectiveBrush(bool ctrl) const {
  editing::Brush b = brush_;
  if (!ctrl) return b;
  // Ctrl inverts the brush (Blender): add subtracts, multiply divides, set paints the
  // scene's uniform value back ("erase"), smooth stays smooth.
  switch (b.mode) {
    case editing::BrushMode::Add:
      b.value = -b.value;
      break;
    case editing::BrushMode::Multiply:
      b.value = b.value > 0.0 ? 1.0 / b.value : b.value;
      break;
    case editing::BrushMode::Set: {
      const UniformProperties& u = uniform_;
      switch (b.property) {
        case Property::Mass:
          b.value = u.mass;
          break;
        case Property::Damping:
          b.value = u.damping;
          break;
        case Property::Stiffness:
          b.value = u.stiffness;
          break;
        case Property::AngularStiffness:
          b.value = u.angularStiffness;
          break;
        case Property::Rigidity:
          b.value = u.rigidity;
          break;
        default:
          b.mode = editing::BrushMode::Smooth;
          break;
      }
      break;
    }
    case editing::BrushMode::Smooth:
      break;
  }
  return b;
}

void Window::dabAt(const Pick& p, bool ctrl) {
  editing::Dab dab;
  dab.brush = effectiveBrush(ctrl);
  dab.centre = p.controlFace >= 0 ? editing::BrushCentre::onFace(p.controlFace, p.point)
                                  : editing::BrushCentre::atPoint(p.point);
  push(Edit{dab});
  lastDab_ = p.point;
  dabbed_ = true;
}

void Window::toolDown(const PointerEvent& e) {
  const Pick& p = *hover_;
  const Snapshot& s = solver_->current();
  toolVertex_ = p.vertex;
  ctrlStroke_ = e.ctrl;
  dabbed_ = false;
  const Vec3 at = s.position.row(p.vertex).transpose();
  toolAnchor_ = at;
  loadEnd_ = at;
  switch (tool_) {
    case Tool::Drag:
      push(DragStart{p.vertex, at});
      break;
    case Tool::Paint:
      dabAt(p, e.ctrl);
      break;
    case Tool::Pin:
      if (pinByBrush_) {
        const editing::BrushCentre centre =
            p.controlFace >= 0 ? editing::BrushCentre::onFace(p.controlFace, p.point)
                               : editing::BrushCentre::atPoint(p.point);
        push(PinBrush{centre, brush_.radius, !e.ctrl});
        lastDab_ = p.point;
      } else {
        push(e.ctrl ? Command(Unpin{p.vertex}) : Command(Pin{p.vertex, std::nullopt}));
      }
      break;
    case Tool::NormalPin:
      push(e.ctrl ? Command(UnpinNormal{p.vertex}) : Command(PinNormal{p.vertex, std::nullopt}));
      break;
    case Tool::Force:
    case Tool::Torque:
    case Tool::Orbit:
      break;
  }
}

void Window::toolMove(const PointerEvent& e) {
  const Ray ray = rayThroughPixel(camera_, viewWidth_, viewHeight_, e.x, e.y);
  switch (tool_) {
    case Tool::Drag:
      // The dragged vertex follows the cursor in the plane through its start facing the
      // camera (section 6: a moving position constraint).
      push(DragMove{onViewPlane(camera_, ray, toolAnchor_)});
      break;
    case Tool::Paint:
    case Tool::Pin: {
      hover_ = pick(e.x, e.y);
      if (!hover_) break;
      // Dabs spaced a quarter radius apart along the stroke.
      if ((hover_->point - lastDab_).norm() < 0.25 * brush_.radius) break;
      if (tool_ == Tool::Paint) {
        dabAt(*hover_, ctrlStroke_);
      } else if (pinByBrush_) {
        const editing::BrushCentre centre =
            hover_->controlFace >= 0
                ? editing::BrushCentre::onFace(hover_->controlFace, hover_->point)
                : editing::BrushCentre::atPoint(hover_->point);
        push(PinBrush{centre, brush_.radius, !ctrlStroke_});
        lastDab_ = hover_->point;
      }
      break;
    }
    case Tool::Force:
    case Tool::Torque:
      loadEnd_ = onViewPlane(camera_, ray, toolAnchor_);
      break;
    default:
      break;
  }
}

void Window::toolUp(const PointerEvent&) {
  switch (tool_) {
    case Tool::Drag:
      push(DragEnd{});
      break;
    case Tool::Force:
    case Tool::Torque: {
      const Vec3 drag = loadEnd_ - toolAnchor_;
      if (drag.norm() <= 0.0) break;
      if (tool_ == Tool::Force) {
        push(AddLoad{LoadKind::Force, toolVertex_, forceScale_ * drag, loadDuration_});
      } else {
        // Trackball-like: dragging right spins the near side of the surface to the right,
        // about the screen's up axis through the vertex.
        const Vec3 toViewer = (camera_.eye() - camera_.target).normalized();
        push(AddLoad{LoadKind::Torque, toolVertex_, torqueScale_ * toViewer.cross(drag),
                     loadDuration_});
      }
      break;
    }
    default:
      break;
  }
  toolVertex_ = -1;
}

// ---- scripts
// -------------------------------------------------------------------------------------

void Window::loadScript(const std::string& path) {
  const Recording script = readRecording(path);  // throws on malformed lines
  for (const auto& [line, j] : script.ui) {
    const std::string where = path + ": line " + std::to_string(line);
    if (!j.at("ui").is_string()) throw InvalidInputError(where + ": ui: expected an action name");
    const std::string action = j.at("ui").get<std::string>();
    // Each action and its members: a misspelt member ("at_vertx") is refused, not ignored.
    static const std::map<std::string, std::vector<std::string>> members = {
        {"wait_frames", {"frames"}},
        {"wait_cycle", {"cycle"}},
        {"wait_time", {"time"}},
        {"wait_applied", {}},
        {"command", {"command"}},
        {"tool", {"tool", "pin_by_brush"}},
        {"brush", {"property", "mode", "value", "strength", "radius", "falloff"}},
        {"display", {"property", "colour_map", "levels", "range", "wireframe", "points"}},
        {"camera", {"yaw", "pitch", "zoom", "frame"}},
        {"frame", {}},
        {"mouse_down", {"at_vertex", "at", "offset", "button", "ctrl", "shift", "alt"}},
        {"mouse_move", {"at_vertex", "at", "offset", "button", "ctrl", "shift", "alt"}},
        {"mouse_up", {"at_vertex", "at", "offset", "button", "ctrl", "shift", "alt"}},
        {"key", {"key", "ctrl", "shift"}},
        {"scroll", {"clicks", "at_vertex", "at", "offset"}},
        {"screenshot", {"name", "what"}},
        {"probe", {"vertex", "name"}},
        {"save_scene", {"path"}},
        {"save_mesh", {"path"}},
        {"open", {"path", "up"}},
        {"quit", {}}};
    const auto known = members.find(action);
    if (known == members.end())
      throw InvalidInputError(where + ": ui: unknown action \"" + action + "\" (valid: " +
                              joinedNames(members, [](const auto& m) { return m.first; }) + ")");
    const std::vector<std::string>& allowed = known->second;
    for (const auto& [member, unused] : j.items()) {
      if (member == "ui" || std::find(allowed.begin(), allowed.end(), member) != allowed.end())
        continue;
      const std::string valid = joinedNames(allowed, [](const std::string& m) { return m; });
      throw InvalidInputError(where + ": " + action + ": unknown member \"" + member +
                              "\" (valid: " + (valid.empty() ? "none" : valid) + ")");
    }
    // Every other member's type, before the window opens too: a string for "button" ran the
    // script and failed at its line with the JSON library's words (a QA pass).
    static const std::map<std::string, char> kinds = {
        {"frames", 'i'},   {"cycle", 'i'},     {"levels", 'i'},   {"button", 'i'},
        {"time", 'n'},     {"value", 'n'},     {"strength", 'n'}, {"radius", 'n'},
        {"yaw", 'n'},      {"pitch", 'n'},     {"zoom", 'n'},     {"clicks", 'n'},
        {"ctrl", 'b'},     {"shift", 'b'},     {"alt", 'b'},      {"pin_by_brush", 'b'},
        {"frame", 'b'},    {"wireframe", 'b'}, {"points", 'b'},   {"tool", 's'},
        {"property", 's'}, {"mode", 's'},      {"falloff", 's'},  {"colour_map", 's'},
        {"key", 's'},      {"name", 's'},      {"what", 's'},     {"path", 's'},
        {"up", 's'}};
    for (const auto& [member, v] : j.items()) {
      const auto kind = kinds.find(member);
      if (kind == kinds.end()) continue;
      const bool ok = kind->second == 'i'   ? v.is_number_integer()
                      : kind->second == 'n' ? v.is_number() && std::isfinite(v.get<double>())
                      : kind->second == 'b' ? v.is_boolean()
                                            : v.is_string();
      if (!ok)
        throw InvalidInputError(where + ": " + action + ": " + member + ": expected " +
                                (kind->second == 'i'   ? "an integer"
                                 : kind->second == 'n' ? "a finite number"
                                 : kind->second == 'b' ? "true or false"
                                                       : "a string") +
                                ", got " + v.dump());
    }
    // Pixel pairs and vertex numbers are checked here, before the window opens: a short
    // array was read past its end (a crash), and a vertex of 2^32 wrapped to vertex 0.
    for (const char* pair : {"at", "offset", "range"}) {
      if (!j.contains(pair)) continue;
      const nlohmann::json& v = j.at(pair);
      if (!v.is_array() || v.size() != 2 || !v[0].is_number() || !v[1].is_number() ||
          !std::isfinite(v[0].get<double>()) || !std::isfinite(v[1].get<double>()))
        throw InvalidInputError(where + ": " + action + ": " + pair + ": expected [" +
                                (std::string(pair) == "range" ? "min, max" : "x, y") +
                                "], two finite numbers, got " + v.dump());
    }
    for (const char* vertex : {"at_vertex", "vertex"}) {
      if (!j.contains(vertex)) continue;
      const nlohmann::json& v = j.at(vertex);
      if (!v.is_number_unsigned() || v.get<std::uint64_t>() > kMaxScriptVertex)
        throw InvalidInputError(where + ": " + action + ": " + vertex +
                                ": expected a vertex number, got " + v.dump());
    }
    if (action == "command") commandFromJson(j.at("command"), where + ": command");
    if (action == "tool") toolFromName(j.value("tool", std::string()));
    if (action == "key") {
      if (!j.contains("key") || !j.at("key").is_string())
        throw InvalidInputError(where + ": key: expected a key name");
      try {
        shortcutKeyFromName(j.at("key").get<std::string>());
      } catch (const InvalidInputError& e) {
        throw InvalidInputError(where + ": " + e.what());
      }
    }
  }
  script_ = script.ui;
  scriptPath_ = path;
  scripted_ = true;
}

std::optional<PointerEvent> Window::scriptPointer(const nlohmann::json& j,
                                                  PointerEvent::Kind kind) {
  PointerEvent e;
  e.kind = kind;
  double x = scriptX_, y = scriptY_;
  if (j.contains("at_vertex")) {
    const Index v = j.at("at_vertex").get<Index>();
    const Snapshot& s = solver_->current();
    if (v < 0 || v >= s.position.rows())
      throw InvalidInputError("at_vertex " + std::to_string(v) + ": no such vertex");
    const auto px = projectToPixel(camera_, viewWidth_, viewHeight_, s.position.row(v).transpose());
    if (!px) throw InvalidInputError("at_vertex " + std::to_string(v) + ": behind the camera");
    x = px->x();
    y = px->y();
    scriptLog_.push_back(
        {{"frame", scriptFrame_}, {"vertex", v}, {"pixel", {x, y}}, {"event", j.at("ui")}});
  } else if (j.contains("at")) {
    x = j.at("at")[0].get<double>() * pixelScale_;
    y = j.at("at")[1].get<double>() * pixelScale_;
  }
  if (j.contains("offset")) {
    x += j.at("offset")[0].get<double>() * pixelScale_;
    y += j.at("offset")[1].get<double>() * pixelScale_;
  }
  e.x = x;
  e.y = y;
  e.button = j.value("button", 0);
  e.ctrl = j.value("ctrl", false);
  e.shift = j.value("shift", false);
  e.alt = j.value("alt", false);
  scriptX_ = x;
  scriptY_ = y;
  return e;
}

void Window::stepScript() {
  if (scriptWaitFrames_ > 0) {
    --scriptWaitFrames_;
    return;
  }
  const Snapshot& s = solver_->current();
  while (scriptNext_ < script_.size()) {
    const auto& [line, j] = script_[scriptNext_];
    const std::string where = scriptPath_ + ": line " + std::to_string(line);
    const std::string action = j.at("ui").get<std::string>();
    try {
      if (action == "wait_frames") {
        scriptWaitFrames_ = j.value("frames", 1);
        ++scriptNext_;
        return;
      }
      if (action == "wait_cycle" || action == "wait_time") {
        const bool reached = action == "wait_cycle" ? s.cycle >= j.at("cycle").get<std::uint64_t>()
                                                    : s.time >= j.at("time").get<double>();
        if (!reached) {
          // Scripts start paused: a wait on a paused solver with nothing pushed still to apply
          // would wait for ever.
          if (!s.running && s.commandsApplied >= pushed_)
            throw InvalidInputError(action +
                                    " while the solver is paused (a script starts paused: "
                                    "push {\"type\": \"play\"} first); skipped");
          return;
        }
      } else if (action == "wait_applied") {
        if (s.commandsApplied < pushed_) return;
      } else if (action == "command") {
        push(commandFromJson(j.at("command"), where));
      } else if (action == "tool") {
        tool_ = toolFromName(j.at("tool").get<std::string>());
        if (j.contains("pin_by_brush")) pinByBrush_ = j.at("pin_by_brush").get<bool>();
      } else if (action == "brush") {
        if (j.contains("property"))
          brush_.property = propertyFromName(j.at("property").get<std::string>());
        if (j.contains("mode"))
          brush_.mode = editing::brushModeFromName(j.at("mode").get<std::string>());
        if (j.contains("value")) brush_.value = j.at("value").get<double>();
        if (j.contains("strength")) brush_.strength = j.at("strength").get<double>();
        if (j.contains("radius")) brush_.radius = j.at("radius").get<double>();
        if (j.contains("falloff"))
          brush_.falloff = editing::falloffFromName(j.at("falloff").get<std::string>());
      } else if (action == "display") {
        if (j.contains("property")) {
          view_.colourByProperty = true;
          solver_->setDisplayProperty(propertyFromName(j.at("property").get<std::string>()));
        }
        if (j.contains("colour_map"))
          view_.colorMap = render::colorMapFromName(j.at("colour_map").get<std::string>());
        if (j.contains("levels")) {
          view_.levels = affordableLevels(*mesh_, j.at("levels").get<int>());
          builder_->setLevels(view_.levels);
        }
        if (j.contains("range")) {
          // [50, 0] drew a legend of 2.5 over 47.5 and [0, 0] one of -1 .. 1 (a QA pass).
          const double low = j.at("range").at(0).get<double>();
          const double high = j.at("range").at(1).get<double>();
          if (!std::isfinite(low) || !std::isfinite(high) || !(low < high))
            throw InvalidInputError("range: [" + std::to_string(low) + ", " + std::to_string(high) +
                                    "] must be finite and go from low to high");
          view_.autoRange = false;
          view_.rangeMin = low;
          view_.rangeMax = high;
        }
        if (j.contains("wireframe")) view_.wireframe = j.at("wireframe").get<bool>();
        if (j.contains("points")) view_.points = j.at("points").get<bool>();
      } else if (action == "camera") {
        if (j.value("frame", false)) frameModel();
        if (j.contains("yaw")) camera_.yawDegrees = j.at("yaw").get<double>();
        if (j.contains("pitch"))
          camera_.pitchDegrees = std::clamp(j.at("pitch").get<double>(), -89.0, 89.0);
        if (j.contains("zoom")) camera_.zoom(j.at("zoom").get<double>());
      } else if (action == "frame") {
        frameModel();
      } else if (action == "mouse_down" || action == "mouse_move" || action == "mouse_up") {
        const PointerEvent::Kind kind = action == "mouse_down"   ? PointerEvent::Kind::Down
                                        : action == "mouse_move" ? PointerEvent::Kind::Move
                                                                 : PointerEvent::Kind::Up;
        if (auto e = scriptPointer(j, kind)) {
          if (kind == PointerEvent::Kind::Down) {
            // The cursor arrives first (hover), then the button goes down.
            PointerEvent move = *e;
            move.kind = PointerEvent::Kind::Move;
            pointer(move);
            scriptButtonDown_ = true;
          }
          if (kind == PointerEvent::Kind::Up) scriptButtonDown_ = false;
          pointer(*e);
          if (kind == PointerEvent::Kind::Down && gesture_ != Gesture::Tool)
            message(where + ": mouse_down did not land on the model");
        }
        ++scriptNext_;
        return;  // one pointer event per frame, as a user's would be
      } else if (action == "key") {
        // As the key pressed over the view with the pointer where the script left it.
        shortcutKey(shortcutKeyFromName(j.at("key").get<std::string>()), j.value("ctrl", false),
                    j.value("shift", false), scriptX_, scriptY_);
        ++scriptNext_;
        return;  // one key per frame, as a user's would be
      } else if (action == "scroll") {
        if (auto e = scriptPointer(j, PointerEvent::Kind::Wheel)) {
          e->wheel = j.value("clicks", 1.0);
          pointer(*e);
        }
        ++scriptNext_;
        return;
      } else if (action == "screenshot") {
        const std::string name = j.value("name", "script_" + std::to_string(line));
        // A name, not a path: "../../escape" wrote outside the screenshot folder, "" a
        // hidden ".png" (a QA pass).
        if (name.empty() || name.find('/') != std::string::npos || name == "." || name == "..")
          throw InvalidInputError("screenshot: name \"" + name +
                                  "\": a file name without a folder, not empty");
        const std::string what = j.value("what", std::string("both"));
        if (what == "window") {
          // Only the window with its panels, as NAME.png (for documentation).
          const fs::path dir =
              options_.screenshotDir.empty() ? fs::path(".") : fs::path(options_.screenshotDir);
          io::ensureWritableDirectory(dir.string());
          pendingWindowCapture_ = (dir / (name + ".png")).string();
        } else if (what == "model" || what == "both") {
          takeScreenshot(name, what == "both");
        } else {
          throw InvalidInputError("screenshot: what \"" + what +
                                  "\": unknown (valid: both, model, window)");
        }
        if (what != "model") {
          // The plots as the captured frame draws them (the layout of the frame before).
          nlohmann::json rects = nlohmann::json::array();
          for (const auto& r : plotRects_) rects.push_back({r[0], r[1], r[2], r[3]});
          scriptLog_.push_back({{"frame", scriptFrame_}, {"screenshot", name}, {"plots", rects}});
          // The window is captured at the end of this frame: the next lines wait for the
          // next, so that it shows the window as it is at this line (a pointer line after
          // it would otherwise move the cursor first).
          ++scriptNext_;
          return;
        }
      } else if (action == "probe") {
        const Index v = j.at("vertex").get<Index>();
        if (v < 0 || v >= s.position.rows())
          throw InvalidInputError("probe " + std::to_string(v) + ": no such vertex");
        // A vertex that does not project (behind the camera) is probed all the same, its
        // pixel null: such probes went missing from the log without a word (a QA pass).
        const auto px =
            projectToPixel(camera_, viewWidth_, viewHeight_, s.position.row(v).transpose());
        const bool statusShown =
            !log_.empty() && std::chrono::steady_clock::now() - lastMessageAt_ < kMessageShown;
        scriptLog_.push_back(
            {{"frame", scriptFrame_},
             {"probe", j.value("name", std::string())},
             {"vertex", v},
             {"pixel", px ? nlohmann::json{px->x(), px->y()} : nlohmann::json()},
             {"status_message", statusShown ? nlohmann::json(log_.back()) : nlohmann::json()},
             {"position", {s.position(v, 0), s.position(v, 1), s.position(v, 2)}},
             {"scalar", s.scalar.size() > v ? s.scalar[v] : 0.0},
             {"tool", nameOfTool(tool_)},
             {"brush_radius", brush_.radius},
             {"brush_strength", brush_.strength},
             {"running", s.running},
             {"cycle", s.cycle},
             {"distance", camera_.distance},
             {"period", s.period},
             {"t_max", s.tMax},
             {"time_step_slider", dtRatio_},
             {"scheme", std::string(schemeName(s.scheme))},
             {"load_labels", loadLabels_},
             {"legend_faded", legendFaded_},
             {"legend_rect", renderer_->legendRect() ? nlohmann::json(*renderer_->legendRect())
                                                     : nlohmann::json()},
             {"damping_slider", damping_},
             {"damping_painted", s.maxDamping > s.minDamping},
             {"plot_samples", plots_.count},
             // The newest sample's time: the ring's times never go back (PlotSeries::push).
             {"plot_time_max", plots_.count > 0
                                   ? plots_.time[static_cast<size_t>(plots_.at(plots_.count - 1))]
                                   : 0.0},
             {"apply_time_step_enabled", timeStepPending_}});
      } else if (action == "save_scene" || action == "save_mesh") {
        // Relative paths are relative to the screenshot folder, so a script's outputs stay
        // together.
        fs::path path = j.at("path").get<std::string>();
        if (path.is_relative() && !options_.screenshotDir.empty()) {
          io::ensureWritableDirectory(options_.screenshotDir);  // made as a screenshot makes it
          path = fs::path(options_.screenshotDir) / path;
        }
        if (action == "save_scene")
          saveScene(path.string(), false);
        else
          saveMesh(path.string());
      } else if (action == "open") {
        // The file panel's Open, with its up-axis choice (by name).
        const std::string up = j.value("up", std::string("auto"));
        const std::string name = io::upAxisName(io::parseUpAxis(up));  // +Y is y
        const auto* choice = std::find(std::begin(kUpChoices), std::end(kUpChoices), name);
        upChoice_ = static_cast<int>(choice - std::begin(kUpChoices));
        openModel(j.at("path").get<std::string>());
      } else if (action == "quit") {
        ++scriptNext_;
        quit_ = true;
        return;
      }
    } catch (const std::exception& e) {
      // A script error is reported and the script goes on (a user's mistake would not
      // stop the program either).
      message(where + ": " + e.what());
      scriptLog_.push_back({{"frame", scriptFrame_}, {"error", where + ": " + e.what()}});
    }
    ++scriptNext_;
  }
}

// ---- entry point ------------------------------------------------------------------------------

int runWindow(SessionSetup setup, const WindowOptions& options) {
  Window window(std::move(setup), options);
  return window.run();
}

}  // namespace zsculpt::app
