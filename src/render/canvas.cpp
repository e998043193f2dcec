#include "zsculpt/render/canvas.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iterator>
#include <map>
#include <mutex>
#include <string>

#include "zsculpt/core/errors.h"

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#pragma GCC diagnostic ignored "-Wsign-compare"
#pragma GCC diagnostic ignored "-Wunused-function"
#pragma GCC diagnostic ignored "-Wunused-parameter"
#pragma GCC diagnostic ignored "-Wpedantic"
#pragma GCC diagnostic ignored "-Wconversion"
#define STB_TRUETYPE_IMPLEMENTATION
#define STBTT_STATIC
#include <stb_easy_font.h>
#include <stb_truetype.h>
#pragma GCC diagnostic pop

namespace zsculpt::render {
namespace {

// ---- fonts -------------------------------------------------------------------------------

// Code points baked into the atlas: ASCII, Latin-1 (degree, squared, times, middle dot),
// Greek (the paper's symbols) and a few dashes.
constexpr int kRangeStarts[] = {32, 160, 0x391};
constexpr int kRangeCounts[] = {95, 96, 0x3C9 - 0x391 + 1};
int kExtraCodepoints[] = {0x2212, 0x2013, 0x2014, 0x2026};

struct BakedFont {
  int atlasWidth = 0;
  int atlasHeight = 0;
  std::vector<unsigned char> atlas;
  std::vector<stbtt_packedchar> chars[4];
  float ascent = 0.0f;  // pixels above the baseline
  float capHeight = 0.0f;
};

class FontLibrary {
 public:
  static FontLibrary& instance() {
    static FontLibrary library;
    return library;
  }
  [[nodiscard]] bool hasTrueType() const { return !data_.empty(); }
  const stbtt_fontinfo& info() const { return info_; }

  // The atlas of one pixel size; baked on first use and kept (sizes are few).
  const BakedFont& baked(int pixelSize) {
    std::lock_guard lock(mutex_);
    auto found = sizes_.find(pixelSize);
    if (found != sizes_.end()) return found->second;
    BakedFont& font = sizes_[pixelSize];
    bake(font, static_cast<float>(pixelSize));
    return font;
  }

 private:
  FontLibrary() {
    std::vector<std::string> candidates;
    if (const char* env = std::getenv("ZSCULPT_FONT"); env != nullptr && *env != '\0') {
      candidates.emplace_back(env);
    }
    for (const char* path :
         {"/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf", "/usr/share/fonts/TTF/DejaVuSans.ttf",
          "/usr/share/fonts/dejavu/DejaVuSans.ttf",
          "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf"}) {
      candidates.emplace_back(path);
    }
    for (const std::string& path : candidates) {
      std::ifstream in(path, std::ios::binary);
      if (!in) continue;
      std::vector<unsigned char> bytes((std::istreambuf_iterator<char>(in)),
                                       std::istreambuf_iterator<char>());
      if (bytes.empty()) continue;
      if (stbtt_InitFont(&info_, bytes.data(), stbtt_GetFontOffsetForIndex(bytes.data(), 0)) == 0) {
        continue;
      }
      data_ = std::move(bytes);
      // stbtt_fontinfo points into the data: re-initialise on the moved buffer.
      stbtt_InitFont(&info_, data_.data(), stbtt_GetFontOffsetForIndex(data_.data(), 0));
      return;
    }
  }

  void bake(BakedFont& font, float size) {
    stbtt_pack_range ranges[4] = {};
    for (int r = 0; r < 3; ++r) {
      font.chars[r].resize(static_cast<size_t>(kRangeCounts[r]));
      ranges[r].font_size = size;
      ranges[r].first_unicode_codepoint_in_range = kRangeStarts[r];
      ranges[r].num_chars = kRangeCounts[r];
      ranges[r].chardata_for_range = font.chars[r].data();
    }
    font.chars[3].resize(std::size(kExtraCodepoints));
    ranges[3].font_size = size;
    ranges[3].array_of_unicode_codepoints = kExtraCodepoints;
    ranges[3].num_chars = static_cast<int>(std::size(kExtraCodepoints));
    ranges[3].chardata_for_range = font.chars[3].data();
    for (int side = 256; side <= 8192; side *= 2) {
      font.atlasWidth = side;
      font.atlasHeight = side;
      font.atlas.assign(static_cast<size_t>(side) * side, 0);
      stbtt_pack_context pack;
      if (stbtt_PackBegin(&pack, font.atlas.data(), side, side, 0, 1, nullptr) == 0) break;
      stbtt_PackSetOversampling(&pack, 2, 2);
      const int ok = stbtt_PackFontRanges(&pack, data_.data(), 0, ranges, 4);
      stbtt_PackEnd(&pack);
      if (ok != 0) break;
    }
    const float scale = stbtt_ScaleForPixelHeight(&info_, size);
    int ascent = 0;
    int descent = 0;
    int lineGap = 0;
    stbtt_GetFontVMetrics(&info_, &ascent, &descent, &lineGap);
    font.ascent = static_cast<float>(ascent) * scale;
    int x0 = 0;
    int y0 = 0;
    int x1 = 0;
    int y1 = 0;
    stbtt_GetCodepointBox(&info_, 'H', &x0, &y0, &x1, &y1);
    font.capHeight = static_cast<float>(y1) * scale;
  }

  std::vector<unsigned char> data_;
  stbtt_fontinfo info_{};
  std::mutex mutex_;
  std::map<int, BakedFont> sizes_;
};

// Next code point of UTF-8 text (invalid bytes become '?').
int nextCodepoint(std::string_view text, size_t& i) {
  const auto c = static_cast<unsigned char>(text[i++]);
  if (c < 0x80) return c;
  int extra = 0;
  int cp = 0;
  if ((c & 0xe0) == 0xc0) {
    extra = 1;
    cp = c & 0x1f;
  } else if ((c & 0xf0) == 0xe0) {
    extra = 2;
    cp = c & 0x0f;
  } else if ((c & 0xf8) == 0xf0) {
    extra = 3;
    cp = c & 0x07;
  } else {
    return '?';
  }
  for (int k = 0; k < extra; ++k) {
    if (i >= text.size() || (static_cast<unsigned char>(text[i]) & 0xc0) != 0x80) return '?';
    cp = (cp << 6) | (static_cast<unsigned char>(text[i++]) & 0x3f);
  }
  return cp;
}

// The packed glyph of a code point: (range, index), or the '?' glyph.
std::pair<int, int> glyphSlot(int cp) {
  for (int r = 0; r < 3; ++r) {
    if (cp >= kRangeStarts[r] && cp < kRangeStarts[r] + kRangeCounts[r]) {
      return {r, cp - kRangeStarts[r]};
    }
  }
  for (size_t k = 0; k < std::size(kExtraCodepoints); ++k) {
    if (kExtraCodepoints[k] == cp) return {3, static_cast<int>(k)};
  }
  return {0, '?' - 32};
}

// stb_easy_font: glyphs are 7 units tall above the baseline-ish line and lines are 12 apart;
// `size` pixels map to 11 units so both fonts have similar extents.
constexpr float kEasyUnits = 11.0f;

// ASCII copy for stb_easy_font (non-ASCII becomes '?'); fixed buffer, no allocation.
size_t toAscii(std::string_view text, char* out, size_t capacity) {
  size_t n = 0;
  for (size_t i = 0; i < text.size() && n + 1 < capacity;) {
    const int cp = nextCodepoint(text, i);
    out[n++] = (cp >= 32 && cp < 127) ? static_cast<char>(cp) : '?';
  }
  out[n] = '\0';
  return n;
}

inline float clamp01(double v) {
  return static_cast<float>(std::clamp(v, 0.0, 1.0));
}

}  // namespace

bool hasTrueTypeFont() {
  return FontLibrary::instance().hasTrueType();
}

std::string formatNumber(double value, int significant) {
  if (!std::isfinite(value)) return std::isnan(value) ? "nan" : (value > 0 ? "inf" : "-inf");
  if (value == 0.0) return "0";
  significant = std::clamp(significant, 1, 15);
  const double magnitude = std::abs(value);
  char buffer[64];
  if (magnitude >= 1e5 || magnitude < 1e-3) {
    std::snprintf(buffer, sizeof buffer, "%.*e", significant - 1, value);
    std::string text(buffer);
    const size_t e = text.find('e');
    std::string mantissa = text.substr(0, e);
    if (mantissa.find('.') != std::string::npos) {
      while (mantissa.back() == '0') mantissa.pop_back();
      if (mantissa.back() == '.') mantissa.pop_back();
    }
    const int exponent = std::atoi(text.c_str() + e + 1);
    return mantissa + "e" + std::to_string(exponent);
  }
  const int order = static_cast<int>(std::floor(std::log10(magnitude)));
  const int decimals = std::max(0, significant - 1 - order);
  std::snprintf(buffer, sizeof buffer, "%.*f", decimals, value);
  std::string text(buffer);
  if (text.find('.') != std::string::npos) {
    while (text.back() == '0') text.pop_back();
    if (text.back() == '.') text.pop_back();
  }
  if (text == "-0") text = "0";
  return text;
}

Canvas::Canvas(int width, int height, Color background) {
  reset(width, height, background);
}

void Canvas::reset(int width, int height, Color background) {
  ZSCULPT_ASSERT(width > 0 && height > 0, "canvas size must be positive");
  image_.resize(width, height);
  const std::uint8_t fill[4] = {
      static_cast<std::uint8_t>(std::lround(std::clamp(background.r, 0.0f, 1.0f) * 255.0f)),
      static_cast<std::uint8_t>(std::lround(std::clamp(background.g, 0.0f, 1.0f) * 255.0f)),
      static_cast<std::uint8_t>(std::lround(std::clamp(background.b, 0.0f, 1.0f) * 255.0f)),
      static_cast<std::uint8_t>(std::lround(std::clamp(background.a, 0.0f, 1.0f) * 255.0f))};
  for (size_t i = 0; i < image_.rgba.size(); i += 4) std::memcpy(&image_.rgba[i], fill, 4);
  coverage_.assign(static_cast<size_t>(width) * height, 0.0f);
}

void Canvas::blend(int x, int y, Color color, float alpha) {
  if (x < 0 || y < 0 || x >= image_.width || y >= image_.height) return;
  const float a = std::clamp(alpha * color.a, 0.0f, 1.0f);
  if (a <= 0.0f) return;
  std::uint8_t* p = image_.pixel(x, y);
  const float da = static_cast<float>(p[3]) / 255.0f;
  const float outA = a + da * (1.0f - a);
  const float src[3] = {color.r, color.g, color.b};
  for (int c = 0; c < 3; ++c) {
    const float d = static_cast<float>(p[c]) / 255.0f;
    const float v = (src[c] * a + d * da * (1.0f - a)) / outA;
    p[c] = static_cast<std::uint8_t>(std::lround(std::clamp(v, 0.0f, 1.0f) * 255.0f));
  }
  p[3] = static_cast<std::uint8_t>(std::lround(outA * 255.0f));
}

void Canvas::fillRect(double x0, double y0, double x1, double y1, Color color) {
  if (x1 < x0) std::swap(x0, x1);
  if (y1 < y0) std::swap(y0, y1);
  const int ix0 = std::max(0, static_cast<int>(std::floor(x0)));
  const int iy0 = std::max(0, static_cast<int>(std::floor(y0)));
  const int ix1 = std::min(image_.width - 1, static_cast<int>(std::ceil(x1)) - 1);
  const int iy1 = std::min(image_.height - 1, static_cast<int>(std::ceil(y1)) - 1);
  for (int y = iy0; y <= iy1; ++y) {
    const double cy = std::min(y1, y + 1.0) - std::max(y0, static_cast<double>(y));
    for (int x = ix0; x <= ix1; ++x) {
      const double cx = std::min(x1, x + 1.0) - std::max(x0, static_cast<double>(x));
      blend(x, y, color, clamp01(cx * cy));
    }
  }
}

void Canvas::fillRoundedRect(double x0, double y0, double x1, double y1, double radius,
                             Color color) {
  const double cx = 0.5 * (x0 + x1);
  const double cy = 0.5 * (y0 + y1);
  const double hx = 0.5 * std::abs(x1 - x0);
  const double hy = 0.5 * std::abs(y1 - y0);
  radius = std::min({radius, hx, hy});
  const int ix0 = std::max(0, static_cast<int>(std::floor(cx - hx)));
  const int iy0 = std::max(0, static_cast<int>(std::floor(cy - hy)));
  const int ix1 = std::min(image_.width - 1, static_cast<int>(std::ceil(cx + hx)));
  const int iy1 = std::min(image_.height - 1, static_cast<int>(std::ceil(cy + hy)));
  for (int y = iy0; y <= iy1; ++y) {
    for (int x = ix0; x <= ix1; ++x) {
      const double qx = std::abs(x + 0.5 - cx) - (hx - radius);
      const double qy = std::abs(y + 0.5 - cy) - (hy - radius);
      const double outside = std::hypot(std::max(qx, 0.0), std::max(qy, 0.0));
      const double d = outside + std::min(std::max(qx, qy), 0.0) - radius;
      blend(x, y, color, clamp01(0.5 - d));
    }
  }
}

void Canvas::strokeRect(double x0, double y0, double x1, double y1, double width, Color color) {
  const double h = 0.5 * width;
  fillRect(x0 - h, y0 - h, x1 + h, y0 + h, color);
  fillRect(x0 - h, y1 - h, x1 + h, y1 + h, color);
  fillRect(x0 - h, y0 + h, x0 + h, y1 - h, color);
  fillRect(x1 - h, y0 + h, x1 + h, y1 - h, color);
}

void Canvas::line(double x0, double y0, double x1, double y1, double width, Color color) {
  const Eigen::Vector2d points[2] = {{x0, y0}, {x1, y1}};
  polyline(points, width, color);
}

void Canvas::disc(double cx, double cy, double radius, Color color) {
  const int ix0 = std::max(0, static_cast<int>(std::floor(cx - radius - 1)));
  const int iy0 = std::max(0, static_cast<int>(std::floor(cy - radius - 1)));
  const int ix1 = std::min(image_.width - 1, static_cast<int>(std::ceil(cx + radius + 1)));
  const int iy1 = std::min(image_.height - 1, static_cast<int>(std::ceil(cy + radius + 1)));
  for (int y = iy0; y <= iy1; ++y) {
    for (int x = ix0; x <= ix1; ++x) {
      const double d = std::hypot(x + 0.5 - cx, y + 0.5 - cy);
      blend(x, y, color, clamp01(radius + 0.5 - d));
    }
  }
}

void Canvas::polyline(std::span<const Eigen::Vector2d> points, double width, Color color,
                      bool dashed, const Eigen::Vector4d* clip) {
  if (points.size() < 2 || image_.width == 0) return;
  const double half = 0.5 * width;
  const double reach = half + 1.0;
  double cx0 = 0.0;
  double cy0 = 0.0;
  double cx1 = image_.width;
  double cy1 = image_.height;
  if (clip != nullptr) {
    cx0 = std::max(cx0, (*clip)[0]);
    cy0 = std::max(cy0, (*clip)[1]);
    cx1 = std::min(cx1, (*clip)[2]);
    cy1 = std::min(cy1, (*clip)[3]);
  }
  const int bx0 = static_cast<int>(std::floor(cx0));
  const int by0 = static_cast<int>(std::floor(cy0));
  const int bx1 = static_cast<int>(std::ceil(cx1)) - 1;
  const int by1 = static_cast<int>(std::ceil(cy1)) - 1;
  int touchedX0 = image_.width;
  int touchedY0 = image_.height;
  int touchedX1 = -1;
  int touchedY1 = -1;

  // Coverage of one sub-segment, max-combined so overlapping joints do not darken.
  auto segment = [&](const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
    const int x0 = std::max(bx0, static_cast<int>(std::floor(std::min(a.x(), b.x()) - reach)));
    const int y0 = std::max(by0, static_cast<int>(std::floor(std::min(a.y(), b.y()) - reach)));
    const int x1 = std::min(bx1, static_cast<int>(std::ceil(std::max(a.x(), b.x()) + reach)));
    const int y1 = std::min(by1, static_cast<int>(std::ceil(std::max(a.y(), b.y()) + reach)));
    if (x0 > x1 || y0 > y1) return;
    touchedX0 = std::min(touchedX0, x0);
    touchedY0 = std::min(touchedY0, y0);
    touchedX1 = std::max(touchedX1, x1);
    touchedY1 = std::max(touchedY1, y1);
    const Eigen::Vector2d d = b - a;
    const double length2 = d.squaredNorm();
    for (int y = y0; y <= y1; ++y) {
      for (int x = x0; x <= x1; ++x) {
        const Eigen::Vector2d p(x + 0.5, y + 0.5);
        double t = length2 > 0.0 ? (p - a).dot(d) / length2 : 0.0;
        t = std::clamp(t, 0.0, 1.0);
        const double dist = (p - (a + t * d)).norm();
        const float c = clamp01(half + 0.5 - dist);
        float& slot = coverage_[static_cast<size_t>(y) * image_.width + x];
        slot = std::max(slot, c);
      }
    }
  };

  const double dash = 4.0 * width;
  const double gap = 3.0 * width;
  double phase = 0.0;  // distance along the current dash pattern
  for (size_t i = 0; i + 1 < points.size(); ++i) {
    const Eigen::Vector2d& a = points[i];
    const Eigen::Vector2d& b = points[i + 1];
    if (!a.allFinite() || !b.allFinite()) continue;
    if (!dashed) {
      segment(a, b);
      continue;
    }
    const double length = (b - a).norm();
    double s = 0.0;
    while (s < length) {
      const bool on = phase < dash;
      const double left = on ? dash - phase : dash + gap - phase;
      const double step = std::min(left, length - s);
      if (on && length > 0.0)
        segment(a + (b - a) * (s / length), a + (b - a) * ((s + step) / length));
      s += step;
      phase += step;
      if (phase >= dash + gap) phase = 0.0;
    }
  }
  if (touchedX1 >= touchedX0) coverageFlush(touchedX0, touchedY0, touchedX1, touchedY1, color);
}

void Canvas::coverageFlush(int x0, int y0, int x1, int y1, Color color) {
  for (int y = y0; y <= y1; ++y) {
    for (int x = x0; x <= x1; ++x) {
      float& c = coverage_[static_cast<size_t>(y) * image_.width + x];
      if (c > 0.0f) blend(x, y, color, c);
      c = 0.0f;
    }
  }
}

double Canvas::textWidth(std::string_view text, double size) const {
  FontLibrary& fonts = FontLibrary::instance();
  if (!fonts.hasTrueType()) {
    char ascii[512];
    toAscii(text, ascii, sizeof ascii);
    return stb_easy_font_width(ascii) * size / kEasyUnits;
  }
  const BakedFont& font = fonts.baked(std::max(1, static_cast<int>(std::lround(size))));
  float x = 0.0f;
  float y = 0.0f;
  for (size_t i = 0; i < text.size();) {
    const auto [range, index] = glyphSlot(nextCodepoint(text, i));
    stbtt_aligned_quad quad;
    stbtt_GetPackedQuad(font.chars[range].data(), font.atlasWidth, font.atlasHeight, index, &x, &y,
                        &quad, 0);
  }
  return x;
}

void Canvas::text(double x, double y, std::string_view text, double size, Color color,
                  Align horizontal, Align verticalAlign, bool vertical) {
  if (text.empty() || size <= 0.0) return;
  FontLibrary& fonts = FontLibrary::instance();
  const double width = textWidth(text, size);
  // Layout space: u along the text from its start, v down from the top of the text box
  // (box height = size; the baseline at `ascent`). Glyph coverage is accumulated there,
  // then mapped to the canvas unrotated or rotated a quarter turn anticlockwise.
  double ascent = 0.78 * size;
  double capHeight = 0.56 * size;
  if (fonts.hasTrueType()) {
    const BakedFont& font = fonts.baked(std::max(1, static_cast<int>(std::lround(size))));
    ascent = font.ascent;
    capHeight = font.capHeight;
  }
  double u0 = 0.0;
  if (horizontal == Align::Center) u0 = -0.5 * width;
  if (horizontal == Align::End) u0 = -width;
  double v0 = 0.0;  // top of the box relative to the anchor
  if (verticalAlign == Align::Center) v0 = -(ascent - 0.5 * capHeight);  // centre on caps
  if (verticalAlign == Align::End) v0 = -size;

  auto plot = [&](double u, double v, float coverage) {
    // u, v: pixel centre in layout space relative to the anchor.
    int px = 0;
    int py = 0;
    if (!vertical) {
      px = static_cast<int>(std::floor(x + u));
      py = static_cast<int>(std::floor(y + v));
    } else {
      px = static_cast<int>(std::floor(x + v));
      py = static_cast<int>(std::floor(y - u));
    }
    blend(px, py, color, coverage);
  };

  if (!fonts.hasTrueType()) {
    char ascii[512];
    toAscii(text, ascii, sizeof ascii);
    static thread_local std::vector<char> vertices(512 * 300);
    const int quads = stb_easy_font_print(0.0f, 0.0f, ascii, nullptr, vertices.data(),
                                          static_cast<int>(vertices.size()));
    const double scale = size / kEasyUnits;
    const double top = v0 + (ascent - 7.0 * scale);  // easy_font caps span y in [0, 7)
    for (int q = 0; q < quads; ++q) {
      const auto* v = reinterpret_cast<const float*>(vertices.data() + q * 4 * 16);
      const double qx0 = u0 + v[0] * scale;
      const double qy0 = top + v[1] * scale;
      const double qx1 = u0 + v[2 * 4] * scale;
      const double qy1 = top + v[2 * 4 + 1] * scale;
      for (int j = static_cast<int>(std::floor(qy0)); j < std::ceil(qy1); ++j) {
        const double cy = std::min(qy1, j + 1.0) - std::max(qy0, static_cast<double>(j));
        for (int i = static_cast<int>(std::floor(qx0)); i < std::ceil(qx1); ++i) {
          const double cx = std::min(qx1, i + 1.0) - std::max(qx0, static_cast<double>(i));
          plot(i + 0.5, j + 0.5, clamp01(cx * cy));
        }
      }
    }
    return;
  }

  const BakedFont& font = fonts.baked(std::max(1, static_cast<int>(std::lround(size))));
  // Sub-pixel pen position; glyph quads are in layout pixels with the baseline at `ascent`.
  const double fracU = u0 - std::floor(u0);
  const double fracV = v0 - std::floor(v0);
  float penX = static_cast<float>(fracU);
  float penY = static_cast<float>(fracV + ascent);
  const double baseU = std::floor(u0);
  const double baseV = std::floor(v0);
  for (size_t i = 0; i < text.size();) {
    const auto [range, index] = glyphSlot(nextCodepoint(text, i));
    stbtt_aligned_quad q;
    stbtt_GetPackedQuad(font.chars[range].data(), font.atlasWidth, font.atlasHeight, index, &penX,
                        &penY, &q, 0);
    if (q.x1 <= q.x0 || q.y1 <= q.y0) continue;
    const int i0 = static_cast<int>(std::floor(q.x0));
    const int i1 = static_cast<int>(std::ceil(q.x1));
    const int j0 = static_cast<int>(std::floor(q.y0));
    const int j1 = static_cast<int>(std::ceil(q.y1));
    for (int j = j0; j < j1; ++j) {
      for (int ii = i0; ii < i1; ++ii) {
        // Average of 2 x 2 bilinear taps inside this pixel (the atlas is 2x oversampled).
        float sum = 0.0f;
        for (int sy = 0; sy < 2; ++sy) {
          for (int sx = 0; sx < 2; ++sx) {
            const float px = static_cast<float>(ii) + 0.25f + 0.5f * static_cast<float>(sx);
            const float py = static_cast<float>(j) + 0.25f + 0.5f * static_cast<float>(sy);
            if (px < q.x0 || px > q.x1 || py < q.y0 || py > q.y1) continue;
            const float s = q.s0 + (q.s1 - q.s0) * (px - q.x0) / (q.x1 - q.x0);
            const float t = q.t0 + (q.t1 - q.t0) * (py - q.y0) / (q.y1 - q.y0);
            const float ax = s * static_cast<float>(font.atlasWidth) - 0.5f;
            const float ay = t * static_cast<float>(font.atlasHeight) - 0.5f;
            const int ax0 = static_cast<int>(std::floor(ax));
            const int ay0 = static_cast<int>(std::floor(ay));
            const float fx = ax - static_cast<float>(ax0);
            const float fy = ay - static_cast<float>(ay0);
            auto at = [&](int xx, int yy) -> float {
              if (xx < 0 || yy < 0 || xx >= font.atlasWidth || yy >= font.atlasHeight) return 0.0f;
              return static_cast<float>(
                         font.atlas[static_cast<size_t>(yy) * font.atlasWidth + xx]) /
                     255.0f;
            };
            sum += (at(ax0, ay0) * (1 - fx) + at(ax0 + 1, ay0) * fx) * (1 - fy) +
                   (at(ax0, ay0 + 1) * (1 - fx) + at(ax0 + 1, ay0 + 1) * fx) * fy;
          }
        }
        if (sum > 0.0f) plot(baseU + ii + 0.5, baseV + j + 0.5, 0.25f * sum);
      }
    }
  }
}

void Canvas::blit(const Image& source, int x, int y) {
  for (int j = 0; j < source.height; ++j) {
    for (int i = 0; i < source.width; ++i) {
      const std::uint8_t* p = source.pixel(i, j);
      blend(x + i, y + j,
            Color{static_cast<float>(p[0]) / 255.0f, static_cast<float>(p[1]) / 255.0f,
                  static_cast<float>(p[2]) / 255.0f, 1.0f},
            static_cast<float>(p[3]) / 255.0f);
    }
  }
}

}  // namespace zsculpt::render
