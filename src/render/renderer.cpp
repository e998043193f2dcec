#include "zsculpt/render/renderer.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <numbers>
#include <sstream>
#include <string>
#include <unordered_map>
#include <vector>

#include "gl_functions.h"
#include "glyph_meshes.h"
#include "zsculpt/core/errors.h"
#include "zsculpt/render/canvas.h"
#include "zsculpt/subdivision/subdivision.h"

#ifndef ZSCULPT_DATA_DIR
#define ZSCULPT_DATA_DIR "."
#endif

namespace zsculpt::render {
namespace {

using Matrix4f = Eigen::Matrix4f;
using Vector3f = Eigen::Vector3f;

// Glyph shapes drawn instanced with glyph.vert.
enum GlyphShape { kCube, kCylinder, kCone, kRing, kGlyphShapeCount };
constexpr int kInstanceFloats = 20;  // model matrix (column-major) + RGBA
constexpr int kBrushSegments = 96;
// The torque ring's sweep and tube radius (relative to its radius).
constexpr float kRingSweep = 1.62f * std::numbers::pi_v<float>;
constexpr float kRingTube = 0.11f;
// Without a fixed force scale, the largest arrow is this share of the model's diagonal.
constexpr double kArrowShare = 0.2;

std::string readFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw IOError(path + ": cannot read shader");
  std::stringstream buffer;
  buffer << in.rdbuf();
  return buffer.str();
}

std::string firstLine(const std::string& text) {
  std::string line;
  std::stringstream in(text);
  while (std::getline(in, line)) {
    if (line.find_first_not_of(" \t\r") != std::string::npos) {
      while (!line.empty() && (line.back() == '\r' || line.back() == ' ')) line.pop_back();
      return line;
    }
  }
  return "unknown error";
}

// A frame whose third axis is `d` (unit).
void basisFrom(const Vec3& d, Vec3& x, Vec3& y) {
  const Vec3 helper = std::abs(d.z()) < 0.9 ? Vec3::UnitZ() : Vec3::UnitX();
  x = helper.cross(d).normalized();
  y = d.cross(x);
}

// An undirected edge as one hashable number.
std::uint64_t edgeKey(Index a, Index b) {
  return (static_cast<std::uint64_t>(std::min(a, b)) << 32) |
         static_cast<std::uint32_t>(std::max(a, b));
}

// How many faces of `faces` have each edge (by edgeKey).
std::unordered_map<std::uint64_t, int> facesPerEdge(const CsrIndex& faces) {
  std::unordered_map<std::uint64_t, int> count;
  for (Index f = 0; f < faces.rows(); ++f) {
    const auto c = faces.row(f);
    for (size_t k = 0; k < c.size(); ++k) ++count[edgeKey(c[k], c[(k + 1) % c.size()])];
  }
  return count;
}

// The size of the pin cubes and arrow heads, from the control mesh's scale: a third of an
// edge, within 1.6 % to 5 % of the bounding box's diagonal.
double glyphSizeOf(const Mesh& mesh) {
  const double diagonal = std::max(mesh.boundingBox().diagonal(), 1e-9);
  const double edge = mesh.numEdges() > 0 ? mesh.meanEdgeLength() : 0.05 * diagonal;
  return std::clamp(0.3 * edge, 0.016 * diagonal, 0.05 * diagonal);
}

// A normal pin's arrow: its length and, on a vertex also held in place, how far from the
// vertex it starts (clear of the pin's cube, whose half-size is half the glyph size).
constexpr double kNormalArrowLength = 4.0;  // glyph sizes
double normalArrowOffset(double glyph, bool pinned) {
  return pinned ? std::sqrt(3.0) * 0.5 * glyph : 0.0;
}

struct Overlay {
  GLuint texture = 0;
  int textureWidth = 0;
  int textureHeight = 0;
  Canvas canvas;
  std::string key;
  bool visible = false;
  double x = 0.0;
  double y = 0.0;
};

struct GlyphBatch {
  GLuint vao = 0;
  GLuint vbo = 0;
  GLuint ebo = 0;
  GLuint instances = 0;
  GLsizei indexCount = 0;
  size_t capacity = 0;  // instances the buffer holds
  std::vector<float> data;
};

}  // namespace

struct Renderer::Impl {
  detail::GlFunctions gl;
  bool loaded = false;
  RenderLimits limits;
  std::string shaderDir;
  std::string lighting;
  bool supersample = false;

  GLuint backgroundProgram = 0;
  GLuint surfaceProgram = 0;
  GLuint glyphProgram = 0;
  GLuint lineProgram = 0;
  GLuint pointProgram = 0;
  GLuint overlayProgram = 0;

  GLuint emptyVao = 0;
  // Surface (refined mesh, or the control mesh without a stencil).
  GLuint surfaceVao = 0;
  GLuint positionVbo = 0;
  GLuint normalVbo = 0;
  GLuint scalarVbo = 0;
  GLuint triangleEbo = 0;
  GLsizei triangleIndexCount = 0;
  GLuint surfaceEdgeVao = 0;
  GLuint surfaceEdgeEbo = 0;
  GLsizei surfaceEdgeIndexCount = 0;
  GLuint wireEdgeVao = 0;
  GLuint wireEdgeEbo = 0;
  GLsizei wireEdgeIndexCount = 0;
  // Control mesh (its own positions only when a stencil refines it).
  GLuint controlVbo = 0;
  GLuint controlEdgeVao = 0;
  GLuint controlEdgeEbo = 0;
  GLsizei controlEdgeIndexCount = 0;
  GLuint controlPointVao = 0;
  // Markers: impostor spheres with a colour each.
  GLuint markerVao = 0;
  GLuint markerVbo = 0;
  size_t markerCapacity = 0;
  std::vector<float> markerData;
  GlyphBatch glyphs[kGlyphShapeCount];
  GLuint brushVao = 0;
  GLuint brushVbo = 0;
  std::vector<float> brushData;
  GLuint colorMapTexture = 0;
  int colorMapLoaded = -1;
  Overlay legend;
  Overlay caption;
  bool captionTooWide = false;  // the caption's first clause does not fit the image

  // Framebuffers.
  GLuint renderFbo = 0;
  GLuint renderColor = 0;
  GLuint renderDepth = 0;
  GLuint resolveFbo = 0;
  GLuint resolveColor = 0;
  int renderWidth = 0;
  int renderHeight = 0;
  int resolveWidth = 0;
  int resolveHeight = 0;

  // Topology cache.
  bool topologyValid = false;
  const Mesh* keyMesh = nullptr;
  const SubdivisionStencil* keyStencil = nullptr;
  std::uint64_t keyVersion = 0;
  Index keyVertices = -1;
  Index keyFaces = -1;
  Index keyEdges = -1;
  Index keyRefined = -1;
  Index surfaceVertexCount = 0;
  // Sheets that meet at a vertex (three fins on one edge): each fan of faces around such a
  // vertex gets a vertex of its own on the GPU, shaded with its fan's normal, rather than one
  // normal averaged over all the sheets. fanVertex[k] is fan k's GPU vertex (the surface
  // vertex itself for its first fan, an extra one after surfaceVertexCount for the others),
  // fanSource[k] the surface vertex, its faces fanFaces[fanStart[k] .. fanStart[k + 1]).
  std::vector<Index> fanVertex, fanSource, fanStart, fanFaces;
  Index gpuVertexCount = 0;  // surfaceVertexCount plus the extra fan vertices
  const CsrIndex* surfaceFaces = nullptr;
  const CsrIndex* surfaceNeighbors = nullptr;
  // Closed, consistently oriented surfaces never show their back faces: culling them
  // halves llvmpipe's work on a 100k-face frame. 0: no culling, else GL_BACK or GL_FRONT
  // (faces wound inwards).
  GLenum cullFace = 0;
  double glyphSize = 0.1;
  double pointRadius = 0.05;
  double diagonal = 1.0;

  // Per-frame scratch, sized once per topology.
  Points refined;
  Points normals;
  VectorX refinedScalar;
  std::vector<float> positionData;
  std::vector<float> normalData;
  std::vector<float> scalarData;
  std::vector<float> controlData;
  std::vector<std::uint8_t> readback;
  double scalarMin = 0.0;
  double scalarMax = 1.0;
  bool scalarUniform = false;  // every finite value the same: the legend shows that value
  double scalarValue = 0.0;

  // ---- setup ------------------------------------------------------------------------------
  GLuint compile(GLenum type, const std::string& name) {
    const std::string path = shaderDir + "/" + name;
    std::string source = readFile(path);
    if (source.rfind("#version", 0) != 0) {
      // Fragment shaders that shade share lighting.glsl.
      source = "#version 330 core\n" + lighting + "\n#line 1\n" + source;
    }
    const GLuint shader = gl.CreateShader(type);
    const char* text = source.c_str();
    gl.ShaderSource(shader, 1, &text, nullptr);
    gl.CompileShader(shader);
    GLint ok = 0;
    gl.GetShaderiv(shader, GL_COMPILE_STATUS, &ok);
    if (ok == 0) {
      char log[2048] = {};
      gl.GetShaderInfoLog(shader, sizeof log, nullptr, log);
      gl.DeleteShader(shader);
      throw IOError(path + ": " + firstLine(log));
    }
    return shader;
  }

  GLuint program(const std::string& vertex, const std::string& geometry,
                 const std::string& fragment) {
    const GLuint vs = compile(GL_VERTEX_SHADER, vertex);
    const GLuint gs = geometry.empty() ? 0 : compile(GL_GEOMETRY_SHADER, geometry);
    const GLuint fs = compile(GL_FRAGMENT_SHADER, fragment);
    const GLuint p = gl.CreateProgram();
    gl.AttachShader(p, vs);
    if (gs != 0) gl.AttachShader(p, gs);
    gl.AttachShader(p, fs);
    gl.LinkProgram(p);
    gl.DeleteShader(vs);
    if (gs != 0) gl.DeleteShader(gs);
    gl.DeleteShader(fs);
    GLint ok = 0;
    gl.GetProgramiv(p, GL_LINK_STATUS, &ok);
    if (ok == 0) {
      char log[2048] = {};
      gl.GetProgramInfoLog(p, sizeof log, nullptr, log);
      gl.DeleteProgram(p);
      throw IOError(shaderDir + "/" + vertex + " + " + fragment +
                    ": link error: " + firstLine(log));
    }
    return p;
  }

  // A uniform's location, looked up once: the programs live as long as this object, and the
  // names are string literals, so (program, name pointer) keys them. A frame asks for about
  // 45; the driver's lookup parses and hashes the name each time.
  struct UniformSlot {
    GLuint program = 0;
    const char* name = nullptr;
    GLint location = -1;
  };
  mutable std::array<UniformSlot, 96> uniforms_{};
  mutable std::size_t uniformCount_ = 0;
  GLint uniform(GLuint p, const char* name) const {
    for (std::size_t i = 0; i < uniformCount_; ++i)
      if (uniforms_[i].program == p && uniforms_[i].name == name) return uniforms_[i].location;
    const GLint location = gl.GetUniformLocation(p, name);
    if (uniformCount_ < uniforms_.size()) uniforms_[uniformCount_++] = {p, name, location};
    return location;
  }

  GLuint buffer() {
    GLuint b = 0;
    gl.GenBuffers(1, &b);
    return b;
  }
  GLuint vertexArray() {
    GLuint v = 0;
    gl.GenVertexArrays(1, &v);
    return v;
  }

  void createGlyph(GlyphShape shape, const detail::GlyphMesh& mesh) {
    GlyphBatch& g = glyphs[shape];
    g.vao = vertexArray();
    g.vbo = buffer();
    g.ebo = buffer();
    g.instances = buffer();
    gl.BindVertexArray(g.vao);
    gl.BindBuffer(GL_ARRAY_BUFFER, g.vbo);
    gl.BufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(mesh.vertices.size() * sizeof(float)),
                  mesh.vertices.data(), GL_STATIC_DRAW);
    gl.EnableVertexAttribArray(0);
    gl.VertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float), nullptr);
    gl.EnableVertexAttribArray(1);
    gl.VertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float),
                           reinterpret_cast<void*>(3 * sizeof(float)));
    gl.BindBuffer(GL_ELEMENT_ARRAY_BUFFER, g.ebo);
    gl.BufferData(GL_ELEMENT_ARRAY_BUFFER,
                  static_cast<GLsizeiptr>(mesh.indices.size() * sizeof(std::uint32_t)),
                  mesh.indices.data(), GL_STATIC_DRAW);
    g.indexCount = static_cast<GLsizei>(mesh.indices.size());
    gl.BindBuffer(GL_ARRAY_BUFFER, g.instances);
    g.capacity = 16;
    gl.BufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(g.capacity * kInstanceFloats * 4),
                  nullptr, GL_DYNAMIC_DRAW);
    for (int k = 0; k < 5; ++k) {
      gl.EnableVertexAttribArray(3 + k);
      gl.VertexAttribPointer(3 + k, 4, GL_FLOAT, GL_FALSE, kInstanceFloats * sizeof(float),
                             reinterpret_cast<void*>(static_cast<size_t>(4 * k) * sizeof(float)));
      gl.VertexAttribDivisor(3 + k, 1);
    }
    g.data.reserve(g.capacity * kInstanceFloats);
    gl.BindVertexArray(0);
  }

  void createOverlay(Overlay& overlay) {
    gl.GenTextures(1, &overlay.texture);
    gl.BindTexture(GL_TEXTURE_2D, overlay.texture);
    gl.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    gl.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    gl.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    gl.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
  }

  void init(const GlLoader& loader, const RendererOptions& options) {
    gl.load(loader);
    loaded = true;
    const auto* version = reinterpret_cast<const char*>(gl.GetString(GL_VERSION));
    const auto* rendererName = reinterpret_cast<const char*>(gl.GetString(GL_RENDERER));
    if (version == nullptr) {
      throw IOError("OpenGL: no current context (glGetString(GL_VERSION) returned null)");
    }
    limits.version = version;
    limits.renderer = rendererName != nullptr ? rendererName : "";
    GLint viewport[2] = {0, 0};
    GLint renderbuffer = 0;
    GLint maxSamples = 0;
    gl.GetIntegerv(GL_MAX_VIEWPORT_DIMS, viewport);
    gl.GetIntegerv(GL_MAX_RENDERBUFFER_SIZE, &renderbuffer);
    gl.GetIntegerv(GL_MAX_SAMPLES, &maxSamples);
    const int samples = std::min(options.samples, static_cast<int>(maxSamples));
    supersample = samples < 2;
    limits.samples = supersample ? 0 : samples;
    limits.maxWidth = std::min(viewport[0], renderbuffer) / (supersample ? 2 : 1);
    limits.maxHeight = std::min(viewport[1], renderbuffer) / (supersample ? 2 : 1);

    shaderDir = options.shaderDir;
    if (shaderDir.empty()) {
      const char* env = std::getenv("ZSCULPT_SHADER_DIR");
      shaderDir = (env != nullptr && *env != '\0') ? std::string(env)
                                                   : std::string(ZSCULPT_DATA_DIR) + "/shaders";
    }
    lighting = readFile(shaderDir + "/lighting.glsl");
    backgroundProgram = program("background.vert", "", "background.frag");
    surfaceProgram = program("surface.vert", "", "surface.frag");
    glyphProgram = program("glyph.vert", "", "surface.frag");
    lineProgram = program("lines.vert", "lines.geom", "lines.frag");
    pointProgram = program("points.vert", "points.geom", "points.frag");
    overlayProgram = program("overlay.vert", "", "overlay.frag");

    emptyVao = vertexArray();
    surfaceVao = vertexArray();
    surfaceEdgeVao = vertexArray();
    wireEdgeVao = vertexArray();
    controlEdgeVao = vertexArray();
    controlPointVao = vertexArray();
    markerVao = vertexArray();
    brushVao = vertexArray();
    positionVbo = buffer();
    normalVbo = buffer();
    scalarVbo = buffer();
    triangleEbo = buffer();
    surfaceEdgeEbo = buffer();
    wireEdgeEbo = buffer();
    controlVbo = buffer();
    controlEdgeEbo = buffer();
    markerVbo = buffer();
    brushVbo = buffer();

    createGlyph(kCube, detail::makeCubeMesh());
    createGlyph(kCylinder, detail::makeCylinderMesh(20));
    createGlyph(kCone, detail::makeConeMesh(24));
    createGlyph(kRing, detail::makeRingMesh(64, 12, kRingTube, kRingSweep));

    // Markers: position and colour per point.
    gl.BindVertexArray(markerVao);
    gl.BindBuffer(GL_ARRAY_BUFFER, markerVbo);
    markerCapacity = 16;
    gl.BufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(markerCapacity * 7 * sizeof(float)),
                  nullptr, GL_DYNAMIC_DRAW);
    gl.EnableVertexAttribArray(0);
    gl.VertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 7 * sizeof(float), nullptr);
    gl.EnableVertexAttribArray(1);
    gl.VertexAttribPointer(1, 4, GL_FLOAT, GL_FALSE, 7 * sizeof(float),
                           reinterpret_cast<void*>(3 * sizeof(float)));
    markerData.reserve(markerCapacity * 7);

    gl.BindVertexArray(brushVao);
    gl.BindBuffer(GL_ARRAY_BUFFER, brushVbo);
    brushData.assign(kBrushSegments * 3, 0.0f);
    gl.BufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(brushData.size() * sizeof(float)),
                  nullptr, GL_DYNAMIC_DRAW);
    gl.EnableVertexAttribArray(0);
    gl.VertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 3 * sizeof(float), nullptr);
    gl.BindVertexArray(0);

    gl.GenTextures(1, &colorMapTexture);
    gl.BindTexture(GL_TEXTURE_2D, colorMapTexture);
    gl.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
    gl.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
    gl.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    gl.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    createOverlay(legend);
    createOverlay(caption);

    gl.GenFramebuffers(1, &renderFbo);
    gl.GenFramebuffers(1, &resolveFbo);
    gl.GenRenderbuffers(1, &renderColor);
    gl.GenRenderbuffers(1, &renderDepth);
    gl.GenRenderbuffers(1, &resolveColor);
  }

  void destroy() {
    if (!loaded) return;  // loading failed: nothing was created
    for (GLuint p : {backgroundProgram, surfaceProgram, glyphProgram, lineProgram, pointProgram,
                     overlayProgram}) {
      if (p != 0) gl.DeleteProgram(p);
    }
    GLuint vaos[] = {emptyVao,       surfaceVao,      surfaceEdgeVao, wireEdgeVao,
                     controlEdgeVao, controlPointVao, markerVao,      brushVao};
    gl.DeleteVertexArrays(static_cast<GLsizei>(std::size(vaos)), vaos);
    GLuint buffers[] = {positionVbo, normalVbo,  scalarVbo,      triangleEbo, surfaceEdgeEbo,
                        wireEdgeEbo, controlVbo, controlEdgeEbo, markerVbo,   brushVbo};
    gl.DeleteBuffers(static_cast<GLsizei>(std::size(buffers)), buffers);
    for (GlyphBatch& g : glyphs) {
      gl.DeleteVertexArrays(1, &g.vao);
      GLuint b[] = {g.vbo, g.ebo, g.instances};
      gl.DeleteBuffers(3, b);
    }
    GLuint textures[] = {colorMapTexture, legend.texture, caption.texture};
    gl.DeleteTextures(3, textures);
    GLuint fbos[] = {renderFbo, resolveFbo};
    gl.DeleteFramebuffers(2, fbos);
    GLuint rbs[] = {renderColor, renderDepth, resolveColor};
    gl.DeleteRenderbuffers(3, rbs);
  }

  // ---- framebuffers -----------------------------------------------------------------------
  void ensureRenderTarget(int width, int height) {
    const int w = supersample ? 2 * width : width;
    const int h = supersample ? 2 * height : height;
    if (w == renderWidth && h == renderHeight) return;
    gl.BindRenderbuffer(GL_RENDERBUFFER, renderColor);
    if (supersample) {
      gl.RenderbufferStorage(GL_RENDERBUFFER, GL_RGBA8, w, h);
    } else {
      gl.RenderbufferStorageMultisample(GL_RENDERBUFFER, limits.samples, GL_RGBA8, w, h);
    }
    gl.BindRenderbuffer(GL_RENDERBUFFER, renderDepth);
    if (supersample) {
      gl.RenderbufferStorage(GL_RENDERBUFFER, GL_DEPTH_COMPONENT24, w, h);
    } else {
      gl.RenderbufferStorageMultisample(GL_RENDERBUFFER, limits.samples, GL_DEPTH_COMPONENT24, w,
                                        h);
    }
    gl.BindFramebuffer(GL_FRAMEBUFFER, renderFbo);
    gl.FramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, renderColor);
    gl.FramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, renderDepth);
    const GLenum status = gl.CheckFramebufferStatus(GL_FRAMEBUFFER);
    if (status != GL_FRAMEBUFFER_COMPLETE) {
      renderWidth = renderHeight = 0;
      char text[96];
      std::snprintf(text, sizeof text, "OpenGL: cannot create a %dx%d framebuffer (status 0x%x)", w,
                    h, status);
      throw IOError(text);
    }
    renderWidth = w;
    renderHeight = h;
  }

  void ensureResolveTarget(int width, int height) {
    if (width == resolveWidth && height == resolveHeight) return;
    gl.BindRenderbuffer(GL_RENDERBUFFER, resolveColor);
    gl.RenderbufferStorage(GL_RENDERBUFFER, GL_RGBA8, width, height);
    gl.BindFramebuffer(GL_FRAMEBUFFER, resolveFbo);
    gl.FramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, resolveColor);
    if (gl.CheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
      resolveWidth = resolveHeight = 0;
      throw IOError("OpenGL: cannot create the read-back framebuffer");
    }
    resolveWidth = width;
    resolveHeight = height;
  }

  // ---- topology ---------------------------------------------------------------------------
  bool topologyChanged(const Frame& frame) const {
    const Mesh& mesh = *frame.mesh;
    const Index refinedCount = frame.stencil != nullptr ? frame.stencil->numRefinedVertices() : -1;
    return !topologyValid || keyMesh != frame.mesh || keyStencil != frame.stencil ||
           keyVersion != frame.topologyVersion || keyVertices != mesh.numVertices() ||
           keyFaces != mesh.numFaces() || keyEdges != mesh.numEdges() || keyRefined != refinedCount;
  }

  void uploadIndices(GLuint vao, GLuint ebo, const std::vector<std::uint32_t>& indices) {
    gl.BindVertexArray(vao);
    gl.BindBuffer(GL_ELEMENT_ARRAY_BUFFER, ebo);
    gl.BufferData(GL_ELEMENT_ARRAY_BUFFER,
                  static_cast<GLsizeiptr>(indices.size() * sizeof(std::uint32_t)),
                  indices.empty() ? nullptr : indices.data(), GL_STATIC_DRAW);
  }

  void bindPositions(GLuint vao, GLuint vbo) {
    gl.BindVertexArray(vao);
    gl.BindBuffer(GL_ARRAY_BUFFER, vbo);
    gl.EnableVertexAttribArray(0);
    gl.VertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 3 * sizeof(float), nullptr);
  }

  // Groups the faces around each vertex into fans, faces joined across the vertex's edges
  // that exactly two faces share; a vertex with more than one fan (sheets meeting there)
  // gives every fan after the first a GPU vertex of its own (fanVertex ...). Returns each
  // face corner's GPU vertex, aligned with faces.indices.
  std::vector<Index> splitSheets(const CsrIndex& faces, Index n,
                                 const std::unordered_map<std::uint64_t, int>& edgeFaces) {
    fanVertex.clear();
    fanSource.clear();
    fanStart.assign(1, 0);
    fanFaces.clear();
    std::vector<Index> cornerVertex(faces.indices.begin(), faces.indices.end());
    gpuVertexCount = n;
    // Only an edge of three or more faces makes sheets meet.
    if (std::none_of(edgeFaces.begin(), edgeFaces.end(),
                     [](const auto& e) { return e.second > 2; }))
      return cornerVertex;
    // The corners at each vertex: (vertex, face, position in faces.indices).
    std::vector<std::array<Index, 3>> corners;
    for (Index f = 0; f < faces.rows(); ++f)
      for (Index at = faces.offsets[static_cast<size_t>(f)];
           at < faces.offsets[static_cast<size_t>(f) + 1]; ++at)
        corners.push_back({faces.indices[static_cast<size_t>(at)], f, at});
    std::sort(corners.begin(), corners.end());
    std::vector<Index> parent, fanOf, firstOfRoot;
    std::unordered_map<Index, Index> byNeighbour;
    for (size_t begin = 0; begin < corners.size();) {
      const Index v = corners[begin][0];
      size_t end = begin;
      while (end < corners.size() && corners[end][0] == v) ++end;
      const size_t count = end - begin;
      // Union-find over v's corners, joined across v's edges of exactly two faces.
      parent.resize(count);
      byNeighbour.clear();
      auto root = [&](Index i) {
        while (parent[static_cast<size_t>(i)] != i) i = parent[static_cast<size_t>(i)];
        return i;
      };
      for (size_t i = 0; i < count; ++i) {
        const auto [vertex, f, at] = corners[begin + i];
        parent[i] = static_cast<Index>(i);
        const auto c = faces.row(f);
        const size_t local = static_cast<size_t>(at - faces.offsets[static_cast<size_t>(f)]);
        for (const Index w : {c[(local + c.size() - 1) % c.size()], c[(local + 1) % c.size()]}) {
          if (edgeFaces.at(edgeKey(v, w)) != 2) continue;  // a border, or where sheets meet
          const auto [it, fresh] = byNeighbour.try_emplace(w, static_cast<Index>(i));
          if (!fresh) parent[static_cast<size_t>(root(static_cast<Index>(i)))] = root(it->second);
        }
      }
      // Fans in the order of their first corner; the first keeps v.
      fanOf.assign(count, -1);
      firstOfRoot.assign(count, -1);
      Index fans = 0;
      for (size_t i = 0; i < count; ++i) {
        const Index r = root(static_cast<Index>(i));
        if (firstOfRoot[static_cast<size_t>(r)] < 0) firstOfRoot[static_cast<size_t>(r)] = fans++;
        fanOf[i] = firstOfRoot[static_cast<size_t>(r)];
      }
      for (Index fan = 0; fans > 1 && fan < fans; ++fan) {
        const Index gpu = fan == 0 ? v : gpuVertexCount++;
        fanVertex.push_back(gpu);
        fanSource.push_back(v);
        for (size_t i = 0; i < count; ++i) {
          if (fanOf[i] != fan) continue;
          fanFaces.push_back(corners[begin + i][1]);
          cornerVertex[static_cast<size_t>(corners[begin + i][2])] = gpu;
        }
        fanStart.push_back(static_cast<Index>(fanFaces.size()));
      }
      begin = end;
    }
    return cornerVertex;
  }

  void rebuildTopology(const Frame& frame) {
    const Mesh& mesh = *frame.mesh;
    const SubdivisionStencil* stencil = frame.stencil;
    if (stencil != nullptr && stencil->numControlVertices() != mesh.numVertices()) {
      throw InvalidInputError("frame: the stencil has " +
                              std::to_string(stencil->numControlVertices()) +
                              " control vertices, the mesh " + std::to_string(mesh.numVertices()));
    }
    surfaceFaces = stencil != nullptr ? &stencil->refinedFaces() : &mesh.faces();
    surfaceVertexCount = stencil != nullptr ? stencil->numRefinedVertices() : mesh.numVertices();
    const auto& surfaceEdges = stencil != nullptr ? stencil->refinedEdges() : mesh.edges();
    const Index n = surfaceVertexCount;

    const std::unordered_map<std::uint64_t, int> edgeFaces = facesPerEdge(*surfaceFaces);
    // Each face corner's GPU vertex: the surface vertex, or its fan's own where sheets meet.
    std::vector<Index> cornerVertex = splitSheets(*surfaceFaces, n, edgeFaces);
    // Triangles: a fan per polygon.
    std::vector<std::uint32_t> triangles;
    for (Index f = 0; f < surfaceFaces->rows(); ++f) {
      const Index* corners = cornerVertex.data() + surfaceFaces->offsets[static_cast<size_t>(f)];
      const size_t size = surfaceFaces->row(f).size();
      for (size_t k = 1; k + 1 < size; ++k) {
        triangles.insert(triangles.end(), {static_cast<std::uint32_t>(corners[0]),
                                           static_cast<std::uint32_t>(corners[k]),
                                           static_cast<std::uint32_t>(corners[k + 1])});
      }
    }
    std::vector<std::uint32_t> edgeIndices;
    edgeIndices.reserve(surfaceEdges.size() * 2);
    for (const auto& e : surfaceEdges) {
      edgeIndices.push_back(static_cast<std::uint32_t>(e[0]));
      edgeIndices.push_back(static_cast<std::uint32_t>(e[1]));
    }
    // Edges with no face: curves (with a stencil, a solid's inner edges are not among them:
    // subdivision.h), and at level 0 a solid's interior lattice edges too.
    std::vector<std::uint32_t> wire;
    if (stencil == nullptr) {
      for (Index e = 0; e < mesh.numEdges(); ++e) {
        if (mesh.isWireEdge(e)) {
          wire.push_back(static_cast<std::uint32_t>(mesh.edge(e)[0]));
          wire.push_back(static_cast<std::uint32_t>(mesh.edge(e)[1]));
        }
      }
    } else {
      for (const auto& e : surfaceEdges) {
        if (edgeFaces.count(edgeKey(e[0], e[1])) == 0) {
          wire.push_back(static_cast<std::uint32_t>(e[0]));
          wire.push_back(static_cast<std::uint32_t>(e[1]));
        }
      }
    }
    std::vector<std::uint32_t> controlEdges;
    controlEdges.reserve(static_cast<size_t>(mesh.numEdges()) * 2);
    for (const auto& e : mesh.edges()) {
      controlEdges.push_back(static_cast<std::uint32_t>(e[0]));
      controlEdges.push_back(static_cast<std::uint32_t>(e[1]));
    }

    // Neighbour table for best-plane normals: the stencil's (a vertex on a face has its ring
    // through the faces, a curve's own vertex along the curve), as its faces are kept.
    surfaceNeighbors =
        stencil != nullptr ? &stencil->refinedVertexNeighbors() : &mesh.vertexNeighborTable();

    // CPU scratch for the per-frame path.
    refined.resize(stencil != nullptr ? n : 0, 3);
    normals.resize(n, 3);
    refinedScalar.resize(stencil != nullptr ? n : 0);
    positionData.assign(static_cast<size_t>(gpuVertexCount) * 3, 0.0f);
    normalData.assign(static_cast<size_t>(gpuVertexCount) * 3, 0.0f);
    scalarData.assign(static_cast<size_t>(gpuVertexCount), 0.0f);
    controlData.assign(static_cast<size_t>(mesh.numVertices()) * 3, 0.0f);

    // GPU buffers: allocated here, refreshed with glBufferSubData every frame.
    auto allocate = [&](GLuint vbo, size_t floats) {
      gl.BindBuffer(GL_ARRAY_BUFFER, vbo);
      gl.BufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(std::max<size_t>(floats, 1) * 4),
                    nullptr, GL_DYNAMIC_DRAW);
    };
    allocate(positionVbo, positionData.size());
    allocate(normalVbo, normalData.size());
    allocate(scalarVbo, scalarData.size());
    allocate(controlVbo, controlData.size());

    gl.BindVertexArray(surfaceVao);
    gl.BindBuffer(GL_ARRAY_BUFFER, positionVbo);
    gl.EnableVertexAttribArray(0);
    gl.VertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 3 * sizeof(float), nullptr);
    gl.BindBuffer(GL_ARRAY_BUFFER, normalVbo);
    gl.EnableVertexAttribArray(1);
    gl.VertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, 3 * sizeof(float), nullptr);
    gl.BindBuffer(GL_ARRAY_BUFFER, scalarVbo);
    gl.EnableVertexAttribArray(2);
    gl.VertexAttribPointer(2, 1, GL_FLOAT, GL_FALSE, sizeof(float), nullptr);
    uploadIndices(surfaceVao, triangleEbo, triangles);
    triangleIndexCount = static_cast<GLsizei>(triangles.size());

    bindPositions(surfaceEdgeVao, positionVbo);
    uploadIndices(surfaceEdgeVao, surfaceEdgeEbo, edgeIndices);
    surfaceEdgeIndexCount = static_cast<GLsizei>(edgeIndices.size());
    bindPositions(wireEdgeVao, positionVbo);
    gl.BindBuffer(GL_ARRAY_BUFFER, scalarVbo);  // the property's colour along curves
    gl.EnableVertexAttribArray(2);
    gl.VertexAttribPointer(2, 1, GL_FLOAT, GL_FALSE, sizeof(float), nullptr);
    uploadIndices(wireEdgeVao, wireEdgeEbo, wire);
    wireEdgeIndexCount = static_cast<GLsizei>(wire.size());
    // Without a stencil the control mesh is the surface: share its positions.
    const GLuint controlPositions = stencil != nullptr ? controlVbo : positionVbo;
    bindPositions(controlEdgeVao, controlPositions);
    uploadIndices(controlEdgeVao, controlEdgeEbo, controlEdges);
    controlEdgeIndexCount = static_cast<GLsizei>(controlEdges.size());
    bindPositions(controlPointVao, controlPositions);
    gl.DisableVertexAttribArray(1);  // one colour for all: set with glVertexAttrib4f
    gl.BindVertexArray(0);

    // Closed: every edge has exactly two faces and no vertex lies off the surface. The sign
    // of the enclosed volume at build time tells the winding.
    cullFace = 0;
    bool closed = mesh.numFaces() > 0 && mesh.isolatedVertices().empty();
    for (Index e = 0; closed && e < mesh.numEdges(); ++e) closed = mesh.edgeFaces(e).size() == 2;
    if (closed) {
      const Points& p = mesh.positions();
      double volume = 0.0;
      for (Index f = 0; f < mesh.numFaces(); ++f) {
        const auto c = mesh.face(f);
        for (size_t k = 1; k + 1 < c.size(); ++k) {
          volume += p.row(c[0]).dot(p.row(c[k]).cross(p.row(c[k + 1])));
        }
      }
      if (volume != 0.0) cullFace = volume > 0.0 ? GL_BACK : GL_FRONT;
    }

    // Glyph sizes follow the control mesh's scale at the time its topology is set, so
    // they do not change from frame to frame.
    const BoundingBox box = mesh.boundingBox();
    diagonal = std::max(box.diagonal(), 1e-9);
    const double edge = mesh.numEdges() > 0 ? mesh.meanEdgeLength() : 0.05 * diagonal;
    glyphSize = glyphSizeOf(mesh);
    pointRadius = std::clamp(0.055 * edge, 0.003 * diagonal, 0.02 * diagonal);

    keyMesh = frame.mesh;
    keyStencil = frame.stencil;
    keyVersion = frame.topologyVersion;
    keyVertices = mesh.numVertices();
    keyFaces = mesh.numFaces();
    keyEdges = mesh.numEdges();
    keyRefined = stencil != nullptr ? stencil->numRefinedVertices() : -1;
    topologyValid = true;
  }

  // ---- per-frame geometry -----------------------------------------------------------------
  static void areaWeightedNormals(const CsrIndex& faces, const Points& p, Points& out) {
    out.setZero();
    for (Index f = 0; f < faces.rows(); ++f) {
      const auto c = faces.row(f);
      Vec3 area = Vec3::Zero();  // Newell: twice the polygon's area vector
      for (size_t k = 0; k < c.size(); ++k) {
        area += p.row(c[k]).transpose().cross(p.row(c[(k + 1) % c.size()]).transpose());
      }
      for (Index v : c) out.row(v) += area.transpose();
    }
    for (Index v = 0; v < out.rows(); ++v) {
      const double length = out.row(v).norm();
      if (length > 0.0) out.row(v) /= length;
    }
  }

  const Points& controlPositions(const Frame& frame) const {
    const Points& p = frame.positions != nullptr ? *frame.positions : frame.mesh->positions();
    if (p.rows() != frame.mesh->numVertices()) {
      throw InvalidInputError("frame positions: " + std::to_string(p.rows()) +
                              " rows for a mesh of " + std::to_string(frame.mesh->numVertices()) +
                              " vertices");
    }
    return p;
  }

  void updateGeometry(const Frame& frame, const Points& control) {
    const Points* surface = &control;
    if (frame.stencil != nullptr) {
      frame.stencil->apply(control, refined);
      surface = &refined;
    }
    if (surfaceFaces->rows() > 0) {
      if (frame.normals == NormalMode::BestPlane) {
        bestPlaneNormals(*surfaceFaces, *surfaceNeighbors, *surface, normals);
      } else {
        areaWeightedNormals(*surfaceFaces, *surface, normals);
      }
    } else {
      normals.setZero();
    }
    const Index n = surfaceVertexCount;
    for (Index v = 0; v < n; ++v) {
      for (int k = 0; k < 3; ++k) {
        positionData[3 * v + k] = static_cast<float>((*surface)(v, k));
        normalData[3 * v + k] = static_cast<float>(normals(v, k));
      }
    }
    // Where sheets meet, each fan's vertex: the shared position, the fan's own normal (the
    // sum of its faces' area vectors).
    for (size_t fan = 0; fan < fanVertex.size(); ++fan) {
      const Index gpu = fanVertex[fan], v = fanSource[fan];
      Vec3 area = Vec3::Zero();
      for (Index k = fanStart[fan]; k < fanStart[fan + 1]; ++k) {
        const auto c = surfaceFaces->row(fanFaces[static_cast<size_t>(k)]);
        for (size_t i = 0; i < c.size(); ++i)
          area +=
              surface->row(c[i]).transpose().cross(surface->row(c[(i + 1) % c.size()]).transpose());
      }
      const double length = area.norm();
      if (length > 0.0) area /= length;
      for (int k = 0; k < 3; ++k) {
        positionData[3 * gpu + k] = static_cast<float>((*surface)(v, k));
        normalData[3 * gpu + k] = static_cast<float>(length > 0.0 ? area[k] : normals(v, k));
      }
    }
    gl.BindBuffer(GL_ARRAY_BUFFER, positionVbo);
    gl.BufferSubData(GL_ARRAY_BUFFER, 0, static_cast<GLsizeiptr>(positionData.size() * 4),
                     positionData.data());
    gl.BindBuffer(GL_ARRAY_BUFFER, normalVbo);
    gl.BufferSubData(GL_ARRAY_BUFFER, 0, static_cast<GLsizeiptr>(normalData.size() * 4),
                     normalData.data());

    const VectorX* values = frame.scalar.values;
    if (values != nullptr) {
      if (values->size() != frame.mesh->numVertices()) {
        throw InvalidInputError("frame scalar " + frame.scalar.name + ": " +
                                std::to_string(values->size()) + " values for " +
                                std::to_string(frame.mesh->numVertices()) + " vertices");
      }
      double lo = std::numeric_limits<double>::infinity();
      double hi = -lo;
      for (Index v = 0; v < values->size(); ++v) {
        const double x = (*values)[v];
        if (!std::isfinite(x)) continue;
        lo = std::min(lo, x);
        hi = std::max(hi, x);
      }
      if (!frame.scalar.autoRange) {
        lo = frame.scalar.min;
        hi = frame.scalar.max;
      }
      if (!std::isfinite(lo) || !std::isfinite(hi)) {
        lo = 0.0;
        hi = 1.0;
      }
      // Values that differ by rounding only (a helix's rest lengths, 0.39515463 in every
      // label of the legend's eight digits) are uniform too: one value, one swatch.
      if (frame.scalar.autoRange && hi - lo <= 1e-9 * std::max(std::abs(lo), std::abs(hi)))
        lo = hi = 0.5 * (lo + hi);
      scalarUniform = frame.scalar.autoRange && hi <= lo;
      scalarValue = lo;
      if (hi <= lo) {  // a uniform field: centre it in a small range (the map's middle colour)
        const double pad = lo == 0.0 ? 1.0 : 0.05 * std::abs(lo);
        lo -= pad;
        hi += pad;
      }
      scalarMin = lo;
      scalarMax = hi;
      const VectorX* drawn = values;
      if (frame.stencil != nullptr) {
        frame.stencil->apply(*values, refinedScalar);
        drawn = &refinedScalar;
      }
      for (Index v = 0; v < n; ++v) scalarData[v] = static_cast<float>((*drawn)[v]);
      for (size_t fan = 0; fan < fanVertex.size(); ++fan)
        scalarData[static_cast<size_t>(fanVertex[fan])] =
            static_cast<float>((*drawn)[fanSource[fan]]);
      gl.BindBuffer(GL_ARRAY_BUFFER, scalarVbo);
      gl.BufferSubData(GL_ARRAY_BUFFER, 0, static_cast<GLsizeiptr>(scalarData.size() * 4),
                       scalarData.data());
    }

    const bool needControl =
        frame.stencil != nullptr && (frame.display.controlWireframe || frame.display.controlPoints);
    if (needControl) {
      for (Index v = 0; v < control.rows(); ++v) {
        for (int k = 0; k < 3; ++k) controlData[3 * v + k] = static_cast<float>(control(v, k));
      }
      gl.BindBuffer(GL_ARRAY_BUFFER, controlVbo);
      gl.BufferSubData(GL_ARRAY_BUFFER, 0, static_cast<GLsizeiptr>(controlData.size() * 4),
                       controlData.data());
    }
  }

  void updateColorMap(ColorMap map) {
    if (colorMapLoaded == static_cast<int>(map)) return;
    std::uint8_t texels[256 * 4];
    for (int i = 0; i < 256; ++i) {
      const Color c = sampleColorMap(map, i / 255.0);
      texels[4 * i + 0] = static_cast<std::uint8_t>(std::lround(c.r * 255.0f));
      texels[4 * i + 1] = static_cast<std::uint8_t>(std::lround(c.g * 255.0f));
      texels[4 * i + 2] = static_cast<std::uint8_t>(std::lround(c.b * 255.0f));
      texels[4 * i + 3] = 255;
    }
    gl.BindTexture(GL_TEXTURE_2D, colorMapTexture);
    gl.PixelStorei(GL_UNPACK_ALIGNMENT, 1);
    gl.TexImage2D(GL_TEXTURE_2D, 0, GL_RGBA8, 256, 1, 0, GL_RGBA, GL_UNSIGNED_BYTE, texels);
    colorMapLoaded = static_cast<int>(map);
  }

  // ---- glyphs -----------------------------------------------------------------------------
  // Outward normal of control vertex v from its faces (zero for a vertex without faces).
  static Vec3 vertexNormal(const Mesh& mesh, const Points& p, Index v) {
    Vec3 sum = Vec3::Zero();
    for (Index f : mesh.vertexFaces(v)) {
      const auto c = mesh.face(f);
      for (size_t k = 0; k < c.size(); ++k) {
        sum += p.row(c[k]).transpose().cross(p.row(c[(k + 1) % c.size()]).transpose());
      }
    }
    const double length = sum.norm();
    return length > 0.0 ? Vec3(sum / length) : Vec3::Zero();
  }

  void pushInstance(GlyphShape shape, const Vec3& x, const Vec3& y, const Vec3& z,
                    const Vec3& origin, Color color) {
    std::vector<float>& d = glyphs[shape].data;
    const Vec3* columns[3] = {&x, &y, &z};
    for (const Vec3* c : columns) {
      d.insert(d.end(), {static_cast<float>(c->x()), static_cast<float>(c->y()),
                         static_cast<float>(c->z()), 0.0f});
    }
    d.insert(d.end(), {static_cast<float>(origin.x()), static_cast<float>(origin.y()),
                       static_cast<float>(origin.z()), 1.0f});
    d.insert(d.end(), {color.r, color.g, color.b, color.a});
  }

  // A straight arrow from `tail` along unit `dir`, `length` long.
  void pushArrow(const Vec3& tail, const Vec3& dir, double length, double size, Color color) {
    const double headLength = 1.1 * size;
    const double headRadius = 0.42 * size;
    const double shaftRadius = 0.15 * size;
    length = std::max(length, 1.6 * headLength);
    Vec3 x;
    Vec3 y;
    basisFrom(dir, x, y);
    const double shaft = length - headLength;
    pushInstance(kCylinder, x * shaftRadius, y * shaftRadius, dir * shaft, tail, color);
    pushInstance(kCone, x * headRadius, y * headRadius, dir * headLength, tail + dir * shaft,
                 color);
  }

  void buildGlyphs(const Frame& frame, const Points& control) {
    for (GlyphBatch& g : glyphs) g.data.clear();
    markerData.clear();
    if (!frame.display.glyphs) return;
    const Mesh& mesh = *frame.mesh;
    const Style& style = frame.style;
    const double g = glyphSize * style.glyphScale;
    const Index count = mesh.numVertices();
    auto checkVertex = [&](Index v, const char* what) {
      if (v < 0 || v >= count) {
        throw InvalidInputError(std::string("frame ") + what + ": vertex " + std::to_string(v) +
                                " is out of range (0.." + std::to_string(count - 1) + ")");
      }
    };
    auto position = [&](Index v) -> Vec3 { return control.row(v).transpose(); };

    for (Index v : frame.pins) {
      checkVertex(v, "pin");
      Vec3 n = vertexNormal(mesh, control, v);
      if (n.isZero()) n = Vec3::UnitZ();
      Vec3 x;
      Vec3 y;
      basisFrom(n, x, y);
      const double h = 0.5 * g;
      pushInstance(kCube, x * h, y * h, n * h, position(v), style.pin);
    }
    for (const NormalPin& pin : frame.normalPins) {
      checkVertex(pin.vertex, "normal pin");
      Vec3 n = pin.normal;
      if (!(n.norm() > 0.0) || !n.allFinite()) n = vertexNormal(mesh, control, pin.vertex);
      if (n.isZero()) n = Vec3::UnitZ();
      n.normalize();
      Vec3 x;
      Vec3 y;
      basisFrom(n, x, y);
      const double h = 0.5 * g;
      // A vertex held in place too keeps its red cube alone (two cubes in one place drew a
      // mottled mix of both colours), and the arrow starts clear of it.
      const bool pinned =
          std::find(frame.pins.begin(), frame.pins.end(), pin.vertex) != frame.pins.end();
      if (!pinned) pushInstance(kCube, x * h, y * h, n * h, position(pin.vertex), style.normalPin);
      pushArrow(position(pin.vertex) + n * normalArrowOffset(g, pinned), n, kNormalArrowLength * g,
                0.9 * g, style.normalPin);
    }
    // Arrow scale: the largest force (and torque) kArrowShare of the diagonal, unless fixed.
    auto scaleFor = [&](const std::vector<VertexVector>& vectors) {
      if (style.forceScale > 0.0) return style.forceScale;
      double largest = 0.0;
      for (const VertexVector& f : vectors) largest = std::max(largest, f.vector.norm());
      return largest > 0.0 ? kArrowShare * diagonal / largest : 0.0;
    };
    const double forceScale = scaleFor(frame.forces);
    for (const VertexVector& f : frame.forces) {
      checkVertex(f.vertex, "force");
      const double magnitude = f.vector.norm();
      if (!(magnitude > 0.0) || !std::isfinite(magnitude)) continue;
      const Vec3 dir = f.vector / magnitude;
      const double length = magnitude * forceScale;
      const Vec3 n = vertexNormal(mesh, control, f.vertex);
      const Vec3 p = position(f.vertex);
      // A push into the surface is drawn with its tip at the vertex, a pull with its tail
      // there, so the arrow stays outside the model.
      const double gap = 0.35 * g;
      if (dir.dot(n) < 0.0) {
        const double drawn = std::max(length, 1.6 * 1.1 * g);
        pushArrow(p - dir * (drawn + gap), dir, drawn, g, style.force);
      } else {
        pushArrow(p + dir * gap, dir, length, g, style.force);
      }
    }
    const double torqueScale = scaleFor(frame.torques);
    for (const VertexVector& t : frame.torques) {
      checkVertex(t.vertex, "torque");
      const double magnitude = t.vector.norm();
      if (!(magnitude > 0.0) || !std::isfinite(magnitude)) continue;
      const Vec3 axis = t.vector / magnitude;
      const Vec3 n = vertexNormal(mesh, control, t.vertex);
      const Vec3 p = position(t.vertex);
      const double length = std::max(magnitude * torqueScale, 3.0 * g);
      // The axis is drawn on the outer side of the surface; the ring's sense of rotation
      // (right-hand rule about `axis`) does not depend on which side that is.
      const Vec3 outward = axis.dot(n) < 0.0 ? Vec3(-axis) : axis;
      if (outward.dot(axis) > 0.0) {
        pushArrow(p, axis, length, g, style.torque);
      } else {
        pushArrow(p - axis * length, axis, length, g, style.torque);
      }
      Vec3 x;
      Vec3 y;
      basisFrom(axis, x, y);
      // The ring grows with the axis so a long torque arrow keeps a readable ring.
      const double radius = std::max(1.6 * g, 0.22 * length);
      const Vec3 centre = p + outward * (0.55 * length);
      pushInstance(kRing, x * radius, y * radius, axis * radius, centre, style.torque);
      // Arrow head at the ring's end, along its tangent.
      const double end = kRingSweep;
      const Vec3 tip = centre + radius * (std::cos(end) * x + std::sin(end) * y);
      const Vec3 tangent = -std::sin(end) * x + std::cos(end) * y;
      Vec3 hx;
      Vec3 hy;
      basisFrom(tangent, hx, hy);
      const double headRadius = 0.42 * g;
      pushInstance(kCone, hx * headRadius, hy * headRadius, tangent * (1.0 * g), tip, style.torque);
    }
    for (const Marker& m : frame.markers) {
      checkVertex(m.vertex, "marker");
      const Vec3 p = position(m.vertex);
      markerData.insert(markerData.end(),
                        {static_cast<float>(p.x()), static_cast<float>(p.y()),
                         static_cast<float>(p.z()), m.color.r, m.color.g, m.color.b, m.color.a});
    }
  }

  void uploadGlyphs() {
    for (GlyphBatch& g : glyphs) {
      const size_t count = g.data.size() / kInstanceFloats;
      if (count == 0) continue;
      gl.BindBuffer(GL_ARRAY_BUFFER, g.instances);
      if (count > g.capacity) {  // grows geometrically: rare after the first frames
        g.capacity = std::max(count, 2 * g.capacity);
        gl.BufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(g.capacity * kInstanceFloats * 4),
                      nullptr, GL_DYNAMIC_DRAW);
      }
      gl.BufferSubData(GL_ARRAY_BUFFER, 0, static_cast<GLsizeiptr>(g.data.size() * 4),
                       g.data.data());
    }
    const size_t markers = markerData.size() / 7;
    if (markers > 0) {
      gl.BindBuffer(GL_ARRAY_BUFFER, markerVbo);
      if (markers > markerCapacity) {
        markerCapacity = std::max(markers, 2 * markerCapacity);
        gl.BufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(markerCapacity * 7 * 4), nullptr,
                      GL_DYNAMIC_DRAW);
      }
      gl.BufferSubData(GL_ARRAY_BUFFER, 0, static_cast<GLsizeiptr>(markerData.size() * 4),
                       markerData.data());
    }
  }

  // ---- overlays ---------------------------------------------------------------------------
  void uploadOverlay(Overlay& overlay) {
    const Image& image = overlay.canvas.image();
    gl.BindTexture(GL_TEXTURE_2D, overlay.texture);
    gl.PixelStorei(GL_UNPACK_ALIGNMENT, 1);
    if (image.width != overlay.textureWidth || image.height != overlay.textureHeight) {
      gl.TexImage2D(GL_TEXTURE_2D, 0, GL_RGBA8, image.width, image.height, 0, GL_RGBA,
                    GL_UNSIGNED_BYTE, image.rgba.data());
      overlay.textureWidth = image.width;
      overlay.textureHeight = image.height;
    } else {
      gl.TexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, image.width, image.height, GL_RGBA, GL_UNSIGNED_BYTE,
                       image.rgba.data());
    }
  }

  static double fontSize(int height) { return std::clamp(0.026 * height, 11.0, 64.0); }

  // The colour bar: the scalar's name above a vertical gradient with five labelled ticks.
  // Rasterized on the CPU only when its text, range, map or the image height change.
  void updateLegend(const Frame& frame, int width, int height) {
    legend.visible = frame.display.legend && frame.scalar.values != nullptr;
    if (!legend.visible) return;
    char key[512];
    std::snprintf(key, sizeof key, "%s|%.9g|%.9g|%d|%d|%d|%d", frame.scalar.name.c_str(), scalarMin,
                  scalarMax, static_cast<int>(frame.scalar.map), height,
                  static_cast<int>(frame.style.text.r * 255.0f), scalarUniform ? 1 : 0);
    const double font = fontSize(height);
    if (legend.key != key) {
      legend.key = key;
      // Whole pixels: the bar's rows must not straddle pixel rows (exact end colours).
      const double pad = std::round(0.75 * font);
      const double barWidth = std::round(0.95 * font);
      const double barHeight = std::round(std::min(0.40 * height, 13.0 * font));
      const double titleHeight = frame.scalar.name.empty() ? 0.0 : 1.7 * font;
      if (scalarUniform) {
        // One value everywhere: one swatch and the value, not a scale of values that are
        // nowhere on the model (a +-5 % range, or -1 to 1 about a zero).
        const std::string label = "uniform, " + formatNumber(scalarValue, 4);
        const double titleWidth = legend.canvas.textWidth(frame.scalar.name, font);
        const double panelWidth =
            std::ceil(std::max(titleWidth,
                               barWidth + 0.8 * font + legend.canvas.textWidth(label, 0.9 * font)) +
                      2 * pad);
        const double panelHeight = std::ceil(pad + titleHeight + barWidth + pad);
        legend.canvas.reset(static_cast<int>(panelWidth), static_cast<int>(panelHeight),
                            Color{1, 1, 1, 0});
        legend.canvas.fillRoundedRect(0, 0, panelWidth, panelHeight, 0.55 * font,
                                      Color{1.0f, 1.0f, 1.0f, 0.80f});
        if (!frame.scalar.name.empty())
          legend.canvas.text(pad, pad, frame.scalar.name, font, frame.style.text);
        const double top = std::round(pad + titleHeight);
        legend.canvas.fillRect(pad, top, pad + barWidth, top + barWidth,
                               sampleColorMap(frame.scalar.map, 0.5));
        legend.canvas.strokeRect(pad, top, pad + barWidth, top + barWidth, 1.0,
                                 Color::hex(0x50586a, 0.9f));
        legend.canvas.text(pad + barWidth + 0.55 * font, top + 0.5 * barWidth, label, 0.9 * font,
                           frame.style.text, Align::Start, Align::Center);
        uploadOverlay(legend);
        const double margin = 0.03 * height;
        legend.x = std::round(width - legend.canvas.width() - margin);
        legend.y = std::round(0.5 * (height - legend.canvas.height()));
        if (legend.canvas.width() > 0.5 * width || legend.canvas.height() > 0.9 * height)
          legend.visible = false;  // as below
        return;
      }
      double labelWidth = 0.0;
      char labels[5][32];
      for (int k = 0; k < 5; ++k) {
        const double v = scalarMin + (scalarMax - scalarMin) * k / 4.0;
        // Enough digits to tell neighbouring labels apart.
        const double spread = std::abs(scalarMax - scalarMin) / 4.0;
        const double magnitude = std::max(std::abs(scalarMin), std::abs(scalarMax));
        // (Up to 10: a range wider than 1e-9 of its values, below which the field counts as
        // uniform (updateScalars), shows its ends apart; at most 8 showed 1e-8 as five 0.5s.)
        const int digits =
            std::clamp(static_cast<int>(std::ceil(std::log10(magnitude / spread))) + 2, 3, 10);
        std::snprintf(labels[k], sizeof labels[k], "%s", formatNumber(v, digits).c_str());
        labelWidth = std::max(labelWidth, legend.canvas.textWidth(labels[k], 0.9 * font));
      }
      const double titleWidth = legend.canvas.textWidth(frame.scalar.name, font);
      const double panelWidth =
          std::ceil(std::max(titleWidth, barWidth + 0.8 * font + labelWidth) + 2 * pad);
      const double panelHeight = std::ceil(pad + titleHeight + barHeight + pad + 0.4 * font);
      legend.canvas.reset(static_cast<int>(panelWidth), static_cast<int>(panelHeight),
                          Color{1, 1, 1, 0});
      legend.canvas.fillRoundedRect(0, 0, panelWidth, panelHeight, 0.55 * font,
                                    Color{1.0f, 1.0f, 1.0f, 0.80f});
      if (!frame.scalar.name.empty()) {
        legend.canvas.text(pad, pad, frame.scalar.name, font, frame.style.text);
      }
      const double barTop = std::round(pad + titleHeight + 0.2 * font);
      for (int row = 0; row < static_cast<int>(barHeight); ++row) {
        const double t = 1.0 - row / std::max(barHeight - 1.0, 1.0);
        legend.canvas.fillRect(pad, barTop + row, pad + barWidth, barTop + row + 1,
                               sampleColorMap(frame.scalar.map, t));
      }
      const Color edge = Color::hex(0x50586a, 0.9f);
      legend.canvas.strokeRect(pad, barTop, pad + barWidth, barTop + barHeight, 1.0, edge);
      for (int k = 0; k < 5; ++k) {
        const double y = barTop + barHeight * (1.0 - k / 4.0);
        legend.canvas.fillRect(pad + barWidth, y - 0.6, pad + barWidth + 0.3 * font, y + 0.6, edge);
        legend.canvas.text(pad + barWidth + 0.55 * font, y, labels[k], 0.9 * font, frame.style.text,
                           Align::Start, Align::Center);
      }
      uploadOverlay(legend);
    }
    const double margin = 0.03 * height;
    legend.x = std::round(width - legend.canvas.width() - margin);  // whole texels
    legend.y = std::round(0.5 * (height - legend.canvas.height()));
    // A legend wider than half the image, or taller than it, would hide the model (and be
    // cut off itself): a narrow or small image goes without.
    if (legend.canvas.width() > 0.5 * width || legend.canvas.height() > 0.9 * height)
      legend.visible = false;
  }

  void updateCaption(const Frame& frame, int width, int height) {
    caption.visible = !frame.caption.empty();
    if (!caption.visible) return;
    char key[512];
    std::snprintf(key, sizeof key, "%s|%d|%d", frame.caption.c_str(), width, height);
    const double font = fontSize(height);
    if (caption.key != key) {
      caption.key = key;
      const double pad = 0.55 * font;
      // A caption wider than the image was cut off mid-word ("t = 8.00 s, c" at 64 x 64): its
      // last clauses (after ", ") go while it does not fit, and a first clause that does not
      // fit goes too, rather than half of it. (Only when the caption changes: no per-frame cost.)
      const double room = width - 2.0 * std::round(0.03 * height);
      std::string_view text = frame.caption;
      double w = std::ceil(caption.canvas.textWidth(text, font) + 2 * pad);
      while (w > room) {
        const size_t cut = text.rfind(", ");
        if (cut == std::string_view::npos) {
          caption.visible = false;
          captionTooWide = true;
          return;
        }
        text = text.substr(0, cut);
        w = std::ceil(caption.canvas.textWidth(text, font) + 2 * pad);
      }
      const double h = std::ceil(font + 2 * pad);
      caption.canvas.reset(static_cast<int>(w), static_cast<int>(h), Color{1, 1, 1, 0});
      caption.canvas.fillRoundedRect(0, 0, w, h, 0.5 * h, Color{1.0f, 1.0f, 1.0f, 0.78f});
      caption.canvas.text(pad, 0.5 * h, text, font, frame.style.text, Align::Start, Align::Center);
      uploadOverlay(caption);
      captionTooWide = false;
    } else if (captionTooWide) {
      caption.visible = false;  // too narrow for any of it (above)
      return;
    }
    caption.x = std::round(0.03 * height);
    caption.y = std::round(height - caption.canvas.height() - 0.03 * height);
  }

  void drawOverlay(const Overlay& overlay, int width, int height, float opacity = 1.0f) {
    if (!overlay.visible) return;
    gl.UseProgram(overlayProgram);
    gl.Uniform1f(uniform(overlayProgram, "uOpacity"), std::clamp(opacity, 0.0f, 1.0f));
    gl.Uniform4f(uniform(overlayProgram, "uRect"), static_cast<float>(overlay.x),
                 static_cast<float>(overlay.y),
                 static_cast<float>(overlay.x + overlay.canvas.width()),
                 static_cast<float>(overlay.y + overlay.canvas.height()));
    gl.Uniform2f(uniform(overlayProgram, "uViewport"), static_cast<float>(width),
                 static_cast<float>(height));
    gl.ActiveTexture(GL_TEXTURE0);
    gl.BindTexture(GL_TEXTURE_2D, overlay.texture);
    gl.Uniform1i(uniform(overlayProgram, "uTexture"), 0);
    gl.BindVertexArray(emptyVao);
    gl.DrawArrays(GL_TRIANGLE_STRIP, 0, 4);
  }

  // ---- drawing ----------------------------------------------------------------------------
  void setCamera(GLuint p, const float* view, const float* projection) {
    gl.UseProgram(p);
    const GLint v = uniform(p, "uView");
    const GLint pr = uniform(p, "uProjection");
    if (v >= 0) gl.UniformMatrix4fv(v, 1, GL_FALSE, view);
    if (pr >= 0) gl.UniformMatrix4fv(pr, 1, GL_FALSE, projection);
  }

  // `byScalar`: coloured by the property through the colour map (the VAO's attribute 2),
  // with `color`'s alpha; the colour map and range are the surface's (updateColorMap).
  void drawLines(GLuint vao, GLsizei count, GLenum mode, float width, float bias, Color color,
                 int w, int h, bool byScalar = false) {
    if (count == 0) return;
    gl.UseProgram(lineProgram);
    gl.Uniform1i(uniform(lineProgram, "uUseScalar"), byScalar ? 1 : 0);
    if (byScalar) {
      gl.Uniform1f(uniform(lineProgram, "uScalarMin"), static_cast<float>(scalarMin));
      gl.Uniform1f(uniform(lineProgram, "uScalarMax"), static_cast<float>(scalarMax));
      gl.ActiveTexture(GL_TEXTURE0);
      gl.BindTexture(GL_TEXTURE_2D, colorMapTexture);
      gl.Uniform1i(uniform(lineProgram, "uColorMap"), 0);
    }
    gl.Uniform2f(uniform(lineProgram, "uViewport"), static_cast<float>(w), static_cast<float>(h));
    gl.Uniform1f(uniform(lineProgram, "uWidth"), width);
    gl.Uniform1f(uniform(lineProgram, "uDepthBias"), bias);
    gl.Uniform4f(uniform(lineProgram, "uColor"), color.r, color.g, color.b, color.a);
    gl.BindVertexArray(vao);
    if (mode == GL_LINES) {
      gl.DrawElements(GL_LINES, count, GL_UNSIGNED_INT, nullptr);
    } else {
      gl.DrawArrays(mode, 0, count);
    }
  }

  void drawScene(const Frame& frame, int w, int h) {
    const Style& style = frame.style;
    const DisplayFlags& show = frame.display;
    const double aspect = static_cast<double>(w) / h;
    const Matrix4f view = frame.camera.viewMatrix().cast<float>();
    const Matrix4f projection = frame.camera.projectionMatrix(aspect).cast<float>();
    const float pixel = static_cast<float>(h) / 720.0f;  // style sizes are for 720 p

    gl.BindFramebuffer(GL_FRAMEBUFFER, renderFbo);
    gl.Viewport(0, 0, w, h);
    gl.Disable(GL_BLEND);
    gl.Disable(GL_CULL_FACE);
    gl.DepthMask(GL_TRUE);
    gl.ClearDepth(1.0);
    gl.ClearColor(style.backgroundTop.r, style.backgroundTop.g, style.backgroundTop.b, 1.0f);
    gl.Clear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);

    // Background gradient (no depth).
    gl.Disable(GL_DEPTH_TEST);
    gl.UseProgram(backgroundProgram);
    gl.Uniform3f(uniform(backgroundProgram, "uTop"), style.backgroundTop.r, style.backgroundTop.g,
                 style.backgroundTop.b);
    gl.Uniform3f(uniform(backgroundProgram, "uBottom"), style.backgroundBottom.r,
                 style.backgroundBottom.g, style.backgroundBottom.b);
    gl.Uniform1i(uniform(backgroundProgram, "uGradient"), show.backgroundGradient ? 1 : 0);
    gl.BindVertexArray(emptyVao);
    gl.DrawArrays(GL_TRIANGLES, 0, 3);
    gl.Enable(GL_DEPTH_TEST);
    gl.DepthFunc(GL_LESS);

    // Surface, pushed back a little so lines drawn on it win the depth test.
    const bool useScalar = frame.scalar.values != nullptr;
    if (show.surface && triangleIndexCount > 0) {
      setCamera(surfaceProgram, view.data(), projection.data());
      gl.Uniform4f(uniform(surfaceProgram, "uColor"), style.surface.r, style.surface.g,
                   style.surface.b, 1.0f);
      gl.Uniform3f(uniform(surfaceProgram, "uBackColor"), style.backSurface.r, style.backSurface.g,
                   style.backSurface.b);
      gl.Uniform1i(uniform(surfaceProgram, "uTwoSided"), 1);
      gl.Uniform1i(uniform(surfaceProgram, "uFlat"), show.flatShading ? 1 : 0);
      gl.Uniform1f(uniform(surfaceProgram, "uSpecular"), useScalar ? 0.18f : 0.28f);
      gl.Uniform1i(uniform(surfaceProgram, "uUseScalar"), useScalar ? 1 : 0);
      gl.Uniform1f(uniform(surfaceProgram, "uScalarMin"), static_cast<float>(scalarMin));
      gl.Uniform1f(uniform(surfaceProgram, "uScalarMax"), static_cast<float>(scalarMax));
      if (useScalar) updateColorMap(frame.scalar.map);
      gl.ActiveTexture(GL_TEXTURE0);
      gl.BindTexture(GL_TEXTURE_2D, colorMapTexture);
      gl.Uniform1i(uniform(surfaceProgram, "uColorMap"), 0);
      gl.Enable(GL_POLYGON_OFFSET_FILL);
      gl.PolygonOffset(1.0f, 1.0f);
      if (cullFace != 0) {
        gl.Enable(GL_CULL_FACE);
        gl.CullFace(cullFace);
      }
      gl.BindVertexArray(surfaceVao);
      gl.DrawElements(GL_TRIANGLES, triangleIndexCount, GL_UNSIGNED_INT, nullptr);
      gl.Disable(GL_CULL_FACE);
      gl.Disable(GL_POLYGON_OFFSET_FILL);
    }

    // Lines (antialiased by the multisampling; blended for translucent colours).
    gl.Enable(GL_BLEND);
    gl.BlendFuncSeparate(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA, GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
    setCamera(lineProgram, view.data(), projection.data());
    const float lineWidth = style.lineWidth * pixel;
    if (show.surface) {
      // Curves (and a solid's inner edges) carry the property colours too: a helix painted
      // with mass was drawn in one colour beside a legend with a scale.
      if (useScalar) updateColorMap(frame.scalar.map);
      drawLines(wireEdgeVao, wireEdgeIndexCount, GL_LINES, 2.6f * lineWidth, 0.0f, style.curve, w,
                h, useScalar);
    }
    if (show.surfaceWireframe) {
      Color c = style.wireframe;
      c.a *= 0.45f;
      drawLines(surfaceEdgeVao, surfaceEdgeIndexCount, GL_LINES, 0.8f * lineWidth, 3e-4f, c, w, h);
    }
    if (show.controlWireframe) {
      drawLines(controlEdgeVao, controlEdgeIndexCount, GL_LINES, lineWidth, 8e-4f, style.wireframe,
                w, h);
    }
    gl.Disable(GL_BLEND);

    // Control points and markers: ray-cast spheres.
    gl.UseProgram(pointProgram);
    setCamera(pointProgram, view.data(), projection.data());
    if (show.controlPoints && frame.mesh->numVertices() > 0) {
      gl.Uniform1f(uniform(pointProgram, "uRadius"), static_cast<float>(pointRadius));
      gl.BindVertexArray(controlPointVao);
      gl.VertexAttrib4f(1, style.controlPoint.r, style.controlPoint.g, style.controlPoint.b, 1.0f);
      gl.DrawArrays(GL_POINTS, 0, frame.mesh->numVertices());
    }
    if (!markerData.empty()) {
      gl.Uniform1f(uniform(pointProgram, "uRadius"),
                   static_cast<float>(0.55 * glyphSize * style.glyphScale));
      gl.BindVertexArray(markerVao);
      gl.DrawArrays(GL_POINTS, 0, static_cast<GLsizei>(markerData.size() / 7));
    }

    // Glyph meshes.
    setCamera(glyphProgram, view.data(), projection.data());
    gl.Uniform1i(uniform(glyphProgram, "uUseScalar"), 0);
    gl.Uniform1i(uniform(glyphProgram, "uTwoSided"), 0);
    gl.Uniform1f(uniform(glyphProgram, "uSpecular"), 0.35f);
    for (const GlyphBatch& g : glyphs) {
      const auto count = static_cast<GLsizei>(g.data.size() / kInstanceFloats);
      if (count == 0) continue;
      gl.BindVertexArray(g.vao);
      gl.DrawElementsInstanced(GL_TRIANGLES, g.indexCount, GL_UNSIGNED_INT, nullptr, count);
    }

    // Brush circle: always visible, a dark halo under a light line.
    if (show.glyphs && frame.brush.visible && frame.brush.radius > 0.0) {
      Vec3 n = frame.brush.normal;
      if (!(n.norm() > 0.0)) n = Vec3::UnitZ();
      n.normalize();
      Vec3 x;
      Vec3 y;
      basisFrom(n, x, y);
      for (int i = 0; i < kBrushSegments; ++i) {
        const double a = 2.0 * std::numbers::pi * i / kBrushSegments;
        const Vec3 p = frame.brush.center +
                       frame.brush.radius * (std::cos(a) * x + std::sin(a) * y) +
                       n * (0.002 * diagonal);
        for (int k = 0; k < 3; ++k) brushData[3 * i + k] = static_cast<float>(p[k]);
      }
      gl.BindBuffer(GL_ARRAY_BUFFER, brushVbo);
      gl.BufferSubData(GL_ARRAY_BUFFER, 0, static_cast<GLsizeiptr>(brushData.size() * 4),
                       brushData.data());
      gl.Disable(GL_DEPTH_TEST);
      gl.Enable(GL_BLEND);
      setCamera(lineProgram, view.data(), projection.data());
      drawLines(brushVao, kBrushSegments, GL_LINE_LOOP, 3.4f * lineWidth, 0.0f,
                Color::hex(0x15181f, 0.55f), w, h);
      drawLines(brushVao, kBrushSegments, GL_LINE_LOOP, 1.6f * lineWidth, 0.0f, style.brush, w, h);
      gl.Disable(GL_BLEND);
      gl.Enable(GL_DEPTH_TEST);
    }

    // Legend and caption on top.
    updateLegend(frame, w, h);
    updateCaption(frame, w, h);
    gl.Disable(GL_DEPTH_TEST);
    gl.Enable(GL_BLEND);
    gl.BlendFuncSeparate(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA, GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
    drawOverlay(legend, w, h, frame.display.legendOpacity);
    drawOverlay(caption, w, h);
    gl.Disable(GL_BLEND);
    gl.Enable(GL_DEPTH_TEST);
    gl.BindVertexArray(0);
  }

  void draw(const Frame& frame, int width, int height, GLuint target) {
    if (frame.mesh == nullptr) throw InvalidInputError("frame: no mesh");
    const Points& control = controlPositions(frame);
    ensureRenderTarget(width, height);
    if (topologyChanged(frame)) rebuildTopology(frame);
    updateGeometry(frame, control);
    buildGlyphs(frame, control);
    uploadGlyphs();
    drawScene(frame, renderWidth, renderHeight);
    // Resolve the samples (or filter the supersampled image) into the target.
    gl.BindFramebuffer(GL_READ_FRAMEBUFFER, renderFbo);
    gl.BindFramebuffer(GL_DRAW_FRAMEBUFFER, target);
    gl.BlitFramebuffer(0, 0, renderWidth, renderHeight, 0, 0, width, height, GL_COLOR_BUFFER_BIT,
                       supersample ? GL_LINEAR : GL_NEAREST);
    gl.BindFramebuffer(GL_FRAMEBUFFER, target);
  }
};

Renderer::Renderer(const GlLoader& loader, const RendererOptions& options)
    : impl_(std::make_unique<Impl>()) {
  try {
    impl_->init(loader, options);
  } catch (...) {
    impl_->destroy();
    throw;
  }
}

Renderer::~Renderer() {
  if (impl_) impl_->destroy();
}

const RenderLimits& Renderer::limits() const {
  return impl_->limits;
}

std::optional<std::array<int, 4>> Renderer::legendRect() const {
  const auto& legend = impl_->legend;
  if (!legend.visible) return std::nullopt;
  // Laid out in the render buffer's pixels: twice the target's when supersampling.
  const double k = impl_->supersample ? 0.5 : 1.0;
  const auto at = [k](double p) { return static_cast<int>(std::floor(k * p)); };
  return std::array<int, 4>{at(legend.x), at(legend.y), at(legend.x + legend.canvas.width()),
                            at(legend.y + legend.canvas.height())};
}

void Renderer::checkSize(int width, int height, std::string_view what) const {
  const RenderLimits& l = impl_->limits;
  const bool positive = width >= 1 && height >= 1;
  if (positive && width <= l.maxWidth && height <= l.maxHeight) return;  // no allocation
  const std::string size =
      std::string(what) + " " + std::to_string(width) + "x" + std::to_string(height);
  if (!positive) throw InvalidInputError(size + ": width and height must be at least 1 pixel");
  throw InvalidInputError(size + ": larger than this OpenGL context allows (" +
                          std::to_string(l.maxWidth) + "x" + std::to_string(l.maxHeight) + ")");
}

void Renderer::draw(const Frame& frame, int width, int height, unsigned targetFramebuffer) {
  checkSize(width, height);
  impl_->draw(frame, width, height, targetFramebuffer);
}

void Renderer::drawToImage(const Frame& frame, int width, int height, Image& image) {
  checkSize(width, height);
  impl_->ensureResolveTarget(width, height);
  impl_->draw(frame, width, height, impl_->resolveFbo);
  auto& gl = impl_->gl;
  auto& rows = impl_->readback;
  rows.resize(static_cast<size_t>(width) * height * 4);
  gl.BindFramebuffer(GL_READ_FRAMEBUFFER, impl_->resolveFbo);
  gl.ReadBuffer(GL_COLOR_ATTACHMENT0);
  gl.PixelStorei(GL_PACK_ALIGNMENT, 1);
  gl.ReadPixels(0, 0, width, height, GL_RGBA, GL_UNSIGNED_BYTE, rows.data());
  // GL rows run bottom to top; images top to bottom. Frames are opaque.
  image.resize(width, height);
  const size_t stride = static_cast<size_t>(width) * 4;
  for (int y = 0; y < height; ++y) {
    std::uint8_t* out = image.rgba.data() + static_cast<size_t>(y) * stride;
    std::memcpy(out, rows.data() + static_cast<size_t>(height - 1 - y) * stride, stride);
    for (size_t i = 3; i < stride; i += 4) out[i] = 255;
  }
}

void Renderer::invalidateTopology() {
  impl_->topologyValid = false;
}

// ---- offscreen --------------------------------------------------------------------------------

OffscreenRenderer::OffscreenRenderer(const RendererOptions& options)
    : context_(std::make_unique<OsMesaContext>()) {
  renderer_ = std::make_unique<Renderer>(context_->loader(), options);
}

OffscreenRenderer::~OffscreenRenderer() {
  if (context_) context_->makeCurrent();
  renderer_.reset();
}

const RenderLimits& OffscreenRenderer::limits() const {
  return renderer_->limits();
}

void OffscreenRenderer::checkSize(int width, int height, std::string_view what) const {
  renderer_->checkSize(width, height, what);
}

const Image& OffscreenRenderer::render(const Frame& frame, int width, int height) {
  context_->makeCurrent();
  renderer_->drawToImage(frame, width, height, image_);
  return image_;
}

void OffscreenRenderer::renderPng(const Frame& frame, int width, int height,
                                  const std::string& path) {
  savePng(path, render(frame, width, height));
}

namespace {

// What frameScene and keepSceneInView keep in view, into `all`: the control points, the
// refined surface and the tips of the force and torque arrows (on either side of their
// vertex: which side depends on the surface normal).
void scenePoints(const Frame& frame, Points& all, Points& refinedPoints) {
  if (frame.mesh == nullptr) throw InvalidInputError("frame: no mesh");
  const Points& control = frame.positions != nullptr ? *frame.positions : frame.mesh->positions();
  const Index refined = frame.stencil != nullptr ? frame.stencil->numRefinedVertices() : 0;
  const double diagonal = frame.mesh->boundingBox().diagonal();
  Index tips = 0;
  if (frame.display.glyphs)
    tips = 2 * static_cast<Index>(frame.forces.size() + frame.torques.size()) +
           static_cast<Index>(frame.normalPins.size());
  all.resize(control.rows() + refined + tips, 3);
  all.topRows(control.rows()) = control;
  if (refined > 0) {
    refinedPoints.resize(refined, 3);
    frame.stencil->apply(control, refinedPoints);
    all.middleRows(control.rows(), refined) = refinedPoints;
  }
  Index next = control.rows() + refined;
  auto arrows = [&](const std::vector<VertexVector>& vectors) {
    double largest = 0.0;
    for (const VertexVector& v : vectors) largest = std::max(largest, v.vector.norm());
    const double scale = frame.style.forceScale > 0.0 ? frame.style.forceScale
                         : largest > 0.0              ? kArrowShare * diagonal / largest
                                                      : 0.0;
    for (const VertexVector& v : vectors) {
      if (v.vertex < 0 || v.vertex >= control.rows() || !v.vector.allFinite()) continue;
      const Vec3 p = control.row(v.vertex).transpose();
      all.row(next++) = (p + v.vector * scale).transpose();
      all.row(next++) = (p - v.vector * scale).transpose();
    }
  };
  if (frame.display.glyphs) {
    arrows(frame.forces);
    arrows(frame.torques);
    // The normal pins' arrow tips (drawn along the pin's normal, a fixed glyph length).
    const double glyph = glyphSizeOf(*frame.mesh) * frame.style.glyphScale;
    for (const NormalPin& pin : frame.normalPins) {
      if (pin.vertex < 0 || pin.vertex >= control.rows() || !(pin.normal.norm() > 0.0) ||
          !pin.normal.allFinite())
        continue;
      const bool pinned =
          std::find(frame.pins.begin(), frame.pins.end(), pin.vertex) != frame.pins.end();
      const double reach = normalArrowOffset(glyph, pinned) + kNormalArrowLength * glyph;
      all.row(next++) = control.row(pin.vertex) + reach * pin.normal.normalized().transpose();
    }
  }
  // Arrows on vertices that do not exist or are not finite are not drawn: the rows kept are
  // the first `next` (conservativeResize only shrinks here, in place).
  all.conservativeResize(next, 3);
}

// The legend takes the right edge (about 0.2 x the height, see updateLegend): the model is
// framed in the rest, its share of the width.
double legendShare(const Frame& frame, double aspect) {
  const bool legend = frame.display.legend && frame.scalar.values != nullptr;
  return legend ? std::min(0.4, 0.21 / aspect) : 0.0;
}

}  // namespace

void frameScene(Frame& frame, double aspect, double margin) {
  Points all, refined;
  scenePoints(frame, all, refined);
  // Framed in the width the legend leaves, and moved left by half the legend's share.
  const double share = legendShare(frame, aspect);
  frame.camera.frame(all, aspect * (1.0 - share), margin);
  if (share > 0.0) frame.camera.pan(0.5 * share * aspect, 0.0);
}

bool keepSceneInView(Frame& frame, double aspect, double margin, Points& all, Points& refined) {
  scenePoints(frame, all, refined);
  const double needed =
      frame.camera.distanceToFit(all, aspect * (1.0 - legendShare(frame, aspect)), margin);
  if (!(needed > frame.camera.distance)) return false;
  frame.camera.distance = needed;
  return true;
}

void parseImageSize(std::string_view text, int& width, int& height, std::string_view what) {
  const std::string s(text);
  const size_t x = s.find_first_of("xX");
  auto fail = [&](const char* reason) {
    throw InvalidInputError(std::string(what) + " " + s + ": " + reason);
  };
  if (x == std::string::npos || x == 0 || x + 1 >= s.size())
    fail("expected WIDTHxHEIGHT, e.g. 1280x720");
  auto number = [&](const std::string& part) {
    if (part.empty() || part.size() > 9 ||
        part.find_first_not_of("0123456789") != std::string::npos) {
      fail("expected WIDTHxHEIGHT with positive whole numbers");
    }
    return std::stoi(part);
  };
  const int w = number(s.substr(0, x));
  const int h = number(s.substr(x + 1));
  // Below 64 pixels the caption, the legend and the glyphs cover the model (a 1 x 1 frame
  // was accepted and held nothing).
  if (w < 64 || h < 64) fail("width and height must be at least 64 pixels");
  width = w;
  height = h;
}

}  // namespace zsculpt::render
