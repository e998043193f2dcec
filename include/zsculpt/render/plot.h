#pragma once
// Line plots of time series to PNG, on the CPU (no GL): one or more panels stacked
// vertically, each with axes, ticks with numbers, axis labels, a title and a legend.
// Used for the energy and momentum plots of `zsculpt render` and `demo` (Figure 7) and
// the partial-energy plot of Figure 3.

#include <Eigen/Core>
#include <optional>
#include <string>
#include <vector>

#include "zsculpt/render/canvas.h"
#include "zsculpt/render/color.h"
#include "zsculpt/render/image.h"

namespace zsculpt::render {

struct Series {
  std::string name;  ///< legend entry
  std::vector<double> x;
  std::vector<double> y;       ///< same size as x; non-finite values break the line
  std::optional<Color> color;  ///< default: the palette colour of the series' index
  bool dashed = false;
};

/// An interval of x shaded behind the curves (when a load acts, say).
struct Band {
  double x0 = 0.0;
  double x1 = 0.0;
};

struct PlotPanel {
  std::string title;
  std::string xLabel;
  std::string yLabel;
  std::vector<Series> series;
  /// Fixed axis limits; unset: x spans the finite data, y the data plus 5 % headroom.
  std::optional<double> xMin, xMax, yMin, yMax;
  bool logY = false;  ///< logarithmic y (non-positive values are skipped)
  /// The least span of an automatic linear y axis: at least minSpan, and at least
  /// minRelativeSpan times the largest |y|, about the data's middle, so that rounding
  /// noise on a conserved quantity is drawn as the flat line it is, not as a signal.
  double minSpan = 0.0;
  double minRelativeSpan = 0.0;
  /// Quantities that cannot be negative (time, a magnitude): an automatic axis stops at
  /// zero rather than padding a lone sample or a zero series into negative values.
  bool nonNegativeX = false;
  bool nonNegativeY = false;
  /// Shaded intervals, with one legend entry (bandLabel) when it is not empty.
  std::vector<Band> bands;
  std::string bandLabel;
  Color bandColor = Color::hex(0xf6d98a, 0.45f);
};

struct PlotOptions {
  int width = 1200;
  int panelHeight = 380;  ///< per panel; the image is panels x panelHeight (+ title)
  std::string title;      ///< above all panels; empty: none
  double lineWidth = 2.2;
  double fontSize = 17.0;
};

/// Where a panel's data area is on the image and which data range it shows.
struct PanelGeometry {
  double left = 0, top = 0, right = 0, bottom = 0;  ///< pixels, y down
  double xMin = 0, xMax = 1, yMin = 0, yMax = 1;
  bool logY = false;
  /// Pixel position (x right, y down) of the data point (x, y).
  [[nodiscard]] Eigen::Vector2d toPixel(double x, double y) const;
};

struct PlotLayout {
  int width = 0;
  int height = 0;
  std::vector<PanelGeometry> panels;
};

/// The palette colour of series `index` (Tableau 10).
Color seriesColor(int index);

/// Computes the layout only (axis ranges and data rectangles).
PlotLayout layoutPlot(const std::vector<PlotPanel>& panels, const PlotOptions& options = {});
/// Draws the plot. Throws InvalidInputError for no panels, a series whose x and y sizes
/// differ, or a size below 100 x 100 pixels. Fills `layout` when given.
Image renderPlot(const std::vector<PlotPanel>& panels, const PlotOptions& options = {},
                 PlotLayout* layout = nullptr);
/// Renders and writes a PNG atomically.
void savePlot(const std::string& path, const std::vector<PlotPanel>& panels,
              const PlotOptions& options = {});

/// The columns of a diagnostics CSV (cli.md: step,time,kinetic,potential,total,px,py,pz,
/// lx,ly,lz).
struct EnergyMomentumSeries {
  std::vector<double> time, kinetic, potential, total, px, py, pz, lx, ly, lz;
};

enum class MomentumDisplay {
  Magnitude,   ///< |p| and |L|
  Components,  ///< px, py, pz and lx, ly, lz
};

/// Three panels: energy (kinetic, potential, total), linear momentum, angular momentum.
std::vector<PlotPanel> energyMomentumPanels(const EnergyMomentumSeries& series,
                                            MomentumDisplay momentum = MomentumDisplay::Magnitude);
/// Reads a diagnostics CSV (columns found by header name). Throws IOError "<path>: ..." for
/// a missing file, a missing column or a malformed number (with its line).
EnergyMomentumSeries readDiagnosticsCsv(const std::string& path);

}  // namespace zsculpt::render
