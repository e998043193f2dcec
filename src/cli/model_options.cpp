#include "model_options.h"

#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "console.h"
#include "zsculpt/core/errors.h"
#include "zsculpt/io/atomic_file.h"
#include "zsculpt/io/state_io.h"
#include "zsculpt/physics/matrices.h"

namespace zsculpt::cli {

void ModelOptions::addTo(CLI::App* app, bool sourceOptional) {
  auto* positional = app->add_option(
      "model", source, "MESH (a file assimp reads, or builtin:NAME) or SCENE (.json)");
  if (!sourceOptional) positional->required();
  app->add_option("--mass", mass, "mass per vertex, kg (default 0.5)");
  app->add_option("--damping", damping, "damping per vertex, kg/s (default 0)");
  app->add_option("--stiffness", stiffness, "radial stiffness per vertex, N/m (default 5)");
  app->add_option("--angular-stiffness", angularStiffness,
                  "angular stiffness per vertex, N m/rad^2 (default 0)");
  app->add_option("--rigidity", rigidity, "rigidity chi in [0, 1] (default 0)");
  app->add_option("--stiffness-cap", stiffnessCap,
                  "kappa_0 of section 4.3: stiffer vertices become partly rigid (default none)");
  app->add_option("--rest-length-scale", restLengthScale,
                  "rest length = scale x length as loaded (default 1; 0: linear springs)");
  app->add_option("--gravity", gravity, "gravity GX,GY,GZ in m/s^2 (default off)")
      ->delimiter(',')
      ->expected(3);
  app->add_option("--up", up,
                  "the mesh file's up axis, turned to zsculpt's +z: auto, x, -x, y, -y, z or -z "
                  "(default auto: y for glTF and Collada, the file's for FBX, z for the rest)");
}

UniformProperties ModelOptions::withFlags(UniformProperties u) const {
  auto flag = [](const std::optional<double>& value, double& target, Property property,
                 const char* name) {
    if (!value) return;
    if (property == Property::Rigidity || property == Property::Mass ||
        property == Property::Damping || property == Property::Stiffness ||
        property == Property::AngularStiffness)
      checkPropertyValue(property, *value, name);
    target = *value;
  };
  flag(mass, u.mass, Property::Mass, "--mass");
  flag(damping, u.damping, Property::Damping, "--damping");
  flag(stiffness, u.stiffness, Property::Stiffness, "--stiffness");
  flag(angularStiffness, u.angularStiffness, Property::AngularStiffness, "--angular-stiffness");
  flag(rigidity, u.rigidity, Property::Rigidity, "--rigidity");
  if (stiffnessCap) {
    if (!(*stiffnessCap > 0.0)) throw InvalidInputError("--stiffness-cap: must be positive");
    u.stiffnessCap = *stiffnessCap;
  }
  if (restLengthScale) {
    if (!(*restLengthScale >= 0.0) || !std::isfinite(*restLengthScale))
      throw InvalidInputError("--rest-length-scale: must be a finite number >= 0");
    u.restLengthScale = *restLengthScale;
  }
  if (!gravity.empty()) {
    u.gravity = Vec3(gravity[0], gravity[1], gravity[2]);
    if (!u.gravity.allFinite()) throw InvalidInputError("--gravity: not finite");
  }
  return u;
}

LoadedModel ModelOptions::load() const {
  LoadedModel loaded;
  loaded.source = source;
  io::SceneDescription scene;
  const bool isScene = io::isSceneFileName(source);
  if (isScene) {
    scene = io::loadScene(source);
  } else {
    scene.mesh = source;
  }
  scene.properties = withFlags(scene.properties);
  const UniformProperties& u = scene.properties;
  if (!up.empty()) {
    try {
      scene.up = io::parseUpAxis(up);
    } catch (const InvalidInputError& e) {
      throw InvalidInputError(std::string("--up: ") + e.what());
    }
  }
  Mesh mesh;
  try {
    mesh = io::loadMeshSource(scene.mesh, &loaded.report, scene.up);
  } catch (const IOError& e) {  // a scene's mesh is said of the scene that names it
    if (!isScene) throw;
    throw IOError(source + ": /mesh: " + e.what());
  } catch (const TopologyError& e) {
    if (!isScene) throw;
    throw TopologyError(source + ": /mesh: " + e.what());
  } catch (const InvalidInputError& e) {
    if (!isScene) throw;
    throw InvalidInputError(source + ": /mesh: " + e.what());
  }
  // A scale that makes some rest length overflow is the scale's fault: said of it, not of
  // "edge 0" (which the model's own check would name).
  for (Index e = 0; e < mesh.numEdges() && u.restLengthScale != 1.0; ++e) {
    const auto [a, b] = mesh.edge(e);
    if (!std::isfinite(u.restLengthScale *
                       (mesh.positions().row(a) - mesh.positions().row(b)).norm()))
      throw InvalidInputError(
          std::string(restLengthScale ? "--rest-length-scale"
                                      : source + ": /properties/rest_length_scale") +
          ": " + jsonNumber(u.restLengthScale) + " makes rest lengths too large to represent");
  }
  {
    // Angle springs grow with the square of a vertex's valence (one per pair of neighbours),
    // and so do Omega^2's rows: a fan of 20,000 triangles about one vertex needs gigabytes.
    // Out of memory anywhere after this, the error names the model and that vertex.
    const CsrIndex& neighbours = mesh.vertexNeighborTable();
    Index busiest = 0, valence = 0;
    for (Index v = 0; v < mesh.numVertices(); ++v) {
      const Index d = neighbours.rowSize(v);
      if (d > valence) {
        valence = d;
        busiest = v;
      }
    }
    std::string context = source;
    if (valence > 1000) {
      context += " (vertex ";
      context += std::to_string(busiest);
      context += " has ";
      context += std::to_string(valence);
      context += " neighbours: its angle springs, one per pair of them, grow with the square)";
    }
    modelInWork() = std::move(context);
  }
  loaded.model = io::buildModel(scene, std::move(mesh));
  // A flag for a property the scene gives every vertex on its own changes nothing (scenes the
  // window saves carry a whole array for every painted property): said, not silent, once the
  // scene has been found valid (a refused run says one line).
  const std::pair<const std::optional<double>*, Property> flagged[] = {
      {&mass, Property::Mass},
      {&damping, Property::Damping},
      {&stiffness, Property::Stiffness},
      {&angularStiffness, Property::AngularStiffness},
      {&rigidity, Property::Rigidity}};
  for (const auto& [value, property] : flagged) {
    if (!value->has_value()) continue;
    std::vector<bool> covered(static_cast<size_t>(loaded.model.mesh.numVertices()), false);
    size_t count = 0;
    for (const io::PropertyOverride& o : scene.overrides) {
      if (o.property != property) continue;
      const size_t elements = o.allElements ? o.values.size() : o.indices.size();
      for (size_t k = 0; k < elements; ++k) {
        const Index v = o.allElements ? static_cast<Index>(k) : o.indices[k];
        if (v >= 0 && v < loaded.model.mesh.numVertices() && !covered[static_cast<size_t>(v)]) {
          covered[static_cast<size_t>(v)] = true;
          ++count;
        }
      }
    }
    if (count > 0 && count == covered.size()) {
      const std::string name(propertyName(property));
      std::string flag = "--" + name;
      std::replace(flag.begin(), flag.end(), '_', '-');
      warn(flag + " " + jsonNumber(**value) + ": " + source + " gives every vertex its own " +
           name + " (/vertex_properties/" + name + "), so the flag changes nothing");
    }
  }
  if (isScene) loaded.scene = std::move(scene);
  return loaded;
}

std::string& modelInWork() {
  static std::string model;
  return model;
}

void RunOptions::addTo(CLI::App* app) {
  app->add_option("--scheme", scheme,
                  "default | paper | exact | symplectic-euler | implicit-euler");
  auto* dtOption = app->add_option("--dt", dt, "time step, seconds");
  app->add_option("--dt-ratio", dtRatio,
                  "time step as a fraction of equation 5's T_max (default 0.5)")
      ->excludes(dtOption);
  auto* stepsOption = app->add_option("--steps", steps, "number of steps (default 1000)");
  app->add_option("--time", time, "simulated time, seconds")->excludes(stepsOption);
  app->add_option("--perturb", perturb, "random initial velocity of this size, zero net momentum");
  app->add_option("--seed", seed, "seed of --perturb, 0 to 4294967295 (default 0)")
      ->check(CLI::Range(0U, 4294967295U));
  app->add_option("--state-in", stateIn, "initial state (CSV x,y,z,vx,vy,vz)");
  app->add_option("--state-out", stateOut, "write the final state here");
  app->add_option("--start-time", startTime,
                  "simulated time the run starts at, seconds (default 0): with --state-in, the "
                  "time that state was written at, so that timed loads and scene edits go on "
                  "(edits due by then are applied before the first step); --time and --steps "
                  "count from it");
  app->add_option("--csv", csv, "diagnostics, one row per step");
  app->add_option("--force", forces, "I:FX,FY,FZ[:T0:T1] force at vertex I (repeatable)");
  app->add_option("--torque", torques, "I:TX,TY,TZ[:T0:T1] torque at vertex I (repeatable)");
  app->add_option("--pin", pins,
                  "I[:X,Y,Z[:T0:T1]] hold vertex I at X,Y,Z (default: where it starts); with "
                  "T0:T1, hold it where it is until T0 s and move it there by T1 s, eased "
                  "(repeatable)");
  app->add_option("--pin-normal", pinNormals,
                  "I[:NX,NY,NZ] hold the normal at vertex I (default: its starting normal; "
                  "repeatable)");
  app->add_flag("--allow-unstable", allowUnstable,
                "run even above the scheme's stable limit (to watch it diverge)");
  // Two callbacks, not CLI11's "!" negation, whose help shows "{false}" after the names.
  auto* driftOn = app->add_flag_callback(
      "--drift-filter", [this] { driftFilter = true; },
      "default scheme on braced models: filter the drift too (the default; "
      "docs/solver.md, section 6)");
  app->add_flag_callback(
         "--no-drift-filter", [this] { driftFilter = false; },
         "default scheme: the kick filter alone")
      ->excludes(driftOn);
  app->add_option("--substep-strain", substepStrain,
                  "default scheme: split a cycle into 2, 4, ... steps when an edge would change "
                  "its length by more than this fraction of its rest length in one (default "
                  "0.2; 0: one step per cycle, the paper's fixed period)");
  app->add_flag("--json", json, "a JSON summary on standard output");
}

namespace {

double parseNumber(std::string_view text, const std::string& what) {
  double value = 0.0;
  const auto [ptr, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc() || ptr != text.data() + text.size() || !std::isfinite(value))
    throw InvalidInputError(what + ": '" + std::string(text) + "' is not a finite number");
  return value;
}

/// A vertex index: a whole number from 0, in digits (the text before a load's or a pin's
/// colon). "3.0" and "1e2" were taken as vertices 3 and 100, where a scene refuses them.
Index parseVertexIndex(const std::string& text, const std::string& what) {
  Index vertex = 0;
  const auto [ptr, ec] = std::from_chars(text.data(), text.data() + text.size(), vertex);
  if (text.empty() || text[0] == '-' || ec != std::errc() || ptr != text.data() + text.size())
    throw InvalidInputError(what + ": '" + text +
                            "' is not a vertex index (a whole number from 0)");
  return vertex;
}

}  // namespace

void checkDistinctOutputs(
    std::initializer_list<std::pair<const char*, const std::string*>> outputs) {
  namespace fs = std::filesystem;
  // Compared where the saves write: a link to a file not yet made names that file too
  // (`--state-out link` to `--csv`'s file got through weakly_canonical: a QA pass).
  auto savedTo = [](const std::string& path) {
    std::error_code ec;
    return fs::weakly_canonical(fs::absolute(io::saveTarget(path).path, ec), ec);
  };
  std::vector<std::pair<const char*, fs::path>> seen;
  for (const auto& [flag, path] : outputs) {
    if (path->empty()) continue;
    std::error_code ec;
    if (fs::exists(*path, ec) && !fs::is_regular_file(*path, ec)) continue;
    const fs::path file = savedTo(*path);
    for (const auto& [other, earlier] : seen)
      if (earlier == file)
        throw InvalidInputError(std::string(flag) + ": " + *path + " is also " + other +
                                "'s file: one output would overwrite the other");
    seen.emplace_back(flag, file);
  }
}

void checkOutputsSpareStdout(
    std::initializer_list<std::pair<const char*, const std::string*>> outputs, bool json) {
  if (!json) return;
  struct stat out {};
  if (::fstat(STDOUT_FILENO, &out) != 0) return;  // closed: nothing to mix with
  struct stat null {};
  const bool haveNull = ::stat("/dev/null", &null) == 0;
  for (const auto& [flag, path] : outputs) {
    struct stat st {};
    if (path->empty() || ::stat(path->c_str(), &st) != 0) continue;
    // Nothing mixes in /dev/null (`--json --csv /dev/null > /dev/null` was refused).
    if (haveNull && S_ISCHR(st.st_mode) && st.st_rdev == null.st_rdev) continue;
    if (st.st_dev == out.st_dev && st.st_ino == out.st_ino)
      throw InvalidInputError(std::string(flag) + ": " + *path +
                              " is standard output, where --json writes its summary: the two "
                              "would mix (name a file, or leave out --json)");
  }
}

void checkOutputsSpareInputs(
    std::initializer_list<std::pair<const char*, const std::string*>> outputs,
    const LoadedModel& loaded, const std::string& stateIn, const std::string& script) {
  namespace fs = std::filesystem;
  // Only existing regular files can be overwritten: built-ins, devices and pipes cannot.
  auto fileOf = [](const std::string& path) -> std::optional<fs::path> {
    std::error_code ec;
    if (path.empty() || !fs::is_regular_file(path, ec)) return std::nullopt;
    return fs::weakly_canonical(fs::absolute(path, ec), ec);
  };
  std::vector<std::pair<std::string, fs::path>> inputs;
  if (const auto model = fileOf(loaded.source)) inputs.emplace_back("the model's file", *model);
  if (loaded.scene)
    if (const auto mesh = fileOf(loaded.scene->mesh))
      inputs.emplace_back("the scene's mesh", *mesh);
  const std::optional<fs::path> state = fileOf(stateIn);
  if (state) inputs.emplace_back("--state-in's file", *state);
  if (const auto scriptFile = fileOf(script)) inputs.emplace_back("--script's file", *scriptFile);
  for (const auto& [flag, path] : outputs) {
    const std::optional<fs::path> file = fileOf(*path);
    if (!file) continue;
    for (const auto& [what, input] : inputs) {
      if (input != *file) continue;
      if (state && input == *state && std::string_view(flag) == "--state-out") continue;
      throw InvalidInputError(std::string(flag) + ": " + *path + " is " + what +
                              " and would be overwritten");
    }
  }
}

void warnAboutOtherFrames(const std::string& dir, std::size_t written) {
  namespace fs = std::filesystem;
  std::error_code ec;
  std::size_t frames = 0;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (name.rfind("frame_", 0) == 0 && it->path().extension() == ".png") ++frames;
  }
  if (frames > written)
    warn(dir + " holds " + std::to_string(frames - written) + " frame_*.png besides this run's " +
         std::to_string(written) + " (an earlier run's: clear the folder to keep only these)");
}

Scheme schemeOption(const std::string& name) {
  try {
    return schemeFromName(name);
  } catch (const InvalidInputError& e) {
    throw InvalidInputError(std::string("--scheme: ") + e.what());
  }
}

Property propertyOption(const std::string& name) {
  try {
    return propertyFromName(name);
  } catch (const InvalidInputError& e) {
    throw InvalidInputError(std::string("--property: ") + e.what());
  }
}

TimedLoad parseTimedLoad(const std::string& text, const std::string& flag) {
  std::vector<std::string> parts;
  std::stringstream in(text);
  std::string part;
  while (std::getline(in, part, ':')) parts.push_back(part);
  const std::string what = flag + " " + text;
  // getline drops a trailing empty field: "0:1,2,3:" would pass as "0:1,2,3".
  if ((parts.size() != 2 && parts.size() != 4) || text.back() == ':')
    throw InvalidInputError(what + ": expected I:X,Y,Z or I:X,Y,Z:T0:T1");
  TimedLoad load;
  load.vertex = parseVertexIndex(parts[0], what);
  std::vector<std::string> xyz;
  std::stringstream v(parts[1]);
  while (std::getline(v, part, ',')) xyz.push_back(part);
  if (xyz.size() != 3 || parts[1].back() == ',')
    throw InvalidInputError(what + ": expected three components X,Y,Z");
  for (int c = 0; c < 3; ++c) load.value[c] = parseNumber(xyz[c], what);
  if (parts.size() == 4) {
    load.start = parseNumber(parts[2], what);
    load.end = parseNumber(parts[3], what);
    // As a scene's loads (scene-format.md), so that a session saved with them opens again.
    if (!(load.start >= 0.0)) throw InvalidInputError(what + ": T0 must be >= 0");
    if (!(load.end > load.start)) throw InvalidInputError(what + ": T1 must be after T0");
  }
  return load;
}

VertexVector parseVertexVector(const std::string& text, const std::string& flag) {
  const std::string what = flag + " " + text;
  const auto colon = text.find(':');
  VertexVector out;
  out.vertex = parseVertexIndex(text.substr(0, colon), what);
  if (colon == std::string::npos) return out;
  std::vector<std::string> xyz;
  std::stringstream in(text.substr(colon + 1));
  std::string part;
  while (std::getline(in, part, ',')) xyz.push_back(part);
  if (xyz.size() != 3 || text.back() == ',')
    throw InvalidInputError(what + (flag == "--pin" ? ": expected I, I:X,Y,Z or I:X,Y,Z:T0:T1"
                                                    : ": expected I or I:X,Y,Z"));
  Vec3 value;
  for (int c = 0; c < 3; ++c) value[c] = parseNumber(xyz[static_cast<size_t>(c)], what);
  out.value = value;
  return out;
}

RunOptions::Resolved RunOptions::resolve(const LoadedModel& loaded) const {
  Resolved r;
  const io::SimulationSettings* fromScene = loaded.scene ? &loaded.scene->simulation : nullptr;
  if (!scheme.empty())
    r.settings.scheme = schemeOption(scheme);
  else if (fromScene)
    r.settings.scheme = schemeFromName(io::schemeName(fromScene->scheme));
  // NaN, infinities and 1e400 (read as infinity) are refused here, not replaced below.
  if (dt && !(*dt > 0.0 && std::isfinite(*dt)))
    throw InvalidInputError("--dt: the time step must be a positive, finite number of seconds");
  if (dtRatio && !(*dtRatio > 0.0 && std::isfinite(*dtRatio)))
    throw InvalidInputError("--dt-ratio: must be a positive, finite fraction of T_max");
  if (time && !(*time >= 0.0 && std::isfinite(*time)))
    throw InvalidInputError("--time: must be a finite number of seconds >= 0");
  const SystemMatrices matrices(loaded.model);
  r.tMax = criticalPeriod(matrices);
  double period = 0.0;
  if (dt) {
    period = *dt;
    r.explicitPeriod = "--dt";
  } else if (dtRatio) {
    period = *dtRatio * r.tMax;
    r.explicitPeriod = "--dt-ratio";
  } else if (fromScene && fromScene->dt) {
    period = *fromScene->dt;
  } else {
    period = (fromScene && fromScene->dtRatio ? *fromScene->dtRatio : 0.5) * r.tMax;
  }
  if (!std::isfinite(period)) {
    // A ratio so large that ratio x T_max overflows is refused, not replaced.
    if (std::isfinite(r.tMax))
      throw InvalidInputError(
          (dtRatio ? std::string("--dt-ratio") : loaded.source + ": /simulation/dt_ratio") +
          ": the time step it gives is not a finite number of seconds");
    // No stiffness at all (a free particle cloud): any step is stable; pick 10 ms.
    period = 0.01;
    if (dtRatio || (fromScene && fromScene->dtRatio))
      warn(std::string(dtRatio ? "--dt-ratio" : loaded.source + ": /simulation/dt_ratio") +
           ": T_max is infinite (nothing stiff), so there is no period to take a share of; "
           "the step is 0.01 s (--dt sets it)");
  }
  if (!(r.tMax > 0.0) && !dt)
    // The ratio is fine; the properties give no period to take it of (equation 5: T_max
    // underflows to 0 for a mass like 1e-320 kg or a stiffness like 1e300 N/m).
    throw InvalidInputError(loaded.source +
                            ": equation 5's critical period T_max is 0 s for these properties "
                            "(a mass too small or a stiffness too large): no time step is stable");
  if (!(period > 0.0))
    throw InvalidInputError(std::string(dt ? "--dt" : "--dt-ratio") +
                            ": the time step must be positive");
  {
    const std::string source = dt                           ? std::string("--dt")
                               : dtRatio                    ? std::string("--dt-ratio")
                               : fromScene && fromScene->dt ? loaded.source + ": /simulation/dt"
                               : fromScene && fromScene->dtRatio
                                   ? loaded.source + ": /simulation/dt_ratio"
                                   : loaded.source + ": the default time step (0.5 T_max)";
    checkPeriodRange(period, source);
  }
  // Refuse a step above the scheme's stable limit. The Gerschgorin bound is cheap and never
  // above the tight one, so the eigenvalue is computed only when the step exceeds it.
  if (beyondStableLimit(period, gershgorinStablePeriodLimit(r.settings.scheme, matrices))) {
    const double limit =
        stablePeriodLimit(r.settings.scheme, matrices, largestEigenvalue(matrices));
    if (beyondStableLimit(period, limit)) {
      // Named where the step came from: a flag, or the scene's own dt or dt_ratio.
      const std::string source = dt                           ? std::string("--dt")
                                 : dtRatio                    ? std::string("--dt-ratio")
                                 : fromScene && fromScene->dt ? loaded.source + ": /simulation/dt"
                                 : fromScene && fromScene->dtRatio
                                     ? loaded.source + ": /simulation/dt_ratio"
                                     : std::string("the default time step");
      std::ostringstream msg;
      msg.precision(6);
      msg << source << ": time step " << period << " s (" << period / r.tMax << " T_max) is "
          << (period > limit * (1.0 + 1e-9) ? "above" : "at") << " the stable limit " << limit
          << " s (" << limit / r.tMax << " T_max) of scheme " << schemeName(r.settings.scheme);
      const VectorX& g = matrices.dampingCoefficient();
      const double dampingRate = g.size() > 0 ? g.maxCoeff() : 0.0;
      if (dampingRate > 0.0 && limit == 1.0 / dampingRate)
        msg << " (equation 4: its damping factor 1 - gamma T must stay positive, gamma = "
               "damping / (2 mass) = "
            << dampingRate << " /s at its most)";
      r.aboveStableLimit = msg.str();
      if (!allowUnstable)
        throw InvalidInputError(msg.str() + "; pass --allow-unstable to run it anyway");
    }
  }
  r.settings.period = period;
  r.settings.stepper.driftFilter = driftFilter;
  if (substepStrain) {
    if (!(*substepStrain >= 0.0) || !std::isfinite(*substepStrain)) {
      std::ostringstream msg;
      msg << "--substep-strain " << *substepStrain
          << ": must be 0 (one step per cycle) or a positive fraction";
      throw InvalidInputError(msg.str());
    }
    r.settings.substepStrain = *substepStrain;
  }
  // A simulated time as a step count, refused (naming where the time came from) when the
  // count would not fit: the cast of a larger double is undefined, and came out negative.
  auto stepsFor = [&](double seconds, const std::string& where) {
    const double count = std::ceil(seconds / period - 1e-9);
    if (!(count < 0x1p62)) {
      std::ostringstream msg;
      msg.precision(6);
      msg << where << ": " << seconds << " s is too many steps of " << period << " s";
      throw InvalidInputError(msg.str());
    }
    return std::max(0L, static_cast<long>(count));
  };
  if (steps) {
    r.steps = *steps;
    r.explicitSteps = true;
  } else if (time) {
    r.steps = stepsFor(*time, "--time");
    r.seconds = *time;
  } else if (fromScene && fromScene->steps) {
    r.steps = static_cast<long>(*fromScene->steps);
    r.explicitSteps = true;
  } else if (fromScene && fromScene->time) {
    r.steps = stepsFor(*fromScene->time, loaded.source + ": /simulation/time");
    r.seconds = *fromScene->time;
  }
  if (r.steps < 0) throw InvalidInputError("--steps: must not be negative");
  return r;
}

namespace {

// A target far from its vertex without a travel is reached in one cycle: said, with the way
// to move it there over time.
void warnIfFarFromVertex(const Simulation& sim, const std::string& what, Index vertex,
                         const Vec3& target, const std::string& remedy) {
  const Mesh& mesh = sim.model().mesh;
  if (vertex < 0 || vertex >= mesh.numVertices()) return;
  const double edge = mesh.meanEdgeLengthAt(vertex, sim.state().position);
  const double distance = (target - sim.state().position.row(vertex).transpose()).norm();
  if (!(edge > 0.0 && distance > edge)) return;
  std::ostringstream msg;
  msg.precision(3);
  msg << what << ": the target is " << distance << " from the vertex (" << distance / edge
      << " of its edge lengths), reached in one cycle, which jerks the model; " << remedy;
  warn(msg.str());
}

}  // namespace

void addSceneConstraints(const LoadedModel& loaded, Simulation& sim) {
  if (!loaded.scene) return;
  for (size_t k = 0; k < loaded.scene->constraints.size(); ++k) {
    const io::ConstraintSpec& c = loaded.scene->constraints[k];
    const std::string where = loaded.source + ": /constraints/" + std::to_string(k);
    try {
      if (c.type == io::ConstraintType::Position && c.target && c.start && c.end) {
        sim.addPositionConstraint(c.vertex, *c.target, PinTravel{*c.start, *c.end});
      } else if (c.type == io::ConstraintType::Position) {
        if (c.target)
          warnIfFarFromVertex(sim, where, c.vertex, *c.target,
                              "give it \"start\" and \"end\" to move it there over time");
        sim.addPositionConstraint(c.vertex, c.target);
      } else {
        sim.addNormalConstraint(c.vertex, c.normal);
      }
    } catch (const InvalidInputError& e) {
      throw InvalidInputError(where + ": " + e.what());
    }
  }
}

void RunOptions::sayLoadsLeft(const LoadedModel& loaded, double end) const {
  // Said, not left silent: a force from t = 10 s in a run of 3 s did nothing, and the run
  // exited 0 as if it had pushed (a QA pass).
  auto say = [&](const std::string& first, double start, size_t more) {
    std::ostringstream text;
    text.precision(6);
    text << first << " starts at t = " << start << " s";
    if (more > 0) text << " and " << more << " more like it";
    text << ", at or after the run's end (t = " << end
         << " s): " << (more > 0 ? "they never act" : "it never acts")
         << " (--time or --steps longer would reach " << (more > 0 ? "them" : "it") << ")";
    warn(text.str());
  };
  const double slack = 1e-9 * std::max(1.0, std::abs(end));
  if (loaded.scene)
    for (const auto& [key, list] : {std::pair{"forces", &loaded.scene->forces},
                                    std::pair{"torques", &loaded.scene->torques}}) {
      size_t late = 0, first = 0;
      for (size_t i = 0; i < list->size(); ++i)
        if ((*list)[i].start >= end - slack && !(late++)) first = i;
      if (late)
        say(loaded.source + ": /" + key + "/" + std::to_string(first), (*list)[first].start,
            late - 1);
    }
  for (const auto& [flag, texts] :
       {std::pair{"--force", &forces}, std::pair{"--torque", &torques}}) {
    size_t late = 0, first = 0;
    for (size_t i = 0; i < texts->size(); ++i)
      if (parseTimedLoad((*texts)[i], flag).start >= end - slack && !(late++)) first = i;
    if (late)
      say(std::string(flag) + " " + (*texts)[first], parseTimedLoad((*texts)[first], flag).start,
          late - 1);
  }
}

void RunOptions::prepare(const LoadedModel& loaded, Simulation& sim) const {
  State state = State::atRest(loaded.model.mesh);
  if (!stateIn.empty()) state = io::loadState(stateIn, loaded.model.mesh.numVertices());
  // The scene's perturbation is part of its own initial state: a state given with --state-in
  // replaces that state, perturbation included (added again, a run continued from its own
  // --state-out did not continue). An explicit --perturb is added to whatever state there is.
  const double amplitude =
      perturb ? *perturb
              : (loaded.scene && stateIn.empty() ? loaded.scene->simulation.perturb : 0.0);
  if (!(amplitude >= 0.0) || !std::isfinite(amplitude))
    throw InvalidInputError("--perturb: must be a finite number >= 0");
  if (amplitude > 0.0) {
    const unsigned s =
        seed ? *seed : (loaded.scene ? static_cast<unsigned>(loaded.scene->simulation.seed) : 0u);
    Points kick;
    randomVelocity(loaded.model.properties.mass, amplitude, s, kick);
    state.velocity += kick;
    const double kinetic = 0.5 * (loaded.model.properties.mass.array() *
                                  state.velocity.rowwise().squaredNorm().array())
                                     .sum();
    if (!state.velocity.allFinite() || !std::isfinite(kinetic))
      throw InvalidInputError(
          std::string(perturb ? "--perturb" : loaded.source + ": /simulation/perturb") + ": " +
          jsonNumber(amplitude) + " m/s gives velocities too large to represent");
  }
  // A state file holds positions and velocities only (cli.md): the time comes from the flag.
  if (!(startTime >= 0.0) || !std::isfinite(startTime))
    throw InvalidInputError("--start-time: must be a finite number of seconds >= 0");
  state.time = startTime;
  sim.setState(state);
  if (loaded.scene) {
    for (const io::TimedLoad& f : loaded.scene->forces)
      sim.addForce(TimedLoad{f.vertex, f.value, f.start, f.end});
    for (const io::TimedLoad& t : loaded.scene->torques)
      sim.addTorque(TimedLoad{t.vertex, t.value, t.start, t.end});
  }
  // A load the simulation refuses (a vertex out of range) is said of the flag that gave it.
  auto addLoad = [&](const std::string& text, const char* flag, bool torque) {
    const TimedLoad load = parseTimedLoad(text, flag);
    try {
      torque ? sim.addTorque(load) : sim.addForce(load);
    } catch (const InvalidInputError& e) {
      throw InvalidInputError(std::string(flag) + " " + text + ": " + e.what());
    }
  };
  for (const std::string& f : forces) addLoad(f, "--force", false);
  for (const std::string& t : torques) addLoad(t, "--torque", true);
  // Constraints (section 6): the scene's, then the flags'. Errors name where they came from.
  addSceneConstraints(loaded, sim);
  auto constrain = [&](const std::vector<std::string>& texts, const std::string& flag,
                       bool position) {
    for (const std::string& text : texts) {
      // --pin I:X,Y,Z:T0:T1: a travel, written as a timed load is.
      const auto colons = std::count(text.begin(), text.end(), ':');
      if (position && colons == 2)
        throw InvalidInputError(flag + " " + text + ": expected I, I:X,Y,Z or I:X,Y,Z:T0:T1");
      if (position && colons == 3) {
        const TimedLoad travel = parseTimedLoad(text, flag);
        try {
          sim.addPositionConstraint(travel.vertex, travel.value,
                                    PinTravel{travel.start, travel.end});
        } catch (const InvalidInputError& e) {
          throw InvalidInputError(flag + " " + text + ": " + e.what());
        }
        continue;
      }
      const VertexVector v = parseVertexVector(text, flag);
      if (position && v.value) {
        std::ostringstream remedy;
        remedy << flag << " " << text << ":0:1 moves it there over the first second";
        warnIfFarFromVertex(sim, flag + " " + text, v.vertex, *v.value, remedy.str());
      }
      try {
        if (position)
          sim.addPositionConstraint(v.vertex, v.value);
        else
          sim.addNormalConstraint(v.vertex, v.value);
      } catch (const InvalidInputError& e) {
        throw InvalidInputError(flag + " " + text + ": " + e.what());
      }
    }
  };
  constrain(pins, "--pin", true);
  constrain(pinNormals, "--pin-normal", false);

  // A clock this far out cannot count the steps: with --start-time 1e17 every step left the
  // time where it was (a QA pass), and loads and edits would never come.
  const double period = sim.period();
  const double counted = (startTime + period) - startTime;
  if (!(std::abs(counted - period) <= 1e-6 * period)) {
    std::ostringstream msg;
    msg << "--start-time: " << startTime << " s is too large for steps of " << period
        << " s: the clock (a double) would count each step as " << counted << " s";
    throw InvalidInputError(msg.str());
  }
  // A start whose energy is not finite is input out of range, not a divergence: it was
  // reported as one (exit 3) for --rest-length-scale 1e300, velocities of 1e300 in a state
  // file and --gravity 1e308,1e308,0 (a QA pass).
  const Diagnostics start = sim.diagnostics();
  const std::string where = loaded.source + ": the start's ";
  if (!std::isfinite(start.kinetic))
    throw InvalidInputError(where + "kinetic energy is not finite: its velocities (" +
                            (stateIn.empty() ? std::string("the perturbation") : stateIn) +
                            ") are beyond what a double holds");
  if (!std::isfinite(start.potential.radial) || !std::isfinite(start.potential.angular))
    throw InvalidInputError(where +
                            "springs' energy is not finite: a stiffness, rest length (--rest-"
                            "length-scale) or position is beyond what a double holds");
  if (!std::isfinite(start.potential.gravity))
    throw InvalidInputError(where +
                            "gravity energy is not finite: --gravity (or the scene's) "
                            "times the masses and heights is beyond what a double holds");
}

double springEnergyScale(const Model& model) {
  const PhysicalProperties& p = model.properties;
  const Index edges = model.mesh.numEdges();
  const double edge = edges > 0 ? model.mesh.meanEdgeLength() : 0.0;
  const double radial =
      edges > 0 ? 0.5 * p.stiffness.cwiseAbs().maxCoeff() * edge * edge * static_cast<double>(edges)
                : 0.0;
  const double angular = model.angles.size() > 0 ? 0.5 * p.angularStiffness.cwiseAbs().maxCoeff() *
                                                       static_cast<double>(model.angles.size())
                                                 : 0.0;
  return radial + angular;
}

std::string jsonNumber(double value) {
  if (!std::isfinite(value)) return "null";
  std::ostringstream out;
  out.precision(17);
  out << value;
  return out.str();
}

std::string shareOfTMax(double period, double tMax) {
  if (!std::isfinite(tMax)) return "T_max infinite";
  std::ostringstream out;
  out << period / tMax << " T_max";
  return out.str();
}

std::string jsonString(std::string_view text) {
  // nlohmann's escaping; bytes that are not UTF-8 (a file name may hold any) become U+FFFD,
  // so the summary always parses.
  return nlohmann::json(std::string(text))
      .dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

}  // namespace zsculpt::cli
