// Tests of the render module: colour maps, camera, offscreen OSMesa frames (no display),
// reference images, glyphs and legend, the CPU plotter and PNG files.
//
// Reference images live in tests/data/render/. After an intended change in shading or
// camera, regenerate them with
//   ZSCULPT_UPDATE_REFERENCES=1 ./test_render --gtest_filter='*Reference*'
// and look at them before committing.

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <new>
#include <nlohmann/json.hpp>
#include <numbers>
#include <string>

// The renderer's own allocations (C++): OSMesa's are the driver's (allocation_counter.h).
#define ZSCULPT_COUNT_NEW_ONLY
#include "support/allocation_counter.h"
#include "zsculpt/core/errors.h"
#include "zsculpt/mesh/builtin.h"
#include "zsculpt/physics/properties.h"
#include "zsculpt/render/camera.h"
#include "zsculpt/render/canvas.h"
#include "zsculpt/render/color.h"
#include "zsculpt/render/frame.h"
#include "zsculpt/render/image.h"
#include "zsculpt/render/plot.h"
#include "zsculpt/render/renderer.h"
#include "zsculpt/subdivision/subdivision.h"

namespace zsculpt::render {
namespace {

namespace fs = std::filesystem;

// ---- helpers --------------------------------------------------------------------------------

// One OSMesa context and renderer for the whole suite: creating them compiles every shader.
OffscreenRenderer& offscreen() {
  static OffscreenRenderer renderer;
  return renderer;
}

fs::path scratchDir() {
  const fs::path dir =
      fs::temp_directory_path() / ("zsculpt_test_render_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  return dir;
}

Frame frameFor(const Mesh& mesh, double yaw = -55.0, double pitch = 30.0, int width = 320,
               int height = 240, double margin = 1.2) {
  Frame frame;
  frame.mesh = &mesh;
  frame.normals = NormalMode::AreaWeighted;
  frame.camera.yawDegrees = yaw;
  frame.camera.pitchDegrees = pitch;
  frame.camera.frame(mesh.positions(), static_cast<double>(width) / height, margin);
  return frame;
}

// Pixels that differ from `background` by more than `threshold` in some channel.
int changedPixels(const Image& image, const Image& background, int threshold = 12) {
  int count = 0;
  for (size_t i = 0; i < image.rgba.size(); i += 4) {
    for (int c = 0; c < 3; ++c) {
      if (std::abs(image.rgba[i + c] - background.rgba[i + c]) > threshold) {
        ++count;
        break;
      }
    }
  }
  return count;
}

int colorDistance(const std::uint8_t* p, Color c) {
  return std::abs(p[0] - static_cast<int>(std::lround(c.r * 255))) +
         std::abs(p[1] - static_cast<int>(std::lround(c.g * 255))) +
         std::abs(p[2] - static_cast<int>(std::lround(c.b * 255)));
}

// Whether a pixel within `radius` of (x, y) is within `tolerance` (sum over RGB) of `c`.
// The range of the green channel over `pixels` (how evenly a surface is shaded there).
int greenSpread(const Image& image, const std::vector<Eigen::Vector2d>& pixels) {
  int lo = 255, hi = 0;
  for (const Eigen::Vector2d& at : pixels) {
    const int g = image.pixel(static_cast<int>(at.x()), static_cast<int>(at.y()))[1];
    lo = std::min(lo, g);
    hi = std::max(hi, g);
  }
  return hi - lo;
}

bool hasColorNear(const Image& image, double x, double y, Color c, int radius, int tolerance) {
  const int cx = static_cast<int>(std::floor(x));
  const int cy = static_cast<int>(std::floor(y));
  for (int j = cy - radius; j <= cy + radius; ++j) {
    for (int i = cx - radius; i <= cx + radius; ++i) {
      if (i < 0 || j < 0 || i >= image.width || j >= image.height) continue;
      if (colorDistance(image.pixel(i, j), c) <= tolerance) return true;
    }
  }
  return false;
}

bool hasColorInRegion(const Image& image, int x0, int y0, int x1, int y1, Color c, int tolerance) {
  for (int y = std::max(0, y0); y < std::min(image.height, y1); ++y) {
    for (int x = std::max(0, x0); x < std::min(image.width, x1); ++x) {
      if (colorDistance(image.pixel(x, y), c) <= tolerance) return true;
    }
  }
  return false;
}

// Compares with tests/data/render/<name>.png, or rewrites it when
// ZSCULPT_UPDATE_REFERENCES=1.
void expectMatchesReference(const Image& image, const std::string& name) {
  const std::string path = std::string(ZSCULPT_TEST_DATA_DIR) + "/render/" + name + ".png";
  const char* update = std::getenv("ZSCULPT_UPDATE_REFERENCES");
  if (update != nullptr && std::string(update) == "1") {
    fs::create_directories(fs::path(path).parent_path());
    savePng(path, image);
    std::printf("updated %s\n", path.c_str());
    return;
  }
  const Image reference = readPng(path);
  ASSERT_EQ(reference.width, image.width);
  ASSERT_EQ(reference.height, image.height);
  const double mad = meanAbsoluteDifference(image, reference);
  EXPECT_LT(mad, 2.0 / 255.0) << name << ": mean absolute difference " << mad * 255.0
                              << "/255 against " << path;
  // The mean alone cannot see a wire, a glyph or a marker gone: they cover a few hundred
  // pixels of a mostly empty image (a frame without its wireframe, or without its pin and
  // arrow, stayed under the mean's bound). So few pixels may differ by much: measured 0, 22
  // and 14 for the three references here, 744 without the dodecahedron's wireframe, pin and
  // arrow, 111 without the torus's wireframe.
  int changed = 0;
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x) {
      const std::uint8_t *a = image.pixel(x, y), *b = reference.pixel(x, y);
      const int d = std::max({std::abs(a[0] - b[0]), std::abs(a[1] - b[1]), std::abs(a[2] - b[2])});
      changed += d > 48;
    }
  EXPECT_LE(changed, 40) << name << ": " << changed << " pixels differ by more than 48/255 from "
                         << path;
}

// ---- colour maps ------------------------------------------------------------------------------

TEST(ColorMap, EndpointsMatchTheirDefinitions) {
  // matplotlib's viridis and ColorBrewer's RdBu (reversed) end colours.
  EXPECT_EQ(sampleColorMap(ColorMap::Viridis, 0.0), Color::hex(0x440154));
  EXPECT_EQ(sampleColorMap(ColorMap::Viridis, 1.0), Color::hex(0xfde725));
  EXPECT_EQ(sampleColorMap(ColorMap::Diverging, 0.0), Color::hex(0x053061));
  EXPECT_EQ(sampleColorMap(ColorMap::Diverging, 0.5), Color::hex(0xf7f7f7));
  EXPECT_EQ(sampleColorMap(ColorMap::Diverging, 1.0), Color::hex(0x67001f));
  EXPECT_EQ(sampleColorMap(ColorMap::Weight, 0.0), Color::hex(0x0000ff));
  EXPECT_EQ(sampleColorMap(ColorMap::Weight, 1.0), Color::hex(0xff0000));
}

TEST(ColorMap, ClampsOutOfRangeAndNonFinite) {
  EXPECT_EQ(sampleColorMap(ColorMap::Viridis, -3.0), sampleColorMap(ColorMap::Viridis, 0.0));
  EXPECT_EQ(sampleColorMap(ColorMap::Viridis, 7.0), sampleColorMap(ColorMap::Viridis, 1.0));
  EXPECT_EQ(sampleColorMap(ColorMap::Viridis, std::nan("")),
            sampleColorMap(ColorMap::Viridis, 0.0));
}

TEST(ColorMap, ViridisLightnessIncreases) {
  // Perceptually ordered: luma grows monotonically from 0 to 1.
  double previous = -1.0;
  for (int i = 0; i <= 50; ++i) {
    const Color c = sampleColorMap(ColorMap::Viridis, i / 50.0);
    const double luma = 0.2126 * c.r + 0.7152 * c.g + 0.0722 * c.b;
    EXPECT_GT(luma, previous) << "at t = " << i / 50.0;
    previous = luma;
  }
}

TEST(ColorMap, NamesRoundTripAndUnknownNamesAreRejected) {
  for (ColorMap map : kAllColorMaps) EXPECT_EQ(colorMapFromName(colorMapName(map)), map);
  try {
    colorMapFromName("jet");
    FAIL() << "no exception";
  } catch (const InvalidInputError& e) {
    EXPECT_NE(std::string(e.what()).find("jet"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("viridis"), std::string::npos);
  }
}

// ---- camera -----------------------------------------------------------------------------------

TEST(Camera, FrameKeepsTheWholeBoxInView) {
  const Mesh torus = makeTorus();
  const BoundingBox box = torus.boundingBox();
  for (double aspect : {0.5, 1.0, 16.0 / 9.0, 3.0}) {
    for (double yaw : {-55.0, 0.0, 90.0, 200.0}) {
      Camera camera;
      camera.yawDegrees = yaw;
      camera.frame(box, aspect);
      const Eigen::Matrix4d m = camera.projectionMatrix(aspect) * camera.viewMatrix();
      double largest = 0.0;
      for (int corner = 0; corner < 8; ++corner) {
        const Vec3 p((corner & 1) ? box.max.x() : box.min.x(),
                     (corner & 2) ? box.max.y() : box.min.y(),
                     (corner & 4) ? box.max.z() : box.min.z());
        const Eigen::Vector4d clip = m * p.homogeneous();
        ASSERT_GT(clip.w(), 0.0);
        largest = std::max({largest, std::abs(clip.x() / clip.w()), std::abs(clip.y() / clip.w())});
        EXPECT_LT(std::abs(clip.z() / clip.w()), 1.0) << "outside the depth range";
      }
      EXPECT_LE(largest, 1.0) << "aspect " << aspect << " yaw " << yaw;
      EXPECT_GT(largest, 0.5) << "model framed too small";
    }
  }
}

TEST(Camera, ViewLooksAtTheTargetWithZUp) {
  Camera camera;
  camera.target = Vec3(1, 2, 3);
  camera.distance = 4;
  camera.yawDegrees = 30;
  camera.pitchDegrees = 20;
  EXPECT_NEAR((camera.eye() - camera.target).norm(), 4.0, 1e-12);
  const Eigen::Vector4d target = camera.viewMatrix() * camera.target.homogeneous();
  EXPECT_NEAR(target.x(), 0.0, 1e-12);
  EXPECT_NEAR(target.y(), 0.0, 1e-12);
  EXPECT_NEAR(target.z(), -4.0, 1e-12);
  // A point above the target appears above it on screen.
  const Eigen::Vector4d above = camera.viewMatrix() * Vec3(1, 2, 4).homogeneous();
  EXPECT_GT(above.y(), 0.0);
}

TEST(Camera, RaysThroughPixelsHitTheProjectedPoints) {
  Camera camera;
  camera.target = Vec3(0.5, -1, 0.2);
  camera.distance = 7;
  camera.yawDegrees = 120;
  camera.pitchDegrees = -20;
  for (const Vec3& p : {Vec3(0, 0, 0), Vec3(1, 2, -1), Vec3(-2, 0.5, 1)}) {
    Eigen::Vector2d pixel;
    ASSERT_TRUE(camera.project(p, 640, 480, pixel));
    Vec3 origin;
    Vec3 direction;
    camera.ray(pixel.x(), pixel.y(), 640, 480, origin, direction);
    EXPECT_NEAR(direction.norm(), 1.0, 1e-12);
    // The point lies on the ray.
    const Vec3 offset = p - origin;
    EXPECT_NEAR((offset - offset.dot(direction) * direction).norm(), 0.0, 1e-9);
    EXPECT_GT(offset.dot(direction), 0.0);
  }
  // The target is at the centre of the view.
  Eigen::Vector2d centre;
  ASSERT_TRUE(camera.project(camera.target, 640, 480, centre));
  EXPECT_NEAR(centre.x(), 320.0, 1e-9);
  EXPECT_NEAR(centre.y(), 240.0, 1e-9);
}

TEST(Camera, ZoomAndPanStayWithinWhatASceneCanHold) {
  // A wheel turned long enough took the distance to 0 or to infinity (and a pan the target
  // to infinity); the window then saved a scene that nothing could load (a review).
  Camera c;
  c.distance = 5.0;
  for (int k = 0; k < 10000; ++k) c.zoom(0.88);
  EXPECT_EQ(c.distance, Camera::kNearest);
  for (int k = 0; k < 10000; ++k) c.zoom(1.0 / 0.88);
  EXPECT_EQ(c.distance, Camera::kFarthest);
  c.distance = 1.5e308;  // a scene may hold this: zooming out keeps it, zooming in works
  c.zoom(2.0);
  EXPECT_EQ(c.distance, 1.5e308);
  c.zoom(0.5);
  EXPECT_EQ(c.distance, 0.75e308);
  const Vec3 before = c.target;
  c.pan(1.0, 1.0);  // would move by about 1e308: not made
  EXPECT_EQ(c.target, before);
  c.distance = 10.0;
  c.pan(0.1, 0.0);
  EXPECT_GT((c.target - before).norm(), 0.1);
  EXPECT_TRUE(c.target.allFinite());
}

TEST(Camera, OrbitClampsPitchAndJsonRoundTrips) {
  Camera camera;
  camera.orbit(10.0, 500.0);
  EXPECT_DOUBLE_EQ(camera.pitchDegrees, 89.0);
  camera.zoom(0.5);
  camera.pan(0.1, -0.2);
  const nlohmann::json j = camera;
  const Camera back = j.get<Camera>();
  EXPECT_EQ(back, camera);
  EXPECT_THROW((void)nlohmann::json::parse(R"({"distance": -1})").get<Camera>(), InvalidInputError);
  EXPECT_THROW((void)nlohmann::json::parse(R"({"pitch": 95})").get<Camera>(), InvalidInputError);
  EXPECT_THROW((void)nlohmann::json::parse(R"({"target": [1, 2]})").get<Camera>(),
               InvalidInputError);
}

// ---- sizes ------------------------------------------------------------------------------------

TEST(ImageSize, ParsesWidthByHeight) {
  int w = 0;
  int h = 0;
  parseImageSize("1280x720", w, h);
  EXPECT_EQ(w, 1280);
  EXPECT_EQ(h, 720);
  for (const char* bad : {"", "1280", "x720", "1280x", "0x720", "12a0x720", "-5x10", "1280x720x3",
                          "1x1", "63x100", "100x63"}) {
    EXPECT_THROW(parseImageSize(bad, w, h), InvalidInputError) << bad;
  }
  try {
    parseImageSize("0x5", w, h, "--size");
  } catch (const InvalidInputError& e) {
    EXPECT_EQ(std::string(e.what()).rfind("--size 0x5: ", 0), 0u) << e.what();
  }
  parseImageSize("64x64", w, h);
  EXPECT_EQ(w, 64);
}

TEST(Offscreen, ALegendThatWouldCoverHalfTheImageIsLeftOut) {
  // A narrow image: the legend, wider than half of it, hid the model and was cut off.
  const Mesh mesh = makeTorus();
  VectorX values = mesh.positions().col(0);
  for (const auto& [width, drawn] : {std::pair{480, true}, std::pair{100, false}}) {
    Frame frame = frameFor(mesh, -55, 35, width, 320);
    frame.scalar.values = &values;
    frame.scalar.name = "angular stiffness (N m/rad\u00b2)";
    frame.display.legend = false;
    const Image without = offscreen().render(frame, width, 320);
    frame.display.legend = true;
    const Image image = offscreen().render(frame, width, 320);
    // What the legend changes: its panel (hundreds of pixels), or nothing when left out.
    if (drawn) {
      EXPECT_GT(changedPixels(image, without, 3), 500) << width;
    } else {
      EXPECT_EQ(changedPixels(image, without, 3), 0) << width;
    }
  }
}

// ---- offscreen frames ---------------------------------------------------------------------------

TEST(Offscreen, ContextIsCoreProfileWithAntialiasing) {
  const RenderLimits& limits = offscreen().limits();
  EXPECT_GE(limits.maxWidth, 4096);
  EXPECT_GE(limits.maxHeight, 4096);
  EXPECT_NE(limits.version.find("Core"), std::string::npos) << limits.version;
  // Either multisampling or the supersampling fallback.
  EXPECT_TRUE(limits.samples >= 2 || limits.samples == 0);
}

TEST(Offscreen, BadSizesAreRejectedWithAClearMessage) {
  const Mesh mesh = makeDodecahedron();
  const Frame frame = frameFor(mesh);
  OffscreenRenderer& r = offscreen();
  EXPECT_THROW(r.render(frame, 0, 240), InvalidInputError);
  EXPECT_THROW(r.render(frame, 320, -1), InvalidInputError);
  const int tooWide = r.limits().maxWidth + 1;
  try {
    r.checkSize(tooWide, 100, "--size");
    FAIL() << "no exception";
  } catch (const InvalidInputError& e) {
    const std::string message = e.what();
    EXPECT_EQ(message.rfind("--size " + std::to_string(tooWide) + "x100: ", 0), 0u) << message;
    EXPECT_EQ(message.find('\n'), std::string::npos);
  }
  EXPECT_NO_THROW(r.checkSize(r.limits().maxWidth, 16));
}

TEST(Offscreen, DodecahedronFrameHasTheAskedSizeAndAPlausibleCoverage) {
  const Mesh mesh = makeDodecahedron();
  Frame frame = frameFor(mesh, -55, 30, 400, 300);
  const Image image = offscreen().render(frame, 400, 300);
  EXPECT_EQ(image.width, 400);
  EXPECT_EQ(image.height, 300);
  ASSERT_EQ(image.rgba.size(), 400u * 300u * 4u);
  frame.display.surface = false;
  const Image background = offscreen().render(frame, 400, 300);
  const double share = changedPixels(image, background) / (400.0 * 300.0);
  // A framed dodecahedron fills a good part of the view but not all of it.
  EXPECT_GT(share, 0.15);
  EXPECT_LT(share, 0.7);
  // Opaque frame.
  for (size_t i = 3; i < image.rgba.size(); i += 4) ASSERT_EQ(image.rgba[i], 255);
}

TEST(Offscreen, TorusFrameCoversAPlausibleShareWithItsHoleVisible) {
  const Mesh mesh = makeTorus();
  Frame frame = frameFor(mesh, -55, 55, 320, 240);
  const Image image = offscreen().render(frame, 320, 240);
  frame.display.surface = false;
  const Image background = offscreen().render(frame, 320, 240);
  const double share = changedPixels(image, background) / (320.0 * 240.0);
  EXPECT_GT(share, 0.15);
  EXPECT_LT(share, 0.75);
  // Seen from above, the torus's centre (on the axis) shows the background.
  Eigen::Vector2d centre;
  ASSERT_TRUE(frame.camera.project(Vec3::Zero(), 320, 240, centre));
  const int cx = static_cast<int>(centre.x());
  const int cy = static_cast<int>(centre.y());
  EXPECT_LT(colorDistance(image.pixel(cx, cy), Color{background.pixel(cx, cy)[0] / 255.0f,
                                                     background.pixel(cx, cy)[1] / 255.0f,
                                                     background.pixel(cx, cy)[2] / 255.0f}),
            6);
}

TEST(Offscreen, StillModelGivesIdenticalFramesAndAMovedModelDifferent) {
  const Mesh mesh = makeTorus();
  Frame frame = frameFor(mesh);
  const Image first = offscreen().render(frame, 320, 240);
  const Image second = offscreen().render(frame, 320, 240);
  EXPECT_EQ(first.rgba, second.rgba);

  Points moved = mesh.positions();
  for (Index v = 0; v < moved.rows(); ++v) moved(v, 0) += 0.2 * std::sin(moved(v, 2) * 2.0);
  frame.positions = &moved;
  const Image third = offscreen().render(frame, 320, 240);
  EXPECT_GT(changedPixels(third, first), 500);
  // Back at rest: the same image again (no state kept between frames).
  frame.positions = nullptr;
  const Image fourth = offscreen().render(frame, 320, 240);
  EXPECT_EQ(fourth.rgba, first.rgba);
}

TEST(Offscreen, SizeChangesBetweenFramesAreHonoured) {
  const Mesh mesh = makeDodecahedron();
  const Frame frame = frameFor(mesh);
  EXPECT_EQ(offscreen().render(frame, 123, 77).width, 123);
  EXPECT_EQ(offscreen().render(frame, 64, 200).height, 200);
  EXPECT_EQ(offscreen().render(frame, 320, 240).rgba.size(), 320u * 240u * 4u);
}

TEST(Offscreen, EdgesAreAntialiased) {
  // A flat-shaded silhouette against a flat background: an aliased frame has only the two
  // colours along a row; an antialiased one has intermediate coverage values.
  const Mesh mesh = makeDodecahedron();
  Frame frame = frameFor(mesh);
  frame.display.backgroundGradient = false;
  const Image image = offscreen().render(frame, 320, 240);
  const Color bg = frame.style.backgroundTop;
  int blended = 0;
  for (int y = 0; y < image.height; ++y) {
    for (int x = 1; x < image.width; ++x) {
      const bool here = colorDistance(image.pixel(x, y), bg) <= 3;
      const bool left = colorDistance(image.pixel(x - 1, y), bg) <= 3;
      if (left && !here) {
        // First pixel off the background: it should be lighter than the pixel after it.
        const int a = image.pixel(x, y)[0] + image.pixel(x, y)[1] + image.pixel(x, y)[2];
        const int b = x + 1 < image.width ? image.pixel(x + 1, y)[0] + image.pixel(x + 1, y)[1] +
                                                image.pixel(x + 1, y)[2]
                                          : a;
        if (a > b + 6) ++blended;
      }
    }
  }
  EXPECT_GT(blended, 40);
}

TEST(Offscreen, InvalidFramesAreRejected) {
  const Mesh mesh = makeDodecahedron();
  Frame frame = frameFor(mesh);
  Points wrong(5, 3);
  wrong.setZero();
  frame.positions = &wrong;
  EXPECT_THROW(offscreen().render(frame, 64, 64), InvalidInputError);
  frame.positions = nullptr;
  frame.pins = {0, 25};
  EXPECT_THROW(offscreen().render(frame, 64, 64), InvalidInputError);
  frame.pins.clear();
  VectorX values(3);
  values.setZero();
  frame.scalar.values = &values;
  EXPECT_THROW(offscreen().render(frame, 64, 64), InvalidInputError);
  Frame empty;
  EXPECT_THROW(offscreen().render(empty, 64, 64), InvalidInputError);
}

TEST(Offscreen, GlyphsAreDrawnInTheirColours) {
  const Mesh mesh = makeDodecahedron();
  Frame frame = frameFor(mesh);
  frame.display.backgroundGradient = false;
  const Image plain = offscreen().render(frame, 320, 240);
  frame.pins = {0, 5};
  frame.forces = {{3, Vec3(0.0, 0.0, -1.0)}};
  frame.torques = {{7, Vec3(0.3, 0.2, 1.0)}};
  frame.normalPins = {{11, Vec3(0, 0, 1)}};
  frame.brush.visible = true;
  frame.brush.center = mesh.positions().row(9).transpose();
  frame.brush.normal = mesh.positions().row(9).transpose().normalized();
  frame.brush.radius = 0.5;
  const Image glyphs = offscreen().render(frame, 320, 240);
  EXPECT_GT(changedPixels(glyphs, plain), 1500);
  // Lit glyph colours vary; count clearly orange (force) and clearly purple (torque) pixels.
  int orange = 0;
  int purple = 0;
  for (int y = 0; y < glyphs.height; ++y) {
    for (int x = 0; x < glyphs.width; ++x) {
      const std::uint8_t* p = glyphs.pixel(x, y);
      if (p[0] > 150 && p[1] > 60 && p[1] < p[0] - 50 && p[2] < p[1] - 40) ++orange;
      if (p[2] > p[1] + 50 && p[0] > p[1] + 30) ++purple;
    }
  }
  EXPECT_GT(orange, 40);
  EXPECT_GT(purple, 40);
  // The same glyphs with glyphs switched off give the plain frame back.
  frame.display.glyphs = false;
  EXPECT_EQ(offscreen().render(frame, 320, 240).rgba, plain.rgba);
}

TEST(Offscreen, ScalarFieldUsesTheColourMapAndTheLegendShowsItsEnds) {
  const Mesh mesh = makeTorus();
  Frame frame = frameFor(mesh, -55, 35, 480, 320);
  VectorX height = mesh.positions().col(0);
  frame.scalar.values = &height;
  frame.scalar.name = "x (m)";
  frame.display.legend = true;
  const Image image = offscreen().render(frame, 480, 320);
  // The colour bar, unlit, holds both end colours exactly, in the right part of the image.
  EXPECT_TRUE(hasColorInRegion(image, 320, 0, 480, 320, Color::hex(0xfde725), 9));
  EXPECT_TRUE(hasColorInRegion(image, 320, 0, 480, 320, Color::hex(0x440154), 9));
  frame.display.legend = false;
  const Image noLegend = offscreen().render(frame, 480, 320);
  EXPECT_FALSE(hasColorInRegion(noLegend, 0, 0, 480, 320, Color::hex(0xfde725), 3));
  // A diverging map changes the surface's colours.
  frame.scalar.map = ColorMap::Diverging;
  EXPECT_GT(changedPixels(offscreen().render(frame, 480, 320), noLegend), 5000);
}

TEST(Offscreen, AUniformFieldsLegendIsOneSwatchNotAScale) {
  // A property with one value everywhere (a uniform stiffness, or a zero damping) was drawn
  // with a scale from 0.95 to 1.05 times it (or -1 to 1 about a zero): values that are
  // nowhere on the model. Its legend is one swatch of the map's middle colour.
  const Mesh mesh = makeTorus();
  Frame frame = frameFor(mesh, -55, 35, 480, 320);
  for (double value : {5.0, 0.0}) {
    const VectorX uniform = VectorX::Constant(mesh.numVertices(), value);
    frame.scalar.values = &uniform;
    frame.scalar.name = "stiffness (N/m)";
    frame.display.legend = true;
    const Image image = offscreen().render(frame, 480, 320);
    const Color middle = sampleColorMap(ColorMap::Viridis, 0.5);
    EXPECT_TRUE(hasColorInRegion(image, 320, 0, 480, 320, middle, 9)) << value;
    EXPECT_FALSE(hasColorInRegion(image, 0, 0, 480, 320, Color::hex(0xfde725), 9)) << value;
    EXPECT_FALSE(hasColorInRegion(image, 0, 0, 480, 320, Color::hex(0x440154), 9)) << value;
  }
  // Values that differ by rounding only (a helix's rest lengths: a QA pass found a scale whose
  // five labels all read 0.39515463) are one value too; a real difference, however small
  // against the value, keeps its scale.
  VectorX rounded(mesh.numVertices());
  for (Index v = 0; v < rounded.size(); ++v)
    rounded[v] = 0.39515463 * (1.0 + 4e-16 * static_cast<double>(v % 3));
  VectorX small = rounded;
  small[0] = 0.39515463 * (1.0 + 1e-8);
  for (const VectorX* values : {&rounded, &small}) {
    frame.scalar.values = values;
    const Image image = offscreen().render(frame, 480, 320);
    const bool scale = hasColorInRegion(image, 0, 0, 480, 320, Color::hex(0xfde725), 9);
    EXPECT_EQ(scale, values == &small);
  }
}

TEST(Offscreen, FlatShadingLightsEachFaceByItsOwnPlane) {
  // A polyhedron at level 0 drawn flat: across the face that looks at the camera the colour
  // hardly changes (only the highlight moves with the view direction); smooth vertex normals
  // (37 degrees off the face's at a dodecahedron's corners) shade it from light to dark. (The
  // paper's Figure 5 shows the original mesh so, and `render --levels 0` does.)
  const Mesh mesh = makeDodecahedron();
  Frame frame = frameFor(mesh, -60, 25, 480, 360);
  const Vec3 eye = frame.camera.eye();
  Index facing = 0;
  double best = -2.0;
  Vec3 centre = Vec3::Zero();
  for (Index f = 0; f < mesh.numFaces(); ++f) {
    Vec3 c = Vec3::Zero();
    for (const Index v : mesh.face(f)) c += mesh.positions().row(v).transpose();
    c /= static_cast<double>(mesh.face(f).size());
    const double cosine = c.normalized().dot((eye - c).normalized());  // centred at the origin
    if (cosine > best) {
      best = cosine;
      facing = f;
      centre = c;
    }
  }
  // The range of the green channel over points inside that face: from its centre towards
  // each corner, up to 70 % of the way.
  std::vector<Eigen::Vector2d> inside;
  for (const Index v : mesh.face(facing))
    for (double t : {0.0, 0.35, 0.7}) {
      Eigen::Vector2d pixel;
      const Vec3 p = (1.0 - t) * centre + t * Vec3(mesh.positions().row(v).transpose());
      ASSERT_TRUE(frame.camera.project(p, 480, 360, pixel));
      inside.push_back(pixel);
    }
  auto spread = [&](const Image& image) { return greenSpread(image, inside); };
  const Image smooth = offscreen().render(frame, 480, 360);
  frame.display.flatShading = true;
  const Image flat = offscreen().render(frame, 480, 360);
  // Measured 7 flat (the highlight alone) and 51 smooth.
  EXPECT_LE(spread(flat), 15);
  EXPECT_GE(spread(smooth), 30);
  EXPECT_GT(changedPixels(flat, smooth, 6), 2000);
}

TEST(Offscreen, ReferenceDodecahedronWithWireframeAndGlyphs) {
  const Mesh mesh = makeDodecahedron();
  Frame frame = frameFor(mesh, -60, 25);
  frame.display.controlWireframe = true;
  frame.display.controlPoints = true;
  frame.pins = {0};
  frame.forces = {{3, Vec3(0.0, 0.0, -1.153)}};
  frameScene(frame, 320.0 / 240.0);
  expectMatchesReference(offscreen().render(frame, 320, 240), "dodecahedron_wireframe");
}

TEST(Offscreen, NormalPinArrowsAreFramedAndLeaveAPinnedVertexItsRedCube) {
  // Figure 9 (a review): a normal pin's arrow ran off the panel, since framing counted the
  // force arrows only, and on a vertex also held in place a blue cube drawn into the red one
  // mottled both. The arrow now starts clear of the red cube and its tip is framed.
  const Mesh mesh = makeDodecahedron();
  Frame frame = frameFor(mesh, -60, 25);
  frame.display.backgroundGradient = false;
  frame.style.glyphScale = 4.0;  // long arrows, far outside the model
  const Vec3 out = mesh.positions().row(0).transpose().normalized();
  frame.pins = {0};
  frame.normalPins = {{0, out}};
  frameScene(frame, 320.0 / 240.0, 1.1);
  const double glyph =
      std::clamp(0.3 * mesh.meanEdgeLength(), 0.016 * mesh.boundingBox().diagonal(),
                 0.05 * mesh.boundingBox().diagonal()) *
      frame.style.glyphScale;
  const Vec3 tip = mesh.positions().row(0).transpose() + (std::sqrt(3.0) * 0.5 + 4.0) * glyph * out;
  Eigen::Vector2d pixel;
  ASSERT_TRUE(frame.camera.project(tip, 320, 240, pixel));
  EXPECT_GE(pixel.x(), 0.0);
  EXPECT_LE(pixel.x(), 320.0);
  EXPECT_GE(pixel.y(), 0.0);
  EXPECT_LE(pixel.y(), 240.0);
  // Blue (the arrow) is drawn; at the vertex, the cube is red with no blue mixed in.
  const Image image = offscreen().render(frame, 320, 240);
  auto blue = [](const std::uint8_t* p) { return p[2] > p[0] + 60 && p[2] > p[1] + 20; };
  auto red = [](const std::uint8_t* p) { return p[0] > p[1] + 80 && p[0] > p[2] + 80; };
  int blueAll = 0;
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x) blueAll += blue(image.pixel(x, y));
  EXPECT_GT(blueAll, 100);
  ASSERT_TRUE(frame.camera.project(mesh.positions().row(0).transpose(), 320, 240, pixel));
  int redAt = 0, blueAt = 0;
  for (int y = static_cast<int>(pixel.y()) - 2; y <= static_cast<int>(pixel.y()) + 2; ++y)
    for (int x = static_cast<int>(pixel.x()) - 2; x <= static_cast<int>(pixel.x()) + 2; ++x) {
      redAt += red(image.pixel(x, y));
      blueAt += blue(image.pixel(x, y));
    }
  EXPECT_GT(redAt, 15);
  EXPECT_EQ(blueAt, 0);
}

TEST(Offscreen, SheetsMeetingAtAnEdgeAreEachShadedWithTheirOwnNormal) {
  // The three fins share their spine. One normal per vertex averaged the three sheets' normals
  // there, so each flat fin was shaded in a gradient from its spine (a review saw streaks);
  // each fan of faces now has its own vertex on the GPU and its own normal. A flat fin
  // smooth-shaded is then as even as flat-shaded.
  const Mesh mesh = makeFins();  // fin 0: (t, 0, z), t and z in [0, 1]
  Frame frame = frameFor(mesh, -75, 10, 480, 360);
  frame.display.backgroundGradient = false;
  std::vector<Eigen::Vector2d> onFin;
  for (double t : {0.12, 0.3, 0.5, 0.7, 0.9}) {
    Eigen::Vector2d pixel;
    ASSERT_TRUE(frame.camera.project(Vec3(t, 0.0, 0.5), 480, 360, pixel));
    onFin.push_back(pixel);
  }
  auto spread = [&](const Image& image) { return greenSpread(image, onFin); };
  for (const NormalMode mode : {NormalMode::AreaWeighted, NormalMode::BestPlane}) {
    frame.normals = mode;
    frame.display.flatShading = false;
    const int smooth = spread(offscreen().render(frame, 480, 360));
    frame.display.flatShading = true;
    const int flat = spread(offscreen().render(frame, 480, 360));
    std::cout << "fin 0's green spread: smooth " << smooth << ", flat " << flat << "\n";
    EXPECT_LE(smooth, flat + 4) << static_cast<int>(mode);
  }
}

TEST(Offscreen, ReferenceTorusWithColourMap) {
  const Mesh mesh = makeTorus();
  Frame frame = frameFor(mesh, -50, 40, 320, 240, 1.3);
  VectorX values = mesh.positions().col(2);
  frame.scalar.values = &values;
  frame.scalar.name = "z";
  frame.display.legend = false;  // text depends on the fonts installed
  frame.display.surfaceWireframe = true;
  expectMatchesReference(offscreen().render(frame, 320, 240), "torus_viridis");
}

TEST(Offscreen, ReferenceSmoothDodecahedron) {
  // Figure 5: the interpolating Doo-Sabin surface with its control vertices in red.
  const Mesh mesh = makeDodecahedron();
  SubdivisionOptions options;
  options.levels = 3;
  const SubdivisionStencil stencil(mesh, options);
  Frame frame = frameFor(mesh, -60, 25);
  frame.stencil = &stencil;
  frame.normals = NormalMode::BestPlane;
  frame.display.controlPoints = true;
  frameScene(frame, 320.0 / 240.0);
  const Image smooth = offscreen().render(frame, 320, 240);
  expectMatchesReference(smooth, "dodecahedron_smooth");
  // Smoothing changes the picture: the flat faces are gone.
  frame.stencil = nullptr;
  frame.normals = NormalMode::AreaWeighted;
  EXPECT_GT(changedPixels(offscreen().render(frame, 320, 240), smooth), 2000);
}

TEST(Offscreen, SmoothSurfaceCarriesTheScalarAndFollowsTheControlMesh) {
  const Mesh mesh = makeTorus();
  SubdivisionOptions options;
  options.levels = 2;
  const SubdivisionStencil stencil(mesh, options);
  Frame frame = frameFor(mesh);
  frame.stencil = &stencil;
  // y: low on the side facing the camera (yaw -55), high on the far side.
  VectorX values = mesh.positions().col(1);
  frame.scalar.values = &values;
  frame.display.legend = false;
  const Image still = offscreen().render(frame, 320, 240);
  EXPECT_EQ(offscreen().render(frame, 320, 240).rgba, still.rgba);
  // Both ends of the map appear on the surface (lit, so only roughly).
  int dark = 0;
  int yellow = 0;
  for (int y = 0; y < still.height; ++y) {
    for (int x = 0; x < still.width; ++x) {
      const std::uint8_t* p = still.pixel(x, y);
      dark += p[0] > p[1] + 20 && p[2] > p[1] + 20;            // purple
      yellow += p[0] > 150 && p[1] > 150 && p[2] < p[1] - 90;  // yellow
    }
  }
  EXPECT_GT(dark, 100);
  EXPECT_GT(yellow, 100);
  // Moving one control vertex moves the smooth surface.
  Points moved = mesh.positions();
  moved.row(0) += Vec3(0.0, 0.0, 0.8).transpose();
  frame.positions = &moved;
  EXPECT_GT(changedPixels(offscreen().render(frame, 320, 240), still), 100);
}

TEST(Offscreen, FramesAfterTheFirstAllocateNothing) {
  // The per-frame path (stencil product, best-plane normals, uploads, glyphs, legend,
  // read-back) reuses buffers sized on the first frame.
  const Mesh mesh = makeTorus();
  SubdivisionOptions options;
  options.levels = 2;
  const SubdivisionStencil stencil(mesh, options);
  Points positions = mesh.positions();
  VectorX values = mesh.positions().col(2);
  Frame frame = frameFor(mesh);
  frame.stencil = &stencil;
  frame.normals = NormalMode::BestPlane;
  frame.positions = &positions;
  frame.scalar.values = &values;
  frame.scalar.name = "z";
  frame.display.controlPoints = true;
  frame.display.controlWireframe = true;
  frame.pins = {0, 1};
  frame.normalPins = {{2, Vec3(0, 0, 1)}};
  frame.forces = {{5, Vec3(0, 0, -1)}};
  frame.torques = {{50, Vec3(0, 0, 1)}};
  frame.markers = {{7, Color::hex(0x1f77b4)}};
  frame.brush.visible = true;
  frame.caption = "t = 0.5 s";
  offscreen().render(frame, 320, 240);
  offscreen().render(frame, 320, 240);
  // The counter sees allocations (else the check below would prove nothing).
  gAllocations = 0;
  gCounting = true;
  auto probe = std::make_unique<std::vector<int>>(10);
  gCounting = false;
  EXPECT_GE(gAllocations.load(), 2);
  for (int step = 0; step < 3; ++step) {
    positions.col(2) *= 1.01;  // the model moves; the scalar's range stays
    gAllocations = 0;
    gCounting = true;
    offscreen().render(frame, 320, 240);
    gCounting = false;
    EXPECT_EQ(gAllocations.load(), 0) << "frame " << step;
  }
}

TEST(Offscreen, SwitchingModelsRebuildsTheTopology) {
  const Mesh torus = makeTorus();
  const Mesh dodecahedron = makeDodecahedron();
  const Mesh fine = makeTorus(16, 12);
  const Frame a = frameFor(torus);
  const Frame b = frameFor(dodecahedron);
  const Frame c = frameFor(fine);
  const Image first = offscreen().render(a, 200, 150);
  const Image other = offscreen().render(b, 200, 150);
  const Image third = offscreen().render(c, 200, 150);
  EXPECT_GT(changedPixels(first, other), 1000);
  EXPECT_GT(changedPixels(first, third), 50);
  EXPECT_EQ(offscreen().render(a, 200, 150).rgba, first.rgba);
}

TEST(Offscreen, CurvesAndSolidsRender) {
  const Mesh helix = makeHelix();
  Frame frame = frameFor(helix);
  const Image image = offscreen().render(frame, 200, 200);
  frame.display.surface = false;
  const Image background = offscreen().render(frame, 200, 200);
  EXPECT_GT(changedPixels(image, background), 300);

  const Mesh lattice = makeLattice(3);
  Frame solid = frameFor(lattice);
  solid.display.controlWireframe = true;
  EXPECT_EQ(offscreen().render(solid, 200, 200).width, 200);
}

TEST(Offscreen, ACaptionTooWideDropsItsLastClausesRatherThanBeingCut) {
  // "t = 8.00 s, c" at 64 x 64 (a QA pass): the clauses after ", " that do not fit go whole,
  // so the narrow frame is the one with the short caption, pixel for pixel; a wide frame keeps
  // all of it.
  const Mesh mesh = makeTorus();
  Frame frame = frameFor(mesh);
  const std::string longer = "t = 8.00 s, centre of mass 0.321 m from its start";
  for (const int width : {64, 160}) {
    frame.caption = longer;
    const Image full = offscreen().render(frame, width, width * 3 / 4 < 64 ? 64 : width * 3 / 4);
    frame.caption = "t = 8.00 s";
    const Image cut = offscreen().render(frame, full.width, full.height);
    EXPECT_EQ(full.rgba, cut.rgba) << width;
  }
  frame.caption = longer;
  const Image wide = offscreen().render(frame, 800, 450);
  frame.caption = "t = 8.00 s";
  EXPECT_GT(changedPixels(wide, offscreen().render(frame, 800, 450)), 100);
}

TEST(Offscreen, ACurveIsColouredByAPropertyAsASurfaceIs) {
  // A helix with a painted property was drawn in the curve's one colour beside a legend
  // with a scale (a QA pass). Its first third at the top of the range, the rest at the
  // bottom: both ends of the map are on the curve, in the view, and the plain colour is not.
  const Mesh helix = makeHelix();
  Frame frame = frameFor(helix);
  VectorX values = VectorX::Zero(helix.numVertices());
  values.head(helix.numVertices() / 3).setConstant(2.0);
  frame.scalar.values = &values;
  frame.scalar.name = "mass (kg)";
  frame.display.legend = false;
  const Image image = offscreen().render(frame, 320, 320);
  const Color top = sampleColorMap(ColorMap::Viridis, 1.0);
  const Color bottom = sampleColorMap(ColorMap::Viridis, 0.0);
  EXPECT_TRUE(hasColorInRegion(image, 0, 0, 320, 320, top, 12));
  EXPECT_TRUE(hasColorInRegion(image, 0, 0, 320, 320, bottom, 12));
  EXPECT_FALSE(hasColorInRegion(image, 0, 0, 320, 320, frame.style.curve, 6));
  frame.scalar.values = nullptr;  // and without a property, the curve's own colour
  const Image plain = offscreen().render(frame, 320, 320);
  EXPECT_TRUE(hasColorInRegion(plain, 0, 0, 320, 320, frame.style.curve, 6));
  EXPECT_FALSE(hasColorInRegion(plain, 0, 0, 320, 320, top, 12));
}

TEST(Offscreen, PngIsWrittenWholeAndUnwritableFoldersAreReported) {
  const Mesh mesh = makeDodecahedron();
  const Frame frame = frameFor(mesh);
  const fs::path path = scratchDir() / "frame.png";
  offscreen().renderPng(frame, 160, 120, path.string());
  const Image back = readPng(path.string());
  EXPECT_EQ(back.width, 160);
  EXPECT_EQ(back.height, 120);
  EXPECT_EQ(back.rgba, offscreen().render(frame, 160, 120).rgba);
  // No temporary file left next to it.
  int files = 0;
  for (const auto& entry : fs::directory_iterator(path.parent_path())) {
    (void)entry;
    ++files;
  }
  EXPECT_EQ(files, 1);
  // A folder that cannot be made (a file stands where it would be); a missing one is made.
  EXPECT_THROW(offscreen().renderPng(frame, 16, 16, (path / "frame.png").string()), IOError);
  offscreen().renderPng(frame, 16, 16, (path.parent_path() / "made" / "frame.png").string());
  EXPECT_EQ(readPng((path.parent_path() / "made" / "frame.png").string()).width, 16);
  fs::remove_all(path.parent_path());
}

TEST(Offscreen, MissingShaderIsNamed) {
  OsMesaContext context;
  try {
    RendererOptions options;
    options.shaderDir = "/nonexistent-zsculpt-shaders";
    Renderer renderer(context.loader(), options);
    FAIL() << "no exception";
  } catch (const IOError& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent-zsculpt-shaders/"), std::string::npos);
  }
}

TEST(Offscreen, PropertyScalarsCoverEveryDomain) {
  Model model = Model::fromMesh(makeDodecahedron());
  VectorX out;
  propertyAsVertexScalar(model.mesh, model.angles, model.properties, Property::Stiffness, out);
  EXPECT_EQ(out, model.properties.stiffness);
  // Rest lengths: the dodecahedron's edges are all 1 long.
  propertyAsVertexScalar(model.mesh, model.angles, model.properties, Property::RestLength, out);
  ASSERT_EQ(out.size(), 20);
  for (Index v = 0; v < 20; ++v) EXPECT_NEAR(out[v], 1.0, 1e-9);
  propertyAsVertexScalar(model.mesh, model.angles, model.properties, Property::RestAngle, out);
  for (Index v = 0; v < 20; ++v) {
    EXPECT_GT(out[v], 0.0);
    EXPECT_LE(out[v], std::numbers::pi);
  }
}

// ---- canvas and plots
// ----------------------------------------------------------------------------

TEST(Canvas, TextIsDrawnAndMeasured) {
  Canvas canvas(200, 60, Color::hex(0xffffff));
  canvas.text(10, 10, "Energy 0.25", 18, Color::hex(0x000000));
  int dark = 0;
  for (size_t i = 0; i < canvas.image().rgba.size(); i += 4) dark += canvas.image().rgba[i] < 128;
  EXPECT_GT(dark, 50);
  EXPECT_GT(canvas.textWidth("Energy 0.25", 18), canvas.textWidth("Energy", 18));
  EXPECT_NEAR(canvas.textWidth("mm", 36), 2.0 * canvas.textWidth("mm", 18), 4.0);
}

TEST(Canvas, LinesAreAntialiased) {
  Canvas canvas(100, 100, Color::hex(0xffffff));
  canvas.line(10.2, 10.7, 90.4, 60.1, 2.0, Color::hex(0x000000));
  int partial = 0;
  for (size_t i = 0; i < canvas.image().rgba.size(); i += 4) {
    const int v = canvas.image().rgba[i];
    partial += v > 20 && v < 235;
  }
  EXPECT_GT(partial, 60);
}

TEST(Canvas, NumbersAreShort) {
  EXPECT_EQ(formatNumber(0.0), "0");
  EXPECT_EQ(formatNumber(1.5), "1.5");
  EXPECT_EQ(formatNumber(-2.0), "-2");
  EXPECT_EQ(formatNumber(1234.5678, 3), "1235");
  EXPECT_EQ(formatNumber(0.012345, 3), "0.0123");
  EXPECT_EQ(formatNumber(1.5e-6, 3), "1.5e-6");
  EXPECT_EQ(formatNumber(2.5e7, 3), "2.5e7");
}

std::vector<PlotPanel> sinePanels(int samples) {
  PlotPanel panel;
  panel.title = "Waves";
  panel.xLabel = "time (s)";
  panel.yLabel = "value";
  Series sine{"sin", {}, {}, std::nullopt, false};
  Series cosine{"cos", {}, {}, std::nullopt, true};
  for (int i = 0; i < samples; ++i) {
    const double t = 10.0 * i / (samples - 1);
    sine.x.push_back(t);
    sine.y.push_back(std::sin(t));
    cosine.x.push_back(t);
    cosine.y.push_back(2.0 + std::cos(t));
  }
  panel.series = {sine, cosine};
  PlotPanel second = panel;
  second.title = "Growth";
  second.series = {{"exp", sine.x, {}, Color::hex(0x2ca02c), false}};
  for (double t : sine.x) second.series[0].y.push_back(std::exp(0.3 * t));
  return {panel, second};
}

TEST(Plot, CurvesPassThroughTheirDataPoints) {
  const auto panels = sinePanels(400);
  PlotLayout layout;
  const Image image = renderPlot(panels, {}, &layout);
  ASSERT_EQ(layout.panels.size(), 2u);
  EXPECT_EQ(image.width, layout.width);
  EXPECT_EQ(image.height, layout.height);
  // Stacked panels, in order.
  EXPECT_LT(layout.panels[0].bottom, layout.panels[1].top);
  for (size_t p = 0; p < panels.size(); ++p) {
    for (size_t s = 0; s < panels[p].series.size(); ++s) {
      const Series& series = panels[p].series[s];
      const Color color = series.color.value_or(seriesColor(static_cast<int>(s)));
      int found = 0;
      int checked = 0;
      for (size_t i = 5; i < series.x.size(); i += 37) {
        const Eigen::Vector2d at = layout.panels[p].toPixel(series.x[i], series.y[i]);
        ++checked;
        // Dashed lines have gaps: look a little further along the line.
        found += hasColorNear(image, at.x(), at.y(), color, series.dashed ? 6 : 1, 60);
      }
      EXPECT_GE(found, checked * (series.dashed ? 6 : 9) / 10) << series.name;
    }
  }
  // And not where the data is not: sin's colour is absent at -sin(t) where they differ.
  const Series& sine = panels[0].series[0];
  int wrong = 0;
  for (size_t i = 5; i < sine.x.size(); i += 37) {
    if (std::abs(sine.y[i]) < 0.5) continue;
    const Eigen::Vector2d at = layout.panels[0].toPixel(sine.x[i], -sine.y[i]);
    wrong += hasColorNear(image, at.x(), at.y(), seriesColor(0), 1, 60);
  }
  EXPECT_EQ(wrong, 0);
}

TEST(Plot, AxesRangesContainTheData) {
  const auto panels = sinePanels(50);
  const PlotLayout layout = layoutPlot(panels);
  const PanelGeometry& g = layout.panels[0];
  EXPECT_LE(g.yMin, -1.0);
  EXPECT_GE(g.yMax, 3.0);
  EXPECT_DOUBLE_EQ(g.xMin, 0.0);
  EXPECT_DOUBLE_EQ(g.xMax, 10.0);
  const Eigen::Vector2d corner = g.toPixel(g.xMin, g.yMin);
  EXPECT_DOUBLE_EQ(corner.x(), g.left);
  EXPECT_DOUBLE_EQ(corner.y(), g.bottom);
}

TEST(Plot, RoundingNoiseOnAConservedQuantityIsDrawnFlat) {
  // |p| of 1e-14 (rounding on a zero momentum) and |L| changing by 2e-4 of itself filled
  // their panels as if they were signals. The energy-momentum panels' y axes span at least
  // 1e-9 and 0.1 % of the largest value, so both are near-flat lines; a real change shows.
  EnergyMomentumSeries d;
  for (int k = 0; k <= 100; ++k) {
    const double t = 0.1 * k, wobble = std::sin(3.0 * t);
    d.time.push_back(t);
    d.kinetic.push_back(1.0 + 0.5 * wobble);
    d.potential.push_back(1.0 - 0.5 * wobble);
    d.total.push_back(2.0);
    d.px.push_back(1e-14 * wobble);
    d.py.push_back(0.0);
    d.pz.push_back(0.0);
    d.lx.push_back(0.0);
    d.ly.push_back(0.0);
    d.lz.push_back(0.18 * (1.0 + 1e-4 * wobble));
  }
  const PlotLayout layout = layoutPlot(energyMomentumPanels(d));
  ASSERT_EQ(layout.panels.size(), 3u);
  const PanelGeometry& linear = layout.panels[1];
  const PanelGeometry& angular = layout.panels[2];
  EXPECT_GE(linear.yMax - linear.yMin, 1e-9);
  EXPECT_GE(angular.yMax - angular.yMin, 1e-3 * 0.18);
  // The energies' real swing of 1 J still fills its panel.
  const PanelGeometry& energy = layout.panels[0];
  EXPECT_LT(energy.yMax - energy.yMin, 3.0);
}

TEST(Plot, ARunOfNoStepsShowsItsOneSampleOnAxesThatStartAtZero) {
  // `render --steps 0` writes one diagnostics row. Its plot ran from t = -1 to 1 s with |p|
  // from -1e-9 to 1e-9 (a time and a magnitude cannot be negative), and its lone sample drew
  // no line, so the panels were empty.
  EnergyMomentumSeries d;
  d.time = {0.0};
  d.kinetic = {1.0};
  d.potential = {1.5};
  d.total = {2.5};
  d.px = d.py = d.pz = {0.0};
  d.lx = d.ly = {0.0};
  d.lz = {0.4};
  const auto panels = energyMomentumPanels(d);
  PlotLayout layout;
  const Image image = renderPlot(panels, {}, &layout);
  ASSERT_EQ(layout.panels.size(), 3u);
  for (const PanelGeometry& g : layout.panels) {
    EXPECT_EQ(g.xMin, 0.0);
    EXPECT_GT(g.xMax, 0.0);
  }
  EXPECT_EQ(layout.panels[1].yMin, 0.0);
  EXPECT_GE(layout.panels[2].yMin, 0.0);
  EXPECT_LE(layout.panels[2].yMin, 0.4);
  // Each sample is drawn: the energies, |p| = 0 on its axis, |L|.
  const auto drawn = [&](size_t panel, double y, Color color) {
    const Eigen::Vector2d at = layout.panels[panel].toPixel(0.0, y);
    return hasColorNear(image, at.x() + 2.0, at.y(), color, 2, 60);
  };
  EXPECT_TRUE(drawn(0, 1.0, panels[0].series[0].color.value()));
  EXPECT_TRUE(drawn(0, 1.5, panels[0].series[1].color.value()));
  EXPECT_TRUE(drawn(0, 2.5, panels[0].series[2].color.value()));
  EXPECT_TRUE(drawn(1, 0.0, panels[1].series[0].color.value()));
  EXPECT_TRUE(drawn(2, 0.4, panels[2].series[0].color.value()));
  // A signed quantity keeps its symmetric axis: components may be negative.
  const PlotLayout components = layoutPlot(energyMomentumPanels(d, MomentumDisplay::Components));
  EXPECT_LT(components.panels[1].yMin, 0.0);
}

TEST(Plot, LogScaleAndNonFiniteValuesAreHandled) {
  PlotPanel panel;
  panel.logY = true;
  Series s{"energy", {0, 1, 2, 3, 4}, {1e-3, 1e-1, std::nan(""), 1e2, 1e5}, std::nullopt, false};
  panel.series = {s};
  PlotLayout layout;
  const Image image = renderPlot({panel}, {}, &layout);
  EXPECT_LE(layout.panels[0].yMin, 1e-3);
  EXPECT_GE(layout.panels[0].yMax, 1e5);
  const Eigen::Vector2d at = layout.panels[0].toPixel(1.0, 1e-1);
  EXPECT_TRUE(hasColorNear(image, at.x(), at.y(), seriesColor(0), 1, 60));
}

TEST(Plot, BadInputIsRejected) {
  EXPECT_THROW(renderPlot({}), InvalidInputError);
  PlotPanel panel;
  panel.series = {{"bad", {0, 1, 2}, {0, 1}, std::nullopt, false}};
  EXPECT_THROW(renderPlot({panel}), InvalidInputError);
  PlotOptions tiny;
  tiny.width = 50;
  EXPECT_THROW(renderPlot(sinePanels(10), tiny), InvalidInputError);
}

TEST(Plot, DiagnosticsCsvBecomesEnergyAndMomentumPanels) {
  const fs::path path = scratchDir() / "diagnostics.csv";
  {
    std::ofstream out(path);
    out << "step,time,kinetic,potential,total,px,py,pz,lx,ly,lz\n";
    for (int i = 0; i <= 200; ++i) {
      const double t = 0.01 * i;
      const double k = std::sin(3 * t) * std::sin(3 * t);
      const double u = 1.0 - k;
      out << i << "," << t << "," << k << "," << u << "," << k + u << "," << 0.1 * t << ",0,0,0,0,"
          << 0.5 + 0.1 * std::cos(t) << "\n";
    }
  }
  const EnergyMomentumSeries data = readDiagnosticsCsv(path.string());
  ASSERT_EQ(data.time.size(), 201u);
  EXPECT_DOUBLE_EQ(data.time[100], 1.0);
  EXPECT_DOUBLE_EQ(data.lz[0], 0.6);
  const auto panels = energyMomentumPanels(data);
  ASSERT_EQ(panels.size(), 3u);
  ASSERT_EQ(panels[0].series.size(), 3u);
  PlotLayout layout;
  const Image image = renderPlot(panels, {}, &layout);
  for (size_t s = 0; s < 3; ++s) {
    const Series& series = panels[0].series[s];
    int found = 0;
    for (size_t i = 3; i < series.x.size(); i += 20) {
      const Eigen::Vector2d at = layout.panels[0].toPixel(series.x[i], series.y[i]);
      found += hasColorNear(image, at.x(), at.y(), *series.color, 1, 60);
    }
    EXPECT_GE(found, 8) << series.name;
  }
  const Series& momentum = panels[1].series[0];
  EXPECT_NEAR(momentum.y[200], 0.2, 1e-12);
  // Components view: three series per momentum panel.
  EXPECT_EQ(energyMomentumPanels(data, MomentumDisplay::Components)[2].series.size(), 3u);

  const fs::path png = path.parent_path() / "plot.png";
  savePlot(png.string(), panels);
  EXPECT_EQ(readPng(png.string()).rgba, image.rgba);

  {
    std::ofstream out(path);
    out << "step,time,kinetic,potential,total,px,py,pz,lx,ly\n0,0,0,0,0,0,0,0,0,0\n";
  }
  EXPECT_THROW(readDiagnosticsCsv(path.string()), IOError);
  {
    std::ofstream out(path);
    out << "step,time,kinetic,potential,total,px,py,pz,lx,ly,lz\n0,0,0,zero,0,0,0,0,0,0,0\n";
  }
  try {
    readDiagnosticsCsv(path.string());
    FAIL() << "no exception";
  } catch (const IOError& e) {
    EXPECT_NE(std::string(e.what()).find(":2:"), std::string::npos) << e.what();
  }
  EXPECT_THROW(readDiagnosticsCsv((path.parent_path() / "missing.csv").string()), IOError);
  fs::remove_all(path.parent_path());
}

TEST(ImageFiles, PngRoundTripAndComposition) {
  Image a(3, 2);
  for (size_t i = 0; i < a.rgba.size(); ++i) a.rgba[i] = static_cast<std::uint8_t>(i * 10);
  const fs::path path = scratchDir() / "tiny.png";
  savePng(path.string(), a);
  EXPECT_EQ(readPng(path.string()).rgba, a.rgba);
  EXPECT_THROW(readPng((path.parent_path() / "missing.png").string()), IOError);
  Image b(2, 4);
  const Image row = composeRow({&a, &b}, 1);
  EXPECT_EQ(row.width, 6);
  EXPECT_EQ(row.height, 4);
  EXPECT_DOUBLE_EQ(meanAbsoluteDifference(a, a), 0.0);
  EXPECT_THROW(meanAbsoluteDifference(a, b), InvalidInputError);
  fs::remove_all(path.parent_path());
}

}  // namespace
}  // namespace zsculpt::render
