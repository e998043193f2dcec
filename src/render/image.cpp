#include "zsculpt/render/image.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <ostream>

#include "zsculpt/core/errors.h"
#include "zsculpt/io/atomic_file.h"

// stb is third-party C code: keep our strict warnings out of it.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#pragma GCC diagnostic ignored "-Wsign-compare"
#pragma GCC diagnostic ignored "-Wunused-function"
#pragma GCC diagnostic ignored "-Wunused-parameter"
#pragma GCC diagnostic ignored "-Wconversion"
#pragma GCC diagnostic ignored "-Wpedantic"
#define STB_IMAGE_WRITE_IMPLEMENTATION
#define STB_IMAGE_WRITE_STATIC
#include <stb_image_write.h>
#define STB_IMAGE_IMPLEMENTATION
#define STB_IMAGE_STATIC
#define STBI_ONLY_PNG
#include <stb_image.h>
#pragma GCC diagnostic pop

namespace zsculpt::render {

std::vector<std::uint8_t> encodePng(const Image& image) {
  if (image.width < 1 || image.height < 1 ||
      image.rgba.size() < static_cast<size_t>(image.width) * image.height * 4) {
    throw IOError("PNG: empty or inconsistent image");
  }
  std::vector<std::uint8_t> bytes;
  auto append = [](void* context, void* data, int size) {
    auto* out = static_cast<std::vector<std::uint8_t>*>(context);
    const auto* begin = static_cast<const std::uint8_t*>(data);
    out->insert(out->end(), begin, begin + size);
  };
  if (stbi_write_png_to_func(append, &bytes, image.width, image.height, 4, image.rgba.data(),
                             image.width * 4) == 0) {
    throw IOError("PNG: encoding failed");
  }
  return bytes;
}

void savePng(const std::string& path, const Image& image) {
  std::vector<std::uint8_t> bytes;
  try {
    bytes = encodePng(image);
  } catch (const IOError& e) {
    throw IOError(path + ": " + (e.what() + std::strlen("PNG: ")));
  }
  io::writeFileAtomically(path, [&](std::ostream& out) {
    out.write(reinterpret_cast<const char*>(bytes.data()),
              static_cast<std::streamsize>(bytes.size()));
  });
}

Image readPng(const std::string& path) {
  int w = 0;
  int h = 0;
  int channels = 0;
  unsigned char* data = stbi_load(path.c_str(), &w, &h, &channels, 4);
  if (data == nullptr) {
    throw IOError(path + ": cannot read PNG (" + stbi_failure_reason() + ")");
  }
  Image image(w, h);
  std::memcpy(image.rgba.data(), data, image.rgba.size());
  stbi_image_free(data);
  return image;
}

double meanAbsoluteDifference(const Image& a, const Image& b) {
  if (a.width != b.width || a.height != b.height) {
    throw InvalidInputError("images: sizes differ (" + std::to_string(a.width) + "x" +
                            std::to_string(a.height) + " and " + std::to_string(b.width) + "x" +
                            std::to_string(b.height) + ")");
  }
  double sum[3] = {0.0, 0.0, 0.0};
  const size_t pixels = static_cast<size_t>(a.width) * a.height;
  for (size_t i = 0; i < pixels; ++i) {
    for (int c = 0; c < 3; ++c) {
      sum[c] += std::abs(static_cast<int>(a.rgba[4 * i + c]) - static_cast<int>(b.rgba[4 * i + c]));
    }
  }
  if (pixels == 0) return 0.0;
  return std::max({sum[0], sum[1], sum[2]}) / (255.0 * static_cast<double>(pixels));
}

Image composeRow(const std::vector<const Image*>& images, int gap, std::uint32_t background) {
  int width = 0;
  int height = 0;
  for (const Image* image : images) {
    width += image->width;
    height = std::max(height, image->height);
  }
  if (!images.empty()) width += gap * static_cast<int>(images.size() - 1);
  Image out(std::max(width, 1), std::max(height, 1));
  const std::uint8_t fill[4] = {
      static_cast<std::uint8_t>(background >> 24), static_cast<std::uint8_t>(background >> 16),
      static_cast<std::uint8_t>(background >> 8), static_cast<std::uint8_t>(background)};
  for (size_t i = 0; i < out.rgba.size(); i += 4) std::memcpy(&out.rgba[i], fill, 4);
  int x = 0;
  for (const Image* image : images) {
    for (int y = 0; y < image->height; ++y) {
      std::memcpy(out.pixel(x, y), image->pixel(0, y), static_cast<size_t>(image->width) * 4);
    }
    x += image->width + gap;
  }
  return out;
}

}  // namespace zsculpt::render
