#pragma once
// Internal to the cli module: the model flags and run flags of ../shared/notes/cli.md,
// shared by info, simulate, render, subdivide and bench, and how they turn a MESH or SCENE
// argument into a model and a simulation.

#include <CLI/CLI.hpp>
#include <initializer_list>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "zsculpt/io/mesh_io.h"
#include "zsculpt/io/scene.h"
#include "zsculpt/simulation/simulation.h"

namespace zsculpt::cli {

struct LoadedModel {
  Model model;
  std::optional<io::SceneDescription> scene;
  io::MeshLoadReport report;
  std::string source;
};

/// MESH|SCENE plus the uniform model flags (they replace the scene's uniform values;
/// per-vertex values painted in a scene stay).
struct ModelOptions {
  std::string source;
  std::optional<double> mass, damping, stiffness, angularStiffness, rigidity, stiffnessCap,
      restLengthScale;
  std::vector<double> gravity;
  std::string up;  ///< --up: the file's up axis (io::parseUpAxis); empty: the scene's, or auto

  /// Registers the positional MESH|SCENE (required unless `sourceOptional`) and the flags.
  void addTo(CLI::App* app, bool sourceOptional = false);
  [[nodiscard]] LoadedModel load() const;
  /// `values` with the property flags given (--mass ... --gravity) put over them; throws
  /// InvalidInputError naming a flag whose value is out of range.
  [[nodiscard]] UniformProperties withFlags(UniformProperties values) const;
};

/// How long and how finely to simulate, and what acts on the model.
struct RunOptions {
  std::string scheme;
  std::optional<double> dt, dtRatio, time;
  std::optional<long> steps;
  std::optional<double> perturb;
  std::optional<unsigned> seed;
  std::string stateIn, stateOut, csv;
  double startTime = 0.0;  ///< the simulated time the initial state is at (--start-time)
  std::vector<std::string> forces, torques;
  std::vector<std::string> pins, pinNormals;
  bool allowUnstable = false;
  bool driftFilter = true;
  std::optional<double> substepStrain;
  bool json = false;

  void addTo(CLI::App* app);
  /// The scheme, period and step count from the flags, else the scene, else defaults
  /// (default scheme, 0.5 T_max, 1000 steps). Refuses a period above the scheme's stable
  /// limit unless --allow-unstable.
  struct Resolved {
    SimulationSettings settings;
    long steps = 1000;
    double tMax = 0.0;
    /// The run's length in seconds when it was given as a time (--time, or the scene's
    /// /simulation/time) rather than as a step count; render fits its steps to it.
    std::optional<double> seconds;
    /// Whether the step count was given (--steps, or the scene's /simulation/steps).
    bool explicitSteps = false;
    /// The flag that gave the period (--dt, --dt-ratio); empty for a scene's or the
    /// default.
    std::string explicitPeriod;
    /// When the period is above the scheme's stable limit (allowed by --allow-unstable, or
    /// by `open` for a scene's own step): what is wrong, naming where the step came from.
    std::string aboveStableLimit;
  };
  [[nodiscard]] Resolved resolve(const LoadedModel& loaded) const;
  /// Initial state (rest, --state-in, --perturb), loads and constraints (scene, then flags)
  /// on `sim`. A constraint without a target or normal holds the initial state's.
  void prepare(const LoadedModel& loaded, Simulation& sim) const;
  /// After a run that ended at `end` seconds: a warning for each source of loads (the
  /// scene's forces and torques, --force, --torque) with loads that start at or after it
  /// and so never acted, naming the first (as TimedEdits::sayWhatIsLeft does for edits).
  void sayLoadsLeft(const LoadedModel& loaded, double end) const;
};

/// "I" or "I:X,Y,Z" (--pin, --pin-normal); throws InvalidInputError naming the flag.
struct VertexVector {
  Index vertex = 0;
  std::optional<Vec3> value;
};
VertexVector parseVertexVector(const std::string& text, const std::string& flag);

/// "I:FX,FY,FZ[:T0:T1]" as in cli.md; throws InvalidInputError naming the flag.
TimedLoad parseTimedLoad(const std::string& text, const std::string& flag);

/// Two output flags naming one file would leave only the second write: InvalidInputError
/// "<flag>: <path> is also <other flag>'s file" (devices and pipes may take both).
void checkDistinctOutputs(
    std::initializer_list<std::pair<const char*, const std::string*>> outputs);

/// With --json the summary is standard output: an output naming the same file (/dev/stdout,
/// the terminal, the file stdout is redirected to) would mix the two, and a reader could parse
/// neither. InvalidInputError "<flag>: <path> is standard output, where --json writes ...".
void checkOutputsSpareStdout(
    std::initializer_list<std::pair<const char*, const std::string*>> outputs, bool json);

/// The model the command works on, as the last ModelOptions::load() named it, with a note on
/// its busiest vertex where that may need much memory: an out-of-memory error names it.
std::string& modelInWork();

/// The scene's constraints added to `sim` (errors name the scene and the constraint's JSON
/// pointer; a target far from its vertex is warned of). RunOptions::prepare and info.
void addSceneConstraints(const LoadedModel& loaded, Simulation& sim);

/// An output naming one of the run's inputs would destroy it: InvalidInputError "<flag>:
/// <path> is the model's file" (or the scene's mesh, --state-in's file, --script's file) "and would
/// be overwritten". --state-out may name --state-in's file: a state carried on in place.
void checkOutputsSpareInputs(
    std::initializer_list<std::pair<const char*, const std::string*>> outputs,
    const LoadedModel& loaded, const std::string& stateIn = "", const std::string& script = "");

/// After a run wrote `written` frames (frame_*.png) into `dir`: a warning on standard error
/// when the folder holds others too (an earlier run's, which this one did not overwrite).
void warnAboutOtherFrames(const std::string& dir, std::size_t written);

/// A property's name given to --property: its Property, or InvalidInputError "--property: ...".
Property propertyOption(const std::string& name);

/// The scheme --scheme NAME names; an unknown one is an error naming the flag.
Scheme schemeOption(const std::string& name);

/// "0.5 T_max", the period as a share of T_max; "T_max infinite" when nothing is stiff.
std::string shareOfTMax(double period, double tMax);

/// The springs' energy with every edge stretched by its own length and every angle bent by a
/// radian (J): the scale below which an energy is rounding (1e-12 of it: a model at its own
/// rest shape holds about 1e-28 J).
double springEnergyScale(const Model& model);

/// A JSON number that stays valid JSON for infinities (as null).
std::string jsonNumber(double value);
/// A JSON string, quotes included: quotes, backslashes and control characters escaped, so a
/// file name holding any of them still gives a summary that parses.
std::string jsonString(std::string_view text);

}  // namespace zsculpt::cli
