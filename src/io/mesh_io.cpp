#include "zsculpt/io/mesh_io.h"

#include <assimp/BaseImporter.h>
#include <assimp/config.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <assimp/Exporter.hpp>
#include <assimp/Importer.hpp>
#include <bit>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <sstream>
#include <string_view>
#include <unordered_map>
#include <unordered_set>

#include "zsculpt/core/errors.h"
#include "zsculpt/io/atomic_file.h"
#include "zsculpt/io/isolated.h"
#include "zsculpt/mesh/builtin.h"
#include "zsculpt/mesh/orientation.h"

namespace zsculpt::io {

namespace fs = std::filesystem;

namespace {

// No post-processing at all: no Triangulate (polygons stay polygons), no
// JoinIdenticalVertices (it compares normals and UVs too; we weld by position below), no
// FindDegenerates (degenerate faces are dropped after welding, where they are counted).
// Not even ValidateDataStructure: it rejects usable files for things we do not read
// (lights without nodes in OpenGEX, an empty solid next to a good one in STL, RAW
// files); meshFromScene checks every pointer, count and index it uses instead.
constexpr unsigned kImportFlags = 0;

std::string lowercase(std::string text) {
  std::transform(text.begin(), text.end(), text.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return text;
}

std::string lowercaseExtension(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  if (!ext.empty() && ext.front() == '.') ext.erase(0, 1);
  return lowercase(ext);
}

/// Assimp's messages may span lines; ours are one line.
std::string oneLine(std::string text) {
  for (char& c : text)
    if (c == '\n' || c == '\r' || c == '\t') c = ' ';
  const auto first = text.find_first_not_of(' ');
  if (first == std::string::npos) return "unknown error";
  const auto last = text.find_last_not_of(' ');
  return text.substr(first, last - first + 1);
}

void configure(Assimp::Importer& importer) {
  // Skeleton-only files (BVH, MD5 animations) would otherwise get made-up bone meshes.
  importer.SetPropertyBool(AI_CONFIG_IMPORT_NO_SKELETON_MESHES, true);
}

// ---- glTF ---------------------------------------------------------------------------------
// glTF stores triangles only. saveMesh writes polygons as fans marked with the
// FB_ngon_encoding extension (consecutive triangles sharing their first corner form one
// polygon); assimp 5.2 reads them back as loose triangles, so we regroup them here. The
// extension needs consecutive polygons to start at different corners; saveMesh rotates a
// polygon by one corner where needed and lists those in the primitive's extras
// ("zsculpt_rotated_faces") so that the corner order, and so the edge numbering, survives.

constexpr const char* kRotatedFacesKey = "zsculpt_rotated_faces";

/// The JSON of a .gltf file, or the JSON chunk of a .glb (12-byte header, then chunks of
/// length, type, data; the first chunk is the JSON), and whatever follows it.
struct GltfParts {
  std::string json;
  std::string rest;  // .glb: the chunks after the JSON chunk
  bool valid = false;
};

GltfParts splitGltf(std::string_view bytes, bool binary) {
  GltfParts parts;
  if (!binary) {
    parts.json = bytes;
    parts.valid = true;
    return parts;
  }
  if (bytes.size() < 20 || bytes.substr(0, 4) != "glTF" || bytes.substr(16, 4) != "JSON")
    return parts;
  std::uint32_t length = 0;
  std::memcpy(&length, bytes.data() + 12, 4);
  if (length > bytes.size() - 20) return parts;
  parts.json = bytes.substr(20, length);
  parts.rest = bytes.substr(20 + length);
  parts.valid = true;
  return parts;
}

std::string joinGlb(const std::string& json, const std::string& rest) {
  std::string padded = json;
  while (padded.size() % 4 != 0) padded += ' ';  // the JSON chunk is padded with spaces
  auto u32 = [](std::uint32_t v) { return std::string(reinterpret_cast<const char*>(&v), 4); };
  const auto total = static_cast<std::uint32_t>(12 + 8 + padded.size() + rest.size());
  return "glTF" + u32(2) + u32(total) + u32(static_cast<std::uint32_t>(padded.size())) + "JSON" +
         padded + rest;
}

struct GltfPrimitive {
  bool ngon = false;              // an FB_ngon_encoding triangle list
  std::vector<unsigned> rotated;  // polygons saveMesh rotated by one corner
};

/// One entry per glTF primitive, in file order (assimp makes one aiMesh per primitive in
/// that order). Empty when the file uses no FB_ngon_encoding or cannot be read.
std::vector<GltfPrimitive> gltfPrimitives(std::string_view bytes, bool binary) {
  const GltfParts parts = splitGltf(bytes, binary);
  if (!parts.valid) return {};
  const auto json = nlohmann::json::parse(parts.json, nullptr, false);
  if (json.is_discarded() || !json.is_object()) return {};
  const auto used = json.find("extensionsUsed");
  if (used == json.end() || !used->is_array() ||
      std::find(used->begin(), used->end(), "FB_ngon_encoding") == used->end())
    return {};
  const auto meshes = json.find("meshes");
  if (meshes == json.end() || !meshes->is_array()) return {};
  std::vector<GltfPrimitive> primitives;
  for (const auto& mesh : *meshes) {
    if (!mesh.is_object() || !mesh.contains("primitives") || !mesh["primitives"].is_array())
      return {};
    for (const auto& primitive : mesh["primitives"]) {
      GltfPrimitive info;
      if (primitive.is_object()) {
        const auto mode = primitive.find("mode");
        const bool triangles =
            mode == primitive.end() || (mode->is_number_integer() && mode->get<int>() == 4);
        const auto ext = primitive.find("extensions");
        info.ngon = triangles && ext != primitive.end() && ext->is_object() &&
                    ext->contains("FB_ngon_encoding");
        const auto extras = primitive.find("extras");
        if (info.ngon && extras != primitive.end() && extras->is_object()) {
          const auto rotated = extras->find(kRotatedFacesKey);
          if (rotated != extras->end() && rotated->is_array())
            for (const auto& f : *rotated)
              if (f.is_number_unsigned()) info.rotated.push_back(f.get<unsigned>());
        }
      }
      primitives.push_back(std::move(info));
    }
  }
  return primitives;
}

std::vector<GltfPrimitive> gltfPrimitivesOfFile(const std::string& path, const std::string& ext) {
  if (ext != "gltf" && ext != "glb") return {};
  std::ifstream in(path, std::ios::binary);
  std::ostringstream bytes;
  bytes << in.rdbuf();
  return gltfPrimitives(bytes.str(), ext == "glb");
}

// ---- welding ------------------------------------------------------------------------------

/// Vertices welded by exact position: the key is the bit pattern of the three doubles,
/// with -0 folded into +0 (they compare equal, so they must weld, or Mesh would see a
/// zero-length spring).
class Welder {
 public:
  Index add(const Vec3& p) {
    Key key;
    for (int k = 0; k < 3; ++k) key[k] = std::bit_cast<std::uint64_t>(p[k] == 0.0 ? 0.0 : p[k]);
    const auto [it, inserted] = index_.try_emplace(key, static_cast<Index>(positions_.size()));
    if (inserted) positions_.push_back(p);
    return it->second;
  }
  [[nodiscard]] const std::vector<Vec3>& positions() const { return positions_; }

 private:
  using Key = std::array<std::uint64_t, 3>;
  struct KeyHash {
    size_t operator()(const Key& key) const {
      std::uint64_t h = 0x9e3779b97f4a7c15ull;
      for (std::uint64_t v : key) {
        h ^= v + 0x9e3779b97f4a7c15ull + (h << 6) + (h >> 2);
        h *= 0xbf58476d1ce4e5b9ull;
        h ^= h >> 31;
      }
      return static_cast<size_t>(h);
    }
  };
  std::unordered_map<Key, Index, KeyHash> index_;
  std::vector<Vec3> positions_;
};

using Transform = Eigen::Matrix4d;

Transform toEigen(const aiMatrix4x4& m) {
  Transform t;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) t(r, c) = static_cast<double>(m[r][c]);
  return t;
}

/// Every (mesh, global transform) pair of the node tree, depth first in file order; a mesh
/// used by several nodes appears once per node. Meshes no node uses are taken as they are.
std::vector<std::pair<unsigned, Transform>> meshInstances(const aiScene& scene,
                                                          const std::string& name) {
  std::vector<std::pair<unsigned, Transform>> instances;
  std::vector<bool> used(scene.mNumMeshes, false);
  if (scene.mRootNode != nullptr) {
    std::vector<std::pair<const aiNode*, Transform>> stack;
    std::unordered_set<const aiNode*> visited;
    stack.emplace_back(scene.mRootNode, toEigen(scene.mRootNode->mTransformation));
    while (!stack.empty()) {
      auto [node, transform] = stack.back();
      stack.pop_back();
      if (!visited.insert(node).second)
        throw IOError(name + ": the node graph is not a tree (a node is used twice)");
      for (unsigned k = 0; node->mMeshes != nullptr && k < node->mNumMeshes; ++k) {
        const unsigned m = node->mMeshes[k];
        if (m >= scene.mNumMeshes)
          throw IOError(name + ": node '" + node->mName.C_Str() + "' refers to mesh " +
                        std::to_string(m) + ", out of range [0, " +
                        std::to_string(scene.mNumMeshes) + ")");
        used[m] = true;
        instances.emplace_back(m, transform);
      }
      for (unsigned c = node->mNumChildren; node->mChildren != nullptr && c-- > 0;) {
        const aiNode* child = node->mChildren[c];
        if (child != nullptr)
          stack.emplace_back(child, transform * toEigen(child->mTransformation));
      }
    }
  }
  for (unsigned m = 0; m < scene.mNumMeshes; ++m)
    if (!used[m]) instances.emplace_back(m, Transform::Identity());
  return instances;
}

/// Regroups FB_ngon_encoding fans: triangles (a,b,c), (a,c,d), ... become (a,b,c,d,...),
/// and undoes the rotations saveMesh recorded.
std::vector<std::vector<unsigned>> decodeNgons(const aiMesh& mesh, const GltfPrimitive& info) {
  std::vector<std::vector<unsigned>> polygons;
  for (unsigned f = 0; mesh.mFaces != nullptr && f < mesh.mNumFaces; ++f) {
    const aiFace& face = mesh.mFaces[f];
    if (face.mIndices == nullptr) {
      polygons.emplace_back();
      continue;
    }
    if (face.mNumIndices == 3 && !polygons.empty() && polygons.back().size() >= 3 &&
        polygons.back().front() == face.mIndices[0] && polygons.back().back() == face.mIndices[1]) {
      polygons.back().push_back(face.mIndices[2]);
      continue;
    }
    polygons.emplace_back(face.mIndices, face.mIndices + face.mNumIndices);
  }
  for (unsigned f : info.rotated)
    if (f < polygons.size() && polygons[f].size() >= 3)
      std::rotate(polygons[f].begin(), polygons[f].end() - 1, polygons[f].end());
  return polygons;
}

// The up axis a file's format implies (UpAxis::Auto): glTF is Y-up by its specification;
// assimp turns a Collada file to Y-up whatever its <up_axis>; FBX names its own.
UpAxis formatUp(const aiScene& scene, const std::string& name) {
  const std::string ext = lowercaseExtension(name);
  if (ext == "gltf" || ext == "glb" || ext == "dae" || ext == "zae") return UpAxis::PlusY;
  if (ext == "fbx" && scene.mMetaData != nullptr) {
    int axis = 1, sign = 1;
    if (scene.mMetaData->Get("UpAxis", axis) && axis >= 0 && axis <= 2) {
      (void)scene.mMetaData->Get("UpAxisSign", sign);
      const UpAxis plus[] = {UpAxis::PlusX, UpAxis::PlusY, UpAxis::PlusZ};
      const UpAxis minus[] = {UpAxis::MinusX, UpAxis::MinusY, UpAxis::MinusZ};
      return sign < 0 ? minus[axis] : plus[axis];
    }
    return UpAxis::PlusY;  // FBX's default
  }
  return UpAxis::PlusZ;
}

Mesh meshFromScene(const aiScene& scene, const std::string& name, MeshLoadReport* report,
                   const std::vector<GltfPrimitive>& gltf, UpAxis up) {
  MeshLoadReport counts;
  Welder welder;
  std::vector<std::vector<Index>> faces;
  std::vector<std::array<Index, 2>> edges;
  const bool decode = !gltf.empty() && gltf.size() == scene.mNumMeshes;
  std::size_t fileVertices = 0;
  std::vector<Index> welded;
  std::vector<Index> corners;

  for (const auto& [m, transform] : meshInstances(scene, name)) {
    const aiMesh* mesh = scene.mMeshes != nullptr ? scene.mMeshes[m] : nullptr;
    if (mesh == nullptr || mesh->mNumVertices == 0 || mesh->mVertices == nullptr) continue;
    ++counts.meshesMerged;
    fileVertices += mesh->mNumVertices;
    if (fileVertices > static_cast<std::size_t>(std::numeric_limits<Index>::max()))
      throw IOError(name + ": too many vertices");
    const bool identity = transform == Transform::Identity();
    welded.resize(mesh->mNumVertices);
    for (unsigned v = 0; v < mesh->mNumVertices; ++v) {
      const aiVector3D& a = mesh->mVertices[v];
      Vec3 p(a.x, a.y, a.z);
      if (!identity) p = (transform * p.homogeneous()).hnormalized();
      if (!p.allFinite())
        // assimp reads coordinates in single precision: a finite 1e308 in the file comes
        // out infinite, so the message says both.
        throw InvalidInputError(name + ": vertex " + std::to_string(v) + " of mesh " +
                                std::to_string(m) +
                                " has a non-finite coordinate as read (infinite or NaN, or "
                                "beyond the importer's single-precision range, about 3.4e38)");
      welded[v] = welder.add(p);
    }
    // A copy: clang 14 cannot capture a structured binding in a lambda (the fuzz build).
    const unsigned meshIndex = m;
    auto addPrimitive = [&](const unsigned* indices, unsigned count, unsigned f) {
      if (indices == nullptr) count = 0;
      for (unsigned k = 0; k < count; ++k)
        if (indices[k] >= mesh->mNumVertices)
          throw InvalidInputError(name + ": face " + std::to_string(f) + " of mesh " +
                                  std::to_string(meshIndex) + " refers to vertex " +
                                  std::to_string(indices[k]) + ", out of range [0, " +
                                  std::to_string(mesh->mNumVertices) + ")");
      if (count < 2) {
        ++counts.pointsAndLinesDropped;
        return;
      }
      // Corners after welding, with repeats of the previous corner removed (cyclically).
      corners.clear();
      for (unsigned k = 0; k < count; ++k) {
        const Index c = welded[indices[k]];
        if (corners.empty() || corners.back() != c) corners.push_back(c);
      }
      while (corners.size() > 1 && corners.back() == corners.front()) corners.pop_back();
      if (count == 2) {
        if (corners.size() == 2)
          edges.push_back({corners[0], corners[1]});
        else
          ++counts.pointsAndLinesDropped;
        return;
      }
      // A face that still repeats a corner (a bow tie, a slit) has no usable springs.
      bool repeats = corners.size() < 3;
      for (size_t i = 0; i < corners.size() && !repeats; ++i)
        for (size_t j = 0; j < i && !repeats; ++j) repeats = corners[i] == corners[j];
      if (repeats)
        ++counts.degenerateFacesDropped;
      else
        faces.push_back(corners);
    };
    if (decode && gltf[m].ngon) {
      const auto polygons = decodeNgons(*mesh, gltf[m]);
      for (size_t f = 0; f < polygons.size(); ++f)
        addPrimitive(polygons[f].data(), static_cast<unsigned>(polygons[f].size()),
                     static_cast<unsigned>(f));
    } else if (mesh->mFaces != nullptr) {
      for (unsigned f = 0; f < mesh->mNumFaces; ++f)
        addPrimitive(mesh->mFaces[f].mIndices, mesh->mFaces[f].mNumIndices, f);
    }
  }

  const auto& positions = welder.positions();
  counts.verticesWelded = static_cast<Index>(fileVertices - positions.size());
  if (faces.empty() && edges.empty()) {
    std::string reason = "empty mesh: no faces or edges";
    if (fileVertices > 0) reason += " among its " + std::to_string(fileVertices) + " vertices";
    if (counts.degenerateFacesDropped > 0 || counts.pointsAndLinesDropped > 0)
      reason += " (" + std::to_string(counts.degenerateFacesDropped) + " degenerate faces and " +
                std::to_string(counts.pointsAndLinesDropped) + " points or lines dropped)";
    throw IOError(name + ": " + reason);
  }

  // Keep only vertices that a face or an edge uses, in order of first occurrence.
  std::vector<Index> newIndex(positions.size(), -1);
  for (const auto& face : faces)
    for (Index c : face) newIndex[c] = 0;
  for (const auto& edge : edges) newIndex[edge[0]] = newIndex[edge[1]] = 0;
  Index kept = 0;
  for (Index& i : newIndex)
    if (i == 0) i = kept++;
  counts.unusedVerticesDropped = static_cast<Index>(positions.size()) - kept;
  Points points(kept, 3);
  for (size_t v = 0; v < positions.size(); ++v)
    if (newIndex[v] >= 0) points.row(newIndex[v]) = positions[v].transpose();
  for (auto& face : faces)
    for (Index& c : face) c = newIndex[c];
  for (auto& edge : edges) edge = {newIndex[edge[0]], newIndex[edge[1]]};
  counts.up = up == UpAxis::Auto ? formatUp(scene, name) : up;
  turnUpToZ(points, counts.up);
  const OrientationReport orientation = orientFaces(points, faces);
  counts.facesReversed = orientation.facesReversed;
  counts.nonOrientableComponents = orientation.nonOrientableComponents;

  try {
    Mesh result(std::move(points), faces, edges);
    if (report != nullptr) *report = counts;
    return result;
  } catch (const TopologyError& e) {
    throw TopologyError(name + ": " + e.what());
  } catch (const InvalidInputError& e) {
    throw InvalidInputError(name + ": " + e.what());
  }
}

// ---- preflight ------------------------------------------------------------------------------
// Checks for inputs that assimp 5.2 handles badly: OFF and PLY headers declaring more
// elements than the file could hold (assimp reserves memory for them first: the corpus'
// invalid/OutOfMemory.off takes minutes and gigabytes), and OBJ face, line or point
// statements without vertices, which assimp skips silently.

[[noreturn]] void preflightError(const std::string& name, const std::string& reason) {
  throw IOError(name + ": " + reason);
}

void checkDeclaredCount(const std::string& name, std::uintmax_t count, const std::string& what,
                        std::uintmax_t bytesEach, std::uintmax_t size) {
  if (bytesEach > 0 && count > size / bytesEach)
    preflightError(name, "the header declares " + std::to_string(count) + " " + what +
                             ", more than a file of " + std::to_string(size) + " bytes can hold");
}

// Assimp 5.2's OFF reader, walked over the text as it walks it (OFFLoader.cpp and
// ParsingUtils.h): tokens skip spaces, line breaks and '#' comment lines; numbers are
// digits only (strtoul10); a line ends at any of \r \n \f and a run of them is one break,
// so there are no empty lines; \0 ends the text; a line holds at most 4096 characters.
class AssimpOffWalk {
 public:
  explicit AssimpOffWalk(std::string_view text) : text_(text) {}

  void nextToken() {
    skipSpacesAndBreaks();
    while (pos_ < text_.size() && (at() == '#' || at() == '\n' || at() == '\r')) {
      while (pos_ < text_.size() && at() != '\n' && at() != '\r' && at() != '\0') ++pos_;
      skipSpacesAndBreaks();
    }
  }
  /// The characters up to the next space, line break or comment.
  std::string_view word() const {
    const size_t end = text_.find_first_of(" \t\r\n\f#", pos_);
    return text_.substr(pos_, (end == std::string_view::npos ? text_.size() : end) - pos_);
  }
  void skip(size_t count) { pos_ = std::min(text_.size(), pos_ + count); }
  /// strtoul10: the digits here (none: nullopt), saturating far above any real count.
  std::optional<unsigned long long> number() {
    if (pos_ >= text_.size() || !std::isdigit(static_cast<unsigned char>(at())))
      return std::nullopt;
    unsigned long long value = 0;
    for (; pos_ < text_.size() && std::isdigit(static_cast<unsigned char>(at())); ++pos_)
      value =
          std::min<unsigned long long>(10 * value + static_cast<unsigned>(at() - '0'), 1ULL << 62);
    return value;
  }
  /// GetNextLine.
  bool line(std::string_view& out) {
    constexpr size_t kBufferSize = 4096;
    while (pos_ < text_.size() && isBreak(at())) ++pos_;
    if (pos_ >= text_.size() || at() == '\0') return false;
    const size_t begin = pos_;
    while (pos_ < text_.size() && pos_ - begin < kBufferSize && at() != '\0' && !isBreak(at()))
      ++pos_;
    out = text_.substr(begin, pos_ - begin);
    return true;
  }

 private:
  static bool isBreak(char c) { return c == '\r' || c == '\n' || c == '\f'; }
  char at() const { return text_[pos_]; }
  void skipSpacesAndBreaks() {
    while (pos_ < text_.size() && (at() == ' ' || at() == '\t' || at() == '\r' || at() == '\n'))
      ++pos_;
  }
  std::string_view text_;
  size_t pos_ = 0;
};

void preflightOff(std::istream& in, const std::string& name, std::uintmax_t size) {
  const std::string text{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  AssimpOffWalk walk(text);
  walk.nextToken();
  // The header as assimp 5.2's OFF reader reads it, character by character: optional
  // prefixes "ST", "C", "N", "4" and "n" (then a dimension before the counts), then "OFF",
  // which need not end a word: "OFF33" is the keyword and a vertex count of 33 (with a face
  // count of 5535235350 on the next line it made assimp reserve 19 GB:
  // tests/regressions/mesh/off_odd_keyword_huge_count_allocates_gigabytes, found by the
  // mesh fuzzer). Without "OFF" the counts come first.
  const std::string_view first = walk.word();
  size_t prefix = 0;
  auto has = [&](std::string_view p) { return first.substr(prefix, p.size()) == p; };
  if (has("ST")) prefix += 2;
  if (has("C")) ++prefix;
  if (has("N")) ++prefix;
  if (has("4")) ++prefix;
  const bool dimension = has("n");
  if (dimension) ++prefix;
  const bool keyword = has("OFF");
  walk.skip(prefix + (keyword ? 3 : 0));
  walk.nextToken();
  if (keyword && walk.word() == "BINARY") return;
  if (dimension) {
    (void)walk.number();
    walk.nextToken();
  }
  const std::optional<unsigned long long> vertices = walk.number();
  walk.nextToken();
  const std::optional<unsigned long long> faces = walk.number();
  if (!vertices || !faces) return;  // not numbers: assimp will say what is wrong
  // An ASCII vertex ("0 0 0\n") or face ("1 0\n") takes at least 4 bytes.
  checkDeclaredCount(name, *vertices, "vertices", 4, size);
  checkDeclaredCount(name, *faces, "faces", 4, size);
  walk.nextToken();
  (void)walk.number();  // the edge count, or whatever number stands there
  walk.nextToken();
  // Assimp 5.2 skips a face line whose vertex count is 0, not a number or above 9 by
  // decrementing the mesh's face count without moving on; more such lines than declared
  // faces make that count wrap below zero and the reader crash
  // (tests/regressions/mesh/off_zero_count_face_lines_underflow_segv). Count them as it
  // would, on its lines: when the header has no edge count, the first vertex's first number
  // is read as one and the vertex lines start inside that line
  // (.../off_carriage_return_face_lines_segv). Comment lines count as bad too (the safe side).
  std::string_view line;
  unsigned long long vertexLines = 0;
  while (vertexLines < *vertices && walk.line(line)) ++vertexLines;
  // Fewer lines than the header declares: a truncated file, which assimp 5.2 loads without
  // a word (with the faces it found, or vertices made of nothing).
  if (vertexLines < *vertices)
    preflightError(name, "the header declares " + std::to_string(*vertices) +
                             " vertices, the file ends after " + std::to_string(vertexLines) +
                             " (truncated?)");
  unsigned long long good = 0, bad = 0;
  bool linesLeft = true;
  while (good < *faces && (linesLeft = walk.line(line))) {
    AssimpOffWalk face(line);
    face.nextToken();
    const unsigned long long count = face.number().value_or(0);
    if (count >= 1 && count <= 9) {
      // Assimp 5.2 clamps an index past the last vertex to the last vertex and loads a
      // different face without a word: refused here, as OBJ and PLY files are.
      for (unsigned long long k = 0; k < count; ++k) {
        face.nextToken();
        const std::optional<unsigned long long> index = face.number();
        if (index && *index >= *vertices)
          preflightError(name, "face " + std::to_string(good) + ": vertex index " +
                                   std::to_string(*index) + " is out of range (the file has " +
                                   std::to_string(*vertices) + " vertices)");
      }
      ++good;
    } else if (++bad > *faces)
      preflightError(name, "more face lines without a vertex count of 1 to 9 than the " +
                               std::to_string(*faces) + " faces the header declares");
  }
  // (A face line assimp skips lowers the face count it expects: those count as faces here.)
  if (!linesLeft && good + bad < *faces)
    preflightError(name, "the header declares " + std::to_string(*faces) +
                             " faces, the file ends after " + std::to_string(good + bad) +
                             " (truncated?)");
}

// Text from a file for a one-line message: at most `limit` characters, anything but
// printable ASCII shown as '?'.
std::string printable(std::string_view token, size_t limit = 40) {
  std::string out;
  for (char c : token.substr(0, limit)) out += (c >= 0x20 && c < 0x7f) ? c : '?';
  if (token.size() > limit) out += "...";
  return out;
}

// "ply" in any mix of cases: assimp 5.2's PLY reader compares letter by letter with either
// case ("Ply" is a PLY file to it: tests/regressions/mesh/ply_mixed_case_magic_segv).
bool startsWithPlyMagic(std::string_view text) {
  if (text.size() < 3) return false;
  auto lower = [](char c) {
    return static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  };
  return lower(text[0]) == 'p' && lower(text[1]) == 'l' && lower(text[2]) == 'y';
}

// A PLY header as assimp 5.2 reads it (PlyParser.cpp): elements with their 32-bit counts
// and the properties that follow each on consecutive lines; the first line that is not a
// property of a known type (a comment, an unknown type) ends the element's list.
struct PlyType {
  enum Kind { kNone, kUnsigned, kSigned, kReal };
  int bytes = 0;
  Kind kind = kNone;  // kNone: not a type assimp knows
};
struct PlyProperty {
  bool list = false;
  PlyType count, item;
};
struct PlyElement {
  std::string name;
  std::uint32_t count = 0;
  bool parsedAsText = false;  // a semantic assimp reads in ASCII files
  std::vector<PlyProperty> properties;
};

PlyType plyType(const std::string& word) {
  if (word == "char" || word == "int8") return {1, PlyType::kSigned};
  if (word == "uchar" || word == "uint8") return {1, PlyType::kUnsigned};
  if (word == "short" || word == "int16") return {2, PlyType::kSigned};
  if (word == "ushort" || word == "uint16") return {2, PlyType::kUnsigned};
  if (word == "int" || word == "int32") return {4, PlyType::kSigned};
  if (word == "uint" || word == "uint32") return {4, PlyType::kUnsigned};
  if (word == "float" || word == "float32") return {4, PlyType::kReal};
  if (word == "double" || word == "double64" || word == "float64") return {8, PlyType::kReal};
  return {};
}

// A list count as assimp 5.2 turns it into an unsigned int (ConvertTo<unsigned int>): integers
// wrap to 32 bits (a negative one becomes huge); a real one is converted, and one outside
// [0, 2^32) is returned as 2^32 (beyond any file here: refused).
std::uint64_t plyListCount(PlyType type, std::uint64_t bits, double real) {
  if (type.kind == PlyType::kReal) {
    if (!(real >= 0.0 && real < 4294967296.0)) return std::uint64_t{1} << 32;
    return static_cast<std::uint64_t>(real);
  }
  return bits & 0xffffffffu;
}

// Assimp's line reading for ASCII PLY (IOStreamBuffer::getNextLine, 5.2): a line ends at
// '\r', '\n', '\f' or '\0' and that one character is skipped; a line that starts at such a
// character first skips through the next '\n'. The line is copied over the same buffer
// each time, followed by '\n', and the buffer keeps what longer lines left behind it: the
// parser can run past a short line's end into them (SkipSpacesAndLineEnd between
// properties), so they are kept here too. Before the first line the buffer holds what the
// header's lines left in it (shifted by the header parser's erasures): not modelled, only
// its extent, at most the longest header line, which fromHeader marks.
class PlyTextLines {
 public:
  PlyTextLines(std::istream& in, size_t headerLeftover)
      : in_(in), buffer_(headerLeftover + 64, '\0'), fromHeader_(headerLeftover + 64, false) {
    std::fill(fromHeader_.begin(),
              fromHeader_.begin() + static_cast<std::ptrdiff_t>(headerLeftover), true);
  }
  /// The next line into buffer(); false at the end of the text.
  bool next() {
    if (eof()) return false;
    if (isLineEnd(peek())) {
      while (!eof() && get() != '\n') {
      }
      if (eof()) return false;
    }
    size_t length = 0;
    lineStart_ = offset_;
    while (!eof() && !isLineEnd(peek())) {
      if (length + 2 > buffer_.size()) grow();
      fromHeader_[length] = false;
      buffer_[length++] = get();
    }
    lineLength_ = length;
    anyLine_ = anyLine_ || length > 0;
    // A last line with no line end: assimp copies it, writes no '\n' after it and reports
    // it unread, so the rest of the buffer (an earlier, longer line's end) reads on after it
    // ("4" over "000000000 -0.000000" made vertices of 400000000 and face lists of as many
    // items: tests/regressions/mesh/ply_last_line_without_line_end_oom, found by the mesh
    // fuzzer).
    if (eof()) return false;
    if (length + 2 > buffer_.size()) grow();
    fromHeader_[length] = false;
    buffer_[length] = '\n';
    (void)get();
    anyLine_ = true;
    return true;
  }
  /// The line buffer: the line, '\n', then what earlier lines left, then '\0's.
  const std::string& buffer() const { return buffer_; }
  /// Where the line starts in the text, and its length.
  std::uintmax_t lineStart() const { return lineStart_; }
  /// Bytes of the body read so far.
  std::uintmax_t offset() const { return offset_; }
  size_t lineLength() const { return lineLength_; }
  static bool isLineEnd(char c) { return c == '\r' || c == '\n' || c == '\f' || c == '\0'; }
  /// Whether buffer()[i] is still what the header left: its content is not known here.
  bool fromHeader(size_t i) const { return i < fromHeader_.size() && fromHeader_[i]; }
  /// Whether a line was read at all.
  bool anyLine() const { return anyLine_; }

 private:
  void grow() {
    buffer_.resize(2 * buffer_.size() + 64, '\0');
    fromHeader_.resize(buffer_.size(), false);
  }
  bool eof() {
    if (at_ < chunk_.size()) return false;
    chunk_.resize(65536);
    in_.read(chunk_.data(), static_cast<std::streamsize>(chunk_.size()));
    chunk_.resize(static_cast<size_t>(in_.gcount()));
    at_ = 0;
    return chunk_.empty();
  }
  char peek() const { return chunk_[at_]; }
  char get() {
    ++offset_;
    return chunk_[at_++];
  }
  std::istream& in_;
  std::string chunk_;
  size_t at_ = 0;
  std::uintmax_t offset_ = 0, lineStart_ = 0;
  size_t lineLength_ = 0;
  std::string buffer_;
  std::vector<bool> fromHeader_;
  bool anyLine_ = false;
};

// Assimp 5.2 sizes every list by the count it reads before reading the list
// (PropertyInstance::ParseInstance: avList.resize(count), 8 bytes an item): in ASCII the
// count is read as a 32-bit number whatever its declared type, so a count of 74 digits in a
// 488-byte file made it allocate 11 GB and take 90 s
// (tests/regressions/mesh/ply_ascii_list_count_of_74_digits_oom, found by the mesh fuzzer);
// in binary a 4-byte (or negative) count asks for up to 32 GB. The body is walked as assimp
// walks it and every list count checked against the bytes left in the file: a list cannot
// hold more items than that.
void preflightPlyBody(std::istream& in, const std::string& name, std::uintmax_t size,
                      const std::vector<PlyElement>& elements, bool ascii, bool bigEndian,
                      size_t headerLeftover) {
  const std::streamoff start = in.tellg();
  if (start < 0) return;
  const std::uintmax_t bodyStart = static_cast<std::uintmax_t>(start);
  // A list of `count` items of `bytes` bytes (in binary; 1 for text, where an item takes a
  // byte at least) whose count was read at byte `at`.
  auto check = [&](const PlyElement& element, std::uint32_t instance, std::uint64_t count,
                   std::uintmax_t at, std::uintmax_t bytes) {
    const std::uintmax_t left = size > at ? size - at : 0;
    if (count <= left / bytes) return;
    preflightError(name, "the list in " + printable(element.name) + " " + std::to_string(instance) +
                             " (at byte " + std::to_string(at) + ") counts " +
                             std::to_string(count) + " items, more than the " +
                             std::to_string(left) + " bytes left in the file hold");
  };
  if (ascii) {
    // Elements of a known semantic (vertex, face, tristrips, edge, material) are parsed one
    // line per instance (PLY::PropertyInstance::ParseInstance); the others' lines skipped.
    PlyTextLines lines(in, headerLeftover);
    for (const PlyElement& element : elements)
      for (std::uint32_t k = 0; k < element.count; ++k) {
        // At the end of the text assimp 5.2's getNextLine fails and leaves its buffer as it
        // was: every instance still to come parses the last line again. A face count of 31
        // digits in a 326-byte file's last line, read for each face, made it take 3.5 GB
        // (tests/regressions/mesh/ply_last_line_read_again_for_each_face_oom, found by the
        // mesh fuzzer). Each later instance of an element parses alike, so one is walked.
        const std::uintmax_t before = lines.offset();
        const bool ended = !lines.next();
        // Fewer lines than the header declares: a truncated file, which assimp 5.2 loads
        // without a word (the missing faces made up from the last line, or dropped). A last
        // line without a line end is read (ended, but not before reading something): the
        // file is whole if it was the last line declared.
        const bool read = lines.offset() != before;
        const bool last = k + 1 == element.count && &element == &elements.back();
        if (ended && !(read && last))
          preflightError(name, "the header declares " + std::to_string(element.count) + " " +
                                   printable(element.name) + " lines, the file ends after " +
                                   std::to_string(read ? k + 1 : k) + " (truncated?)");
        if (!element.parsedAsText) continue;
        const std::string& b = lines.buffer();
        size_t p = 0;
        // A line with fewer values than the element has properties: assimp 5.2 reads the
        // rest past the line's end, and on the first lines that is what the header left in
        // its line buffer. A header line of digits made the list count of 954437176 items
        // (7.6 GB, 40 s) from a 1.4 kB file (tests/regressions/mesh/
        // ply_short_line_reads_the_header_leftover_oom, found by the mesh fuzzer).
        bool parsing = false;
        auto at = [&](size_t i) {
          if (parsing && lines.fromHeader(i) && !lines.anyLine())
            preflightError(name, "the file ends before the line of " + printable(element.name) +
                                     " " + std::to_string(k) +
                                     ": assimp 5.2 would read it from what the header left in "
                                     "its buffer");
          if (parsing && lines.fromHeader(i))
            preflightError(name, printable(element.name) + " " + std::to_string(k) +
                                     " (the line at byte " +
                                     std::to_string(bodyStart + lines.lineStart()) +
                                     ") has fewer values than properties: assimp 5.2 would "
                                     "read the rest from what the header left in its buffer");
          return i < b.size() ? b[i] : '\0';
        };
        auto skipSpaces = [&] {  // Assimp::SkipSpaces
          while (at(p) == ' ' || at(p) == '\t') ++p;
          return !PlyTextLines::isLineEnd(at(p));
        };
        auto digits = [&] {  // strtoul10
          std::uint64_t value = 0;
          while (at(p) >= '0' && at(p) <= '9')
            value = (value * 10 + static_cast<std::uint64_t>(at(p++) - '0')) & 0xffffffffu;
          return value;
        };
        // One value of the type (PropertyInstance::ParseValue); false where assimp would
        // throw (a real that does not start like a number: the import fails anyway).
        auto value = [&](PlyType type, std::uint64_t& bits, double& real) {
          bits = 0;
          real = 0.0;
          if (type.kind == PlyType::kUnsigned) {
            bits = digits();
          } else if (type.kind == PlyType::kSigned) {
            const bool negative = at(p) == '-';
            if (at(p) == '-' || at(p) == '+') ++p;
            bits = digits();
            if (negative) bits = (0x100000000u - bits) & 0xffffffffu;
          } else {
            // fast_atoreal_move (assimp/fast_atof.h, 5.2): a sign, then "nan", "inf" or
            // "infinity", or an integer part, a fraction after '.' or ',', and an exponent;
            // it throws where no number starts.
            const bool negative = at(p) == '-';
            if (at(p) == '-' || at(p) == '+') ++p;
            auto word = [&](const char* w) {
              for (size_t i = 0; w[i] != '\0'; ++i)
                if (std::tolower(static_cast<unsigned char>(at(p + i))) != w[i]) return false;
              return true;
            };
            if (word("nan")) {
              p += 3;
              return true;
            }
            if (word("inf")) {
              p += word("infinity") ? 8 : 3;
              real = std::numeric_limits<double>::infinity();
              return true;
            }
            auto digit = [&](size_t i) { return at(i) >= '0' && at(i) <= '9'; };
            const bool number = digit(p) || ((at(p) == '.' || at(p) == ',') && digit(p + 1));
            if (!number) return false;
            // strtoul10_64: where the digits overflow 64 bits it returns 0 and leaves the
            // cursor where it was, so the next properties read the same digits again, and a
            // list count reads them as 32 bits
            // (tests/data/io/ply_vertex_list_count_of_21_digits_oom.ply: a 6.6 GB list).
            // Otherwise the cursor moves past all the digits, of which the value takes the
            // first `most` (all when `most` is 0).
            auto unsignedDigits = [&](std::uint64_t& out, int most) {
              std::uint64_t v = 0;
              int n = 0;
              for (size_t i = p; digit(i) && (most == 0 || n < most); ++i, ++n) {
                const std::uint64_t next = v * 10 + static_cast<std::uint64_t>(at(i) - '0');
                if (next < v) {
                  out = 0;
                  return 0;  // no digit consumed
                }
                v = next;
              }
              out = v;
              while (digit(p)) ++p;
              return n;
            };
            std::uint64_t whole = 0;
            if (at(p) != '.' && at(p) != ',') (void)unsignedDigits(whole, 0);
            double f = static_cast<double>(whole);
            if ((at(p) == '.' || at(p) == ',') && digit(p + 1)) {
              ++p;
              std::uint64_t fraction = 0;
              const int n = unsignedDigits(fraction, 15);
              f += static_cast<double>(fraction) * std::pow(10.0, -n);
            } else if (at(p) == '.') {
              ++p;  // "1." is 1: assimp eats a trailing dot (not a trailing comma)
            }
            if (at(p) == 'e' || at(p) == 'E') {
              ++p;
              const bool negativeExponent = at(p) == '-';
              if (at(p) == '-' || at(p) == '+') ++p;
              if (!digit(p)) return false;  // strtoul10_64 throws: the import fails
              std::uint64_t exponent = 0;
              (void)unsignedDigits(exponent, 0);  // an overflowing one stays unread
              f *= std::pow(10.0, negativeExponent ? -static_cast<double>(exponent)
                                                   : static_cast<double>(exponent));
            }
            real = negative ? -f : f;
          }
          return true;
        };
        for (const PlyProperty& property : element.properties) {
          parsing = true;
          if (!skipSpaces()) {
            parsing = false;
            continue;  // "Unable to parse property instance": the next one
          }
          std::uint64_t bits = 0;
          double real = 0.0;
          if (!value(property.list ? property.count : property.item, bits, real)) return;
          if (property.list) {
            const std::uint64_t count = plyListCount(property.count, bits, real);
            // (Past the line's end the bytes are an earlier line's: the end is then named.)
            check(element, k, count,
                  bodyStart + lines.lineStart() + std::min(p, lines.lineLength()), 1);
            bool stopped = false;
            for (std::uint64_t item = 0; item < count && !stopped; ++item) {
              if (!skipSpaces()) {
                stopped = true;
                break;
              }
              const size_t before = p;
              if (!value(property.item, bits, real)) return;
              if (p == before) break;  // no digits: the rest of the list reads nothing too
            }
            if (stopped) {
              parsing = false;
              continue;  // ParseInstance returned false: no line-end skip
            }
          }
          // SkipSpacesAndLineEnd: spaces and line ends, up to a '\0'. (Past the last
          // property it may run into the header's leftovers harmlessly: the next line
          // starts over.)
          parsing = false;
          while (at(p) == ' ' || at(p) == '\t' || at(p) == '\r' || at(p) == '\n') ++p;
        }
        if (ended) break;  // the element's other instances: the same line, the same walk
      }
    return;
  }
  // Binary: every element, each property at its size; a list's count in its own type. The
  // stream moves forward only (ignore for short skips: a seek may cost a system call).
  std::uintmax_t at = bodyStart;
  auto advance = [&](std::uintmax_t bytes) {
    at += bytes;
    if (bytes > (1u << 20)) {
      in.seekg(static_cast<std::streamoff>(at));
    } else if (bytes > 0) {
      in.ignore(static_cast<std::streamsize>(bytes));
    }
  };
  for (const PlyElement& element : elements) {
    bool hasList = false;
    std::uintmax_t rowBytes = 0;
    for (const PlyProperty& property : element.properties) {
      hasList = hasList || property.list;
      rowBytes += static_cast<std::uintmax_t>(property.item.bytes);
    }
    if (!hasList) {  // fixed-size rows: skip them at once
      const std::uintmax_t bytes = rowBytes * element.count;
      if (bytes > size - std::min(size, at)) return;  // assimp says the file is corrupt
      advance(bytes);
      continue;
    }
    for (std::uint32_t k = 0; k < element.count; ++k)
      for (const PlyProperty& property : element.properties) {
        if (!property.list) {
          advance(static_cast<std::uintmax_t>(property.item.bytes));
          continue;
        }
        unsigned char raw[8] = {0, 0, 0, 0, 0, 0, 0, 0};
        const int n = property.count.bytes;
        if (n < 1 || n > 8 || !in.read(reinterpret_cast<char*>(raw), n)) return;
        std::uint64_t bits = 0;
        for (int i = 0; i < n; ++i)
          bits |= std::uint64_t{raw[bigEndian ? n - 1 - i : i]} << (8 * i);
        double real = 0.0;
        if (property.count.kind == PlyType::kSigned && (bits >> (8 * n - 1)) != 0)
          bits |= ~std::uint64_t{0} << (8 * n);  // sign-extended
        if (property.count.kind == PlyType::kReal) {
          if (n == 4) {
            float f = 0.0f;
            const auto b32 = static_cast<std::uint32_t>(bits);
            std::memcpy(&f, &b32, 4);
            real = f;
          } else {
            std::memcpy(&real, &bits, 8);
          }
        }
        const std::uint64_t count = plyListCount(property.count, bits, real);
        // Items of 1 to 8 bytes: compared in items, so that nothing overflows.
        check(element, k, count, at, static_cast<std::uintmax_t>(property.item.bytes));
        at += static_cast<std::uintmax_t>(n);
        advance(count * static_cast<std::uintmax_t>(property.item.bytes));
      }
  }
}

// A header line's words as assimp 5.2's PLY parser separates them: at spaces and tabs only
// (SkipSpaces, TokenMatch). Split as std::istream splits, at any white space, the line
// "property float\vy" was a property to the preflight and ended the element for assimp.
class PlyWords {
 public:
  explicit PlyWords(const std::string& line) : line_(line) {}
  /// The next word into `word`; false (and `word` empty) when the line has no more.
  bool next(std::string& word) {
    while (at_ < line_.size() && (line_[at_] == ' ' || line_[at_] == '\t')) ++at_;
    const size_t start = at_;
    while (at_ < line_.size() && line_[at_] != ' ' && line_[at_] != '\t') ++at_;
    word.assign(line_, start, at_ - start);
    return !word.empty();
  }

 private:
  const std::string& line_;
  size_t at_ = 0;
};

bool endsPlyHeader(const std::string& line) {
  if (line.compare(0, 10, "end_header") != 0) return false;
  const char next = line.size() > 10 ? line[10] : '\n';
  return next == ' ' || next == '\t' || next == '\r' || next == '\n' || next == '\0' ||
         next == '\f';
}

void preflightPly(std::istream& in, const std::string& name, std::uintmax_t size) {
  std::string line;
  bool ascii = false, magic = false, ended = false, bigEndian = false;
  std::uintmax_t total = 0;
  size_t longestLine = 0;  // what the header can leave in assimp's line buffer
  std::vector<PlyElement> elements;
  bool inElement = false;  // property lines still belong to the last element
  // Header lines as assimp 5.2's getNextLine splits them (PlyTextLines): at '\r', '\n', '\f'
  // or '\0', that one character consumed; a line that starts at one first skips through the
  // next '\n'. Split at '\n' only, "property float32 x \0\x02\0..." hid that assimp ends
  // the element at the "\x02" line, and the next property line was counted in
  // (tests/regressions/mesh/ply_property_line_split_at_a_nul_oom, found by the mesh fuzzer).
  bool unterminated = false;  // the last line read ran to the end of the file
  auto nextLine = [&](std::string& out) {
    auto isEnd = [](int c) { return c == '\r' || c == '\n' || c == '\f' || c == '\0'; };
    int c = in.peek();
    if (c == std::char_traits<char>::eof()) return false;
    if (isEnd(c)) {
      while ((c = in.get()) != std::char_traits<char>::eof() && c != '\n') {
      }
      if (in.peek() == std::char_traits<char>::eof()) return false;
    }
    out.clear();
    while ((c = in.peek()) != std::char_traits<char>::eof() && !isEnd(c))
      out.push_back(static_cast<char>(in.get()));
    unterminated = c == std::char_traits<char>::eof();
    if (!unterminated) (void)in.get();
    return true;
  };
  for (int lines = 0; lines < 10000 && nextLine(line); ++lines) {
    longestLine = std::max(longestLine, line.size() + 1);
    // A declaration that stops right after a word assimp 5.2 matched: its TokenMatch takes
    // the character after the word, here the line end, and reads what should follow on past
    // the line's end, from what longer lines left in its buffer. The PLY format requires it.
    auto cutShort = [&](const char* declaration, const char* form) {
      preflightError(name, "the header's line '" + printable(line) + "' is " + declaration +
                               " cut short (" + form + ")");
    };
    PlyWords words(line);
    std::string keyword;
    words.next(keyword);
    if (lines == 0) magic = startsWithPlyMagic(line);
    // Assimp 5.2 ends the header only at "end_header" at the very start of a line followed
    // by a space, a tab or a line end (TokenMatch); "end_header\v..." is not the end for it,
    // and it loops past the end of the file looking for one
    // (tests/data/io/ply_end_header_with_vertical_tab.ply, found by the mesh fuzzer).
    if (keyword == "end_header" && !endsPlyHeader(line)) continue;
    if (keyword == "end_header") {
      ended = true;
      // Assimp 5.2 reads its header lines into one buffer without clearing it and goes on
      // when a line cannot be read. An end_header line the file ends in, with no line end,
      // is read but reported unread, and if an earlier, longer line left a letter in the
      // buffer just after it, the header never ends for assimp: it reads past the end of
      // the file forever (tests/data/io/ply_end_header_at_end_of_file_hangs.ply, found by
      // the mesh fuzzer). No element can have data after it, so it is refused always.
      if (unterminated)
        preflightError(name, "the file ends at its end_header line: no data follows it");
      break;
    }
    if (keyword == "property" && inElement) {
      PlyProperty property;
      std::string word, first, second, propertyName;
      auto propertyCutShort = [&] {
        cutShort("a property declaration",
                 "property <type> <name>, or property list <count type> <item type> <name>");
      };
      if (!words.next(word)) propertyCutShort();
      if (word == "list") {
        if (!words.next(first) || (plyType(first).bytes > 0 && !words.next(second)))
          propertyCutShort();
        property.list = true;
        property.count = plyType(first);
        property.item = plyType(second);
        inElement = property.count.bytes > 0 && property.item.bytes > 0;
      } else {
        property.item = plyType(word);
        inElement = property.item.bytes > 0;
      }
      // A property of a known type with no name: assimp 5.2 then ends the element when
      // spaces follow the type, and otherwise reads on past the line's end into what its
      // earlier lines left in its buffer. Counted in, "property float32 " made the
      // preflight walk a vertex's lines with one value too many, stop at a value that was
      // no number, and miss a face list of 1.2 billion items that assimp went on to read
      // (tests/regressions/mesh/ply_property_without_a_name_oom, found by the mesh
      // fuzzer). The PLY format requires the name.
      if (inElement && !words.next(propertyName)) propertyCutShort();
      if (inElement) elements.back().properties.push_back(property);
      continue;
    }
    inElement = false;
    if (keyword == "format") {
      std::string format;
      words.next(format);
      ascii = format == "ascii";
      bigEndian = format == "binary_big_endian";
      // Assimp 5.2 corrupts its heap on a format it does not know
      // (tests/regressions/mesh/ply_unknown_format_bad_free); the PLY format names three.
      if (magic && !ascii && format != "binary_little_endian" && format != "binary_big_endian")
        preflightError(name, "unknown PLY format '" + printable(format) +
                                 "' (ascii, binary_little_endian or binary_big_endian)");
    } else if (keyword == "element") {
      // Assimp reads the count's leading digits into 32 bits, wrapping: a count of 63
      // digits was 4294967294 vertices to it, read for 40 s from a 1 KB file
      // (tests/regressions/mesh/ply_count_of_63_digits_times_out). Any count beyond 64 bits
      // is refused, the rest checked against the file's size.
      // Its count follows the name only where assimp knows the name (ParseSemantic
      // consumes the word): for any other name it reads the count from the name itself, so
      // "element 6 afec" is six elements of a list to it, "element foo 5" none. Read as the
      // first, an element with a list of 540 million items passed for empty
      // (tests/regressions/mesh/ply_element_named_by_its_count_oom, found by the mesh fuzzer).
      std::string element, digits;
      // "element" or "element vertex" with nothing after (cutShort): "element vertex" cut
      // by a NUL byte became a count of millions to assimp 5.2
      // (tests/regressions/mesh/ply_element_without_a_count_oom, found by the mesh fuzzer).
      auto elementCutShort = [&] { cutShort("an element declaration", "element <name> <count>"); };
      if (!words.next(element)) elementCutShort();
      const bool named = element == "vertex" || element == "face" || element == "tristrips" ||
                         element == "edge" || element == "material";
      if (!named)
        digits = element;
      else if (!words.next(digits))
        elementCutShort();
      std::uintmax_t count = 0;
      for (const char c : digits) {
        if (c < '0' || c > '9') break;
        if (count > (std::numeric_limits<std::uintmax_t>::max() - 9) / 10)
          preflightError(name, "the header's " + printable(element) + " count '" +
                                   printable(digits) + "' is out of range");
        count = 10 * count + static_cast<std::uintmax_t>(c - '0');
      }
      checkDeclaredCount(name, count, element + " elements", 1, size);
      total += count;
      PlyElement parsed;
      parsed.name = element;
      parsed.count = static_cast<std::uint32_t>(count);  // assimp's 32 bits
      parsed.parsedAsText = element == "vertex" || element == "face" || element == "tristrips" ||
                            element == "edge" || element == "material";
      elements.push_back(std::move(parsed));
      inElement = true;
    }
  }
  // Assimp 5.2 loops forever on a PLY header without its end_header line
  // (tests/regressions/mesh/ply_without_end_header_hangs).
  if (magic && !ended) preflightError(name, "the header has no end_header line");
  // An element takes at least one byte in binary and two ("0\n") in ASCII.
  checkDeclaredCount(name, total, "elements in all", ascii ? 2 : 1, size);
  if (!magic || !ended) return;
  // Assimp 5.2 sizes the mesh's vertices by the first vertex element and its faces by the
  // first face or tristrips element, and writes every later one into those arrays at its
  // own instance numbers: past their end when it is longer (a SEGV in Release:
  // tests/regressions/mesh/ply_second_face_element_overflows, found by the mesh fuzzer).
  const std::string* firstVertex = nullptr;
  const std::string* firstFace = nullptr;
  for (const PlyElement& element : elements) {
    const bool vertex = element.name == "vertex";
    if (!vertex && element.name != "face" && element.name != "tristrips") continue;
    const std::string*& first = vertex ? firstVertex : firstFace;
    if (first != nullptr)
      preflightError(name, "the header declares a second " +
                               std::string(vertex ? "vertex" : "face") + " element ('" +
                               element.name + "' after '" + *first +
                               "'), which assimp 5.2 writes into the first one's arrays");
    first = &element.name;
  }
  // The body starts after the end_header line's first line-end character, as assimp reads
  // it ("\r\n" leaves the "\n" in the body): where nextLine stopped.
  preflightPlyBody(in, name, size, elements, ascii, bigEndian, longestLine);
}

void preflightObj(std::istream& in, const std::string& name) {
  // OBJ is text, and a NUL byte in it is damage. Assimp 5.2's OBJ reader corrupted its heap
  // on some such file three times under the mesh fuzzer (an allocator check firing later,
  // the input never found: tests/regressions/mesh/obj_nul_byte*_assimp_heap_corruption);
  // every input at hand then held NUL bytes in its lines. Text in UTF-16 or UTF-32 (a byte
  // order mark first) is converted by assimp and exempt.
  char bom[4] = {1, 1, 1, 1};
  in.read(bom, 4);
  in.clear();
  in.seekg(0);
  const auto u = [&](int i) { return static_cast<unsigned char>(bom[i]); };
  const bool wide = (u(0) == 0xFE && u(1) == 0xFF) || (u(0) == 0xFF && u(1) == 0xFE) ||
                    (u(0) == 0 && u(1) == 0 && u(2) == 0xFE && u(3) == 0xFF);
  std::string line;
  bool continued = false;
  for (size_t number = 1; std::getline(in, line); ++number) {
    if (!wide && line.find('\0') != std::string::npos)
      preflightError(name, "line " + std::to_string(number) + " holds a NUL byte (at column " +
                               std::to_string(line.find('\0') + 1) +
                               "): not OBJ text; the file is damaged");
    const bool continues =
        !line.empty() && (line.back() == '\\' || (line.size() > 1 && line.back() == '\r' &&
                                                  line[line.size() - 2] == '\\'));
    if (!continued) {
      const size_t start = line.find_first_not_of(" \t");
      if (start != std::string::npos && start + 1 <= line.size()) {
        const char kind = line[start];
        const bool statement = (kind == 'f' || kind == 'l' || kind == 'p') &&
                               (start + 1 == line.size() || line[start + 1] == ' ' ||
                                line[start + 1] == '\t' || line[start + 1] == '\r');
        if (statement && !continues &&
            line.find_first_not_of(" \t\r", start + 1) == std::string::npos)
          preflightError(name, "line " + std::to_string(number) + ": '" + std::string(1, kind) +
                                   "' without vertices");
      }
    }
    continued = continues;
  }
}

// Assimp 5.2 allocates a GLB's chunks at the lengths they declare before reading them: a
// 1941-byte file whose JSON chunk claims 4.3 GB made it allocate 4.3 GB (found by the mesh
// fuzzer, tests/regressions/mesh/glb_chunk_length_past_the_file_allocates_gigabytes). The
// binary glTF container (glTF 2.0, 4.4): a 12-byte header (magic, version, total length),
// then chunks of length, type and data. Every length must fit in the file.
// The bytes of standard base64 text (RFC 4648; padding optional); nullopt for any other
// character.
std::optional<std::string> decodeBase64(std::string_view text) {
  std::string out;
  out.reserve(text.size() / 4 * 3 + 3);
  std::uint32_t bits = 0;
  int held = 0;
  for (const char c : text) {
    int value = -1;
    if (c >= 'A' && c <= 'Z')
      value = c - 'A';
    else if (c >= 'a' && c <= 'z')
      value = c - 'a' + 26;
    else if (c >= '0' && c <= '9')
      value = c - '0' + 52;
    else if (c == '+')
      value = 62;
    else if (c == '/')
      value = 63;
    else if (c == '=')
      break;
    else
      return std::nullopt;
    bits = (bits << 6) | static_cast<std::uint32_t>(value);
    held += 6;
    if (held >= 8) {
      held -= 8;
      out += static_cast<char>((bits >> held) & 0xffu);
    }
  }
  return out;
}

void preflightGlbChunks(std::string_view bytes, const std::string& name) {
  if (bytes.size() < 12)
    preflightError(name, "a binary glTF needs a 12-byte header; the file has " +
                             std::to_string(bytes.size()) + " bytes");
  auto u32 = [&](size_t at) {
    std::uint32_t v = 0;
    std::memcpy(&v, bytes.data() + at, 4);
    return std::uint64_t{v};
  };
  const std::uint64_t total = u32(8);
  if (total > bytes.size())
    preflightError(name, "the binary glTF header declares " + std::to_string(total) +
                             " bytes; the file has " + std::to_string(bytes.size()));
  if (u32(4) == 1) {  // glTF 1.0's KHR_binary_glTF: a 20-byte header, then the JSON
    const std::uint64_t content = total >= 20 ? u32(12) : 0;
    if (total < 20 || content > total - 20)
      preflightError(name, "the binary glTF 1.0 header declares " + std::to_string(content) +
                               " bytes of JSON in a file of " + std::to_string(total));
    return;
  }
  // Assimp reads the JSON chunk whatever the total says: a total too small for it (zero, in
  // tests/regressions/mesh/glb_total_length_zero_oom) left a 1.9 GB chunk length unchecked.
  if (total < 20)
    preflightError(name, "the binary glTF header declares " + std::to_string(total) +
                             " bytes, too few for its 12-byte header and a chunk's 8");
  // Chunks are read to the declared total; what follows it is not part of the glTF.
  for (std::uint64_t at = 12, chunk = 0; at < total; ++chunk) {
    if (total - at < 8)
      preflightError(name, "binary glTF chunk " + std::to_string(chunk) + " at byte " +
                               std::to_string(at) + " has no room for its 8-byte header");
    const std::uint64_t length = u32(at);
    if (length > total - at - 8)
      preflightError(name, "binary glTF chunk " + std::to_string(chunk) + " declares " +
                               std::to_string(length) + " bytes; " +
                               std::to_string(total - at - 8) + " remain of the " +
                               std::to_string(total) + " the header declares");
    at += 8 + length;
  }
}

// Assimp 5.2's glTF 2 reader trusts the sizes a file declares: an accessor that reaches
// past its buffer view, or a view past its buffer, makes it copy beyond the buffer it
// allocated (tests/regressions/mesh/gltf_accessor_past_its_buffer_view_overflows, found by
// the mesh fuzzer). Checks what the glTF 2.0 specification requires of accessors (3.6.2.4,
// 5.1, 5.11): every accessor (and sparse part) inside its buffer view, offsets aligned to
// the component size, and views naming buffers that exist.
void preflightGltf(std::istream& in, const std::string& name, bool binary, bool named) {
  const std::string bytes{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  in.clear();
  in.seekg(0);
  if (binary) preflightGlbChunks(bytes, name);
  const GltfParts parts = splitGltf(bytes, binary);
  if (!parts.valid) return;  // assimp's own error names it
  // JSON that does not parse is refused: assimp's parser (rapidjson) takes some of it, such
  // as ill-formed UTF-8 in a key, and its glTF reader then dereferences what is missing (a
  // SEGV on an accessor whose componentType key was garbled:
  // tests/regressions/mesh/glb_garbled_key_segv, found by the mesh fuzzer).
  // (Only for files named .gltf or .glb: other files that merely start with '{' go to their
  // own readers, e.g. a binary STL whose free-text header starts so.)
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(parts.json);
  } catch (const nlohmann::json::exception& e) {  // parse_error, out_of_range (a huge number)
    if (!named) return;
    const std::string_view what = e.what();  // "[json.exception.parse_error.101] parse ..."
    const size_t close = what.find("] ");
    preflightError(name, "its glTF JSON does not parse: " +
                             printable(close == what.npos ? what : what.substr(close + 2), 200));
  }
  if (!j.is_object()) {
    if (!named) return;
    preflightError(name, "its glTF JSON is not an object");
  }
  auto list = [&](const char* key) {
    const auto it = j.find(key);
    return it != j.end() && it->is_array() ? *it : nlohmann::json::array();
  };
  // A non-negative integer field, or fallback when absent; anything else is an error.
  auto number = [&](const nlohmann::json& o, const char* key, std::uint64_t fallback,
                    const std::string& what) -> std::uint64_t {
    const auto it = o.find(key);
    if (it == o.end()) return fallback;
    if (!it->is_number_unsigned())
      preflightError(name, what + ": " + key + " is not a non-negative integer");
    return it->get<std::uint64_t>();
  };
  const nlohmann::json buffers = list("buffers"), views = list("bufferViews");
  std::vector<std::uint64_t> viewLength;
  for (size_t v = 0; v < views.size(); ++v) {
    const std::string what = "buffer view " + std::to_string(v);
    if (!views[v].is_object()) preflightError(name, what + " is not an object");
    const std::uint64_t buffer = number(views[v], "buffer", buffers.size(), what);
    if (buffer >= buffers.size() || !buffers[buffer].is_object())
      preflightError(name,
                     what + " names buffer " + std::to_string(buffer) + ", which does not exist");
    // A view past its buffer is left to assimp, which checks that itself: the corpus has one
    // (glTF2/IncorrectVertexArrays/Cube.gltf, views up to byte 936 of a 514-byte buffer),
    // which it reads without a sanitizer report.
    const std::uint64_t length = number(views[v], "byteLength", 0, what);
    viewLength.push_back(length);
  }
  auto componentSize = [](std::uint64_t type) -> std::uint64_t {
    switch (type) {
      case 5120:
      case 5121:
        return 1;  // (unsigned) byte
      case 5122:
      case 5123:
        return 2;  // (unsigned) short
      case 5125:
      case 5126:
        return 4;  // unsigned int, float
      default:
        return 0;
    }
  };
  auto componentCount = [](const std::string& type) -> std::uint64_t {
    if (type == "SCALAR") return 1;
    if (type == "VEC2") return 2;
    if (type == "VEC3") return 3;
    if (type == "VEC4" || type == "MAT2") return 4;
    if (type == "MAT3") return 9;
    if (type == "MAT4") return 16;
    return 0;
  };
  // `count` elements of `element` bytes from `offset` in view `view`, `stride` apart
  // (0: packed), components of `component` bytes.
  auto fits = [&](const std::string& what, std::uint64_t view, std::uint64_t offset,
                  std::uint64_t count, std::uint64_t element, std::uint64_t component,
                  std::uint64_t stride) {
    if (view >= viewLength.size())
      preflightError(
          name, what + " names buffer view " + std::to_string(view) + ", which does not exist");
    if (component == 0 || element == 0)
      preflightError(name, what + " has an unknown component type or element type");
    if (offset % component != 0)
      preflightError(name, what + ": byteOffset " + std::to_string(offset) +
                               " is not a multiple of its component size " +
                               std::to_string(component));
    if (count == 0) return;
    const std::uint64_t step = stride == 0 ? element : stride;
    const std::uint64_t limit = viewLength[view];
    // offset + step (count - 1) + element <= limit, without overflow.
    if (offset > limit || element > limit - offset ||
        (count - 1) > (limit - offset - element) / step)
      preflightError(name, what + " reads " + std::to_string(count) + " elements of " +
                               std::to_string(element) + " bytes from byte " +
                               std::to_string(offset) + " of buffer view " + std::to_string(view) +
                               ", which has " + std::to_string(limit));
  };
  const nlohmann::json accessors = list("accessors");
  for (size_t a = 0; a < accessors.size(); ++a) {
    const std::string what = "accessor " + std::to_string(a);
    const nlohmann::json& acc = accessors[a];
    if (!acc.is_object()) preflightError(name, what + " is not an object");
    const std::uint64_t component = componentSize(number(acc, "componentType", 0, what));
    const auto type = acc.find("type");
    const std::uint64_t components =
        type != acc.end() && type->is_string() ? componentCount(type->get<std::string>()) : 0;
    const std::uint64_t count = number(acc, "count", 0, what);
    if (acc.contains("bufferView")) {
      const std::uint64_t view = number(acc, "bufferView", 0, what);
      const std::uint64_t stride =
          view < views.size()
              ? number(views[view], "byteStride", 0, "buffer view " + std::to_string(view))
              : 0;
      fits(what, view, number(acc, "byteOffset", 0, what), count, components * component, component,
           stride);
    }
    const auto sparse = acc.find("sparse");
    if (sparse == acc.end()) continue;
    if (!sparse->is_object()) preflightError(name, what + ": sparse is not an object");
    const std::uint64_t sparseCount = number(*sparse, "count", 0, what + " sparse");
    if (sparseCount > count)
      preflightError(name, what + ": sparse count " + std::to_string(sparseCount) +
                               " exceeds the accessor's " + std::to_string(count));
    for (const char* part : {"indices", "values"}) {
      const auto p = sparse->find(part);
      if (p == sparse->end() || !p->is_object())
        preflightError(name, what + ": sparse " + part + " missing");
      const std::string where = what + " sparse " + part;
      const bool indices = std::string(part) == "indices";
      const std::uint64_t size =
          indices ? componentSize(number(*p, "componentType", 0, where)) : component;
      fits(where, number(*p, "bufferView", viewLength.size(), where),
           number(*p, "byteOffset", 0, where), sparseCount, indices ? size : components * component,
           size, 0);
    }
  }
  // A skin's inverseBindMatrices may be left out (glTF 2.0, 5.28: identity matrices then),
  // but assimp 5.2 reads them for every skinned node with a mesh without checking, a null
  // dereference (tests/regressions/mesh/gltf_skin_without_inverse_bind_matrices_segv, found
  // by the mesh fuzzer; Release too).
  const nlohmann::json nodes = list("nodes"), skins = list("skins");
  for (size_t n = 0; n < nodes.size(); ++n) {
    if (!nodes[n].is_object() || !nodes[n].contains("mesh") || !nodes[n].contains("skin")) continue;
    const std::string what = "node " + std::to_string(n);
    const std::uint64_t skin = number(nodes[n], "skin", 0, what);
    if (skin >= skins.size() || !skins[skin].is_object())
      preflightError(name, what + " names skin " + std::to_string(skin) + ", which does not exist");
    const std::string where = "skin " + std::to_string(skin) + " (of " + what + ")";
    if (!skins[skin].contains("inverseBindMatrices"))
      preflightError(name, where +
                               " has no inverseBindMatrices, which assimp 5.2 needs (the "
                               "glTF specification lets them default to identities)");
    const std::uint64_t matrices = number(skins[skin], "inverseBindMatrices", 0, where);
    if (matrices >= accessors.size())
      preflightError(name, where + ": inverseBindMatrices names an accessor that does not exist");
    // One matrix per joint: assimp reads as many as there are joints.
    const auto joints = skins[skin].find("joints");
    const std::uint64_t jointCount =
        joints != skins[skin].end() && joints->is_array() ? joints->size() : 0;
    const std::uint64_t count =
        number(accessors[matrices], "count", 0, "accessor " + std::to_string(matrices));
    if (count < jointCount)
      preflightError(name, where + " has " + std::to_string(jointCount) +
                               " joints but its inverseBindMatrices accessor holds " +
                               std::to_string(count) + " matrices");
  }
  // Assimp 5.2's glTF readers (1.0 and 2.0) count a triangle strip's or fan's faces as
  // count - 2 and a line strip's as count - 1 in 32-bit unsigned arithmetic, count being the
  // indices' or else the positions': a strip with no positions asks for 2^32 - 2 faces
  // (tests/regressions/mesh/glb_triangle_strip_without_positions_oom, found by the mesh
  // fuzzer: 64 GB, bad_alloc in Release, an abort under ASan). Such a primitive draws
  // nothing. Line loops, and strips or fans of 2 vertices, assimp reads without harm.
  const auto accessorsField = j.find("accessors");
  // The count of an accessor named by index (glTF 2.0) or by id (glTF 1.0); 0 if it is not
  // there (assimp names a reference it cannot resolve).
  auto accessorCount = [&](const nlohmann::json& reference, const std::string& what) {
    if (accessorsField == j.end()) return std::uint64_t{0};
    const nlohmann::json* accessor = nullptr;
    if (reference.is_number_unsigned() && accessorsField->is_array() &&
        reference.get<std::uint64_t>() < accessorsField->size())
      accessor = &(*accessorsField)[reference.get<size_t>()];
    else if (reference.is_string() && accessorsField->is_object() &&
             accessorsField->contains(reference.get<std::string>()))
      accessor = &(*accessorsField)[reference.get<std::string>()];
    if (accessor == nullptr || !accessor->is_object()) return std::uint64_t{0};
    return number(*accessor, "count", 0, what);
  };
  // Bytes [offset, offset + length) of buffer `b`: the .glb's BIN chunk, a data: URI, or a
  // file beside the glTF. nullopt when they cannot be had (assimp then judges the file).
  auto bufferRange = [&](std::uint64_t b, std::uint64_t offset,
                         std::uint64_t length) -> std::optional<std::string> {
    if (b >= buffers.size() || !buffers[b].is_object()) return std::nullopt;
    const auto uri = buffers[b].find("uri");
    if (uri == buffers[b].end()) {
      if (!binary || parts.rest.size() < 8 ||
          parts.rest.compare(4, 4, std::string("BIN\0", 4)) != 0)
        return std::nullopt;
      std::uint32_t declared = 0;
      std::memcpy(&declared, parts.rest.data(), 4);
      const std::string_view bin = std::string_view(parts.rest).substr(8, declared);
      if (offset > bin.size() || length > bin.size() - offset) return std::nullopt;
      return std::string(bin.substr(offset, length));
    }
    if (!uri->is_string()) return std::nullopt;
    const std::string& text = uri->get_ref<const std::string&>();
    if (text.rfind("data:", 0) == 0) {
      const size_t comma = text.find(";base64,");
      if (comma == std::string::npos) return std::nullopt;
      const auto decoded = decodeBase64(std::string_view(text).substr(comma + 8));
      if (!decoded || offset > decoded->size() || length > decoded->size() - offset)
        return std::nullopt;
      return decoded->substr(offset, length);
    }
    std::error_code ec;
    const fs::path file = fs::path(name).parent_path() / text;
    const std::uintmax_t size = fs::file_size(file, ec);
    if (ec || offset > size || length > size - offset) return std::nullopt;
    std::ifstream in(file, std::ios::binary);
    std::string out(length, '\0');
    in.seekg(static_cast<std::streamoff>(offset));
    in.read(out.data(), static_cast<std::streamsize>(length));
    if (!in || static_cast<std::uint64_t>(in.gcount()) != length) return std::nullopt;
    return out;
  };
  // Assimp 5.2's glTF 2 reader takes an embedded image's extension from its mimeType as
  // strchr(mimeType, '/') + 1 and compares it with strcmp: a mimeType without '/' makes that
  // the address 1, a SEGV (tests/regressions/mesh/glb_image_mime_type_without_slash_segv,
  // found by the mesh fuzzer).
  const nlohmann::json images = list("images");
  for (size_t i = 0; i < images.size(); ++i) {
    if (!images[i].is_object()) continue;
    const auto mime = images[i].find("mimeType");
    if (mime == images[i].end() || !mime->is_string()) continue;
    const std::string& type = mime->get_ref<const std::string&>();
    const auto uri = images[i].find("uri");
    const bool embedded = images[i].contains("bufferView") ||
                          (uri != images[i].end() && uri->is_string() &&
                           uri->get_ref<const std::string&>().rfind("data:", 0) == 0);
    if (embedded && !type.empty() && type.find('/') == std::string::npos)
      preflightError(name, "image " + std::to_string(i) + " has the mimeType \"" +
                               printable(type, 40) +
                               "\", without a '/', on which assimp 5.2 reads from address 1");
  }
  // Assimp 5.2's glTF 2 reader makes a line loop's (mode 2) faces from consecutive index
  // pairs, dropping those with an index past the positions, and closes the loop with
  // faces[0].mIndices[0]. When it dropped every pair, faces[0] was never made: a null
  // dereference (tests/regressions/mesh/glb_line_loop_with_damaged_indices_segv, found by
  // the mesh fuzzer). With fewer than two indices it reads and writes past its arrays.
  auto refuseFacelessLineLoop = [&](const nlohmann::json& primitive, const std::string& what) {
    const auto indices = primitive.find("indices");
    if (indices == primitive.end() || !indices->is_number_unsigned() ||
        indices->get<std::uint64_t>() >= accessors.size())
      return;
    const nlohmann::json& acc = accessors[indices->get<size_t>()];
    const std::string where = what + " indices";
    const std::uint64_t count = number(acc, "count", 0, where);
    if (count < 2)
      preflightError(name, what + " is a line loop (mode 2) of " + std::to_string(count) +
                               (count == 1 ? " index" : " indices") +
                               ", past which assimp 5.2 reads and writes");
    // Without positions (no "attributes" object, no POSITION in it, or none counted) assimp
    // 5.2 makes the mesh with no vertices, so every pair is out of range whatever the
    // indices (tests/regressions/mesh/glb_line_loop_without_positions_segv, found by the
    // mesh fuzzer: "aptributes").
    const auto attributes = primitive.find("attributes");
    const std::uint64_t vertices =
        attributes != primitive.end() && attributes->is_object() && attributes->contains("POSITION")
            ? accessorCount((*attributes)["POSITION"], what + " POSITION") & 0xffffffffu
            : 0;
    if (vertices == 0)
      preflightError(name, what +
                               " is a line loop (mode 2) without positions: assimp 5.2 "
                               "then closes the loop through a face it never made (a null "
                               "dereference)");
    if (!acc.contains("bufferView")) return;
    // Assimp reads an index as the first min(element size, 4) bytes of its element, whatever
    // the accessor's types: a float VEC3 accessor named as indices gives each x's bits
    // (tests/regressions/mesh/glb_line_loop_over_float_indices_segv).
    const auto typeName = acc.find("type");
    const std::uint64_t element = componentSize(number(acc, "componentType", 0, where)) *
                                  (typeName != acc.end() && typeName->is_string()
                                       ? componentCount(typeName->get<std::string>())
                                       : 0);
    if (element == 0) return;  // refused above when it names a buffer view
    const std::uint64_t component = std::min<std::uint64_t>(element, 4);
    const std::uint64_t view = number(acc, "bufferView", 0, where);
    if (view >= views.size()) return;
    const std::string viewName = "buffer view " + std::to_string(view);
    std::uint64_t stride = number(views[view], "byteStride", 0, viewName);
    if (stride == 0) stride = element;
    // The accessor fits its view (checked above), so this does not overflow.
    const std::optional<std::string> bytes = bufferRange(
        number(views[view], "buffer", buffers.size(), viewName),
        number(views[view], "byteOffset", 0, viewName) + number(acc, "byteOffset", 0, where),
        stride * (count - 1) + component);
    if (!bytes) return;
    auto index = [&](std::uint64_t i) {
      std::uint64_t value = 0;
      for (std::uint64_t k = component; k-- > 0;)  // little-endian
        value = (value << 8) | static_cast<unsigned char>((*bytes)[i * stride + k]);
      return value;
    };
    for (std::uint64_t i = 1; i < count; ++i)
      if (index(i - 1) < vertices && index(i) < vertices) return;  // faces[0] is made
    preflightError(name, what + " is a line loop (mode 2) none of whose " + std::to_string(count) +
                             " indices has a neighbour pair within its " +
                             std::to_string(vertices) +
                             " positions: assimp 5.2 then closes the loop through a face it "
                             "never made (a null dereference)");
  };
  const auto meshesField = j.find("meshes");
  std::vector<std::pair<std::string, const nlohmann::json*>> meshes;
  if (meshesField != j.end() && meshesField->is_array())
    for (size_t m = 0; m < meshesField->size(); ++m)
      meshes.emplace_back(std::to_string(m), &(*meshesField)[m]);
  else if (meshesField != j.end() && meshesField->is_object())
    for (const auto& [key, mesh] : meshesField->items())
      meshes.emplace_back("\"" + key + "\"", &mesh);
  for (const auto& [meshName, mesh] : meshes) {
    if (!mesh->is_object()) continue;
    const auto primitives = mesh->find("primitives");
    if (primitives == mesh->end() || !primitives->is_array()) continue;
    for (size_t p = 0; p < primitives->size(); ++p) {
      const nlohmann::json& primitive = (*primitives)[p];
      if (!primitive.is_object()) continue;
      const std::string what = "mesh " + meshName + " primitive " + std::to_string(p);
      // (A mode that is not an integer is assimp's to judge.)
      const auto modeField = primitive.find("mode");
      const std::uint64_t mode = modeField == primitive.end() || !modeField->is_number_unsigned()
                                     ? 4
                                     : modeField->get<std::uint64_t>();
      if (mode == 2) refuseFacelessLineLoop(primitive, what);
      // Faces: count - lost, in assimp's 32 bits.
      const std::uint64_t lost = mode == 3 ? 1 : mode == 5 || mode == 6 ? 2 : 0;
      if (lost == 0) continue;
      std::uint64_t count = 0;
      std::string of = "positions";
      if (const auto indices = primitive.find("indices"); indices != primitive.end()) {
        count = accessorCount(*indices, what + " indices");
        of = "indices";
      } else if (const auto attributes = primitive.find("attributes");
                 attributes != primitive.end() && attributes->is_object() &&
                 attributes->contains("POSITION")) {
        count = accessorCount((*attributes)["POSITION"], what + " POSITION");
      }
      count &= 0xffffffffu;
      if (count < lost) {
        const char* kind = mode == 3 ? "line strip" : mode == 5 ? "triangle strip" : "triangle fan";
        preflightError(name, what + " is a " + kind + " (mode " + std::to_string(mode) + ") of " +
                                 std::to_string(count) + " " + of + ", which assimp 5.2 reads as " +
                                 std::to_string((count - lost) & 0xffffffffu) + " faces");
      }
    }
  }
}

void preflight(std::istream& in, const std::string& ext, const std::string& name,
               std::uintmax_t size) {
  // Assimp picks a reader by the extension and, when that reader declines, by the content:
  // a PLY or OFF text named .glb reaches the PLY or OFF reader all the same
  // (tests/regressions/mesh/ply_header_named_glb_hangs). So these checks go by content too:
  // the first token of the first 1 KB, past comment lines.
  std::string head(1024, '\0');
  in.read(head.data(), static_cast<std::streamsize>(head.size()));
  head.resize(static_cast<size_t>(in.gcount()));
  in.clear();
  in.seekg(0);
  std::istringstream lines(head);
  std::string line, first;
  while (first.empty() && std::getline(lines, line)) {
    std::istringstream words(line.substr(0, line.find('#')));
    words >> first;
  }
  // A file named .gltf or .glb goes to the glTF readers (refuseForeignReader stops the
  // others), and one that starts with the binary glTF magic is glTF whatever its first line
  // ends with: a GLB whose first "line" ended in "OFF" got the OFF checks instead of the
  // container's, and assimp allocated the 2 GB its JSON chunk claimed
  // (tests/regressions/mesh/glb_first_line_ending_in_off_allocates_gigabytes).
  const bool gltfMagic = head.rfind("glTF", 0) == 0;
  if (ext == "gltf" || ext == "glb" || gltfMagic) {
    preflightGltf(in, name, gltfMagic, ext == "gltf" || ext == "glb");
    return;
  }
  const bool plyText = startsWithPlyMagic(head);
  const bool offText = first.size() >= 3 && first.compare(first.size() - 3, 3, "OFF") == 0;
  if (ext == "ply" || plyText)
    preflightPly(in, name, size);
  else if (ext == "off" || offText)
    preflightOff(in, name, size);
  else if (ext == "obj")
    preflightObj(in, name);
  else if (first.rfind('{', 0) == 0)
    preflightGltf(in, name, false, false);
}

/// Runs an assimp read, turning everything it can throw into IOError.
template <class Read>
const aiScene* guardedRead(const std::string& name, Read&& read) {
  try {
    return read();
  } catch (const std::bad_alloc&) {
    throw IOError(name + ": out of memory while reading");
  } catch (const std::exception& e) {
    throw IOError(name + ": " + oneLine(e.what()));
  }
}

// Assimp 5.2.5 picks a reader as Importer::ReadFile does here: the readers whose extension
// list ends the file's name; the only one, or the first of several whose CanRead accepts the
// content; and when none does (or none is named for the file), the first of all the readers
// whose CanRead accepts it, by a few words of the content whatever the file's name. A
// damaged .glb holding the word "IndexArray" went to the OpenGEX reader that way, which read
// past its buffer (tests/regressions/mesh/glb_with_opengex_words_overreads, found by the
// mesh fuzzer). The same choice is made here first, and refused are: a file named for one
// format whose content would go to the reader of another (that reader is never what the
// name asks for), and OpenGEX text that does not end with its closing brace, on which
// assimp 5.2's OpenDDL parser reads past the end of the text (a .ogex or a file without a
// known extension can still reach it).
void refuseForeignReader(const Assimp::Importer& importer, const std::string& path,
                         const std::string& name) {
  const std::string lower = lowercase(path);
  auto namedFor = [&](Assimp::BaseImporter& reader) {
    std::set<std::string> extensions;
    reader.GetExtensionList(extensions);
    for (const std::string& e : extensions)  // whole endings: Ogre's is "mesh.xml"
      if (lower.size() > e.size() && lower.compare(lower.size() - e.size(), e.size(), e) == 0 &&
          lower[lower.size() - e.size() - 1] == '.')
        return true;
    return false;
  };
  std::vector<Assimp::BaseImporter*> named;
  for (size_t i = 0; i < importer.GetImporterCount(); ++i)
    if (Assimp::BaseImporter* reader = importer.GetImporter(i); reader && namedFor(*reader))
      named.push_back(reader);
  Assimp::IOSystem* io = importer.GetIOHandler();
  Assimp::BaseImporter* chosen = named.size() == 1 ? named.front() : nullptr;
  bool foreign = false;
  try {
    for (size_t k = 0; chosen == nullptr && k < named.size(); ++k)
      if (named[k]->CanRead(path, io, true)) chosen = named[k];
    for (size_t i = 0; chosen == nullptr && i < importer.GetImporterCount(); ++i) {
      Assimp::BaseImporter* reader = importer.GetImporter(i);
      if (reader != nullptr && reader->CanRead(path, io, true)) {
        chosen = reader;
        foreign = !named.empty();
      }
    }
  } catch (const std::exception& e) {
    throw IOError(name + ": " + oneLine(e.what()));
  }
  if (chosen == nullptr) return;  // "No suitable reader found": readFailed names it
  const aiImporterDesc* info = chosen->GetInfo();
  const std::string reader =
      info != nullptr && info->mName != nullptr ? info->mName : "another format";
  // XML is a container many formats share: there the content names the format
  // (XGL/sample_official_asxml.xml of the corpus is read by the XGL reader this way).
  if (foreign && !lower.ends_with(".xml"))
    throw IOError(name + ": not a " + lower.substr(lower.find_last_of('.')) +
                  " file that assimp can read; it would read the content as " + reader);
  std::set<std::string> extensions;
  chosen->GetExtensionList(extensions);
  if (extensions.count("ogex") != 0) {
    std::ifstream in(path, std::ios::binary);
    in.seekg(0, std::ios::end);
    char last = ' ';
    for (std::streamoff at = static_cast<std::streamoff>(in.tellg()) - 1;
         at >= 0 && std::isspace(static_cast<unsigned char>(last)); --at) {
      in.seekg(at);
      in.get(last);
    }
    if (last != '}')
      throw IOError(name + ": OpenGEX text that does not end with '}' (truncated or not OpenGEX)");
  }
}

[[noreturn]] void readFailed(const std::string& name, const std::string& ext,
                             const Assimp::Importer& importer) {
  const std::string error = oneLine(importer.GetErrorString());
  const bool known = !ext.empty() && importer.IsExtensionSupported("." + ext);
  if (!known)
    throw IOError(name + ": unsupported file format" + (ext.empty() ? "" : " '." + ext + "'"));
  if (error.find("No suitable reader found") != std::string::npos)
    throw IOError(name + ": not a ." + ext + " file that assimp can read");
  // Assimp catches an allocation failure inside a reader and reports the exception's name.
  if (error == "std::bad_alloc") throw IOError(name + ": out of memory while reading");
  throw IOError(name + ": " + error);
}

// ---- the import process's answer -----------------------------------------------------------

// Counts and the load report, then positions, face sizes, face corners and the wire edges
// in edge order (Mesh numbers them after the face edges, so the rebuilt mesh numbers its
// edges as the child's did). Native byte order: both ends are this program.
template <class T>
void put(std::string& out, const T* data, std::size_t count) {
  if (count > 0) out.append(reinterpret_cast<const char*>(data), count * sizeof(T));
}

std::string encodeMesh(const Mesh& mesh, const MeshLoadReport& report) {
  std::vector<Index> wires;
  for (Index e = 0; e < mesh.numEdges(); ++e)
    if (mesh.isWireEdge(e)) wires.insert(wires.end(), mesh.edge(e).begin(), mesh.edge(e).end());
  std::vector<Index> sizes(static_cast<std::size_t>(mesh.numFaces()));
  for (Index f = 0; f < mesh.numFaces(); ++f)
    sizes[static_cast<std::size_t>(f)] = static_cast<Index>(mesh.face(f).size());
  const std::int64_t header[] = {mesh.numVertices(),
                                 mesh.numFaces(),
                                 static_cast<std::int64_t>(mesh.faces().indices.size()),
                                 static_cast<std::int64_t>(wires.size() / 2),
                                 report.meshesMerged,
                                 report.verticesWelded,
                                 report.degenerateFacesDropped,
                                 report.pointsAndLinesDropped,
                                 report.unusedVerticesDropped,
                                 report.facesReversed,
                                 report.nonOrientableComponents,
                                 static_cast<std::int64_t>(report.up)};
  std::string out;
  put(out, header, std::size(header));
  put(out, mesh.positions().data(), static_cast<std::size_t>(mesh.positions().size()));
  put(out, sizes.data(), sizes.size());
  put(out, mesh.faces().indices.data(), mesh.faces().indices.size());
  put(out, wires.data(), wires.size());
  return out;
}

Mesh decodeMesh(const std::string& bytes, const std::string& name, MeshLoadReport* report) {
  const std::string garbled = name + ": the import process's answer is garbled";
  std::size_t at = 0;
  auto take = [&](auto* data, std::size_t count) {
    if (count > (bytes.size() - at) / sizeof(*data)) throw IOError(garbled);
    if (count == 0) return;  // data() of an empty vector may be null: no memcpy from it
    std::memcpy(data, bytes.data() + at, count * sizeof(*data));
    at += count * sizeof(*data);
  };
  std::int64_t header[12];
  take(header, std::size(header));
  for (std::int64_t count : header)
    if (count < 0 || count > std::numeric_limits<Index>::max()) throw IOError(garbled);
  const auto count = [&](int k) { return static_cast<std::size_t>(header[k]); };
  if (count(0) > bytes.size()) throw IOError(garbled);  // before allocating
  Points positions(static_cast<Index>(header[0]), 3);
  take(positions.data(), 3 * count(0));
  if (count(1) + count(2) + 2 * count(3) > bytes.size()) throw IOError(garbled);
  std::vector<Index> sizes(count(1)), corners(count(2)), wires(2 * count(3));
  take(sizes.data(), sizes.size());
  take(corners.data(), corners.size());
  take(wires.data(), wires.size());
  if (at != bytes.size()) throw IOError(garbled);
  std::vector<std::vector<Index>> faces(sizes.size());
  std::size_t next = 0;
  for (std::size_t f = 0; f < sizes.size(); ++f) {
    const auto size = static_cast<std::size_t>(sizes[f]);
    if (sizes[f] < 0 || size > corners.size() - next) throw IOError(garbled);
    faces[f].assign(corners.begin() + static_cast<std::ptrdiff_t>(next),
                    corners.begin() + static_cast<std::ptrdiff_t>(next + size));
    next += size;
  }
  std::vector<std::array<Index, 2>> edges(count(3));
  for (std::size_t e = 0; e < edges.size(); ++e) edges[e] = {wires[2 * e], wires[2 * e + 1]};
  if (report != nullptr)
    *report = MeshLoadReport{static_cast<Index>(header[4]), static_cast<Index>(header[5]),
                             static_cast<Index>(header[6]), static_cast<Index>(header[7]),
                             static_cast<Index>(header[8]), static_cast<Index>(header[9]),
                             static_cast<Index>(header[10])};
  if (report != nullptr) {
    if (header[11] > static_cast<std::int64_t>(UpAxis::MinusZ)) throw IOError(garbled);
    report->up = static_cast<UpAxis>(header[11]);
  }
  return Mesh(std::move(positions), faces, edges);
}

// ---- export --------------------------------------------------------------------------------

std::string base64(const void* data, std::size_t size) {
  static constexpr char kDigits[] =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  const auto* bytes = static_cast<const unsigned char*>(data);
  std::string out;
  out.reserve((size + 2) / 3 * 4);
  for (std::size_t i = 0; i < size; i += 3) {
    const unsigned b0 = bytes[i];
    const unsigned b1 = i + 1 < size ? bytes[i + 1] : 0;
    const unsigned b2 = i + 2 < size ? bytes[i + 2] : 0;
    const unsigned triple = (b0 << 16) | (b1 << 8) | b2;
    out += kDigits[(triple >> 18) & 63];
    out += kDigits[(triple >> 12) & 63];
    out += i + 1 < size ? kDigits[(triple >> 6) & 63] : '=';
    out += i + 2 < size ? kDigits[triple & 63] : '=';
  }
  return out;
}

struct ExportFormat {
  std::string id;
  bool triangles = false;  // the format stores triangles only
  bool fans = false;       // write polygons as FB_ngon_encoding fans (glTF)
  bool wires = true;       // the format stores line primitives
  bool yUp = false;        // its readers take +y as up (glTF, Collada): +z is turned to +y
};

ExportFormat exportFormat(const std::string& path) {
  const std::string ext = lowercaseExtension(path);
  // objnomtl: a material file would be a second file, not covered by the atomic write.
  if (ext == "obj") return {"objnomtl"};
  // Binary PLY keeps the float coordinates exactly (assimp's text parser can be one ulp
  // off, e.g. for 2.07085699e-16).
  if (ext == "ply") return {"plyb"};
  // Binary STL keeps the float coordinates exactly.
  if (ext == "stl") return {"stlb", true, false, false};
  if (ext == "gltf") return {"gltf2", true, true, true, true};
  if (ext == "glb") return {"glb2", true, true, true, true};
  // Other assimp 5.2 exporters are not offered: pbrt crashes, FBX and 3MF write files
  // assimp cannot read back, assjson's .json would pass for a scene. Collada round-trips.
  if (ext == "dae") return {"collada", false, false, true, true};
  throw IOError(path + ": unsupported export format" + (ext.empty() ? "" : " '." + ext + "'") +
                " (use .obj, .ply, .stl, .gltf, .glb or .dae)");
}

aiMesh* newAiMesh(const Mesh& mesh, const char* name) {
  auto* out = new aiMesh;
  out->mName = name;
  out->mMaterialIndex = 0;
  out->mNumVertices = static_cast<unsigned>(mesh.numVertices());
  out->mVertices = new aiVector3D[out->mNumVertices];
  const Points& x = mesh.positions();
  for (Index v = 0; v < mesh.numVertices(); ++v)
    out->mVertices[v] = aiVector3D(static_cast<ai_real>(x(v, 0)), static_cast<ai_real>(x(v, 1)),
                                   static_cast<ai_real>(x(v, 2)));
  return out;
}

void setFace(aiFace& face, std::initializer_list<Index> corners) {
  face.mNumIndices = static_cast<unsigned>(corners.size());
  face.mIndices = new unsigned[corners.size()];
  unsigned k = 0;
  for (Index c : corners) face.mIndices[k++] = static_cast<unsigned>(c);
}

/// The faces as one aiMesh: polygons as they are, or (fans) as FB_ngon_encoding
/// triangle fans, each fan starting at a corner other than the previous fan's start.
aiMesh* facesMesh(const Mesh& mesh, bool fans, std::vector<unsigned>& rotated) {
  aiMesh* out = newAiMesh(mesh, "faces");
  std::vector<std::vector<Index>> polygons;
  Index previousStart = -1;
  for (Index f = 0; f < mesh.numFaces(); ++f) {
    const auto face = mesh.face(f);
    std::vector<Index> corners(face.begin(), face.end());
    if (fans && corners.front() == previousStart) {
      std::rotate(corners.begin(), corners.begin() + 1, corners.end());
      rotated.push_back(static_cast<unsigned>(f));
    }
    previousStart = corners.front();
    polygons.push_back(std::move(corners));
  }
  size_t count = 0;
  for (const auto& p : polygons) count += fans ? p.size() - 2 : 1;
  out->mNumFaces = static_cast<unsigned>(count);
  out->mFaces = new aiFace[count];
  unsigned types = 0;
  size_t i = 0;
  for (const auto& p : polygons) {
    if (fans) {
      for (size_t k = 1; k + 1 < p.size(); ++k) setFace(out->mFaces[i++], {p[0], p[k], p[k + 1]});
      types |= aiPrimitiveType_TRIANGLE | aiPrimitiveType_NGONEncodingFlag;
    } else {
      aiFace& face = out->mFaces[i++];
      face.mNumIndices = static_cast<unsigned>(p.size());
      face.mIndices = new unsigned[p.size()];
      std::copy(p.begin(), p.end(), face.mIndices);
      types |= p.size() == 3 ? aiPrimitiveType_TRIANGLE : aiPrimitiveType_POLYGON;
    }
  }
  out->mPrimitiveTypes = types;
  return out;
}

/// Edges that belong to no face (curves, interior edges of solids) as line primitives.
aiMesh* wiresMesh(const Mesh& mesh) {
  aiMesh* out = newAiMesh(mesh, "edges");
  std::vector<Index> wires;
  for (Index e = 0; e < mesh.numEdges(); ++e)
    if (mesh.isWireEdge(e)) wires.push_back(e);
  out->mNumFaces = static_cast<unsigned>(wires.size());
  out->mFaces = new aiFace[wires.size()];
  for (size_t i = 0; i < wires.size(); ++i)
    setFace(out->mFaces[i], {mesh.edge(wires[i])[0], mesh.edge(wires[i])[1]});
  out->mPrimitiveTypes = aiPrimitiveType_LINE;
  return out;
}

/// The mesh's vertices, in order, as point primitives. Some importers (OBJ) renumber
/// vertices in order of use by faces; welding visits this mesh first, so the file keeps
/// our vertex order through a round trip.
aiMesh* pointsMesh(const Mesh& mesh) {
  aiMesh* out = newAiMesh(mesh, "vertices");
  out->mNumFaces = static_cast<unsigned>(mesh.numVertices());
  out->mFaces = new aiFace[out->mNumFaces];
  for (Index v = 0; v < mesh.numVertices(); ++v) setFace(out->mFaces[v], {v});
  out->mPrimitiveTypes = aiPrimitiveType_POINT;
  return out;
}

std::unique_ptr<aiScene> exportScene(const Mesh& mesh, const ExportFormat& format, bool withPoints,
                                     std::vector<unsigned>& rotated) {
  std::vector<aiMesh*> meshes;
  if (withPoints) meshes.push_back(pointsMesh(mesh));
  if (mesh.numFaces() > 0) meshes.push_back(facesMesh(mesh, format.fans, rotated));
  bool hasWires = false;
  for (Index e = 0; e < mesh.numEdges() && !hasWires; ++e) hasWires = mesh.isWireEdge(e);
  if (hasWires && format.wires) meshes.push_back(wiresMesh(mesh));

  auto scene = std::make_unique<aiScene>();
  scene->mNumMaterials = 1;
  scene->mMaterials = new aiMaterial* [1] { new aiMaterial };
  scene->mNumMeshes = static_cast<unsigned>(meshes.size());
  scene->mMeshes = new aiMesh*[meshes.size()];
  std::copy(meshes.begin(), meshes.end(), scene->mMeshes);
  scene->mRootNode = new aiNode("zsculpt");
  scene->mRootNode->mNumMeshes = scene->mNumMeshes;
  scene->mRootNode->mMeshes = new unsigned[meshes.size()];
  for (unsigned m = 0; m < scene->mNumMeshes; ++m) scene->mRootNode->mMeshes[m] = m;
  return scene;
}

/// Finishes assimp's glTF: buffers in side files (extra blobs) are embedded as data URIs
/// so that a .gltf is one self-contained file, written atomically; rotated fans are listed
/// in the extras of the FB_ngon_encoding primitive.
std::string finishGltf(const std::string& path, const aiExportDataBlob& blob, bool binary,
                       const std::vector<unsigned>& rotated) {
  const GltfParts parts =
      splitGltf(std::string_view(static_cast<const char*>(blob.data), blob.size), binary);
  auto json = parts.valid ? nlohmann::ordered_json::parse(parts.json, nullptr, false)
                          : nlohmann::ordered_json(nlohmann::ordered_json::value_t::discarded);
  if (json.is_discarded() || !json.is_object())
    throw IOError(path + ": assimp wrote an unreadable glTF file");
  if (json.contains("buffers") && json["buffers"].is_array()) {
    for (auto& buffer : json["buffers"]) {
      if (!buffer.contains("uri") || !buffer["uri"].is_string()) continue;
      const std::string uri = buffer["uri"].get<std::string>();
      if (uri.rfind("data:", 0) == 0) continue;
      const aiExportDataBlob* side = blob.next;
      const std::string suffix = uri.substr(uri.rfind('.') + 1);
      while (side != nullptr && suffix != side->name.C_Str()) side = side->next;
      if (side == nullptr) throw IOError(path + ": assimp did not produce buffer " + uri);
      buffer["uri"] = "data:application/octet-stream;base64," + base64(side->data, side->size);
    }
  }
  if (!rotated.empty() && json.contains("meshes") && json["meshes"].is_array()) {
    for (auto& mesh : json["meshes"]) {
      if (!mesh.contains("primitives") || !mesh["primitives"].is_array()) continue;
      for (auto& primitive : mesh["primitives"])
        if (primitive.contains("extensions") &&
            primitive["extensions"].contains("FB_ngon_encoding"))
          primitive["extras"][kRotatedFacesKey] = rotated;
    }
  }
  if (binary) return joinGlb(json.dump(), parts.rest);
  return json.dump(2) + "\n";
}

}  // namespace

Mesh loadMesh(const std::string& path, MeshLoadReport* report, UpAxis up) {
  // In a child process (isolated.h): a fault in assimp costs the import, not the session.
  const char* inProcess = std::getenv("ZSCULPT_IMPORT_IN_PROCESS");
  if (inProcess != nullptr && std::string(inProcess) == "1")
    return loadMeshInProcess(path, report, up);
  std::error_code ec;
  const std::uintmax_t size = fs::is_regular_file(path, ec) ? fs::file_size(path, ec) : 0;
  IsolationLimits limits;
  // Generous: a 150 MB OBJ of 1M vertices loads in 12 s and 1.1 GB here
  // (docs/reliability.md); assimp 5.2 has asked for 6.6 GB for a damaged 1.6 kB PLY.
  limits.timeout = std::chrono::seconds(60 + 2 * static_cast<long long>(size >> 20));
  if (const char* timeout = std::getenv("ZSCULPT_IMPORT_TIMEOUT")) {
    char* end = nullptr;
    const double seconds = std::strtod(timeout, &end);
    if (end == timeout || *end != '\0' || !(seconds > 0.0) || seconds > 1e6)
      throw InvalidInputError(std::string("ZSCULPT_IMPORT_TIMEOUT: '") + timeout +
                              "' is not a number of seconds between 0 and 1e6");
    limits.timeout = std::chrono::milliseconds(static_cast<long long>(seconds * 1000.0));
  }
  limits.memoryBytes = std::max<std::uint64_t>(std::uint64_t{2} << 30, 64 * std::uint64_t{size});
  const std::string answer = runIsolated(
      path,
      [&] {
        MeshLoadReport childReport;
        const Mesh mesh = loadMeshInProcess(path, &childReport, up);
        return encodeMesh(mesh, childReport);
      },
      limits);
  return decodeMesh(answer, path, report);
}

Mesh loadMeshInProcess(const std::string& path, MeshLoadReport* report, UpAxis up) {
  std::error_code ec;
  const auto status = fs::status(path, ec);
  if (!fs::exists(status)) throw IOError(path + ": no such file");
  if (fs::is_directory(status)) throw IOError(path + ": is a folder, not a mesh file");
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw IOError(path + ": cannot read: " + std::strerror(errno));
  ::close(fd);
  // Several assimp importers misbehave on empty input; nothing is to be read from it anyway.
  if (fs::is_regular_file(status) && fs::file_size(path, ec) == 0)
    throw IOError(path + ": the file is empty");

  const std::string ext = lowercaseExtension(path);
  {
    std::ifstream in(path, std::ios::binary);
    preflight(in, ext, path, fs::file_size(path, ec));
  }
  Assimp::Importer importer;
  configure(importer);
  refuseForeignReader(importer, path, path);
  const aiScene* scene = guardedRead(path, [&] { return importer.ReadFile(path, kImportFlags); });
  if (scene == nullptr) readFailed(path, ext, importer);
  return meshFromScene(*scene, path, report, gltfPrimitivesOfFile(path, ext), up);
}

Mesh loadMeshFromMemory(const void* data, std::size_t size, const std::string& hint,
                        MeshLoadReport* report, UpAxis up) {
  const std::string name = "<memory>." + hint;
  if (data == nullptr || size == 0) throw IOError(name + ": the data is empty");
  const std::string ext = lowercase(hint);
  {
    std::istringstream in(std::string(static_cast<const char*>(data), size));
    preflight(in, ext, name, size);
  }
  // Assimp reads through a temporary file, as it reads a user's file: its memory reader
  // behaves differently on malformed input (a SEGV in the OBJ reader on
  // tests/regressions/mesh/obj_from_memory_assimp_segv, which the file reader refuses), and
  // what the fuzzers test should be what users meet.
  std::string pattern = (fs::temp_directory_path() / "zsculpt-mesh-XXXXXX.").string() + ext;
  const int suffix = static_cast<int>(ext.size() + 1);
  const int fd = ::mkstemps(pattern.data(), suffix);
  if (fd < 0) throw IOError(name + ": cannot make a temporary file: " + std::strerror(errno));
  struct Remove {
    std::string path;
    ~Remove() { ::unlink(path.c_str()); }
  } remove{pattern};
  {
    const char* bytes = static_cast<const char*>(data);
    std::size_t written = 0;
    while (written < size) {
      const ssize_t n = ::write(fd, bytes + written, size - written);
      if (n <= 0) {
        const int error = errno;
        ::close(fd);
        throw IOError(name + ": cannot write a temporary file: " + std::strerror(error));
      }
      written += static_cast<std::size_t>(n);
    }
    ::close(fd);
  }
  Assimp::Importer importer;
  configure(importer);
  refuseForeignReader(importer, remove.path, name);
  const aiScene* scene =
      guardedRead(name, [&] { return importer.ReadFile(remove.path, kImportFlags); });
  if (scene == nullptr) readFailed(name, ext, importer);
  std::vector<GltfPrimitive> gltf;
  if (ext == "gltf" || ext == "glb")
    gltf = gltfPrimitives(std::string_view(static_cast<const char*>(data), size), ext == "glb");
  return meshFromScene(*scene, name, report, gltf, up);
}

Mesh loadMeshSource(const std::string& source, MeshLoadReport* report, UpAxis up) {
  if (isBuiltinName(source)) {
    Mesh mesh = makeBuiltin(source);
    MeshLoadReport built;
    built.up = up == UpAxis::Auto ? UpAxis::PlusZ : up;
    if (built.up != UpAxis::PlusZ) {
      Points points = mesh.positions();
      turnUpToZ(points, built.up);
      mesh.setPositions(points);
    }
    if (report != nullptr) *report = built;
    return mesh;
  }
  return loadMesh(source, report, up);
}

// The axes by name, in the enum's order: one table both ways.
constexpr const char* kUpAxisNames[] = {"auto", "x", "-x", "y", "-y", "z", "-z"};

UpAxis parseUpAxis(const std::string& text) {
  std::string t = lowercase(text);
  if (!t.empty() && t[0] == '+') t.erase(0, 1);
  for (size_t k = 0; k < std::size(kUpAxisNames); ++k)
    if (t == kUpAxisNames[k]) return static_cast<UpAxis>(k);
  throw InvalidInputError("'" + text + "' is not an axis (auto, x, -x, y, -y, z or -z)");
}

std::string upAxisName(UpAxis up) {
  const auto k = static_cast<size_t>(up);
  return k < std::size(kUpAxisNames) ? kUpAxisNames[k] : "auto";
}

void turnUpToZ(Points& points, UpAxis up) {
  // Each a proper rotation (determinant +1, so windings and volumes keep their sign) that
  // takes the named axis to +z: a quarter turn about x or y, or a half turn about x. 0 - c
  // rather than -c: a zero stays +0, as welding left it.
  for (Index i = 0; i < points.rows(); ++i) {
    const double x = points(i, 0), y = points(i, 1), z = points(i, 2);
    switch (up) {
      case UpAxis::Auto:
      case UpAxis::PlusZ:
        return;
      case UpAxis::PlusY:  // +90 degrees about x
        points.row(i) << x, 0.0 - z, y;
        break;
      case UpAxis::MinusY:  // -90 degrees about x
        points.row(i) << x, z, 0.0 - y;
        break;
      case UpAxis::PlusX:  // -90 degrees about y
        points.row(i) << 0.0 - z, y, x;
        break;
      case UpAxis::MinusX:  // +90 degrees about y
        points.row(i) << z, y, 0.0 - x;
        break;
      case UpAxis::MinusZ:  // 180 degrees about x
        points.row(i) << x, 0.0 - y, 0.0 - z;
        break;
    }
  }
}

void checkMeshOutput(const std::string& path) {
  checkOutputFile(path);  // first: a folder is "is a directory", not an unknown format
  (void)exportFormat(path);
}

void saveMesh(const Mesh& mesh, const std::string& path) {
  const ExportFormat format = exportFormat(path);
  if (format.triangles && !format.fans && mesh.numFaces() == 0)
    throw IOError(path + ": this format stores triangles only and the mesh has no faces");
  // OBJ importers number vertices as faces use them, and glTF drops those no face uses:
  // a leading point per vertex fixes the order. PLY keeps its vertex list as it is; STL
  // has none.
  const bool withPoints = format.id == "objnomtl" || format.fans;
  std::vector<unsigned> rotated;
  // Y-up formats: +z up turned to +y up, so that loadMesh's Auto reads the file back as it
  // was. Turning -y up to +z, (x, z, -y), is the inverse of turning +y up.
  std::optional<Mesh> turned;
  if (format.yUp) {
    Points points = mesh.positions();
    turnUpToZ(points, UpAxis::MinusY);
    turned.emplace(mesh);
    turned->setPositions(points);
  }
  const auto scene = exportScene(turned ? *turned : mesh, format, withPoints, rotated);
  Assimp::Exporter exporter;
  // STL: assimp's triangulation handles concave polygons, unlike a plain fan.
  const unsigned preprocessing = format.triangles && !format.fans ? aiProcess_Triangulate : 0u;
  const aiExportDataBlob* blob = exporter.ExportToBlob(scene.get(), format.id, preprocessing);
  if (blob == nullptr) throw IOError(path + ": " + oneLine(exporter.GetErrorString()));
  std::string embedded;
  const char* bytes = static_cast<const char*>(blob->data);
  std::size_t size = blob->size;
  if (format.fans) {
    embedded = finishGltf(path, *blob, format.id == "glb2", rotated);
    bytes = embedded.data();
    size = embedded.size();
  }
  writeFileAtomically(
      path, [&](std::ostream& out) { out.write(bytes, static_cast<std::streamsize>(size)); });
}

}  // namespace zsculpt::io
