#include "zsculpt/render/color.h"

#include <algorithm>
#include <cmath>
#include <span>
#include <string>

#include "zsculpt/core/errors.h"

namespace zsculpt::render {
namespace {

// matplotlib's viridis sampled at 17 evenly spaced points (entries 0, 16, ..., 255 of
// the 256-entry table); linear interpolation between them stays within 6/255 of it.
constexpr std::uint32_t kViridis[] = {0x440154, 0x48186a, 0x472d7b, 0x424086, 0x3b528b, 0x33638d,
                                      0x2c728e, 0x26828e, 0x21918c, 0x1f9f88, 0x27ad81, 0x3dbc74,
                                      0x5cc863, 0x81d34d, 0xaadc32, 0xd5e21a, 0xfde725};
// ColorBrewer RdBu (11 classes), reversed so low values are blue and high values red.
constexpr std::uint32_t kDiverging[] = {0x053061, 0x2166ac, 0x4393c3, 0x92c5de, 0xd1e5f0, 0xf7f7f7,
                                        0xfddbc7, 0xf4a582, 0xd6604d, 0xb2182b, 0x67001f};
// Blender's weight paint: 0 blue, 0.25 cyan, 0.5 green, 0.75 yellow, 1 red.
constexpr std::uint32_t kWeight[] = {0x0000ff, 0x00ffff, 0x00ff00, 0xffff00, 0xff0000};

std::span<const std::uint32_t> samples(ColorMap map) {
  switch (map) {
    case ColorMap::Viridis:
      return kViridis;
    case ColorMap::Diverging:
      return kDiverging;
    case ColorMap::Weight:
      return kWeight;
  }
  return kViridis;
}

}  // namespace

std::string_view colorMapName(ColorMap map) {
  switch (map) {
    case ColorMap::Viridis:
      return "viridis";
    case ColorMap::Diverging:
      return "diverging";
    case ColorMap::Weight:
      return "weight";
  }
  return "viridis";
}

ColorMap colorMapFromName(std::string_view name) {
  for (ColorMap map : kAllColorMaps) {
    if (colorMapName(map) == name) return map;
  }
  throw InvalidInputError("colour map " + std::string(name) +
                          ": unknown (viridis, diverging, weight)");
}

Color sampleColorMap(ColorMap map, double t) {
  const auto table = samples(map);
  if (!std::isfinite(t)) t = 0.0;
  t = std::clamp(t, 0.0, 1.0);
  const double position = t * static_cast<double>(table.size() - 1);
  const size_t i = std::min(static_cast<size_t>(position), table.size() - 2);
  const auto f = static_cast<float>(position - static_cast<double>(i));
  const Color a = Color::hex(table[i]);
  const Color b = Color::hex(table[i + 1]);
  return {a.r + (b.r - a.r) * f, a.g + (b.g - a.g) * f, a.b + (b.b - a.b) * f, 1.0f};
}

}  // namespace zsculpt::render
