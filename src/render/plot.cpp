#include "zsculpt/render/plot.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <map>
#include <sstream>

#include "zsculpt/core/errors.h"

namespace zsculpt::render {
namespace {

const Color kAxis = Color::hex(0x3a3f4b);
const Color kGrid = Color::hex(0xe4e7ec);
const Color kText = Color::hex(0x1d2230);
const Color kMutedText = Color::hex(0x4a5060);

struct Ticks {
  double min = 0.0;
  double max = 1.0;
  double step = 0.2;
  std::vector<double> values;
};

// 1, 2, 2.5 or 5 times a power of ten, near raw.
double niceStep(double raw) {
  if (!(raw > 0.0) || !std::isfinite(raw)) return 1.0;
  const double power = std::pow(10.0, std::floor(std::log10(raw)));
  const double f = raw / power;
  double nice = 10.0;
  if (f <= 1.0) {
    nice = 1.0;
  } else if (f <= 2.0) {
    nice = 2.0;
  } else if (f <= 2.5) {
    nice = 2.5;
  } else if (f <= 5.0) {
    nice = 5.0;
  }
  return nice * power;
}

// Ticks at multiples of a nice step inside [lo, hi].
Ticks linearTicks(double lo, double hi, int target) {
  Ticks t;
  t.step = niceStep((hi - lo) / target);
  t.min = lo;
  t.max = hi;
  const double first = std::ceil(t.min / t.step - 1e-9) * t.step;
  for (int k = 0; k < 1000; ++k) {
    double v = first + k * t.step;
    if (v > t.max + 1e-9 * t.step) break;
    if (std::abs(v) < 1e-9 * t.step) v = 0.0;
    t.values.push_back(v);
  }
  return t;
}

Ticks logTicks(double lo, double hi) {
  Ticks t;
  const double a = std::floor(std::log10(lo));
  const double b = std::max(a + 1.0, std::ceil(std::log10(hi)));
  t.min = std::pow(10.0, a);
  t.max = std::pow(10.0, b);
  const int decades = static_cast<int>(b - a);
  const int every = std::max(1, (decades + 5) / 6);
  for (int k = 0; k <= decades; k += every) t.values.push_back(std::pow(10.0, a + k));
  t.step = every;
  return t;
}

// Label of tick `v` on an axis with spacing `step`: enough digits to tell ticks apart.
std::string tickLabel(double v, double step) {
  if (v == 0.0) return "0";
  // Steps of 2.5 x 10^k need one digit more than their power of ten.
  const double power = std::pow(10.0, std::floor(std::log10(step) + 1e-9));
  const double mantissa = step / power;
  const int extra = std::abs(mantissa - std::round(mantissa)) > 1e-6 ? 1 : 0;
  const double magnitude = std::max(std::abs(v), step);
  if (magnitude >= 1e5 || step < 1e-4) {
    const int significant = std::clamp(static_cast<int>(std::floor(std::log10(std::abs(v)) + 1e-9) -
                                                        std::floor(std::log10(step) + 1e-9)) +
                                           1 + extra,
                                       1, 8);
    return formatNumber(v, significant);
  }
  const int decimals = std::max(0, -static_cast<int>(std::floor(std::log10(step) + 1e-9)));
  char buffer[64];
  std::snprintf(buffer, sizeof buffer, "%.*f", decimals + extra, v);
  return buffer;
}

struct AxisData {
  Ticks x;
  Ticks y;
};

AxisData computeAxes(const PlotPanel& panel) {
  double xlo = std::numeric_limits<double>::infinity();
  double xhi = -xlo;
  double ylo = xlo;
  double yhi = -xlo;
  for (const Series& s : panel.series) {
    if (s.x.size() != s.y.size()) {
      throw InvalidInputError("plot series " + s.name + ": x and y sizes differ (" +
                              std::to_string(s.x.size()) + " and " + std::to_string(s.y.size()) +
                              ")");
    }
    for (size_t i = 0; i < s.x.size(); ++i) {
      if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) continue;
      if (panel.logY && s.y[i] <= 0.0) continue;
      xlo = std::min(xlo, s.x[i]);
      xhi = std::max(xhi, s.x[i]);
      ylo = std::min(ylo, s.y[i]);
      yhi = std::max(yhi, s.y[i]);
    }
  }
  if (!std::isfinite(xlo)) {  // no data
    xlo = 0.0;
    xhi = 1.0;
    ylo = panel.logY ? 1.0 : 0.0;
    yhi = panel.logY ? 10.0 : 1.0;
  }
  if (panel.xMin) xlo = *panel.xMin;
  if (panel.xMax) xhi = *panel.xMax;
  if (panel.yMin) ylo = *panel.yMin;
  if (panel.yMax) yhi = *panel.yMax;
  const bool xFloor = panel.nonNegativeX && !panel.xMin && xlo >= 0.0;
  const bool yFloor = panel.nonNegativeY && !panel.yMin && ylo >= 0.0;
  if (xhi <= xlo) {
    const double pad = xlo == 0.0 ? 1.0 : 0.5 * std::abs(xlo);
    xlo -= pad;
    xhi += pad;
  }
  if (xFloor && xlo < 0.0) xlo = 0.0;  // a lone sample at t = 0: [0, 1], not [-1, 1]
  AxisData axes;
  axes.x = linearTicks(xlo, xhi, 7);
  if (panel.logY) {
    if (ylo <= 0.0) ylo = 1e-12;
    if (yhi <= ylo) yhi = ylo * 10.0;
    axes.y = logTicks(ylo, yhi);
    if (panel.yMin) axes.y.min = *panel.yMin;
    if (panel.yMax) axes.y.max = *panel.yMax;
    return axes;
  }
  if (!panel.yMin && !panel.yMax) {
    const double least =
        std::max(panel.minSpan, panel.minRelativeSpan * std::max(std::abs(ylo), std::abs(yhi)));
    if (yhi - ylo < least) {
      const double middle = 0.5 * (ylo + yhi);
      ylo = middle - 0.5 * least;
      yhi = middle + 0.5 * least;
      if (yFloor && ylo < 0.0) {  // the same span, from zero
        yhi -= ylo;
        ylo = 0.0;
      }
    }
  }
  if (yhi <= ylo) {
    const double pad = ylo == 0.0 ? 1.0 : 0.1 * std::abs(ylo);
    ylo -= pad;
    yhi += pad;
  }
  // A little headroom so a curve does not run along the frame; ticks fall inside.
  const double pad = 0.05 * (yhi - ylo);
  if (!panel.yMin) ylo -= pad;
  if (!panel.yMax) yhi += pad;
  if (yFloor && ylo < 0.0) ylo = 0.0;
  axes.y = linearTicks(ylo, yhi, 5);
  if (panel.yMin) axes.y.min = *panel.yMin;
  if (panel.yMax) axes.y.max = *panel.yMax;
  return axes;
}

struct Metrics {
  double font;
  double small;
  double titleHeight;
  double left;
  double right;
  double panelTop;
  double panelBottom;
};

Metrics computeMetrics(const std::vector<PlotPanel>& panels, const std::vector<AxisData>& axes,
                       const PlotOptions& options) {
  Canvas measure;  // textWidth needs no pixels
  Metrics m{};
  m.font = options.fontSize;
  m.small = 0.88 * options.fontSize;
  m.titleHeight = options.title.empty() ? 0.0 : 2.2 * m.font;
  double tickWidth = 0.0;
  double legendWidth = 0.0;
  for (size_t p = 0; p < panels.size(); ++p) {
    for (double v : axes[p].y.values) {
      tickWidth = std::max(tickWidth, measure.textWidth(tickLabel(v, axes[p].y.step), m.small));
    }
    for (const Series& s : panels[p].series) {
      legendWidth = std::max(legendWidth, measure.textWidth(s.name, m.small));
    }
    if (!panels[p].bands.empty() && !panels[p].bandLabel.empty())
      legendWidth = std::max(legendWidth, measure.textWidth(panels[p].bandLabel, m.small));
  }
  const bool anyYLabel = std::any_of(panels.begin(), panels.end(),
                                     [](const PlotPanel& p) { return !p.yLabel.empty(); });
  m.left = 0.9 * m.font + tickWidth + 0.9 * m.font + (anyYLabel ? 1.5 * m.font : 0.0);
  m.right = legendWidth > 0.0 ? legendWidth + 4.6 * m.font : 1.5 * m.font;
  m.panelTop = 2.1 * m.font;
  m.panelBottom = 3.4 * m.font;
  return m;
}

}  // namespace

Eigen::Vector2d PanelGeometry::toPixel(double x, double y) const {
  const double u = (x - xMin) / (xMax - xMin);
  double v = 0.0;
  if (logY) {
    v = (std::log10(y) - std::log10(yMin)) / (std::log10(yMax) - std::log10(yMin));
  } else {
    v = (y - yMin) / (yMax - yMin);
  }
  return {left + u * (right - left), bottom - v * (bottom - top)};
}

Color seriesColor(int index) {
  static constexpr std::uint32_t kPalette[] = {0x1f77b4, 0xff7f0e, 0x2ca02c, 0xd62728, 0x9467bd,
                                               0x8c564b, 0xe377c2, 0x7f7f7f, 0xbcbd22, 0x17becf};
  const int n = static_cast<int>(std::size(kPalette));
  return Color::hex(kPalette[((index % n) + n) % n]);
}

static PlotLayout layoutWith(const std::vector<PlotPanel>& panels, const PlotOptions& options,
                             std::vector<AxisData>& axes, Metrics& metrics) {
  if (panels.empty()) throw InvalidInputError("plot: no panels");
  if (options.width < 100 || options.panelHeight < 100) {
    throw InvalidInputError("plot: size " + std::to_string(options.width) + "x" +
                            std::to_string(options.panelHeight) +
                            " per panel is below 100 x 100 pixels");
  }
  axes.clear();
  for (const PlotPanel& panel : panels) axes.push_back(computeAxes(panel));
  metrics = computeMetrics(panels, axes, options);
  PlotLayout layout;
  layout.width = options.width;
  layout.height = static_cast<int>(std::lround(metrics.titleHeight)) +
                  options.panelHeight * static_cast<int>(panels.size());
  for (size_t p = 0; p < panels.size(); ++p) {
    PanelGeometry g;
    const double top = metrics.titleHeight + static_cast<double>(p) * options.panelHeight;
    g.left = std::round(metrics.left);
    g.right = std::round(options.width - metrics.right);
    g.top = std::round(top + metrics.panelTop);
    g.bottom = std::round(top + options.panelHeight - metrics.panelBottom);
    g.xMin = axes[p].x.min;
    g.xMax = axes[p].x.max;
    g.yMin = axes[p].y.min;
    g.yMax = axes[p].y.max;
    g.logY = panels[p].logY;
    if (g.right - g.left < 20 || g.bottom - g.top < 20) {
      throw InvalidInputError("plot: the image is too small for its labels");
    }
    layout.panels.push_back(g);
  }
  return layout;
}

PlotLayout layoutPlot(const std::vector<PlotPanel>& panels, const PlotOptions& options) {
  std::vector<AxisData> axes;
  Metrics metrics{};
  return layoutWith(panels, options, axes, metrics);
}

Image renderPlot(const std::vector<PlotPanel>& panels, const PlotOptions& options,
                 PlotLayout* layoutOut) {
  std::vector<AxisData> axes;
  Metrics m{};
  const PlotLayout layout = layoutWith(panels, options, axes, m);
  Canvas canvas(layout.width, layout.height, Color::hex(0xffffff));
  if (!options.title.empty()) {
    canvas.text(0.5 * layout.width, 0.55 * m.titleHeight, options.title, 1.15 * m.font, kText,
                Align::Center, Align::Center);
  }
  std::vector<Eigen::Vector2d> points;
  for (size_t p = 0; p < panels.size(); ++p) {
    const PlotPanel& panel = panels[p];
    const PanelGeometry& g = layout.panels[p];
    const AxisData& a = axes[p];
    // Bands behind the grid and the curves, clipped to the data area.
    for (const Band& band : panel.bands) {
      const double x0 =
          std::clamp(g.toPixel(std::min(band.x0, band.x1), g.yMin).x(), g.left, g.right);
      const double x1 =
          std::clamp(g.toPixel(std::max(band.x0, band.x1), g.yMin).x(), g.left, g.right);
      if (x1 > x0) canvas.fillRect(x0, g.top, x1, g.bottom, panel.bandColor);
    }
    // Grid.
    for (double v : a.y.values) {
      if (v < g.yMin || v > g.yMax) continue;
      const double y = std::round(g.toPixel(g.xMin, v).y()) + 0.5;
      canvas.fillRect(g.left, y - 0.5, g.right, y + 0.5, kGrid);
    }
    for (double v : a.x.values) {
      const double x = std::round(g.toPixel(v, g.yMin).x()) + 0.5;
      canvas.fillRect(x - 0.5, g.top, x + 0.5, g.bottom, kGrid);
    }
    // Series, clipped to the data area.
    const Eigen::Vector4d clip(g.left, g.top, g.right, g.bottom);
    for (size_t s = 0; s < panel.series.size(); ++s) {
      const Series& series = panel.series[s];
      points.resize(series.x.size());
      for (size_t i = 0; i < series.x.size(); ++i) {
        const bool valid = std::isfinite(series.x[i]) && std::isfinite(series.y[i]) &&
                           (!panel.logY || series.y[i] > 0.0);
        points[i] = valid ? g.toPixel(series.x[i], series.y[i])
                          : Eigen::Vector2d::Constant(std::numeric_limits<double>::quiet_NaN());
      }
      const Color color = series.color.value_or(seriesColor(static_cast<int>(s)));
      canvas.polyline(points, options.lineWidth, color, series.dashed, &clip);
      // A sample with no valid neighbour draws no line: a dot shows it (a run of no steps
      // has one sample).
      for (size_t i = 0; i < points.size(); ++i) {
        const auto valid = [&](size_t k) { return !std::isnan(points[k].x()); };
        if (!valid(i) || (i > 0 && valid(i - 1)) || (i + 1 < points.size() && valid(i + 1)))
          continue;
        const Eigen::Vector2d& q = points[i];
        if (q.x() >= g.left && q.x() <= g.right && q.y() >= g.top && q.y() <= g.bottom)
          canvas.disc(q.x(), q.y(), 1.8 * options.lineWidth, color);
      }
    }
    // Frame, ticks and tick labels.
    canvas.strokeRect(g.left, g.top, g.right, g.bottom, 1.2, kAxis);
    const double tick = 0.35 * m.font;
    for (double v : a.x.values) {
      const double x = g.toPixel(v, g.yMin).x();
      canvas.fillRect(x - 0.6, g.bottom, x + 0.6, g.bottom + tick, kAxis);
      canvas.text(x, g.bottom + tick + 0.3 * m.font, tickLabel(v, a.x.step), m.small, kMutedText,
                  Align::Center, Align::Start);
    }
    for (double v : a.y.values) {
      if (v < g.yMin - 1e-12 * std::abs(g.yMin) || v > g.yMax + 1e-12 * std::abs(g.yMax)) continue;
      const double y = g.toPixel(g.xMin, v).y();
      canvas.fillRect(g.left - tick, y - 0.6, g.left, y + 0.6, kAxis);
      const std::string label = panel.logY ? formatNumber(v, 1) : tickLabel(v, a.y.step);
      canvas.text(g.left - tick - 0.35 * m.font, y, label, m.small, kMutedText, Align::End,
                  Align::Center);
    }
    // Labels and title.
    if (!panel.xLabel.empty()) {
      canvas.text(0.5 * (g.left + g.right), g.bottom + tick + 1.55 * m.font, panel.xLabel, m.font,
                  kText, Align::Center, Align::Start);
    }
    if (!panel.yLabel.empty()) {
      canvas.text(0.4 * m.font, 0.5 * (g.top + g.bottom), panel.yLabel, m.font, kText,
                  Align::Center, Align::Start, true);
    }
    if (!panel.title.empty()) {
      canvas.text(g.left, g.top - 0.55 * m.font, panel.title, 1.05 * m.font, kText, Align::Start,
                  Align::End);
    }
    // Legend, right of the data area.
    double ly = g.top + 0.8 * m.font;
    for (size_t s = 0; s < panel.series.size(); ++s) {
      const Series& series = panel.series[s];
      const Color color = series.color.value_or(seriesColor(static_cast<int>(s)));
      const double x0 = g.right + 1.0 * m.font;
      const double x1 = x0 + 2.2 * m.font;
      const Eigen::Vector2d swatch[2] = {{x0, ly}, {x1, ly}};
      canvas.polyline(swatch, options.lineWidth, color, series.dashed);
      canvas.text(x1 + 0.6 * m.font, ly, series.name, m.small, kText, Align::Start, Align::Center);
      ly += 1.5 * m.font;
    }
    if (!panel.bands.empty() && !panel.bandLabel.empty()) {
      const double x0 = g.right + 1.0 * m.font;
      const double x1 = x0 + 2.2 * m.font;
      canvas.fillRect(x0, ly - 0.45 * m.font, x1, ly + 0.45 * m.font, panel.bandColor);
      canvas.text(x1 + 0.6 * m.font, ly, panel.bandLabel, m.small, kText, Align::Start,
                  Align::Center);
    }
  }
  if (layoutOut != nullptr) *layoutOut = layout;
  return std::move(canvas.image());
}

void savePlot(const std::string& path, const std::vector<PlotPanel>& panels,
              const PlotOptions& options) {
  savePng(path, renderPlot(panels, options));
}

std::vector<PlotPanel> energyMomentumPanels(const EnergyMomentumSeries& d,
                                            MomentumDisplay momentum) {
  std::vector<PlotPanel> panels(3);
  PlotPanel& energy = panels[0];
  energy.title = "Energy";
  energy.xLabel = "time (s)";
  energy.yLabel = "energy (J)";
  energy.series = {{"kinetic", d.time, d.kinetic, seriesColor(0), false},
                   {"potential", d.time, d.potential, seriesColor(1), false},
                   {"total", d.time, d.total, Color::hex(0x222833), false}};

  auto magnitude = [&](const std::vector<double>& x, const std::vector<double>& y,
                       const std::vector<double>& z) {
    std::vector<double> out(std::min({x.size(), y.size(), z.size()}));
    for (size_t i = 0; i < out.size(); ++i)
      out[i] = std::sqrt(x[i] * x[i] + y[i] * y[i] + z[i] * z[i]);
    return out;
  };
  PlotPanel& linear = panels[1];
  linear.title = "Linear momentum";
  linear.xLabel = "time (s)";
  PlotPanel& angular = panels[2];
  angular.title = "Angular momentum about the centre of mass";
  angular.xLabel = "time (s)";
  // Conserved quantities: a change under 0.1 % of their size, or of 1e-9 (rounding on a
  // zero momentum is 1e-14), is drawn flat rather than magnified to fill the panel.
  for (PlotPanel* panel : {&energy, &linear, &angular}) {
    panel->minRelativeSpan = 1e-3;
    panel->minSpan = 1e-9;
    panel->nonNegativeX = true;
  }
  if (momentum == MomentumDisplay::Magnitude) {
    linear.nonNegativeY = angular.nonNegativeY = true;
    linear.yLabel = "|p| (kg m/s)";
    linear.series = {{"|p|", d.time, magnitude(d.px, d.py, d.pz), seriesColor(2), false}};
    angular.yLabel = "|L| (kg m\u00b2/s)";
    angular.series = {{"|L|", d.time, magnitude(d.lx, d.ly, d.lz), seriesColor(4), false}};
  } else {
    linear.yLabel = "p (kg m/s)";
    linear.series = {{"px", d.time, d.px, seriesColor(0), false},
                     {"py", d.time, d.py, seriesColor(1), false},
                     {"pz", d.time, d.pz, seriesColor(2), false}};
    angular.yLabel = "L (kg m\u00b2/s)";
    angular.series = {{"Lx", d.time, d.lx, seriesColor(0), false},
                      {"Ly", d.time, d.ly, seriesColor(1), false},
                      {"Lz", d.time, d.lz, seriesColor(2), false}};
  }
  return panels;
}

EnergyMomentumSeries readDiagnosticsCsv(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw IOError(path + ": cannot open");
  std::string line;
  if (!std::getline(in, line)) throw IOError(path + ": empty file");
  std::map<std::string, size_t> columns;
  {
    std::stringstream header(line);
    std::string name;
    for (size_t c = 0; std::getline(header, name, ','); ++c) {
      while (!name.empty() && (name.back() == '\r' || name.back() == ' ')) name.pop_back();
      columns[name] = c;
    }
  }
  EnergyMomentumSeries d;
  const std::pair<const char*, std::vector<double>*> wanted[] = {
      {"time", &d.time},   {"kinetic", &d.kinetic}, {"potential", &d.potential},
      {"total", &d.total}, {"px", &d.px},           {"py", &d.py},
      {"pz", &d.pz},       {"lx", &d.lx},           {"ly", &d.ly},
      {"lz", &d.lz}};
  std::vector<std::pair<size_t, std::vector<double>*>> targets;
  for (const auto& [name, target] : wanted) {
    const auto found = columns.find(name);
    if (found == columns.end()) throw IOError(path + ": missing column '" + name + "'");
    targets.emplace_back(found->second, target);
  }
  std::vector<double> fields;
  for (size_t number = 2; std::getline(in, line); ++number) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty()) continue;
    fields.clear();
    const char* p = line.c_str();
    while (true) {
      char* end = nullptr;
      const double v = std::strtod(p, &end);
      if (end == p) throw IOError(path + ":" + std::to_string(number) + ": malformed number");
      fields.push_back(v);
      p = end;
      while (*p == ' ') ++p;
      if (*p == '\0') break;
      if (*p != ',') throw IOError(path + ":" + std::to_string(number) + ": malformed number");
      ++p;
    }
    for (const auto& [column, target] : targets) {
      if (column >= fields.size()) {
        throw IOError(path + ":" + std::to_string(number) + ": too few columns");
      }
      target->push_back(fields[column]);
    }
  }
  return d;
}

}  // namespace zsculpt::render
