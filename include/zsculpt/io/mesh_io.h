#pragma once
// Mesh files through assimp: import of every format assimp reads, welded by position, and
// export to OBJ, PLY, STL and glTF. Errors name the file: "<path>: <reason>".

#include <cstddef>
#include <string>

#include "zsculpt/mesh/mesh.h"

namespace zsculpt::io {

/// Which way is up in a mesh file. zsculpt's up is +z (gravity 0,0,-9.81, the built-ins,
/// the camera); a file whose up is another axis is turned, rigidly, so that its up becomes
/// +z. Auto: +y for glTF (Y-up by its specification) and Collada (assimp delivers it Y-up),
/// the file's own axis for FBX (its global settings), +z (as the file is) for the rest.
enum class UpAxis { Auto, PlusX, MinusX, PlusY, MinusY, PlusZ, MinusZ };

/// "auto", "x", "-x", "y", "-y", "z", "-z" (a leading '+' allowed). Throws InvalidInputError
/// "'<text>' is not an axis ..." for anything else.
UpAxis parseUpAxis(const std::string& text);
/// The inverse of parseUpAxis ("auto", "x", "-x", ...).
std::string upAxisName(UpAxis up);
/// Turns points whose up is `up` (not Auto) so that it becomes +z: a rotation by a quarter
/// or half turn, exact in floating point (coordinates are swapped and negated).
void turnUpToZ(Points& points, UpAxis up);

struct MeshLoadReport {
  Index meshesMerged = 0;             // assimp meshes joined into one
  Index verticesWelded = 0;           // file vertices merged into another at the same position
  Index degenerateFacesDropped = 0;   // faces with < 3 distinct corners after welding, or
                                      // repeating a corner
  Index pointsAndLinesDropped = 0;    // point and line primitives that were not kept as edges
  Index unusedVerticesDropped = 0;    // welded vertices that no kept face or edge uses
  Index facesReversed = 0;            // faces turned to agree with their neighbours, or a
                                      // closed sheet turned outward (mesh/orientation.h)
  Index nonOrientableComponents = 0;  // sheets no winding can make agree (a Moebius band)
  UpAxis up = UpAxis::PlusZ;          // the file's up, turned to +z (PlusZ: as it was)
};

/// Imports a mesh file. Vertices are welded by exact position across all meshes of the
/// file with node transforms applied, in order of first occurrence; polygons stay
/// polygons; degenerate faces are dropped and counted (see docs/scene-format.md, "Mesh
/// files"). Throws IOError "<path>: <reason>" (missing, unreadable, unsupported, empty,
/// assimp's error) or InvalidInputError (non-finite coordinates, an index out of range).
/// The reading is done in a child process (io/isolated.h): a crash or hang of the importer
/// on a damaged file is an IOError "<path>: the importer crashed ..." and the caller lives
/// on. With the environment variable ZSCULPT_IMPORT_IN_PROCESS=1 it is done in this process.
/// The file's up (`up`; Auto: by its format) is turned to +z (UpAxis).
Mesh loadMesh(const std::string& path, MeshLoadReport* report = nullptr, UpAxis up = UpAxis::Auto);

/// loadMesh in this process, without the child.
Mesh loadMeshInProcess(const std::string& path, MeshLoadReport* report = nullptr,
                       UpAxis up = UpAxis::Auto);

/// Same from memory; `hint` is the format's extension ("obj", "ply"...). For fuzzing.
Mesh loadMeshFromMemory(const void* data, std::size_t size, const std::string& hint,
                        MeshLoadReport* report = nullptr, UpAxis up = UpAxis::Auto);

/// A built-in model name ("builtin:torus:20:10") or a mesh file. A built-in is +z up, so
/// Auto leaves it as it is; another axis turns it as it would a file.
Mesh loadMeshSource(const std::string& source, MeshLoadReport* report = nullptr,
                    UpAxis up = UpAxis::Auto);

/// Exports by extension: .obj .ply .stl .gltf .glb .dae. Written atomically (temporary
/// file, flush, rename). Throws IOError. Coordinates are stored as floats; glTF and Collada
/// files are written Y-up, as their readers expect (+z turned to +y; loadMesh turns back). OBJ, PLY
/// and glTF keep vertex order, polygons and curve edges (glTF as FB_ngon_encoding fans, which
/// loadMesh regroups; .gltf embeds its buffer); STL keeps triangulated faces only (vertex order and
/// curve edges are lost).
void saveMesh(const Mesh& mesh, const std::string& path);
/// Before the work whose mesh goes to `path`: throws IOError unless saveMesh could write
/// there (a format it exports, checkOutputFile).
void checkMeshOutput(const std::string& path);

}  // namespace zsculpt::io
