#pragma once
// Internal to the app module: the window class shared by application.cpp (loop, input,
// tools, scripts) and panels.cpp (the Dear ImGui panels).

#include <array>
#include <chrono>
#include <deque>
#include <limits>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "zsculpt/app/application.h"
#include "zsculpt/app/picking.h"
#include "zsculpt/app/plot_series.h"
#include "zsculpt/app/recording.h"
#include "zsculpt/app/solver_thread.h"
#include "zsculpt/app/view.h"
#include "zsculpt/render/image.h"
#include "zsculpt/render/renderer.h"

struct GLFWwindow;

namespace zsculpt::app {

enum class Tool { Orbit, Drag, Paint, Pin, NormalPin, Force, Torque };

struct PointerEvent {
  enum class Kind { Down, Move, Up, Wheel };
  Kind kind = Kind::Move;
  double x = 0.0, y = 0.0;  // framebuffer pixels, y down, in the 3D view
  int button = 0;           // 0 left, 1 right, 2 middle
  bool shift = false, ctrl = false, alt = false;
  double wheel = 0.0;
};

/// GL entry points the window itself needs (screenshots, clearing), loaded through GLFW.
struct WindowGl {
  void (*BindFramebuffer)(unsigned, unsigned) = nullptr;
  void (*Viewport)(int, int, int, int) = nullptr;
  void (*ClearColor)(float, float, float, float) = nullptr;
  void (*Clear)(unsigned) = nullptr;
  void (*ReadBuffer)(unsigned) = nullptr;
  void (*PixelStorei)(unsigned, int) = nullptr;
  void (*ReadPixels)(int, int, int, int, unsigned, unsigned, void*) = nullptr;
};

struct Pick {
  Index vertex = -1;
  Vec3 point = Vec3::Zero();
  Vec3 normal = Vec3::UnitZ();
  Index controlFace = -1;  // the control face hit (-1 when picking the refined surface)
};

// How long the newest message stays under the status line.
inline constexpr std::chrono::seconds kMessageShown{8};

class Window {
 public:
  Window(SessionSetup setup, const WindowOptions& options);
  ~Window();
  int run();

 private:
  // Sessions.
  void startSession(std::unique_ptr<Session> session, bool record);
  void stopSession();
  void openModel(const std::string& path);

  // The frame.
  void drawFrame();
  void layout();
  void readImGuiInput();
  void pointer(const PointerEvent& e);
  void shortcuts();
  void shortcutKey(int key, bool ctrl, bool shift, double x, double y);
  void requestQuit();
  void takeScreenshot(const std::string& name, bool window);
  void captureWindow();
  void message(std::string text);

  // Tools.
  std::optional<Pick> pick(double x, double y);
  editing::Brush effectiveBrush(bool ctrl) const;
  void dabAt(const Pick& p, bool ctrl);
  void toolDown(const PointerEvent& e);
  void toolMove(const PointerEvent& e);
  void toolUp(const PointerEvent& e);
  void frameModel();
  void push(Command c);

  // Scripts.
  void loadScript(const std::string& path);
  void stepScript();
  std::optional<PointerEvent> scriptPointer(const nlohmann::json& j, PointerEvent::Kind kind);

  // Panels (panels.cpp).
  void panels();
  void simulationPanel(const Snapshot& s);
  void followModel(const Snapshot& s);
  [[nodiscard]] bool timeStepChanged(const Snapshot& s) const;
  void toolPanel(const Snapshot& s);
  void displayPanel(const Snapshot& s);
  void plotStrip();
  void showPaintedProperty(const Snapshot& s);
  void statisticsPanel(const Snapshot& s);
  void filePanel(const Snapshot& s);
  void messagePanel();
  void popups(const Snapshot& s);
  void overlays(const Snapshot& s);
  void saveScene(const std::string& path, bool thenQuit);
  void saveMesh(const std::string& path);

  WindowOptions options_;
  GLFWwindow* window_ = nullptr;
  WindowGl gl_;
  std::unique_ptr<render::Renderer> renderer_;
  std::string source_;

  // The session: the solver thread and the display's copy of the topology.
  std::unique_ptr<SolverThread> solver_;
  std::shared_ptr<Recorder> recorder_;
  std::unique_ptr<Mesh> mesh_;
  UniformProperties uniform_;
  std::unique_ptr<FrameBuilder> builder_;
  Points refined_;
  double tMaxAtStart_ = 0.0;
  std::uint64_t pushed_ = 0;
  std::uint64_t lastSerial_ = 0;
  PlotSeries plots_;
  // Where the last frame drew each plot (x0, y0, x1, y1, framebuffer pixels), for a script's
  // screenshot log: the window test checks the curves are drawn.
  std::array<std::array<float, 4>, 5> plotRects_{};
  double statsSolverSeconds_ = 0.0;

  // View.
  render::Camera camera_;
  ViewSettings view_;
  // The most subdivision levels the Display panel offers for this model: judging its loose
  // edges (subdivision.h) is not a per-frame cost.
  int mostLevels_ = 0;
  int fbWidth_ = 1, fbHeight_ = 1, viewWidth_ = 1, viewHeight_ = 1;
  double pixelScale_ = 1.0;  // framebuffer pixels per window coordinate
  int sidebarPixels_ = 0;

  // Input state.
  Tool tool_ = Tool::Drag;
  // The tool and brush property of the frame before: choosing the paint tool, or another
  // property to paint, colours the surface by it (showPaintedProperty).
  Tool lastTool_ = Tool::Drag;
  Property lastBrushProperty_ = Property::Stiffness;
  enum class Gesture { None, Orbit, Pan, Tool } gesture_ = Gesture::None;
  int gestureButton_ = -1;
  double lastX_ = 0.0, lastY_ = 0.0;
  double cursorX_ = -1.0, cursorY_ = -1.0;  // the cursor now, framebuffer pixels (-1: none)
  std::optional<Pick> hover_;
  Index toolVertex_ = -1;
  Vec3 toolAnchor_ = Vec3::Zero();
  Vec3 lastDab_ = Vec3::Zero();
  bool dabbed_ = false;
  Vec3 loadEnd_ = Vec3::Zero();
  bool ctrlStroke_ = false;
  // F / Shift+F: brush radius and strength by mouse (Blender).
  enum class Adjust { None, Radius, Strength } adjust_ = Adjust::None;
  double adjustCentreX_ = 0.0, adjustCentreY_ = 0.0, adjustBefore_ = 0.0;

  // Tool settings.
  editing::Brush brush_;
  bool pinByBrush_ = false;
  double forceScale_ = 1.0;   // N per scene unit of drag
  double torqueScale_ = 0.5;  // N m per scene unit of drag
  float loadDuration_ = 0.5f;

  // Panel state.
  int schemeIndex_ = 0;
  float dtRatio_ = 0.5f;
  bool gravityOn_ = false;
  std::array<float, 3> gravity_{0.0f, 0.0f, -9.81f};
  bool capOn_ = false;
  float cap_ = 50.0f;
  float damping_ = 0.0f;
  // What the panel last saw applied (scheme, period, gravity, cap): a change from elsewhere
  // (a script, a replayed command, a paint that lowered T_max) is shown, so that Apply never
  // sends back a stale choice.
  Scheme seenScheme_ = Scheme::Default;
  double seenPeriod_ = -1.0;
  double seenTMax_ = -1.0;
  bool timeStepPending_ = false;  // the panel's Apply time step is enabled (a probe logs it)
  Vec3 seenGravity_ = Vec3::Constant(std::numeric_limits<double>::quiet_NaN());
  double seenCap_ = -1.0;
  double seenMinDamping_ = -1.0, seenMaxDamping_ = -1.0, seenMeanDamping_ = -1.0;
  bool legendFaded_ = false;  // the cursor is over the legend, drawn faded
  bool dampingHeld_ = false;  // the damping slider is being dragged (it then follows no edit)
  // The sizes the last frame wrote beside the loads (forces, then torques), for scripts;
  // reserved for both kinds' labels at construction.
  std::vector<double> loadLabels_;
  std::string pathField_;
  // The Open field's up axis: an index into kUpChoices (0: auto).
  static constexpr const char* kUpChoices[] = {"auto", "y", "z", "x", "-x", "-y", "-z"};
  int upChoice_ = 0;
  std::string sceneField_;
  std::string meshField_;
  int screenshotCounter_ = 0;
  std::deque<std::string> log_;
  // When the newest message came: it is shown under the status a while.
  std::chrono::steady_clock::time_point lastMessageAt_{};
  bool showPlots_ = true;  // the energy and momentum strip across the top of the view
  std::string lastError_;
  bool quit_ = false;
  bool confirmQuit_ = false;
  bool quitAfterSave_ = false;
  std::string pendingOpen_;
  bool confirmOpen_ = false;
  std::optional<std::string> pendingWindowCapture_;

  // Script.
  std::vector<std::pair<int, nlohmann::json>> script_;
  std::string scriptPath_;
  size_t scriptNext_ = 0;
  int scriptWaitFrames_ = 0;
  std::uint64_t scriptFrame_ = 0;
  nlohmann::json scriptLog_ = nlohmann::json::array();
  double scriptX_ = 0.0, scriptY_ = 0.0;
  bool scriptButtonDown_ = false;
  bool scripted_ = false;
};

}  // namespace zsculpt::app
