#pragma once
// Colours and colour maps for per-vertex scalars (viridis by default, as in Polyscope and
// libigl; a diverging map for signed quantities; Blender's blue-to-red weight map).

#include <array>
#include <cstdint>
#include <string_view>

namespace zsculpt::render {

/// sRGB-encoded colour, components in [0, 1].
struct Color {
  float r = 0.0f;
  float g = 0.0f;
  float b = 0.0f;
  float a = 1.0f;

  /// From 0xRRGGBB.
  static constexpr Color hex(std::uint32_t rgb, float alpha = 1.0f) {
    return {static_cast<float>((rgb >> 16) & 0xff) / 255.0f,
            static_cast<float>((rgb >> 8) & 0xff) / 255.0f, static_cast<float>(rgb & 0xff) / 255.0f,
            alpha};
  }
  friend constexpr bool operator==(const Color&, const Color&) = default;
};

enum class ColorMap {
  Viridis,    ///< perceptually uniform, dark purple to yellow (default)
  Diverging,  ///< blue - white - red (ColorBrewer RdBu, reversed): signed quantities
  Weight,     ///< blue - cyan - green - yellow - red (Blender weight paint)
};

inline constexpr std::array<ColorMap, 3> kAllColorMaps = {ColorMap::Viridis, ColorMap::Diverging,
                                                          ColorMap::Weight};

/// "viridis", "diverging", "weight".
std::string_view colorMapName(ColorMap map);
/// Throws InvalidInputError "colour map NAME: unknown (viridis, diverging, weight)".
ColorMap colorMapFromName(std::string_view name);
/// The map's colour at t, clamped to [0, 1]; linear interpolation between the map's samples.
Color sampleColorMap(ColorMap map, double t);

}  // namespace zsculpt::render
