#include "zsculpt/app/commands.h"

#include <cmath>
#include <limits>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>

#include "zsculpt/core/errors.h"
#include "zsculpt/core/overloaded.h"

namespace zsculpt::app {

namespace {

using nlohmann::json;

json vec(const Vec3& v) {
  return json::array({v.x(), v.y(), v.z()});
}

// Infinity is not JSON: written as null.
json number(double value) {
  return std::isfinite(value) ? json(value) : json(nullptr);
}

json centreToJson(const editing::BrushCentre& c) {
  switch (c.kind) {
    case editing::BrushCentre::Kind::Vertex:
      return {{"vertex", c.vertex}};
    case editing::BrushCentre::Kind::FacePoint:
      return {{"face", c.face}, {"point", vec(c.point)}};
    case editing::BrushCentre::Kind::Point:
      return {{"point", vec(c.point)}};
  }
  return {};
}

void brushToJson(json& j, const editing::Brush& b, bool local) {
  j["property"] = std::string(propertyName(b.property));
  j["mode"] = std::string(editing::brushModeName(b.mode));
  j["value"] = b.value;
  j["strength"] = b.strength;
  if (local) {
    j["radius"] = b.radius;
    j["falloff"] = std::string(editing::falloffName(b.falloff));
    j["distance"] = std::string(editing::distanceKindName(b.distance));
  }
}

// Reads the fields of one JSON object, refusing unknown keys and wrong types.
class Reader {
 public:
  Reader(const json& j, std::string where) : j_(j), where_(std::move(where)) {
    if (!j.is_object()) fail("", "a command must be a JSON object");
  }
  [[noreturn]] void fail(const std::string& key, const std::string& reason) const {
    throw InvalidInputError(where_ + (key.empty() ? "" : ": " + key) + ": " + reason);
  }
  bool has(const char* key) const { return j_.contains(key); }
  const json& get(const char* key) {
    used_.insert(key);
    if (!j_.contains(key)) fail(key, "missing");
    return j_.at(key);
  }
  double real(const char* key) {
    const json& v = get(key);
    if (!v.is_number()) fail(key, "expected a number");
    return v.get<double>();
  }
  /// A number, or null for infinity.
  double realOrInfinity(const char* key) {
    const json& v = get(key);
    if (v.is_null()) return std::numeric_limits<double>::infinity();
    if (!v.is_number()) fail(key, "expected a number or null");
    return v.get<double>();
  }
  Index index(const char* key) {
    const json& v = get(key);
    if (!v.is_number_integer()) fail(key, "expected an integer index");
    const auto i = v.get<std::int64_t>();
    if (i < 0 || i > std::numeric_limits<Index>::max()) fail(key, "index out of range");
    return static_cast<Index>(i);
  }
  bool boolean(const char* key) {
    const json& v = get(key);
    if (!v.is_boolean()) fail(key, "expected true or false");
    return v.get<bool>();
  }
  std::string text(const char* key) {
    const json& v = get(key);
    if (!v.is_string()) fail(key, "expected a string");
    return v.get<std::string>();
  }
  Vec3 vec3(const char* key) {
    const json& v = get(key);
    if (!v.is_array() || v.size() != 3 || !v[0].is_number() || !v[1].is_number() ||
        !v[2].is_number())
      fail(key, "expected [x, y, z]");
    return {v[0].get<double>(), v[1].get<double>(), v[2].get<double>()};
  }
  std::optional<Vec3> optionalVec3(const char* key) {
    if (!has(key)) return std::nullopt;
    return vec3(key);
  }
  editing::BrushCentre centre(const char* key) {
    Reader c(get(key), where_ + ": " + key);
    editing::BrushCentre out;
    if (c.has("vertex")) {
      out = editing::BrushCentre::atVertex(c.index("vertex"));
    } else if (c.has("face")) {
      const Index f = c.index("face");
      out = editing::BrushCentre::onFace(f, c.vec3("point"));
    } else {
      out = editing::BrushCentre::atPoint(c.vec3("point"));
    }
    c.finish();
    return out;
  }
  editing::Brush brush(bool local) {
    editing::Brush b;
    try {
      b.property = propertyFromName(text("property"));
      b.mode = editing::brushModeFromName(text("mode"));
      b.value = real("value");
      b.strength = real("strength");
      if (local) {
        b.radius = real("radius");
        b.falloff = editing::falloffFromName(text("falloff"));
        b.distance = editing::distanceKindFromName(text("distance"));
      }
    } catch (const InvalidInputError& e) {
      if (std::string(e.what()).rfind(where_, 0) == 0) throw;
      fail("", e.what());
    }
    return b;
  }
  /// Refuses keys that were not read.
  void finish() const {
    for (auto it = j_.begin(); it != j_.end(); ++it)
      if (!used_.count(it.key())) fail(it.key(), "unknown field");
  }

 private:
  const json& j_;
  std::string where_;
  std::set<std::string> used_;
};

}  // namespace

std::string_view commandName(const Command& command) {
  return std::visit(
      Overloaded{
          [](const Play&) -> std::string_view { return "play"; },
          [](const Pause&) -> std::string_view { return "pause"; },
          [](const StepOnce&) -> std::string_view { return "step"; },
          [](const Reset&) -> std::string_view { return "reset"; },
          [](const SetTimeStep&) -> std::string_view { return "set_time_step"; },
          [](const SetGravity&) -> std::string_view { return "set_gravity"; },
          [](const SetStiffnessCap&) -> std::string_view { return "set_stiffness_cap"; },
          [](const Edit& e) -> std::string_view {
            return std::visit(
                Overloaded{
                    [](const editing::Dab&) -> std::string_view { return "dab"; },
                    [](const editing::GlobalEdit&) -> std::string_view { return "global_edit"; },
                    [](const editing::Relax&) -> std::string_view { return "relax"; },
                    [](const editing::ScaleRest&) -> std::string_view { return "scale_rest"; },
                    [](const editing::Undo&) -> std::string_view { return "undo"; },
                    [](const editing::Redo&) -> std::string_view { return "redo"; },
                },
                e.command);
          },
          [](const AddLoad& l) -> std::string_view {
            return l.kind == LoadKind::Force ? "force" : "torque";
          },
          [](const ClearLoads&) -> std::string_view { return "clear_loads"; },
          [](const Pin&) -> std::string_view { return "pin"; },
          [](const Unpin&) -> std::string_view { return "unpin"; },
          [](const PinBrush&) -> std::string_view { return "pin_brush"; },
          [](const UnpinAll&) -> std::string_view { return "unpin_all"; },
          [](const PinNormal&) -> std::string_view { return "pin_normal"; },
          [](const UnpinNormal&) -> std::string_view { return "unpin_normal"; },
          [](const DragStart&) -> std::string_view { return "drag_start"; },
          [](const DragMove&) -> std::string_view { return "drag_move"; },
          [](const DragEnd&) -> std::string_view { return "drag_end"; },
          [](const MarkSaved&) -> std::string_view { return "mark_saved"; },
      },
      command);
}

std::string describe(const Command& command) {
  if (const auto* e = std::get_if<Edit>(&command)) return editing::describe(e->command);
  std::ostringstream out;
  out << commandName(command);
  std::visit(
      Overloaded{
          [&](const SetTimeStep& s) {
            out << ' ' << schemeName(s.scheme) << ", T = " << s.period << " s";
          },
          [&](const SetGravity& g) { out << ' ' << g.gravity.transpose(); },
          [&](const SetStiffnessCap& c) { out << ' ' << c.cap; },
          [&](const AddLoad& l) {
            out << " (" << l.value.transpose() << ") at vertex " << l.vertex << " for "
                << l.duration << " s";
          },
          [&](const Pin& p) { out << " vertex " << p.vertex; },
          [&](const Unpin& p) { out << " vertex " << p.vertex; },
          [&](const PinBrush& p) { out << (p.pin ? " pin" : " unpin") << ", radius " << p.radius; },
          [&](const PinNormal& p) { out << " vertex " << p.vertex; },
          [&](const UnpinNormal& p) { out << " vertex " << p.vertex; },
          [&](const DragStart& d) { out << " vertex " << d.vertex; },
          [](const auto&) {},
      },
      command);
  return out.str();
}

json commandToJson(const Command& command) {
  json j;
  j["type"] = std::string(commandName(command));
  std::visit(Overloaded{
                 [&](const SetTimeStep& s) {
                   j["scheme"] = std::string(schemeName(s.scheme));
                   j["period"] = s.period;
                 },
                 [&](const SetGravity& g) { j["gravity"] = vec(g.gravity); },
                 [&](const SetStiffnessCap& c) { j["cap"] = number(c.cap); },
                 [&](const Edit& e) {
                   std::visit(
                       Overloaded{
                           [&](const editing::Dab& d) {
                             brushToJson(j, d.brush, true);
                             j["centre"] = centreToJson(d.centre);
                           },
                           [&](const editing::GlobalEdit& g) { brushToJson(j, g.brush, false); },
                           [&](const editing::ScaleRest& s) { j["factor"] = s.factor; },
                           [](const auto&) {},
                       },
                       e.command);
                 },
                 [&](const AddLoad& l) {
                   j["vertex"] = l.vertex;
                   j["value"] = vec(l.value);
                   j["duration"] = number(l.duration);
                 },
                 [&](const Pin& p) {
                   j["vertex"] = p.vertex;
                   if (p.target) j["target"] = vec(*p.target);
                 },
                 [&](const Unpin& p) { j["vertex"] = p.vertex; },
                 [&](const PinBrush& p) {
                   j["centre"] = centreToJson(p.centre);
                   j["radius"] = p.radius;
                   j["pin"] = p.pin;
                 },
                 [&](const PinNormal& p) {
                   j["vertex"] = p.vertex;
                   if (p.normal) j["normal"] = vec(*p.normal);
                 },
                 [&](const UnpinNormal& p) { j["vertex"] = p.vertex; },
                 [&](const DragStart& d) {
                   j["vertex"] = d.vertex;
                   j["target"] = vec(d.target);
                 },
                 [&](const DragMove& d) { j["target"] = vec(d.target); },
                 [](const auto&) {},
             },
             command);
  return j;
}

Command commandFromJson(const json& j, const std::string& where) {
  Reader r(j, where);
  const std::string type = r.text("type");
  Command out;
  auto edit = [](editing::EditCommand e) { return Command(Edit{std::move(e)}); };
  if (type == "play") {
    out = Play{};
  } else if (type == "pause") {
    out = Pause{};
  } else if (type == "step") {
    out = StepOnce{};
  } else if (type == "reset") {
    out = Reset{};
  } else if (type == "set_time_step") {
    SetTimeStep s;
    try {
      s.scheme = schemeFromName(r.text("scheme"));
    } catch (const InvalidInputError& e) {
      r.fail("scheme", e.what());
    }
    s.period = r.real("period");
    out = s;
  } else if (type == "set_gravity") {
    out = SetGravity{r.vec3("gravity")};
  } else if (type == "set_stiffness_cap") {
    out = SetStiffnessCap{r.realOrInfinity("cap")};
  } else if (type == "dab") {
    editing::Dab d;
    d.brush = r.brush(true);
    d.centre = r.centre("centre");
    out = edit(d);
  } else if (type == "global_edit") {
    out = edit(editing::GlobalEdit{r.brush(false)});
  } else if (type == "relax") {
    out = edit(editing::Relax{});
  } else if (type == "scale_rest") {
    out = edit(editing::ScaleRest{r.real("factor")});
  } else if (type == "undo") {
    out = edit(editing::Undo{});
  } else if (type == "redo") {
    out = edit(editing::Redo{});
  } else if (type == "force" || type == "torque") {
    AddLoad l;
    l.kind = type == "force" ? LoadKind::Force : LoadKind::Torque;
    l.vertex = r.index("vertex");
    l.value = r.vec3("value");
    l.duration = r.realOrInfinity("duration");
    out = l;
  } else if (type == "clear_loads") {
    out = ClearLoads{};
  } else if (type == "pin") {
    Pin p;
    p.vertex = r.index("vertex");
    p.target = r.optionalVec3("target");
    out = p;
  } else if (type == "unpin") {
    out = Unpin{r.index("vertex")};
  } else if (type == "pin_brush") {
    PinBrush p;
    p.centre = r.centre("centre");
    p.radius = r.real("radius");
    p.pin = r.boolean("pin");
    out = p;
  } else if (type == "unpin_all") {
    out = UnpinAll{};
  } else if (type == "pin_normal") {
    PinNormal p;
    p.vertex = r.index("vertex");
    p.normal = r.optionalVec3("normal");
    out = p;
  } else if (type == "unpin_normal") {
    out = UnpinNormal{r.index("vertex")};
  } else if (type == "drag_start") {
    DragStart d;
    d.vertex = r.index("vertex");
    d.target = r.vec3("target");
    out = d;
  } else if (type == "drag_move") {
    out = DragMove{r.vec3("target")};
  } else if (type == "drag_end") {
    out = DragEnd{};
  } else if (type == "mark_saved") {
    out = MarkSaved{};
  } else {
    r.fail("type", "unknown command \"" + type +
                       "\" (valid: play, pause, step, reset, set_time_step, set_gravity, "
                       "set_stiffness_cap, dab, global_edit, relax, scale_rest, undo, redo, "
                       "force, torque, clear_loads, pin, unpin, pin_brush, unpin_all, "
                       "pin_normal, unpin_normal, drag_start, drag_move, drag_end, mark_saved)");
  }
  r.finish();
  return out;
}

}  // namespace zsculpt::app
