#pragma once
// RGBA8 images and PNG files. Every PNG is encoded in memory and written through
// io::writeFileAtomically, so a frame on disk is whole or absent.

#include <cstdint>
#include <string>
#include <vector>

namespace zsculpt::render {

/// 8-bit RGBA pixels, rows top to bottom, 4 bytes per pixel, no padding.
struct Image {
  int width = 0;
  int height = 0;
  std::vector<std::uint8_t> rgba;

  Image() = default;
  Image(int w, int h) : width(w), height(h), rgba(static_cast<size_t>(w) * h * 4, 0) {}

  /// Reallocates only when the pixel count grows.
  void resize(int w, int h) {
    width = w;
    height = h;
    rgba.resize(static_cast<size_t>(w) * h * 4);
  }
  [[nodiscard]] std::uint8_t* pixel(int x, int y) {
    return rgba.data() + (static_cast<size_t>(y) * width + x) * 4;
  }
  [[nodiscard]] const std::uint8_t* pixel(int x, int y) const {
    return rgba.data() + (static_cast<size_t>(y) * width + x) * 4;
  }
};

/// PNG bytes of `image` (stb_image_write). Throws IOError if encoding fails.
std::vector<std::uint8_t> encodePng(const Image& image);
/// Encodes `image` and writes it atomically. Throws IOError "<path>: <reason>".
void savePng(const std::string& path, const Image& image);
/// Reads a PNG (any channel count) as RGBA8. Throws IOError "<path>: <reason>".
Image readPng(const std::string& path);

/// Mean absolute difference per channel (R, G, B; alpha ignored) in [0, 1]: the largest
/// of the three channel means. Throws InvalidInputError if the sizes differ.
double meanAbsoluteDifference(const Image& a, const Image& b);

/// Places images side by side (top-aligned) on `background` (0xRRGGBBAA), `gap` pixels
/// apart (e.g. Figure 6's two moments, or Figure 9's two constraint sets).
Image composeRow(const std::vector<const Image*>& images, int gap = 0,
                 std::uint32_t background = 0xffffffffu);

}  // namespace zsculpt::render
