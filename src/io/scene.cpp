#include "zsculpt/io/scene.h"

#include <algorithm>
#include <array>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>

#include "zsculpt/core/errors.h"
#include "zsculpt/io/atomic_file.h"
#include "zsculpt/mesh/builtin.h"

namespace zsculpt::io {

namespace fs = std::filesystem;
using Json = nlohmann::json;
using OrderedJson = nlohmann::ordered_json;

// ---- enum names -------------------------------------------------------------------------

namespace {

template <class Enum, size_t N>
struct NameTable {
  std::array<std::pair<Enum, std::string_view>, N> entries;
  const char* what;

  [[nodiscard]] std::string_view name(Enum value) const {
    for (const auto& [e, n] : entries)
      if (e == value) return n;
    return "?";
  }
  [[nodiscard]] std::string validNames() const {
    std::string names;
    for (const auto& [e, n] : entries) names += (names.empty() ? "" : ", ") + std::string(n);
    return names;
  }
  /// nullopt when unknown.
  [[nodiscard]] std::optional<Enum> find(std::string_view name) const {
    for (const auto& [e, n] : entries)
      if (n == name) return e;
    return std::nullopt;
  }
  [[nodiscard]] Enum parse(std::string_view name) const {
    if (auto e = find(name)) return *e;
    throw InvalidInputError(std::string(name) + ": unknown " + what + " (valid: " + validNames() +
                            ")");
  }
};

constexpr NameTable<ConstraintType, 2> kConstraintTypes{
    {{{ConstraintType::Position, "position"}, {ConstraintType::Normal, "normal"}}},
    "constraint type"};
constexpr NameTable<BrushMode, 4> kBrushModes{{{{BrushMode::Set, "set"},
                                                {BrushMode::Add, "add"},
                                                {BrushMode::Multiply, "multiply"},
                                                {BrushMode::Smooth, "smooth"}}},
                                              "brush mode"};
constexpr NameTable<BrushFalloff, 5> kFalloffs{{{{BrushFalloff::Smooth, "smooth"},
                                                 {BrushFalloff::Sphere, "sphere"},
                                                 {BrushFalloff::Linear, "linear"},
                                                 {BrushFalloff::Sharp, "sharp"},
                                                 {BrushFalloff::Constant, "constant"}}},
                                               "falloff"};
constexpr NameTable<BrushDistance, 2> kDistances{
    {{{BrushDistance::Surface, "surface"}, {BrushDistance::Euclidean, "euclidean"}}}, "distance"};
constexpr NameTable<SimulationScheme, 5> kSchemes{
    {{{SimulationScheme::Default, "default"},
      {SimulationScheme::Paper, "paper"},
      {SimulationScheme::Exact, "exact"},
      {SimulationScheme::SymplecticEuler, "symplectic-euler"},
      {SimulationScheme::ImplicitEuler, "implicit-euler"}}},
    "scheme"};

}  // namespace

std::string_view constraintTypeName(ConstraintType type) {
  return kConstraintTypes.name(type);
}
std::string_view brushModeName(BrushMode mode) {
  return kBrushModes.name(mode);
}
std::string_view brushFalloffName(BrushFalloff falloff) {
  return kFalloffs.name(falloff);
}
std::string_view brushDistanceName(BrushDistance distance) {
  return kDistances.name(distance);
}
std::string_view schemeName(SimulationScheme scheme) {
  return kSchemes.name(scheme);
}
BrushMode brushModeFromName(std::string_view name) {
  return kBrushModes.parse(name);
}
BrushFalloff brushFalloffFromName(std::string_view name) {
  return kFalloffs.parse(name);
}
BrushDistance brushDistanceFromName(std::string_view name) {
  return kDistances.parse(name);
}
SimulationScheme schemeFromName(std::string_view name) {
  return kSchemes.parse(name);
}

bool isSceneFileName(std::string_view path) {
  std::string ext = fs::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return ext == ".json";
}

// ---- reading ------------------------------------------------------------------------------

namespace {

std::string formatNumber(double value) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.10g", value);
  return buffer;
}

/// JSON pointer token (RFC 6901): "~" -> "~0", "/" -> "~1".
std::string token(std::string_view key) {
  std::string out;
  for (char c : key) {
    if (c == '~')
      out += "~0";
    else if (c == '/')
      out += "~1";
    else
      out += c;
  }
  return out;
}

std::string describe(const Json& j) {
  switch (j.type()) {
    case Json::value_t::object:
      return "an object";
    case Json::value_t::array:
      return "an array";
    case Json::value_t::string: {
      std::string s = j.get<std::string>();
      if (s.size() > 40) s = s.substr(0, 40) + "...";
      for (char& c : s)
        if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) c = '?';  // one printable line
      return "a string (\"" + s + "\")";
    }
    case Json::value_t::boolean:
      return j.get<bool>() ? "true" : "false";
    case Json::value_t::null:
      return "null";
    case Json::value_t::number_float:
      return "the number " + formatNumber(j.get<double>());
    case Json::value_t::number_integer:
    case Json::value_t::number_unsigned:
      return "the number " + j.dump();
    default:
      return "an invalid value";
  }
}

/// Section 4.1's ranges as a phrase: "must be > 0", "must be >= 0", "must be in [0, 1]".
std::string rangePhrase(const PropertyRange& r) {
  if (std::isinf(r.max))
    return std::string("must be ") + (r.minExclusive ? "> " : ">= ") + formatNumber(r.min);
  return "must be in " + std::string(r.minExclusive ? "(" : "[") + formatNumber(r.min) + ", " +
         formatNumber(r.max) + "]";
}

bool inRange(const PropertyRange& r, double v) {
  return std::isfinite(v) && (r.minExclusive ? v > r.min : v >= r.min) && v <= r.max;
}

std::string overridePointer(Property property) {
  switch (propertyDomain(property)) {
    case PropertyDomain::Edge:
      return "/rest_lengths";
    case PropertyDomain::Angle:
      return "/rest_angles";
    default:
      return "/vertex_properties/" + std::string(propertyName(property));
  }
}

std::string elementName(Property property) {
  switch (propertyDomain(property)) {
    case PropertyDomain::Edge:
      return "edge";
    case PropertyDomain::Angle:
      return "angle";
    default:
      return "vertex";
  }
}

class SceneReader {
 public:
  explicit SceneReader(const std::string& file) : file_(file.empty() ? "<scene>" : file) {}

  [[noreturn]] void fail(const std::string& pointer, const std::string& reason) const {
    throw InvalidInputError(file_ + ": " + (pointer.empty() ? "/" : pointer) + ": " + reason);
  }

  /// Checks that `j` is an object with no keys but `keys`.
  void object(const Json& j, const std::string& pointer,
              std::initializer_list<std::string_view> keys) const {
    if (!j.is_object()) fail(pointer, "expected an object, got " + describe(j));
    for (auto it = j.begin(); it != j.end(); ++it) {
      if (std::find(keys.begin(), keys.end(), it.key()) != keys.end()) continue;
      std::string valid;
      for (std::string_view k : keys) valid += (valid.empty() ? "" : ", ") + std::string(k);
      fail(pointer + "/" + token(it.key()), "unknown key (valid here: " + valid + ")");
    }
  }

  const Json& array(const Json& j, const std::string& pointer) const {
    if (!j.is_array()) fail(pointer, "expected an array, got " + describe(j));
    return j;
  }

  double number(const Json& j, const std::string& pointer) const {
    if (!j.is_number()) fail(pointer, "expected a number, got " + describe(j));
    const double v = j.get<double>();
    if (!std::isfinite(v)) fail(pointer, "the number is not finite");
    return v;
  }

  double positive(const Json& j, const std::string& pointer) const {
    const double v = number(j, pointer);
    if (!(v > 0.0)) fail(pointer, "must be > 0, got " + formatNumber(v));
    return v;
  }

  double nonNegative(const Json& j, const std::string& pointer) const {
    const double v = number(j, pointer);
    if (!(v >= 0.0)) fail(pointer, "must be >= 0, got " + formatNumber(v));
    return v;
  }

  double between(const Json& j, const std::string& pointer, double lo, double hi, bool loExclusive,
                 bool hiExclusive) const {
    const double v = number(j, pointer);
    const bool ok = (loExclusive ? v > lo : v >= lo) && (hiExclusive ? v < hi : v <= hi);
    if (!ok)
      fail(pointer, "must be in " + std::string(loExclusive ? "(" : "[") + formatNumber(lo) + ", " +
                        formatNumber(hi) + (hiExclusive ? ")" : "]") + ", got " + formatNumber(v));
    return v;
  }

  double propertyValue(const Json& j, const std::string& pointer, Property property) const {
    const double v = number(j, pointer);
    const PropertyRange r = propertyRange(property);
    if (!inRange(r, v))
      fail(pointer,
           std::string(propertyName(property)) + " " + rangePhrase(r) + ", got " + formatNumber(v));
    return v;
  }

  std::uint64_t unsignedInteger(const Json& j, const std::string& pointer,
                                std::string_view what) const {
    if (!j.is_number_integer())
      fail(pointer, "expected " + std::string(what) + " (an integer >= 0), got " + describe(j));
    if (j.is_number_unsigned()) return j.get<std::uint64_t>();
    const auto v = j.get<std::int64_t>();
    if (v < 0) fail(pointer, "must be >= 0, got " + std::to_string(v));
    return static_cast<std::uint64_t>(v);
  }

  Index index(const Json& j, const std::string& pointer, std::string_view what) const {
    const std::uint64_t v = unsignedInteger(j, pointer, what);
    if (v > static_cast<std::uint64_t>(std::numeric_limits<Index>::max()))
      fail(pointer, std::to_string(v) + " is too large");
    return static_cast<Index>(v);
  }

  Vec3 vec3(const Json& j, const std::string& pointer) const {
    if (!j.is_array() || j.size() != 3)
      fail(pointer, "expected an array of 3 numbers, got " + describe(j));
    Vec3 v;
    for (int k = 0; k < 3; ++k) v[k] = number(j[k], pointer + "/" + std::to_string(k));
    return v;
  }

  std::string string(const Json& j, const std::string& pointer) const {
    if (!j.is_string()) fail(pointer, "expected a string, got " + describe(j));
    std::string text = j.get<std::string>();
    // A NUL (\u0000) would end the text where a file name or a message is passed on:
    // "a.obj\u0000.ply" would open a.obj.
    if (text.find('\0') != std::string::npos) fail(pointer, "the string contains a NUL character");
    return text;
  }

  bool boolean(const Json& j, const std::string& pointer) const {
    if (!j.is_boolean()) fail(pointer, "expected true or false, got " + describe(j));
    return j.get<bool>();
  }

  template <class Enum, size_t N>
  Enum name(const Json& j, const std::string& pointer, const NameTable<Enum, N>& table) const {
    const std::string s = string(j, pointer);
    if (auto e = table.find(s)) return *e;
    fail(pointer, "unknown " + std::string(table.what) + " \"" + s +
                      "\" (valid: " + table.validNames() + ")");
  }

  Property property(const Json& j, const std::string& pointer) const {
    const std::string s = string(j, pointer);
    try {
      return propertyFromName(s);
    } catch (const InvalidInputError& e) {
      fail(pointer, e.what());
    }
  }

  [[nodiscard]] const std::string& file() const { return file_; }

 private:
  std::string file_;
};

const Json* find(const Json& j, std::string_view key) {
  const auto it = j.find(key);
  return it == j.end() ? nullptr : &*it;
}

void readProperties(const SceneReader& r, const Json& j, UniformProperties& p) {
  const std::string at = "/properties";
  r.object(j, at,
           {"mass", "damping", "stiffness", "angular_stiffness", "rigidity", "stiffness_cap",
            "rest_length_scale", "gravity"});
  if (auto* v = find(j, "mass")) p.mass = r.propertyValue(*v, at + "/mass", Property::Mass);
  if (auto* v = find(j, "damping"))
    p.damping = r.propertyValue(*v, at + "/damping", Property::Damping);
  if (auto* v = find(j, "stiffness"))
    p.stiffness = r.propertyValue(*v, at + "/stiffness", Property::Stiffness);
  if (auto* v = find(j, "angular_stiffness"))
    p.angularStiffness = r.propertyValue(*v, at + "/angular_stiffness", Property::AngularStiffness);
  if (auto* v = find(j, "rigidity"))
    p.rigidity = r.propertyValue(*v, at + "/rigidity", Property::Rigidity);
  if (auto* v = find(j, "stiffness_cap"))
    p.stiffnessCap = v->is_null() ? std::numeric_limits<double>::infinity()
                                  : r.positive(*v, at + "/stiffness_cap");
  if (auto* v = find(j, "rest_length_scale"))
    // 0 is allowed, as --rest-length-scale 0 is: every rest length 0, equation 1's linear
    // springs (a scene saved from such a session must open again).
    p.restLengthScale = r.nonNegative(*v, at + "/rest_length_scale");
  if (auto* v = find(j, "gravity")) p.gravity = r.vec3(*v, at + "/gravity");
}

PropertyOverride readOverride(const SceneReader& r, const Json& j, const std::string& at,
                              Property property) {
  r.object(j, at, {"indices", "values", "value"});
  PropertyOverride o;
  o.property = property;
  const Json* indices = find(j, "indices");
  const Json* values = find(j, "values");
  const Json* value = find(j, "value");
  if (values != nullptr && value != nullptr) r.fail(at, "give \"values\" or \"value\", not both");
  if (values == nullptr && value == nullptr) r.fail(at, "needs \"values\" or \"value\"");
  if (value != nullptr && indices == nullptr) r.fail(at + "/value", "needs \"indices\"");
  const std::string element = elementName(property);
  if (indices != nullptr) {
    r.array(*indices, at + "/indices");
    std::set<Index> seen;
    for (size_t k = 0; k < indices->size(); ++k) {
      const std::string p = at + "/indices/" + std::to_string(k);
      const Index i = r.index((*indices)[k], p, "a " + element + " index");
      if (!seen.insert(i).second)
        r.fail(p, element + " " + std::to_string(i) + " appears more than once");
      o.indices.push_back(i);
    }
  } else {
    o.allElements = true;
  }
  if (values != nullptr) {
    r.array(*values, at + "/values");
    for (size_t k = 0; k < values->size(); ++k)
      o.values.push_back(
          r.propertyValue((*values)[k], at + "/values/" + std::to_string(k), property));
    if (indices != nullptr && o.values.size() != o.indices.size())
      r.fail(at + "/values", std::to_string(o.values.size()) + " values for " +
                                 std::to_string(o.indices.size()) + " indices");
  } else {
    o.values.assign(o.indices.size(), r.propertyValue(*value, at + "/value", property));
  }
  return o;
}

void readOverrides(const SceneReader& r, const Json& root, SceneDescription& scene) {
  if (const Json* vp = find(root, "vertex_properties")) {
    if (!vp->is_object()) r.fail("/vertex_properties", "expected an object, got " + describe(*vp));
    for (auto it = vp->begin(); it != vp->end(); ++it) {
      const std::string at = "/vertex_properties/" + token(it.key());
      Property property;
      try {
        property = propertyFromName(it.key());
      } catch (const InvalidInputError& e) {
        r.fail(at, e.what());
      }
      if (propertyDomain(property) == PropertyDomain::Edge)
        r.fail(at, "rest_length is a per-edge property: give it in /rest_lengths");
      if (propertyDomain(property) == PropertyDomain::Angle)
        r.fail(at, "rest_angle is a per-angle property: give it in /rest_angles");
    }
    // In the properties' canonical order (JSON objects have none), as saveScene writes.
    for (Property property : kAllProperties) {
      const std::string name(propertyName(property));
      if (const Json* o = find(*vp, name))
        scene.overrides.push_back(readOverride(r, *o, "/vertex_properties/" + name, property));
    }
  }
  if (const Json* rl = find(root, "rest_lengths"))
    scene.overrides.push_back(readOverride(r, *rl, "/rest_lengths", Property::RestLength));
  if (const Json* ra = find(root, "rest_angles"))
    scene.overrides.push_back(readOverride(r, *ra, "/rest_angles", Property::RestAngle));
}

void readConstraints(const SceneReader& r, const Json& j, SceneDescription& scene) {
  r.array(j, "/constraints");
  for (size_t i = 0; i < j.size(); ++i) {
    const std::string at = "/constraints/" + std::to_string(i);
    const Json& c = j[i];
    if (!c.is_object()) r.fail(at, "expected an object, got " + describe(c));
    const Json* type = find(c, "type");
    if (type == nullptr) r.fail(at, "needs \"type\" (position or normal)");
    ConstraintSpec spec;
    spec.type = r.name(*type, at + "/type", kConstraintTypes);
    if (spec.type == ConstraintType::Position)
      r.object(c, at, {"type", "vertex", "target", "start", "end"});
    else
      r.object(c, at, {"type", "vertex", "normal"});
    const Json* vertex = find(c, "vertex");
    if (vertex == nullptr) r.fail(at, "needs \"vertex\"");
    spec.vertex = r.index(*vertex, at + "/vertex", "a vertex index");
    if (const Json* t = find(c, "target")) spec.target = r.vec3(*t, at + "/target");
    const Json* start = find(c, "start");
    const Json* end = find(c, "end");
    if (start != nullptr || end != nullptr) {
      // A travel: both times, and a target to travel to.
      if (start == nullptr || end == nullptr)
        r.fail(at, "a pin's travel needs both \"start\" and \"end\"");
      if (!spec.target) r.fail(at, "a pin with \"start\" and \"end\" needs a \"target\"");
      spec.start = r.nonNegative(*start, at + "/start");
      spec.end = r.number(*end, at + "/end");
      if (!(*spec.end > *spec.start && std::isfinite(*spec.end)))
        r.fail(at + "/end", "must be after start (" + formatNumber(*spec.start) + "), got " +
                                formatNumber(*spec.end));
    }
    if (const Json* n = find(c, "normal")) {
      spec.normal = r.vec3(*n, at + "/normal");
      if (spec.normal->norm() == 0.0) r.fail(at + "/normal", "the normal must not be zero");
    }
    scene.constraints.push_back(spec);
  }
}

void readLoads(const SceneReader& r, const Json& j, const std::string& section,
               const char* vectorKey, std::vector<TimedLoad>& loads) {
  r.array(j, "/" + section);
  for (size_t i = 0; i < j.size(); ++i) {
    const std::string at = "/" + section + "/" + std::to_string(i);
    const Json& l = j[i];
    r.object(l, at, {"vertex", vectorKey, "start", "end"});
    TimedLoad load;
    const Json* vertex = find(l, "vertex");
    if (vertex == nullptr) r.fail(at, "needs \"vertex\"");
    load.vertex = r.index(*vertex, at + "/vertex", "a vertex index");
    const Json* value = find(l, vectorKey);
    if (value == nullptr) r.fail(at, std::string("needs \"") + vectorKey + "\"");
    load.value = r.vec3(*value, at + "/" + vectorKey);
    if (const Json* s = find(l, "start")) load.start = r.nonNegative(*s, at + "/start");
    if (const Json* e = find(l, "end")) {
      load.end = r.number(*e, at + "/end");
      if (!(load.end > load.start))
        r.fail(at + "/end", "must be after start (" + formatNumber(load.start) + "), got " +
                                formatNumber(load.end));
    }
    loads.push_back(load);
  }
}

void readEdits(const SceneReader& r, const Json& j, SceneDescription& scene) {
  r.array(j, "/edits");
  for (size_t i = 0; i < j.size(); ++i) {
    const std::string at = "/edits/" + std::to_string(i);
    const Json& e = j[i];
    if (!e.is_object()) r.fail(at, "expected an object, got " + describe(e));
    SceneEdit edit;
    std::string action = "paint";
    if (const Json* a = find(e, "action")) {
      action = r.string(*a, at + "/action");
      if (action != "paint" && action != "relax" && action != "scale_rest")
        r.fail(at + "/action",
               "unknown action \"" + action + "\" (valid: paint, relax, scale_rest)");
    }
    if (action == "relax") {
      r.object(e, at, {"time", "action"});
      edit.kind = EditKind::Relax;
    } else if (action == "scale_rest") {
      r.object(e, at, {"time", "action", "factor"});
      edit.kind = EditKind::ScaleRest;
      const Json* f = find(e, "factor");
      if (f == nullptr) r.fail(at, "needs \"factor\"");
      edit.factor = r.positive(*f, at + "/factor");
    } else {
      const Json* global = find(e, "global");
      const bool isGlobal = global != nullptr && r.boolean(*global, at + "/global");
      if (isGlobal)
        r.object(e, at, {"time", "action", "global", "property", "mode", "value", "strength"});
      else
        r.object(e, at,
                 {"time", "action", "global", "property", "center", "radius", "mode", "value",
                  "strength", "falloff", "distance"});
      edit.kind = isGlobal ? EditKind::Global : EditKind::Brush;
      BrushSettings& b = edit.brush;
      const Json* property = find(e, "property");
      if (property == nullptr) r.fail(at, "needs \"property\"");
      b.property = r.property(*property, at + "/property");
      if (const Json* m = find(e, "mode")) b.mode = r.name(*m, at + "/mode", kBrushModes);
      const Json* value = find(e, "value");
      if (b.mode == BrushMode::Smooth) {
        if (value != nullptr) r.fail(at + "/value", "not used by mode smooth");
      } else {
        if (value == nullptr) r.fail(at, "needs \"value\"");
        const std::string vp = at + "/value";
        switch (b.mode) {
          case BrushMode::Set:
            b.value = r.propertyValue(*value, vp, b.property);
            break;
          case BrushMode::Multiply:
            b.value = r.nonNegative(*value, vp);
            break;
          default:
            b.value = r.number(*value, vp);
            break;
        }
      }
      if (const Json* s = find(e, "strength"))
        b.strength = r.between(*s, at + "/strength", 0.0, 1.0, false, false);
      if (!isGlobal) {
        const Json* center = find(e, "center");
        if (center == nullptr) r.fail(at, "needs \"center\" (a vertex index or [x, y, z])");
        if (center->is_array())
          edit.centerPoint = r.vec3(*center, at + "/center");
        else
          edit.centerVertex = r.index(*center, at + "/center", "a vertex index or [x, y, z]");
        const Json* radius = find(e, "radius");
        if (radius == nullptr) r.fail(at, "needs \"radius\"");
        b.radius = r.positive(*radius, at + "/radius");
        if (const Json* f = find(e, "falloff")) b.falloff = r.name(*f, at + "/falloff", kFalloffs);
        if (const Json* d = find(e, "distance"))
          b.distance = r.name(*d, at + "/distance", kDistances);
      }
    }
    if (const Json* t = find(e, "time")) edit.time = r.nonNegative(*t, at + "/time");
    scene.edits.push_back(edit);
  }
}

void readSimulation(const SceneReader& r, const Json& j, SimulationSettings& s) {
  const std::string at = "/simulation";
  r.object(j, at, {"scheme", "dt", "dt_ratio", "steps", "time", "perturb", "seed"});
  if (const Json* v = find(j, "scheme")) s.scheme = r.name(*v, at + "/scheme", kSchemes);
  if (const Json* v = find(j, "dt")) s.dt = r.positive(*v, at + "/dt");
  if (const Json* v = find(j, "dt_ratio")) {
    if (s.dt) r.fail(at + "/dt_ratio", "give dt or dt_ratio, not both");
    s.dtRatio = r.positive(*v, at + "/dt_ratio");
  }
  if (const Json* v = find(j, "steps")) {
    const std::uint64_t steps = r.unsignedInteger(*v, at + "/steps", "a step count");
    if (steps > static_cast<std::uint64_t>(std::numeric_limits<std::int64_t>::max()))
      r.fail(at + "/steps", "too many steps");
    s.steps = static_cast<std::int64_t>(steps);
  }
  if (const Json* v = find(j, "time")) {
    if (s.steps) r.fail(at + "/time", "give steps or time, not both");
    s.time = r.positive(*v, at + "/time");
  }
  if (const Json* v = find(j, "perturb")) s.perturb = r.nonNegative(*v, at + "/perturb");
  if (const Json* v = find(j, "seed")) {
    // The generator takes 32 bits, as --seed does: a larger seed would wrap onto another.
    s.seed = r.unsignedInteger(*v, at + "/seed", "a seed");
    if (s.seed > std::numeric_limits<std::uint32_t>::max())
      r.fail(at + "/seed", "must be at most 4294967295 (32 bits), got " + std::to_string(s.seed));
  }
}

void readCamera(const SceneReader& r, const Json& j, CameraSettings& c) {
  const std::string at = "/camera";
  r.object(j, at, {"target", "distance", "yaw", "pitch", "fov"});
  if (const Json* v = find(j, "target")) c.target = r.vec3(*v, at + "/target");
  if (const Json* v = find(j, "distance")) c.distance = r.positive(*v, at + "/distance");
  if (const Json* v = find(j, "yaw")) c.yaw = r.number(*v, at + "/yaw");
  if (const Json* v = find(j, "pitch"))
    c.pitch = r.between(*v, at + "/pitch", -90, 90, false, false);
  if (const Json* v = find(j, "fov")) c.fov = r.between(*v, at + "/fov", 0, 180, true, true);
}

std::string resolveMesh(const std::string& mesh, const std::string& sceneFile) {
  if (isBuiltinName(mesh)) return mesh;
  const fs::path path(mesh);
  if (path.is_absolute() || sceneFile.empty()) return path.lexically_normal().string();
  // Relative to the folder the scene file is in, as the system finds it (through symbolic
  // links, as meshForFile writes it); a scene written by the text of its path before (a
  // folder reached through a link) still opens by that text.
  const fs::path folder = fs::path(sceneFile).parent_path();
  const fs::path byText = (folder / path).lexically_normal();
  std::error_code ec;
  const fs::path real = fs::weakly_canonical(folder.empty() ? fs::path(".") : folder, ec);
  if (!ec) {
    const fs::path physical = (real / path).lexically_normal();
    if (fs::exists(physical, ec) || !fs::exists(byText, ec)) return physical.string();
  }
  return byText.string();
}

}  // namespace

SceneDescription sceneFromJson(const Json& json, const std::string& sceneFile) {
  const SceneReader r(sceneFile);
  r.object(
      json, "",
      {"version", "description", "mesh", "up", "properties", "vertex_properties", "rest_lengths",
       "rest_angles", "constraints", "forces", "torques", "edits", "simulation", "camera"});
  SceneDescription scene;
  scene.sourcePath = sceneFile;
  if (const Json* v = find(json, "version")) {
    const auto version = r.unsignedInteger(*v, "/version", "a format version");
    if (version != static_cast<std::uint64_t>(kSceneFormatVersion))
      r.fail("/version", "unsupported version " + std::to_string(version) +
                             " (this program reads version " + std::to_string(kSceneFormatVersion) +
                             ")");
  }
  if (const Json* v = find(json, "description")) scene.description = r.string(*v, "/description");
  const Json* mesh = find(json, "mesh");
  if (mesh == nullptr)
    r.fail("", "needs \"mesh\" (a built-in name such as builtin:torus or a file)");
  scene.mesh = r.string(*mesh, "/mesh");
  if (scene.mesh.empty()) r.fail("/mesh", "must not be empty");
  scene.mesh = resolveMesh(scene.mesh, sceneFile);
  if (const Json* v = find(json, "up")) {
    const std::string axis = r.string(*v, "/up");
    try {
      scene.up = parseUpAxis(axis);
    } catch (const InvalidInputError& e) {
      r.fail("/up", e.what());
    }
  }
  if (const Json* v = find(json, "properties")) readProperties(r, *v, scene.properties);
  readOverrides(r, json, scene);
  if (const Json* v = find(json, "constraints")) readConstraints(r, *v, scene);
  if (const Json* v = find(json, "forces")) readLoads(r, *v, "forces", "force", scene.forces);
  if (const Json* v = find(json, "torques")) readLoads(r, *v, "torques", "torque", scene.torques);
  if (const Json* v = find(json, "edits")) readEdits(r, *v, scene);
  if (const Json* v = find(json, "simulation")) readSimulation(r, *v, scene.simulation);
  if (const Json* v = find(json, "camera")) readCamera(r, *v, scene.camera);
  return scene;
}

// The number literals of a JSON text in document order (the order of the parser's value
// events for numbers), each with whether it is not zero but lies below a double's range: the
// parser reads 1e-400 as 0 without a word, and a scene's "mass": 1e-400 was then refused as
// "must be > 0, got 0". (On text that is not JSON the list may be off; the parse fails then.)
std::vector<bool> numbersBelowRange(std::string_view text, std::vector<std::string>& literals) {
  std::vector<bool> below;
  for (size_t i = 0; i < text.size();) {
    const char c = text[i];
    if (c == '"') {
      for (++i; i < text.size() && text[i] != '"'; i += text[i] == '\\' ? 2 : 1) {
      }
      ++i;
      continue;
    }
    if (c != '-' && (c < '0' || c > '9')) {
      ++i;
      continue;
    }
    size_t end = i + 1;
    while (end < text.size() && (std::strchr("0123456789+-.eE", text[end]) != nullptr) &&
           text[end] != '\0')
      ++end;
    const std::string_view literal = text.substr(i, end - i);
    bool nonzero = false;
    for (char d : literal) {
      if (d == 'e' || d == 'E') break;
      nonzero = nonzero || (d >= '1' && d <= '9');
    }
    double value = 0.0;
    const auto result = std::from_chars(literal.data(), literal.data() + literal.size(), value);
    const size_t exponent = literal.find_first_of("eE");
    const bool tiny = nonzero && (result.ec == std::errc::result_out_of_range || value == 0.0) &&
                      exponent != std::string_view::npos && exponent + 1 < literal.size() &&
                      literal[exponent + 1] == '-';
    below.push_back(tiny);
    literals.emplace_back(tiny ? literal : std::string_view());
    i = end;
  }
  return below;
}

SceneDescription parseScene(std::string_view text, const std::string& sceneFile) {
  const std::string name = sceneFile.empty() ? "<scene>" : sceneFile;
  Json json;
  // A key given twice in one object: the parser keeps the last silently, so a scene that
  // names "mesh" twice loaded whichever came second. Refused, as unknown keys are.
  // The containers the parse is in, for the JSON pointer of what it reads.
  struct Level {
    bool array = false;
    size_t count = 0;  // an array's elements read so far
    std::set<std::string> keys;
    std::string key;  // an object's latest, for the path
  };
  std::vector<Level> objects;
  auto pointer = [&](size_t levels) {
    std::string path;
    for (size_t k = 0; k < levels; ++k) {
      path.push_back('/');
      path.append(objects[k].array ? std::to_string(objects[k].count) : token(objects[k].key));
    }
    return path;
  };
  auto elementRead = [&] {
    if (!objects.empty() && objects.back().array) ++objects.back().count;
  };
  std::string duplicate;
  std::vector<std::string> literals;
  const std::vector<bool> belowRange = numbersBelowRange(text, literals);
  size_t numbersRead = 0;
  std::string tooSmall;
  auto noDuplicateKeys = [&](int, Json::parse_event_t event, Json& parsed) {
    switch (event) {
      case Json::parse_event_t::object_start:
        objects.emplace_back();
        break;
      case Json::parse_event_t::array_start:
        objects.emplace_back().array = true;
        break;
      case Json::parse_event_t::object_end:
      case Json::parse_event_t::array_end:
        if (!objects.empty()) objects.pop_back();
        elementRead();
        break;
      case Json::parse_event_t::value:  // a number, string, boolean or null
        if (parsed.is_number()) {
          if (numbersRead < belowRange.size() && belowRange[numbersRead] &&
              parsed.get<double>() == 0.0 && tooSmall.empty())
            tooSmall = pointer(objects.size()) + ": the number '" + literals[numbersRead] +
                       "' is below a double's range (it would read as 0)";
          ++numbersRead;
        }
        elementRead();
        break;
      case Json::parse_event_t::key: {
        const std::string key = parsed.get<std::string>();
        if (!objects.back().keys.insert(key).second && duplicate.empty())
          duplicate = pointer(objects.size() - 1).append("/").append(token(key));
        objects.back().key = key;
        break;
      }
    }
    return true;
  };
  try {
    json = Json::parse(text, noDuplicateKeys);
  } catch (const Json::out_of_range& e) {
    // "number overflow parsing '1e400'": the parser says no place, so the value is named by
    // the keys and array indices the parse had reached.
    std::string what = e.what();
    const auto quote = what.find('\'');
    const std::string path = pointer(objects.size());
    if (quote == std::string::npos || path.empty()) throw InvalidInputError(name + ": " + what);
    throw InvalidInputError(name + ": " + path + ": the number " + what.substr(quote) +
                            " is beyond a double's range");
  } catch (const Json::exception& e) {
    // "[json.exception.parse_error.101] parse error at line 3, column 5: syntax error ..."
    std::string what = e.what();
    const auto close = what.find("] ");
    if (close != std::string::npos) what.erase(0, close + 2);
    const std::string prefix = "parse error at ";
    if (what.rfind(prefix, 0) == 0) what.erase(0, prefix.size());
    throw InvalidInputError(name + ": " + what);
  }
  if (!duplicate.empty()) throw InvalidInputError(name + ": " + duplicate + ": given twice");
  if (!tooSmall.empty()) throw InvalidInputError(name + ": " + tooSmall);
  return sceneFromJson(json, sceneFile);
}

SceneDescription loadScene(const std::string& path) {
  std::error_code ec;
  if (fs::is_directory(path, ec)) throw IOError(path + ": is a folder, not a scene file");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw IOError(path + ": cannot open: " + std::strerror(errno));
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) throw IOError(path + ": read error");
  return parseScene(text.str(), path);
}

// ---- checks against the mesh ------------------------------------------------------------

void validateScene(const SceneDescription& scene, const Mesh& mesh) {
  const SceneReader r(scene.sourcePath);
  const Index n = mesh.numVertices();
  auto checkVertex = [&](Index v, const std::string& pointer) {
    if (v < 0 || v >= n)
      r.fail(pointer,
             "vertex " + std::to_string(v) + " is out of range [0, " + std::to_string(n) + ")");
  };
  std::optional<Index> angleCount;
  for (const PropertyOverride& o : scene.overrides) {
    const std::string at = overridePointer(o.property);
    Index count = n;
    if (propertyDomain(o.property) == PropertyDomain::Edge) count = mesh.numEdges();
    if (propertyDomain(o.property) == PropertyDomain::Angle) {
      if (!angleCount) angleCount = buildAngleTable(mesh).size();
      count = *angleCount;
    }
    const std::string element = elementName(o.property);
    if (o.allElements) {
      if (static_cast<Index>(o.values.size()) != count)
        r.fail(at + "/values", std::to_string(o.values.size()) + " values for " +
                                   std::to_string(count) + " " +
                                   (count == 1            ? element
                                    : element == "vertex" ? std::string("vertices")
                                                          : element + "s") +
                                   " (one per " + element + ")");
      continue;
    }
    for (size_t k = 0; k < o.indices.size(); ++k)
      if (o.indices[k] < 0 || o.indices[k] >= count)
        r.fail(at + "/indices/" + std::to_string(k), element + " " + std::to_string(o.indices[k]) +
                                                         " is out of range [0, " +
                                                         std::to_string(count) + ")");
  }
  for (size_t i = 0; i < scene.constraints.size(); ++i)
    checkVertex(scene.constraints[i].vertex, "/constraints/" + std::to_string(i) + "/vertex");
  for (size_t i = 0; i < scene.forces.size(); ++i)
    checkVertex(scene.forces[i].vertex, "/forces/" + std::to_string(i) + "/vertex");
  for (size_t i = 0; i < scene.torques.size(); ++i)
    checkVertex(scene.torques[i].vertex, "/torques/" + std::to_string(i) + "/vertex");
  for (size_t i = 0; i < scene.edits.size(); ++i)
    if (scene.edits[i].centerVertex)
      checkVertex(*scene.edits[i].centerVertex, "/edits/" + std::to_string(i) + "/center");
}

Model buildModel(const SceneDescription& scene, Mesh mesh) {
  validateScene(scene, mesh);
  Model model = Model::fromMesh(std::move(mesh), scene.properties);
  for (const PropertyOverride& o : scene.overrides) {
    VectorX& values = model.properties.values(o.property);
    if (o.allElements)
      values = Eigen::Map<const VectorX>(o.values.data(), static_cast<Index>(o.values.size()));
    else
      for (size_t k = 0; k < o.indices.size(); ++k) values[o.indices[k]] = o.values[k];
  }
  model.properties.validate(model.mesh, model.angles);
  return model;
}

void recordProperties(SceneDescription& scene, const Model& model) {
  scene.properties.stiffnessCap = model.properties.stiffnessCap;
  scene.properties.gravity = model.properties.gravity;
  const PhysicalProperties uniform =
      PhysicalProperties::uniform(model.mesh, model.angles, scene.properties);
  scene.overrides.clear();
  for (Property property : kAllProperties) {
    const VectorX& values = model.properties.values(property);
    if (values.size() == uniform.values(property).size() && values == uniform.values(property))
      continue;
    PropertyOverride o;
    o.property = property;
    o.allElements = true;
    o.values.assign(values.data(), values.data() + values.size());
    scene.overrides.push_back(std::move(o));
  }
}

// ---- writing ------------------------------------------------------------------------------

namespace {

OrderedJson vecJson(const Vec3& v) {
  return OrderedJson::array({v.x(), v.y(), v.z()});
}

/// Overrides of one property merged in order, so that the file (one key per property)
/// means what the list means.
PropertyOverride mergeOverrides(const std::vector<const PropertyOverride*>& list) {
  PropertyOverride merged = *list.front();
  for (size_t i = 1; i < list.size(); ++i) {
    const PropertyOverride& o = *list[i];
    if (o.allElements) {
      merged = o;
      continue;
    }
    for (size_t k = 0; k < o.indices.size(); ++k) {
      const Index index = o.indices[k];
      if (merged.allElements && index >= 0 && static_cast<size_t>(index) < merged.values.size()) {
        merged.values[index] = o.values[k];
        continue;
      }
      const auto it = std::find(merged.indices.begin(), merged.indices.end(), index);
      if (it != merged.indices.end() && !merged.allElements) {
        merged.values[it - merged.indices.begin()] = o.values[k];
      } else if (!merged.allElements) {
        merged.indices.push_back(index);
        merged.values.push_back(o.values[k]);
      }
    }
  }
  return merged;
}

OrderedJson overrideJson(const PropertyOverride& o) {
  OrderedJson j = OrderedJson::object();
  if (!o.allElements) j["indices"] = o.indices;
  j["values"] = o.values;
  return j;
}

std::string meshForFile(const std::string& mesh, const std::string& sceneFile) {
  if (mesh.empty() || isBuiltinName(mesh)) return mesh;
  // From the folder the scene file really is in (through symbolic links: by the text of its
  // path, a scene saved into a folder reached through a link named the mesh by a path that
  // only worked through the link), to the mesh as named (its own links kept: a "current"
  // link is still followed when it is pointed at another mesh).
  std::error_code ec;
  const fs::path absoluteMesh = fs::absolute(mesh, ec).lexically_normal();
  fs::path folder = fs::path(sceneFile).parent_path();
  if (folder.empty()) folder = ".";
  fs::path absoluteFolder = fs::weakly_canonical(folder, ec);
  if (ec) absoluteFolder = fs::absolute(folder, ec).lexically_normal();
  const fs::path relative = absoluteMesh.lexically_relative(absoluteFolder);
  return relative.empty() ? absoluteMesh.generic_string() : relative.generic_string();
}

}  // namespace

OrderedJson sceneToJson(const SceneDescription& scene, const std::string& sceneFile) {
  OrderedJson j = OrderedJson::object();
  j["version"] = kSceneFormatVersion;
  if (!scene.description.empty()) j["description"] = scene.description;
  j["mesh"] = meshForFile(scene.mesh, sceneFile);
  // Always written, so that a save reloads the mesh the same way whatever Auto comes to mean;
  // a file without it loads as Auto (docs/scene-format.md).
  j["up"] = upAxisName(scene.up);

  const UniformProperties& p = scene.properties;
  OrderedJson props = OrderedJson::object();
  props["mass"] = p.mass;
  props["damping"] = p.damping;
  props["stiffness"] = p.stiffness;
  props["angular_stiffness"] = p.angularStiffness;
  props["rigidity"] = p.rigidity;
  if (std::isfinite(p.stiffnessCap)) props["stiffness_cap"] = p.stiffnessCap;
  props["rest_length_scale"] = p.restLengthScale;
  props["gravity"] = vecJson(p.gravity);
  j["properties"] = props;

  OrderedJson vertexProperties = OrderedJson::object();
  OrderedJson restLengths, restAngles;
  for (Property property : kAllProperties) {
    std::vector<const PropertyOverride*> list;
    for (const PropertyOverride& o : scene.overrides)
      if (o.property == property) list.push_back(&o);
    if (list.empty()) continue;
    OrderedJson value = overrideJson(mergeOverrides(list));
    switch (propertyDomain(property)) {
      case PropertyDomain::Edge:
        restLengths = std::move(value);
        break;
      case PropertyDomain::Angle:
        restAngles = std::move(value);
        break;
      default:
        vertexProperties[std::string(propertyName(property))] = std::move(value);
        break;
    }
  }
  if (!vertexProperties.empty()) j["vertex_properties"] = vertexProperties;
  if (!restLengths.is_null()) j["rest_lengths"] = restLengths;
  if (!restAngles.is_null()) j["rest_angles"] = restAngles;

  if (!scene.constraints.empty()) {
    OrderedJson list = OrderedJson::array();
    for (const ConstraintSpec& c : scene.constraints) {
      OrderedJson item = OrderedJson::object();
      item["type"] = constraintTypeName(c.type);
      item["vertex"] = c.vertex;
      if (c.type == ConstraintType::Position && c.target) item["target"] = vecJson(*c.target);
      if (c.type == ConstraintType::Position && c.target && c.start && c.end) {
        item["start"] = *c.start;
        item["end"] = *c.end;
      }
      if (c.type == ConstraintType::Normal && c.normal) item["normal"] = vecJson(*c.normal);
      list.push_back(item);
    }
    j["constraints"] = list;
  }
  auto loads = [&](const std::vector<TimedLoad>& in, const char* section, const char* key) {
    if (in.empty()) return;
    OrderedJson list = OrderedJson::array();
    for (const TimedLoad& l : in) {
      OrderedJson item = OrderedJson::object();
      item["vertex"] = l.vertex;
      item[key] = vecJson(l.value);
      if (l.start != 0.0) item["start"] = l.start;
      if (std::isfinite(l.end)) item["end"] = l.end;
      list.push_back(item);
    }
    j[section] = list;
  };
  loads(scene.forces, "forces", "force");
  loads(scene.torques, "torques", "torque");

  if (!scene.edits.empty()) {
    OrderedJson list = OrderedJson::array();
    for (const SceneEdit& e : scene.edits) {
      OrderedJson item = OrderedJson::object();
      item["time"] = e.time;
      if (e.kind == EditKind::Relax) {
        item["action"] = "relax";
      } else if (e.kind == EditKind::ScaleRest) {
        item["action"] = "scale_rest";
        item["factor"] = e.factor;
      } else {
        const BrushSettings& b = e.brush;
        if (e.kind == EditKind::Global) item["global"] = true;
        item["property"] = propertyName(b.property);
        item["mode"] = brushModeName(b.mode);
        if (b.mode != BrushMode::Smooth) item["value"] = b.value;
        item["strength"] = b.strength;
        if (e.kind == EditKind::Brush) {
          if (e.centerVertex)
            item["center"] = *e.centerVertex;
          else if (e.centerPoint)
            item["center"] = vecJson(*e.centerPoint);
          item["radius"] = b.radius;
          item["falloff"] = brushFalloffName(b.falloff);
          item["distance"] = brushDistanceName(b.distance);
        }
      }
      list.push_back(item);
    }
    j["edits"] = list;
  }

  const SimulationSettings& s = scene.simulation;
  OrderedJson sim = OrderedJson::object();
  sim["scheme"] = schemeName(s.scheme);
  if (s.dt) sim["dt"] = *s.dt;
  if (s.dtRatio) sim["dt_ratio"] = *s.dtRatio;
  if (s.steps) sim["steps"] = *s.steps;
  if (s.time) sim["time"] = *s.time;
  if (s.perturb != 0.0) sim["perturb"] = s.perturb;
  if (s.seed != 0) sim["seed"] = s.seed;
  j["simulation"] = sim;

  const CameraSettings& c = scene.camera;
  OrderedJson camera = OrderedJson::object();
  if (c.target) camera["target"] = vecJson(*c.target);
  if (c.distance) camera["distance"] = *c.distance;
  if (c.yaw) camera["yaw"] = *c.yaw;
  if (c.pitch) camera["pitch"] = *c.pitch;
  if (c.fov) camera["fov"] = *c.fov;
  if (!camera.empty()) j["camera"] = camera;
  return j;
}

void saveScene(const SceneDescription& scene, const std::string& path) {
  const std::string text = sceneToJson(scene, path).dump(2) + "\n";
  writeFileAtomically(path, [&](std::ostream& out) { out << text; });
}

}  // namespace zsculpt::io
