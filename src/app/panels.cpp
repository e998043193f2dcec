// The Dear ImGui panels of the window: simulation, tools and brush, display, live plots,
// statistics, file, messages; the unsaved-edits dialogs; overlays drawn over the 3D view.

#include <imgui.h>
#include <imgui_stdlib.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <string_view>

#include "window.h"
#include "zsculpt/app/text_wrap.h"
#include "zsculpt/core/errors.h"
#include "zsculpt/io/mesh_io.h"

namespace zsculpt::app {

namespace {

const char* kSchemes[] = {"default", "paper", "exact", "symplectic-euler", "implicit-euler"};
const char* kProperties[] = {"mass",     "damping",     "stiffness", "angular_stiffness",
                             "rigidity", "rest_length", "rest_angle"};
const char* kModes[] = {"set", "add", "multiply", "smooth"};
const char* kFalloffs[] = {"smooth", "sphere", "linear", "sharp", "constant"};
const char* kMaps[] = {"viridis", "diverging", "weight"};

// TextWrapped that breaks lines at spaces only (text_wrap.h): no number is cut at its
// decimal point. Draws substrings of the text: nothing is allocated per frame.
void wrappedText(std::string_view text) {
  const float width = std::max(1.0f, ImGui::GetContentRegionAvail().x);
  // The font's advances, unrounded (ImGui::CalcTextSize rounds each measure up to a whole
  // pixel, which summed word by word or character by character would add up).
  ImFont* font = ImGui::GetFont();
  const float size = ImGui::GetFontSize();
  auto measure = [font, size](std::string_view t) {
    return font
        ->CalcTextSizeA(size, std::numeric_limits<float>::max(), 0.0f, t.data(),
                        t.data() + t.size())
        .x;
  };
  forEachWrappedLine(text, width, measure, [](std::string_view line) {
    ImGui::TextUnformatted(line.data(), line.data() + line.size());
  });
}

void help(const char* text) {
  if (ImGui::IsItemHovered()) {
    ImGui::BeginTooltip();
    ImGui::PushTextWrapPos(ImGui::GetFontSize() * 28.0f);
    ImGui::TextUnformatted(text);
    ImGui::PopTextWrapPos();
    ImGui::EndTooltip();
  }
}

std::string seconds(double s) {
  char text[32];
  if (!std::isfinite(s)) return "inf";
  std::snprintf(text, sizeof text, s < 0.01 ? "%.3g s" : "%.4f s", s);
  return text;
}

// PlotLines over a ring buffer, the oldest sample first, as wide as the panel, under a line
// with its label and newest value; the top and bottom of its range are written at its left
// corners (its scale). Returns where the plot was drawn (window coordinates).
std::array<float, 4> plot(const char* label, const std::array<float, PlotSeries::kSize>& data,
                          const PlotSeries& series, float width, float height) {
  constexpr int kSize = PlotSeries::kSize;
  // The samples are the `count` before `next` in the ring (a rollback can drop the newest of
  // a full ring, so they need not start at 0).
  struct Ring {
    const float* values;
    int first;
  } ring{data.data(), series.at(0)};
  const int count = series.count;
  float lo = std::numeric_limits<float>::infinity(), hi = -lo;
  for (int i = 0; i < count; ++i) {
    const float v = data[static_cast<size_t>(series.at(i))];
    lo = std::min(lo, v);
    hi = std::max(hi, v);
  }
  if (count == 0) lo = hi = 0.0f;
  if (hi - lo < 1e-9f * (std::abs(hi) + 1.0f)) {
    // A flat series gets a range about it; one that never goes below zero (a magnitude, the
    // kinetic energy) keeps zero as its floor rather than a scale reading -5e-07 for |p|.
    const bool nonNegative = lo >= 0.0f;
    hi += 0.5f * (std::abs(hi) + 1e-6f);
    lo -= 0.5f * (std::abs(lo) + 1e-6f);
    if (nonNegative) lo = std::max(lo, 0.0f);
  }
  const float last = count > 0 ? data[static_cast<size_t>(series.at(count - 1))] : 0.0f;
  ImGui::BeginGroup();
  // The label and newest value, at the height a SameLine after a plot gives (a framed item's
  // text offset), within the plot's width: a wider one pushed the plots after it off the
  // view on a narrow window ("kinetic 1.823e+04" over a 78-pixel plot; a QA pass). Where the
  // two do not fit, the value alone (the tooltip names the plot), clipped if even that is wider.
  char text[96], value[32];
  std::snprintf(value, sizeof value, "%.4g", static_cast<double>(last));
  if (count > 0)
    std::snprintf(text, sizeof text, "%s %s", label, value);
  else
    std::snprintf(text, sizeof text, "%s", label);
  const char* shown = count > 0 && ImGui::CalcTextSize(text).x > width ? value : text;
  const ImVec2 at = ImGui::GetCursorScreenPos();
  const float line = ImGui::GetFrameHeight();
  ImDrawList* labels = ImGui::GetWindowDrawList();
  labels->PushClipRect(at, ImVec2(at.x + width, at.y + line), true);
  labels->AddText(ImVec2(at.x, at.y + ImGui::GetStyle().FramePadding.y),
                  ImGui::GetColorU32(ImGuiCol_Text), shown);
  labels->PopClipRect();
  ImGui::Dummy(ImVec2(width, line));
  // A width given, not -1: ImGui 1.86 (Debian 12's) takes a negative plot width literally, and
  // drew every plot as an empty sliver.
  char id[64];  // no string built per frame
  std::snprintf(id, sizeof id, "##%s", label);
  ImGui::PlotLines(
      id,
      [](void* r, int i) {
        const Ring& ring = *static_cast<const Ring*>(r);
        return ring.values[(ring.first + i) % kSize];
      },
      &ring, count, 0, nullptr, lo, hi, ImVec2(width, height));
  const ImVec2 min = ImGui::GetItemRectMin(), max = ImGui::GetItemRectMax();
  if (count > 0) {
    char top[24], bottom[24];
    std::snprintf(top, sizeof top, "%.3g", static_cast<double>(hi));
    std::snprintf(bottom, sizeof bottom, "%.3g", static_cast<double>(lo));
    ImDrawList* draw = ImGui::GetWindowDrawList();
    const ImU32 dim = ImGui::GetColorU32(ImGuiCol_Text, 0.55f);
    // On a backing of the plot's own colour: the curve (a first sample's jump) ran through
    // the digits (a QA pass).
    const ImU32 backing = ImGui::GetColorU32(ImGuiCol_FrameBg, 0.85f);
    const float pad = 2.0f, line = ImGui::GetTextLineHeight();
    const ImVec2 topAt(min.x + pad, min.y + pad), bottomAt(min.x + pad, max.y - pad - line);
    draw->AddRectFilled(topAt, ImVec2(topAt.x + ImGui::CalcTextSize(top).x, topAt.y + line),
                        backing);
    draw->AddRectFilled(
        bottomAt, ImVec2(bottomAt.x + ImGui::CalcTextSize(bottom).x, bottomAt.y + line), backing);
    draw->AddText(topAt, dim, top);
    draw->AddText(bottomAt, dim, bottom);
  }
  ImGui::EndGroup();
  return {min.x, min.y, max.x, max.y};
}

}  // namespace

void Window::panels() {
  const Snapshot& s = solver_->current();
  const ImGuiIO& io = ImGui::GetIO();
  const float sidebar = static_cast<float>(sidebarPixels_ / pixelScale_);
  ImGui::SetNextWindowPos(ImVec2(io.DisplaySize.x - sidebar, 0.0f));
  ImGui::SetNextWindowSize(ImVec2(sidebar, io.DisplaySize.y));
  ImGui::Begin("zsculpt", nullptr,
               ImGuiWindowFlags_NoMove | ImGuiWindowFlags_NoResize | ImGuiWindowFlags_NoCollapse |
                   ImGuiWindowFlags_NoTitleBar);
  // Status line: what the solver is doing, and any divergence.
  if (s.running)
    ImGui::TextColored(ImVec4(0.1f, 0.55f, 0.2f, 1), "running  t = %.2f s", s.time);
  else
    ImGui::TextColored(ImVec4(0.6f, 0.4f, 0.0f, 1), "paused  t = %.2f s", s.time);
  if (s.fallingBehind) {
    ImGui::SameLine();
    ImGui::TextColored(ImVec4(0.8f, 0.1f, 0.1f, 1), "  falling behind (x%.2f)", s.simOverWall);
    help(
        "The solver needs longer for a step than the step simulates, so simulated time runs "
        "slower than wall time (the paper's solver fell behind beyond about 1200 vertices). "
        "Raise the time step, lower the stiffness, or use a coarser model.");
  }
  if (s.unsaved) {
    ImGui::SameLine();
    ImGui::TextDisabled("  (unsaved edits)");
  }
  // The newest message for a while under the status, where it is seen: the Messages panel
  // at the bottom of the sidebar is off screen on a small window.
  if (!log_.empty() && std::chrono::steady_clock::now() - lastMessageAt_ < kMessageShown) {
    ImGui::PushStyleColor(ImGuiCol_Text, ImVec4(0.15f, 0.25f, 0.6f, 1));
    wrappedText(log_.back());
    ImGui::PopStyleColor();
  }

  if (ImGui::CollapsingHeader("Simulation", ImGuiTreeNodeFlags_DefaultOpen)) simulationPanel(s);
  if (ImGui::CollapsingHeader("Tools and brush", ImGuiTreeNodeFlags_DefaultOpen)) toolPanel(s);
  if (ImGui::CollapsingHeader("Display", ImGuiTreeNodeFlags_DefaultOpen)) displayPanel(s);
  if (ImGui::CollapsingHeader("Statistics")) statisticsPanel(s);
  if (ImGui::CollapsingHeader("File")) filePanel(s);
  if (ImGui::CollapsingHeader("Messages", ImGuiTreeNodeFlags_DefaultOpen)) messagePanel();
  ImGui::End();
  if (showPlots_) plotStrip();
  showPaintedProperty(s);
  popups(s);
}

// The scheme or slider differs from what the session runs: the slider is compared as it holds
// the ratio (a float: a period compared with the float ratio times T_max differs by its
// rounding).
bool Window::timeStepChanged(const Snapshot& s) const {
  const double period = dtRatio_ * s.tMax;
  return static_cast<int>(s.scheme) != schemeIndex_ ||
         (std::isfinite(period) && s.tMax > 0.0 &&
          dtRatio_ != static_cast<float>(s.period / s.tMax));
}

// The sliders and switches follow the model (a new step, scheme or T_max, gravity, the cap,
// the damping), first thing in a frame: a script's probe in the frame reads them as the
// panels will show them (it read the time-step slider a frame late; a QA pass).
void Window::followModel(const Snapshot& s) {
  // The time-step slider follows what the session runs: a new step, scheme or T_max
  // (painting, undo) resets it, so that it never shows a ratio other than the one in the line
  // below it.
  if (s.scheme != seenScheme_ || s.period != seenPeriod_ || s.tMax != seenTMax_) {
    seenScheme_ = s.scheme;
    seenPeriod_ = s.period;
    seenTMax_ = s.tMax;
    schemeIndex_ = static_cast<int>(s.scheme);
    if (std::isfinite(s.tMax) && s.tMax > 0.0) dtRatio_ = static_cast<float>(s.period / s.tMax);
  }
  timeStepPending_ = timeStepChanged(s);
  if (s.gravity != seenGravity_) {
    seenGravity_ = s.gravity;
    gravityOn_ = !s.gravity.isZero();
    if (gravityOn_)
      gravity_ = {static_cast<float>(s.gravity.x()), static_cast<float>(s.gravity.y()),
                  static_cast<float>(s.gravity.z())};
  }
  if (s.stiffnessCap != seenCap_) {
    seenCap_ = s.stiffnessCap;
    capOn_ = std::isfinite(s.stiffnessCap);
    if (capOn_) cap_ = static_cast<float>(s.stiffnessCap);
  }
  // The slider follows the model's damping (a brush, undo, a global edit), except while it is
  // held. Painted damping differs between vertices: the slider then says so and shows the
  // mean, and moving it replaces the paint everywhere (a global edit, which Ctrl+Z undoes).
  if ((s.minDamping != seenMinDamping_ || s.maxDamping != seenMaxDamping_ ||
       s.meanDamping != seenMeanDamping_) &&
      !dampingHeld_) {
    seenMeanDamping_ = s.meanDamping;
    seenMinDamping_ = s.minDamping;
    seenMaxDamping_ = s.maxDamping;
    damping_ = static_cast<float>(s.meanDamping);
    // The start's "no damping" line under the status is no longer true: it goes from there
    // (it stays in the log), rather than contradicting the slider above it (a QA pass).
    if (s.maxDamping > 0.0 && !log_.empty() && log_.back().rfind("no damping:", 0) == 0)
      lastMessageAt_ = {};
  }
}

void Window::simulationPanel(const Snapshot& s) {
  if (ImGui::Button(s.running ? "Pause" : "Play"))
    push(s.running ? Command(Pause{}) : Command(Play{}));
  help("Space");
  ImGui::SameLine();
  if (ImGui::Button("Step")) push(StepOnce{});
  help("Period key: one cycle");
  ImGui::SameLine();
  if (ImGui::Button("Reset")) push(Reset{});
  help(
      "Back to the start as a save and a reopen would have it: painted properties (undo them "
      "with Ctrl+Z) and pins stay; forces and torques added with the tools go.");

  ImGui::Combo("scheme", &schemeIndex_, kSchemes, IM_ARRAYSIZE(kSchemes));
  ImGui::SliderFloat("T / T_max", &dtRatio_, 0.05f, 1.5f, "%.3f");
  help(
      "The time step as a fraction of equation 5's critical period T_max. Above the "
      "scheme's stable limit the simulation diverges (it is then rolled back and paused).");
  const double period = dtRatio_ * s.tMax;
  const bool changed = timeStepChanged(s);  // after the slider's and the combo's input
  timeStepPending_ = changed;
  if (!changed) ImGui::BeginDisabled();
  if (ImGui::Button("Apply time step")) {
    const double p = std::isfinite(period) && period > 0.0 ? period : s.period;
    push(SetTimeStep{static_cast<Scheme>(schemeIndex_), p});
  }
  if (!changed) ImGui::EndDisabled();
  ImGui::Text("T = %s = %.3f T_max,  T_max = %s", seconds(s.period).c_str(),
              std::isfinite(s.tMax) ? s.period / s.tMax : 0.0, seconds(s.tMax).c_str());
  if (beyondStableLimit(s.period, s.stableLimit) && s.stableLimitTight)
    ImGui::TextColored(ImVec4(0.8f, 0.1f, 0.1f, 1), "T is at or above the stable limit %s",
                       seconds(s.stableLimit).c_str());
  else if (beyondStableLimit(s.period, s.stableLimit))
    ImGui::TextColored(ImVec4(0.75f, 0.4f, 0.0f, 1), "T may be above the stable limit (bound %s)",
                       seconds(s.stableLimit).c_str());
  else if (changed && static_cast<int>(s.scheme) == schemeIndex_ &&
           beyondStableLimit(period, s.stableLimit))
    // Before it is applied: the limit shown is Gershgorin's bound, at most the tight one.
    ImGui::TextColored(ImVec4(0.75f, 0.4f, 0.0f, 1),
                       "T / T_max %.3f may be above the stable limit %s",
                       static_cast<double>(dtRatio_), seconds(s.stableLimit).c_str());
  if (s.substeps > 1 && s.running)
    ImGui::Text(s.stableSubsteps >= s.substeps
                    ? "near the stable limit after an edit: each cycle taken in %d steps of T / %d"
                    : "fast motion: each cycle taken in %d steps of T / %d",
                s.substeps, s.substeps);

  const bool dampingPainted = s.maxDamping > s.minDamping;
  ImGui::SliderFloat("damping", &damping_, 0.0f, 1.0f,
                     dampingPainted ? "painted, mean %.4f kg/s" : "%.4f kg/s",
                     ImGuiSliderFlags_Logarithmic);
  dampingHeld_ = ImGui::IsItemActive();
  if (dampingPainted) {
    char text[256];
    std::snprintf(text, sizeof text,
                  "rho of equation 1, painted: it varies over the vertices (%.4g to %.4g kg/s). "
                  "Moving the slider sets every vertex to one value and replaces the paint "
                  "(Ctrl+Z undoes it).",
                  s.minDamping, s.maxDamping);
    help(text);
  } else
    help("rho of equation 1 on every vertex (a global edit: Ctrl+Z undoes it).");
  if (ImGui::IsItemDeactivatedAfterEdit()) {
    editing::Brush b;
    b.property = Property::Damping;
    b.mode = editing::BrushMode::Set;
    b.value = damping_;
    push(Edit{editing::GlobalEdit{b}});
  }
  bool gravityChanged = ImGui::Checkbox("gravity", &gravityOn_);
  ImGui::SameLine();
  ImGui::SetNextItemWidth(-1.0f);
  ImGui::InputFloat3("##gravity", gravity_.data(), "%.2f");
  gravityChanged |= ImGui::IsItemDeactivatedAfterEdit();
  if (gravityChanged) {
    const Vec3 g = gravityOn_ ? Vec3(gravity_[0], gravity_[1], gravity_[2]) : Vec3::Zero();
    push(SetGravity{g});
  }
  bool capChanged = ImGui::Checkbox("stiffness cap", &capOn_);
  help(
      "kappa_0 of section 4.3: vertices stiffer than this become partly rigid, so the "
      "critical period depends on kappa_0 instead of the stiffest vertex.");
  ImGui::SameLine();
  ImGui::SetNextItemWidth(-1.0f);
  ImGui::InputFloat("##cap", &cap_, 0.0f, 0.0f, "%.3g N/m");
  capChanged |= ImGui::IsItemDeactivatedAfterEdit();
  if (capChanged) {
    if (capOn_ && !(cap_ > 0.0f)) {
      message("stiffness cap: must be positive");
    } else {
      push(SetStiffnessCap{capOn_ ? static_cast<double>(cap_)
                                  : std::numeric_limits<double>::infinity()});
    }
  }
}

void Window::toolPanel(const Snapshot& s) {
  (void)s;
  int tool = static_cast<int>(tool_);
  const char* names[] = {"orbit (Q)",      "drag (D)",  "paint (B)", "pin (P)",
                         "normal pin (N)", "force (V)", "torque (T)"};
  for (int i = 0; i < 7; ++i) {
    if (i % 3 != 0) ImGui::SameLine();
    ImGui::RadioButton(names[i], &tool, i);
  }
  tool_ = static_cast<Tool>(tool);
  switch (tool_) {
    case Tool::Orbit:
      ImGui::TextWrapped(
          "Left-drag orbits, right-drag or Shift+left pans, wheel zooms, Home frames.");
      break;
    case Tool::Drag:
      ImGui::TextWrapped(
          "Press on the model and drag: the vertex follows the cursor (a moving position "
          "constraint).");
      break;
    case Tool::Paint:
      ImGui::TextWrapped("Paint the property below. F: radius, Shift+F: strength, Ctrl: invert.");
      break;
    case Tool::Pin:
      ImGui::TextWrapped(
          "Click pins the vertex, Ctrl+click unpins; with 'by brush' a stroke pins (Ctrl: unpins) "
          "everything under the brush.");
      break;
    case Tool::NormalPin:
      ImGui::TextWrapped("Click holds the normal at the vertex as it is; Ctrl+click releases it.");
      break;
    case Tool::Force:
      ImGui::TextWrapped(
          "Press on a vertex and drag: the arrow is the force, applied on release for the duration "
          "below.");
      break;
    case Tool::Torque:
      ImGui::TextWrapped(
          "Press on a vertex and drag: a torque that spins the surface like a trackball, applied "
          "on release.");
      break;
  }
  if (tool_ == Tool::Pin) ImGui::Checkbox("pin by brush", &pinByBrush_);
  if (tool_ == Tool::Force || tool_ == Tool::Torque) {
    float scale = static_cast<float>(tool_ == Tool::Force ? forceScale_ : torqueScale_);
    if (ImGui::InputFloat(tool_ == Tool::Force ? "N per unit" : "N m per unit", &scale, 0, 0,
                          "%.3g") &&
        scale > 0)
      (tool_ == Tool::Force ? forceScale_ : torqueScale_) = scale;
    ImGui::SliderFloat("duration", &loadDuration_, 0.05f, 10.0f, "%.2f s",
                       ImGuiSliderFlags_Logarithmic);
    if (ImGui::Button("Clear loads")) push(ClearLoads{});
  }
  if (tool_ == Tool::Pin || tool_ == Tool::NormalPin) {
    if (ImGui::Button("Unpin all")) push(UnpinAll{});
  }

  ImGui::Separator();
  ImGui::TextDisabled("Brush");
  int property = static_cast<int>(brush_.property);
  if (ImGui::Combo("property", &property, kProperties, IM_ARRAYSIZE(kProperties)))
    brush_.property = static_cast<Property>(property);
  int mode = static_cast<int>(brush_.mode);
  if (ImGui::Combo("mode", &mode, kModes, IM_ARRAYSIZE(kModes)))
    brush_.mode = static_cast<editing::BrushMode>(mode);
  if (brush_.mode != editing::BrushMode::Smooth)
    ImGui::InputDouble("value", &brush_.value, 0.0, 0.0, "%.4g");
  float strength = static_cast<float>(brush_.strength);
  if (ImGui::SliderFloat("strength", &strength, 0.0f, 1.0f)) brush_.strength = strength;
  help("Shift+F then move the mouse (Blender)");
  float radius = static_cast<float>(brush_.radius);
  if (ImGui::InputFloat("radius", &radius, 0, 0, "%.3g") && radius > 0.0f) brush_.radius = radius;
  help(
      "Scene units. F then move the mouse, click to confirm, right click or Esc to cancel "
      "(Blender).");
  int falloff = static_cast<int>(brush_.falloff);
  if (ImGui::Combo("falloff", &falloff, kFalloffs, IM_ARRAYSIZE(kFalloffs)))
    brush_.falloff = static_cast<editing::Falloff>(falloff);
  bool euclidean = brush_.distance == editing::DistanceKind::Euclidean;
  if (ImGui::Checkbox("straight-line distance", &euclidean))
    brush_.distance = euclidean ? editing::DistanceKind::Euclidean : editing::DistanceKind::Surface;
  if (ImGui::Button("Apply to all")) push(Edit{editing::GlobalEdit{brush_}});
  help("The brush at full weight on every vertex (edge, angle).");
  ImGui::SameLine();
  if (ImGui::Button("Relax rest shape")) push(Edit{editing::Relax{}});
  help("R: the current shape becomes the rest shape (rest lengths and angles).");
  if (s.undoDepth == 0) ImGui::BeginDisabled();
  if (ImGui::Button("Undo")) push(Edit{editing::Undo{}});
  if (s.undoDepth == 0) ImGui::EndDisabled();
  help("Ctrl+Z");
  ImGui::SameLine();
  if (s.redoDepth == 0) ImGui::BeginDisabled();
  if (ImGui::Button("Redo")) push(Edit{editing::Redo{}});
  if (s.redoDepth == 0) ImGui::EndDisabled();
  help("Ctrl+Shift+Z or Ctrl+Y");
  ImGui::SameLine();
  ImGui::TextDisabled("%zu / %zu", s.undoDepth, s.redoDepth);
}

void Window::displayPanel(const Snapshot& s) {
  ImGui::Checkbox("surface", &view_.surface);
  ImGui::SameLine();
  ImGui::Checkbox("wireframe", &view_.wireframe);
  ImGui::SameLine();
  ImGui::Checkbox("points", &view_.points);
  ImGui::Checkbox("refined wireframe", &view_.surfaceWireframe);
  ImGui::SameLine();
  ImGui::Checkbox("glyphs", &view_.glyphs);
  ImGui::SameLine();
  ImGui::Checkbox("plots", &showPlots_);
  help(
      "Kinetic, potential and total energy, |p| and |L| over the last cycles, across the top of "
      "the view.");
  int levels = view_.levels;
  if (ImGui::SliderInt("subdivision", &levels, 0, std::max(mostLevels_, 0))) {
    try {
      builder_->setLevels(levels);
      view_.levels = levels;
      refined_.resize(builder_->stencil() ? builder_->stencil()->numRefinedVertices() : 0, 3);
    } catch (const Error& e) {
      message(std::string("subdivision: ") + e.what());
    }
  }
  help(
      "Levels of the interpolating Doo-Sabin surface drawn over the control mesh (0: the control "
      "mesh).");
  ImGui::Checkbox("colour by", &view_.colourByProperty);
  ImGui::SameLine();
  int property = static_cast<int>(s.scalarProperty);
  ImGui::SetNextItemWidth(-1.0f);
  if (ImGui::Combo("##colourproperty", &property, kProperties, IM_ARRAYSIZE(kProperties))) {
    solver_->setDisplayProperty(static_cast<Property>(property));
    view_.colourByProperty = true;
  }
  int map = static_cast<int>(view_.colorMap);
  if (ImGui::Combo("colour map", &map, kMaps, IM_ARRAYSIZE(kMaps)))
    view_.colorMap = static_cast<render::ColorMap>(map);
  ImGui::Checkbox("automatic range", &view_.autoRange);
  if (!view_.autoRange) {
    float range[2] = {static_cast<float>(view_.rangeMin), static_cast<float>(view_.rangeMax)};
    if (ImGui::InputFloat2("range", range, "%.3g")) {
      view_.rangeMin = range[0];
      view_.rangeMax = range[1];
    }
  }
  if (ImGui::Button("Frame model (Home)")) frameModel();
}

void Window::showPaintedProperty(const Snapshot& s) {
  // A dab changes nothing on screen unless the surface is coloured by what it paints: picking
  // the paint tool, or another property to paint, colours by that property (as weight
  // painting does elsewhere); a fixed range made for another property gives way to the
  // automatic one. Turning the colouring off afterwards is the user's to do.
  const bool changed = tool_ != lastTool_ || brush_.property != lastBrushProperty_;
  lastTool_ = tool_;
  lastBrushProperty_ = brush_.property;
  if (tool_ != Tool::Paint || !changed) return;
  if (s.scalarProperty != brush_.property) {
    solver_->setDisplayProperty(brush_.property);
    view_.autoRange = true;
  }
  if (!view_.colourByProperty)
    message("colouring by " + std::string(propertyName(brush_.property)) +
            ", the property painted");
  view_.colourByProperty = true;
}

void Window::plotStrip() {
  // Across the top of the view, where the model seldom is (framing centres it), and always in
  // sight: in the sidebar the plots were below the fold of an 800-pixel window.
  const ImGuiIO& io = ImGui::GetIO();
  const float sidebar = static_cast<float>(sidebarPixels_ / pixelScale_);
  const float plotHeight = 48.0f;
  const ImGuiStyle& style = ImGui::GetStyle();
  ImGui::SetNextWindowPos(ImVec2(0.0f, 0.0f));
  ImGui::SetNextWindowSize(
      ImVec2(std::max(1.0f, io.DisplaySize.x - sidebar),
             ImGui::GetFrameHeightWithSpacing() + plotHeight + 2.0f * style.WindowPadding.y));
  ImGui::SetNextWindowBgAlpha(0.7f);
  ImGui::Begin("plots", nullptr,
               ImGuiWindowFlags_NoMove | ImGuiWindowFlags_NoResize | ImGuiWindowFlags_NoCollapse |
                   ImGuiWindowFlags_NoTitleBar | ImGuiWindowFlags_NoScrollbar |
                   ImGuiWindowFlags_NoSavedSettings | ImGuiWindowFlags_NoBringToFrontOnFocus);
  const float width =
      std::max(1.0f, (ImGui::GetContentRegionAvail().x - 4.0f * style.ItemSpacing.x) / 5.0f);
  const struct {
    const char* label;
    const std::array<float, PlotSeries::kSize>& data;
  } series[5] = {{"kinetic", plots_.kinetic},
                 {"potential", plots_.potential},
                 {"total energy", plots_.total},
                 {"|p|", plots_.momentum},
                 {"|L|", plots_.angular}};
  for (int i = 0; i < 5; ++i) {
    if (i > 0) ImGui::SameLine();
    std::array<float, 4>& rect = plotRects_[static_cast<size_t>(i)];
    rect = plot(series[i].label, series[i].data, plots_, width, plotHeight);
    for (float& c : rect) c *= static_cast<float>(pixelScale_);
    if (ImGui::IsItemHovered())
      ImGui::SetTooltip(
          i < 3    ? "%s (J): the last %d samples%s"
          : i == 3 ? "%s, linear momentum (kg m/s): the last %d samples%s"
                   : "%s, angular momentum about the centre of mass (kg m^2/s): the last %d "
                     "samples%s",
          series[i].label, plots_.count,
          " (one per state the solver publishes: each cycle, and each edit while paused; Reset "
          "and a rollback drop the samples after the time they go back to)");
  }
  ImGui::End();
}

void Window::statisticsPanel(const Snapshot& s) {
  ImGui::Text("V / E / F: %d / %d / %d", mesh_->numVertices(), mesh_->numEdges(),
              mesh_->numFaces());
  if (builder_->stencil())
    ImGui::Text("drawn: %d vertices at level %d", builder_->stencil()->numRefinedVertices(),
                builder_->levels());
  ImGui::Text("solver: %.3f ms per step (T = %.1f ms)", 1e3 * s.solverSecondsPerStep,
              1e3 * s.period);
  ImGui::Text("display: %.1f frames/s", static_cast<double>(ImGui::GetIO().Framerate));
  ImGui::Text("simulated / wall time: %.3f", s.simOverWall);
  ImGui::Text("cycles: %llu, divergences: %llu", static_cast<unsigned long long>(s.cycle),
              static_cast<unsigned long long>(s.divergences));
  ImGui::Text("pins: %zu, normal pins: %zu, loads: %zu", s.pins.size(), s.normalPins.size(),
              s.forces.size() + s.torques.size());
  if (recorder_) ImGui::Text("recording to %s", recorder_->path().c_str());
}

void Window::filePanel(const Snapshot& s) {
  ImGui::TextWrapped("model: %s", source_.c_str());
  ImGui::InputText("##open", &pathField_);
  ImGui::SameLine();
  if (ImGui::Button("Open")) {
    if (s.unsaved) {
      pendingOpen_ = pathField_;
      confirmOpen_ = true;
    } else {
      openModel(pathField_);
    }
  }
  help(
      "A mesh file assimp reads (OBJ, PLY, STL, OFF, glTF, FBX, ...), builtin:NAME, or a scene "
      "(.json).");
  ImGui::SetNextItemWidth(6.0f * ImGui::GetFontSize());
  ImGui::Combo("up axis", &upChoice_, kUpChoices, IM_ARRAYSIZE(kUpChoices));
  help(
      "The file's up axis, turned to +z as it opens (auto: y for glTF and Collada, the file's "
      "own for FBX, z for OBJ, PLY, STL and OFF, which have no convention; a Y-up OBJ needs "
      "y).");
  ImGui::InputText("##scene", &sceneField_);
  ImGui::SameLine();
  if (ImGui::Button("Save scene")) saveScene(sceneField_, false);
  help("Ctrl+S: the scene with its painted properties, constraints and settings (JSON).");
  ImGui::InputText("##mesh", &meshField_);
  ImGui::SameLine();
  if (ImGui::Button("Save mesh")) saveMesh(meshField_);
  help("The current shape: .obj .ply .stl .gltf .glb .dae");
  if (ImGui::Button("Screenshot (F12)"))
    takeScreenshot("screenshot_" + std::to_string(++screenshotCounter_), true);
}

void Window::messagePanel() {
  ImGui::BeginChild("messages", ImVec2(0, 0), true);
  for (const std::string& m : log_) wrappedText(m);
  if (ImGui::GetScrollY() >= ImGui::GetScrollMaxY() - 1.0f) ImGui::SetScrollHereY(1.0f);
  ImGui::EndChild();
}

void Window::saveScene(const std::string& path, bool thenQuit) {
  if (path.empty()) {
    message("save scene: give a file name");
    return;
  }
  quitAfterSave_ = thenQuit;
  // The view as it is now (the session knows only the camera the scene was opened with).
  const io::CameraSettings camera = cameraSettingsOf(camera_);
  solver_->runOnSolver([path, camera](Session& session) {
    try {
      io::SceneDescription scene = session.currentScene();
      scene.camera = camera;
      io::saveScene(scene, path);
      session.apply(MarkSaved{});
      return "scene saved to " + path;
    } catch (const Error& e) {
      return std::string("save scene: ") + e.what();
    }
  });
}

void Window::saveMesh(const std::string& path) {
  if (path.empty()) {
    message("save mesh: give a file name");
    return;
  }
  solver_->runOnSolver([path](Session& session) {
    try {
      io::saveMesh(session.currentMesh(), path);
      return "mesh saved to " + path;
    } catch (const Error& e) {
      return std::string("save mesh: ") + e.what();
    }
  });
}

void Window::popups(const Snapshot& s) {
  if (quitAfterSave_ && !s.unsaved) quit_ = true;
  if (confirmQuit_) {
    ImGui::OpenPopup("Unsaved edits");
    confirmQuit_ = false;
  }
  if (ImGui::BeginPopupModal("Unsaved edits", nullptr, ImGuiWindowFlags_AlwaysAutoResize)) {
    ImGui::Text("The model has edits that are not saved.");
    ImGui::InputText("scene file", &sceneField_);
    if (ImGui::Button("Save and quit")) {
      saveScene(sceneField_, true);
      ImGui::CloseCurrentPopup();
    }
    ImGui::SameLine();
    if (ImGui::Button("Quit without saving")) {
      quit_ = true;
      ImGui::CloseCurrentPopup();
    }
    ImGui::SameLine();
    if (ImGui::Button("Cancel")) ImGui::CloseCurrentPopup();
    ImGui::EndPopup();
  }
  if (confirmOpen_) {
    ImGui::OpenPopup("Discard edits?");
    confirmOpen_ = false;
  }
  if (ImGui::BeginPopupModal("Discard edits?", nullptr, ImGuiWindowFlags_AlwaysAutoResize)) {
    ImGui::Text("Opening %s discards the unsaved edits of this model.", pendingOpen_.c_str());
    if (ImGui::Button("Open anyway")) {
      ImGui::CloseCurrentPopup();
      openModel(pendingOpen_);
    }
    ImGui::SameLine();
    if (ImGui::Button("Cancel")) ImGui::CloseCurrentPopup();
    ImGui::EndPopup();
  }
}

void Window::overlays(const Snapshot& s) {
  ImDrawList* draw = ImGui::GetForegroundDrawList();
  const float k = static_cast<float>(1.0 / pixelScale_);
  if (adjust_ != Adjust::None) {
    const ImVec2 centre(static_cast<float>(adjustCentreX_) * k,
                        static_cast<float>(adjustCentreY_) * k);
    const float r = adjust_ == Adjust::Radius
                        ? static_cast<float>(brush_.radius /
                                             worldPerPixel(camera_, viewHeight_, camera_.target)) *
                              k
                        : static_cast<float>(brush_.strength * 200.0);
    draw->AddCircle(centre, r, IM_COL32(255, 255, 255, 230), 64, 2.0f);
    draw->AddCircle(centre, r + 1.5f, IM_COL32(30, 30, 40, 200), 64, 1.0f);
    char text[64];
    if (adjust_ == Adjust::Radius)
      std::snprintf(text, sizeof text, "radius %.3g", brush_.radius);
    else
      std::snprintf(text, sizeof text, "strength %.2f", brush_.strength);
    draw->AddText(ImVec2(centre.x + 6, centre.y - 8), IM_COL32(20, 20, 30, 255), text);
  }
  if (gesture_ == Gesture::Tool && (tool_ == Tool::Force || tool_ == Tool::Torque) &&
      toolVertex_ >= 0 && toolVertex_ < s.position.rows()) {
    const auto a = projectToPixel(camera_, viewWidth_, viewHeight_, toolAnchor_);
    const auto b = projectToPixel(camera_, viewWidth_, viewHeight_, loadEnd_);
    if (a && b) {
      const ImU32 colour =
          tool_ == Tool::Force ? IM_COL32(255, 140, 26, 255) : IM_COL32(155, 79, 209, 255);
      const ImVec2 pa(static_cast<float>(a->x()) * k, static_cast<float>(a->y()) * k);
      const ImVec2 pb(static_cast<float>(b->x()) * k, static_cast<float>(b->y()) * k);
      draw->AddLine(pa, pb, colour, 3.0f);
      draw->AddCircleFilled(pb, 5.0f, colour);
      const Vec3 drag = loadEnd_ - toolAnchor_;
      char text[64];
      std::snprintf(text, sizeof text, tool_ == Tool::Force ? "%.3g N" : "%.3g N m",
                    (tool_ == Tool::Force ? forceScale_ : torqueScale_) * drag.norm());
      draw->AddText(ImVec2(pb.x + 8, pb.y - 8), IM_COL32(20, 20, 30, 255), text);
    }
  }
  // The loads acting now, each labelled with its size beside its vertex: the arrows are drawn
  // to a common scale (the largest a fifth of the model), so they show directions and ratios,
  // not newtons. The first kMaxLabels of each kind only: a scene of hundreds would be text.
  loadLabels_.clear();
  if (view_.glyphs) {
    constexpr size_t kMaxLabels = 16;
    auto label = [&](const std::vector<std::pair<Index, Vec3>>& loads, const char* format,
                     ImU32 colour) {
      size_t drawn = 0;
      for (size_t i = 0; i < loads.size() && drawn < kMaxLabels; ++i) {
        const auto& [v, value] = loads[i];
        if (v < 0 || v >= s.position.rows()) continue;
        const auto p = projectToPixel(camera_, viewWidth_, viewHeight_, s.position.row(v));
        // Only loads in the view: a label is drawn over everything, the sidebar included.
        if (!p || p->x() < 0.0 || p->y() < 0.0 || p->x() >= viewWidth_ || p->y() >= viewHeight_)
          continue;
        char text[32];
        std::snprintf(text, sizeof text, format, value.norm());
        const ImVec2 at(static_cast<float>(p->x()) * k + 10.0f,
                        static_cast<float>(p->y()) * k + 4.0f);
        const ImVec2 size = ImGui::CalcTextSize(text);
        draw->AddRectFilled(ImVec2(at.x - 3.0f, at.y - 1.0f),
                            ImVec2(at.x + size.x + 3.0f, at.y + size.y + 1.0f),
                            IM_COL32(255, 255, 255, 190), 3.0f);
        draw->AddText(at, colour, text);
        ++drawn;
        if (loadLabels_.size() < loadLabels_.capacity()) loadLabels_.push_back(value.norm());
      }
    };
    // Clipped to the view: a label near its right edge would run over the sidebar.
    draw->PushClipRect(ImVec2(0.0f, 0.0f), ImVec2(static_cast<float>(viewWidth_) * k,
                                                  static_cast<float>(viewHeight_) * k));
    label(s.forces, "%.4g N", IM_COL32(176, 84, 0, 255));
    label(s.torques, "%.4g N m", IM_COL32(110, 50, 160, 255));
    draw->PopClipRect();
  }
}

}  // namespace zsculpt::app
