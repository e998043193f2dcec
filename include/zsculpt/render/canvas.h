#pragma once
// A small CPU rasterizer with antialiased primitives and text, for plots, the legend and
// figure captions. Lines are drawn with analytic coverage (distance to the segment), and
// a polyline takes the largest coverage over its segments so joints do not darken.
//
// Text uses DejaVu Sans through stb_truetype when the font file is found ($ZSCULPT_FONT,
// then the usual Debian paths) and stb_easy_font otherwise.

#include <Eigen/Core>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "zsculpt/render/color.h"
#include "zsculpt/render/image.h"

namespace zsculpt::render {

enum class Align { Start, Center, End };

class Canvas {
 public:
  Canvas() = default;
  Canvas(int width, int height, Color background);

  /// Resizes (allocating only when the pixel count grows) and fills with `background`
  /// (which may be transparent).
  void reset(int width, int height, Color background);
  [[nodiscard]] int width() const { return image_.width; }
  [[nodiscard]] int height() const { return image_.height; }
  [[nodiscard]] const Image& image() const { return image_; }
  [[nodiscard]] Image& image() { return image_; }

  /// Blends `color` with coverage `alpha` (0..1, times color.a) over pixel (x, y).
  void blend(int x, int y, Color color, float alpha);
  /// Axis-aligned rectangle with antialiased fractional edges.
  void fillRect(double x0, double y0, double x1, double y1, Color color);
  /// Rectangle with rounded corners of `radius` pixels.
  void fillRoundedRect(double x0, double y0, double x1, double y1, double radius, Color color);
  void strokeRect(double x0, double y0, double x1, double y1, double width, Color color);
  /// One segment with round caps, `width` pixels wide.
  void line(double x0, double y0, double x1, double y1, double width, Color color);
  /// Connected segments; points with a non-finite coordinate break the line. Dashed lines
  /// use dashes and gaps of 4 line widths. Clipped to `clip` (x0, y0, x1, y1) when given.
  void polyline(std::span<const Eigen::Vector2d> points, double width, Color color,
                bool dashed = false, const Eigen::Vector4d* clip = nullptr);
  /// Filled disc.
  void disc(double cx, double cy, double radius, Color color);

  /// Draws UTF-8 text (ASCII and Latin-1) of `size` pixels (cap-to-descender line height)
  /// anchored at (x, y) by the alignments; `vertical` runs it bottom to top.
  void text(double x, double y, std::string_view text, double size, Color color,
            Align horizontal = Align::Start, Align verticalAlign = Align::Start,
            bool vertical = false);
  [[nodiscard]] double textWidth(std::string_view text, double size) const;

  /// Copies `source` with its alpha blended, top-left corner at (x, y).
  void blit(const Image& source, int x, int y);

 private:
  void coverageFlush(int x0, int y0, int x1, int y1, Color color);

  Image image_;
  std::vector<float> coverage_;  // per-pixel scratch for polylines and text
};

/// Whether text is drawn with a TrueType font (false: the stb_easy_font fallback).
bool hasTrueTypeFont();

/// Short, readable number: fixed notation with `significant` digits for moderate
/// magnitudes, scientific ("1.5e-06") otherwise; "0" for zero.
std::string formatNumber(double value, int significant = 3);

}  // namespace zsculpt::render
