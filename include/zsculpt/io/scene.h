#pragma once
// Scene files: JSON describing a mesh, its physical properties (uniform defaults and
// per-vertex, per-edge, per-angle overrides), constraints, timed forces and edits,
// simulation settings and a camera. The format is documented in docs/scene-format.md.
//
// SceneDescription is plain data: the CLI and the app turn it into a simulation (the
// editing module converts SceneEdit into its own brush types). Every error a scene can
// cause is one line, InvalidInputError "<scene file>: <JSON pointer>: <reason>", e.g.
// "scenes/a.json: /forces/2/vertex: vertex 120 is out of range [0, 100)".

#include <cstdint>
#include <limits>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "zsculpt/core/types.h"
#include "zsculpt/io/mesh_io.h"
#include "zsculpt/mesh/mesh.h"
#include "zsculpt/physics/properties.h"

namespace zsculpt::io {

inline constexpr int kSceneFormatVersion = 1;

/// Values of one property for some of its elements (vertices, edges or angles, by the
/// property's domain). In the file: {"values": [...all...]}, {"indices": [...], "values":
/// [...]} or {"indices": [...], "value": x}; the last is stored with one value per index.
struct PropertyOverride {
  Property property = Property::Stiffness;
  bool allElements = false;    // values[i] is element i's (values.size() == element count)
  std::vector<Index> indices;  // otherwise values[k] is element indices[k]'s
  std::vector<double> values;
  bool operator==(const PropertyOverride&) const = default;
};

enum class ConstraintType { Position, Normal };

struct ConstraintSpec {
  ConstraintType type = ConstraintType::Position;
  Index vertex = 0;
  std::optional<Vec3> target;  // position: where to hold the vertex (absent: where it is)
  std::optional<Vec3> normal;  // normal: the direction to hold (absent: the normal as loaded)
  /// position with a target: travel there over [start, end] seconds (Simulation's
  /// PinTravel) rather than at once; absent: the target holds from the start.
  std::optional<double> start, end;
  bool operator==(const ConstraintSpec&) const = default;
};

/// A force (N) or torque (N m) on one vertex during [start, end) seconds.
struct TimedLoad {
  Index vertex = 0;
  Vec3 value = Vec3::Zero();
  double start = 0.0;
  double end = std::numeric_limits<double>::infinity();
  bool operator==(const TimedLoad&) const = default;
};

enum class BrushMode { Set, Add, Multiply, Smooth };
enum class BrushFalloff { Smooth, Sphere, Linear, Sharp, Constant };
enum class BrushDistance { Surface, Euclidean };

/// What a brush does to a property where it touches (the editing module applies it).
struct BrushSettings {
  Property property = Property::Stiffness;
  BrushMode mode = BrushMode::Set;
  double value = 0.0;     // unused by Smooth
  double strength = 1.0;  // in [0, 1]: blend between the old value and the brush's result
  double radius = 1.0;    // scene units; > 0
  BrushFalloff falloff = BrushFalloff::Smooth;
  BrushDistance distance = BrushDistance::Surface;
  bool operator==(const BrushSettings&) const = default;
};

enum class EditKind {
  Brush,      // one dab of `brush` at a vertex or a point
  Global,     // `brush` applied to every element at full weight (radius, falloff unused)
  Relax,      // the current shape becomes the rest shape (rest lengths and angles)
  ScaleRest,  // rest lengths multiplied by `factor`
};

struct SceneEdit {
  double time = 0.0;  // seconds of simulated time
  EditKind kind = EditKind::Brush;
  BrushSettings brush;                // Brush, Global
  std::optional<Index> centerVertex;  // Brush: centred on a vertex ...
  std::optional<Vec3> centerPoint;    // ... or on a point
  double factor = 1.0;                // ScaleRest
  bool operator==(const SceneEdit&) const = default;
};

enum class SimulationScheme { Default, Paper, Exact, SymplecticEuler, ImplicitEuler };

struct SimulationSettings {
  SimulationScheme scheme = SimulationScheme::Default;
  std::optional<double> dt;           // seconds; at most one of dt and dtRatio
  std::optional<double> dtRatio;      // fraction of equation 5's T_max
  std::optional<std::int64_t> steps;  // at most one of steps and time
  std::optional<double> time;         // seconds
  double perturb = 0.0;               // random initial velocity size
  std::uint64_t seed = 0;             // at most 2^32 - 1 (the generator's, as --seed)
  bool operator==(const SimulationSettings&) const = default;
};

/// Absent values are left to the viewer (it frames the model).
struct CameraSettings {
  std::optional<Vec3> target;
  std::optional<double> distance;
  std::optional<double> yaw;    // degrees
  std::optional<double> pitch;  // degrees, [-90, 90]
  std::optional<double> fov;    // vertical, degrees, (0, 180)
  bool operator==(const CameraSettings&) const = default;
};

struct SceneDescription {
  std::string sourcePath;   // the scene file, for messages ("" when built in code)
  std::string description;  // free text
  /// A built-in name or a mesh file; a relative path in the file is resolved against the
  /// scene file's folder, so this is usable as it is (loadMeshSource).
  std::string mesh;
  /// The mesh file's up axis, turned to +z as it loads (loadMeshSource); "up" in the file.
  UpAxis up = UpAxis::Auto;
  UniformProperties properties;
  std::vector<PropertyOverride> overrides;  // applied in order after the uniform values
  std::vector<ConstraintSpec> constraints;
  std::vector<TimedLoad> forces;
  std::vector<TimedLoad> torques;
  std::vector<SceneEdit> edits;
  SimulationSettings simulation;
  CameraSettings camera;
};

/// Reads and validates a scene file (everything that does not need the mesh). Throws
/// IOError "<path>: <reason>" when it cannot be read and InvalidInputError
/// "<path>: <JSON pointer>: <reason>" (or "<path>: line L, column C: <reason>" for a JSON
/// syntax error) when it is not a valid scene.
SceneDescription loadScene(const std::string& path);
/// Same from text; `sceneFile` names it in messages and its folder resolves relative mesh
/// paths.
SceneDescription parseScene(std::string_view text, const std::string& sceneFile);
SceneDescription sceneFromJson(const nlohmann::json& json, const std::string& sceneFile);

/// The scene as JSON, with a mesh path relative to `sceneFile`'s folder when possible.
nlohmann::ordered_json sceneToJson(const SceneDescription& scene, const std::string& sceneFile);
/// Writes the scene atomically. Throws IOError.
void saveScene(const SceneDescription& scene, const std::string& path);

/// The checks that need the mesh: vertex, edge and angle indices in range, full arrays of
/// the right length. Throws InvalidInputError "<scene file>: <JSON pointer>: <reason>".
void validateScene(const SceneDescription& scene, const Mesh& mesh);
/// validateScene, then the model: uniform properties, then the overrides in order.
Model buildModel(const SceneDescription& scene, Mesh mesh);
/// Stores a (painted) model's properties in the scene: stiffness cap and gravity, and a
/// full array override for every property whose values differ from what the uniform
/// values would give. Replaces scene.overrides.
void recordProperties(SceneDescription& scene, const Model& model);

/// True for a path ending in ".json": MESH|SCENE arguments are told apart by this.
bool isSceneFileName(std::string_view path);

std::string_view constraintTypeName(ConstraintType type);
std::string_view brushModeName(BrushMode mode);
std::string_view brushFalloffName(BrushFalloff falloff);
std::string_view brushDistanceName(BrushDistance distance);
std::string_view schemeName(SimulationScheme scheme);
/// Parse the names above; throw InvalidInputError "<name>: unknown <what> (valid: ...)".
BrushMode brushModeFromName(std::string_view name);
BrushFalloff brushFalloffFromName(std::string_view name);
BrushDistance brushDistanceFromName(std::string_view name);
SimulationScheme schemeFromName(std::string_view name);

}  // namespace zsculpt::io
