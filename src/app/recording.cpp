#include "zsculpt/app/recording.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

#include "zsculpt/app/view.h"
#include "zsculpt/core/errors.h"
#include "zsculpt/io/atomic_file.h"
#include "zsculpt/io/mesh_io.h"
#include "zsculpt/io/state_io.h"
#include "zsculpt/render/renderer.h"

namespace zsculpt::app {

namespace {

using nlohmann::json;
using nlohmann::ordered_json;

std::string hex(std::uint64_t v) {
  char text[17];
  std::snprintf(text, sizeof text, "%016llx", static_cast<unsigned long long>(v));
  return text;
}

std::uint64_t parseHex(const json& j, const std::string& where) {
  // Sixteen hex digits and nothing else: stoull alone took a sign, "0x" and spaces
  // ("-000000000000001" was compared as ffffffffffffffff).
  const std::string text = j.is_string() ? j.get<std::string>() : std::string();
  if (text.size() != 16 || !std::all_of(text.begin(), text.end(), [](char c) {
        return std::isxdigit(static_cast<unsigned char>(c)) != 0;
      }))
    throw InvalidInputError(where + ": expected a 16-digit hexadecimal hash");
  try {
    size_t used = 0;
    const auto v = std::stoull(text, &used, 16);
    if (used != 16) throw std::invalid_argument("hash");
    return v;
  } catch (const std::exception&) {
    throw InvalidInputError(where + ": expected a 16-digit hexadecimal hash");
  }
}

ordered_json pointsJson(const Points& p) {
  ordered_json rows = ordered_json::array();
  for (Index i = 0; i < p.rows(); ++i) rows.push_back({p(i, 0), p(i, 1), p(i, 2)});
  return rows;
}

Points pointsFromJson(const json& j, const std::string& where, Index rows) {
  if (!j.is_array() || static_cast<Index>(j.size()) != rows)
    throw InvalidInputError(where + ": expected " + std::to_string(rows) + " rows [x, y, z]");
  Points p(rows, 3);
  for (Index i = 0; i < rows; ++i) {
    const json& r = j[static_cast<size_t>(i)];
    if (!r.is_array() || r.size() != 3 || !r[0].is_number() || !r[1].is_number() ||
        !r[2].is_number())
      throw InvalidInputError(where + ": row " + std::to_string(i) + ": expected [x, y, z]");
    for (int c = 0; c < 3; ++c) p(i, c) = r[static_cast<size_t>(c)].get<double>();
  }
  return p;
}

SessionSetup setupFromHeader(const json& header, const std::string& path,
                             std::optional<std::uint64_t>& meshHashOut) {
  const std::string where = path + ": line 1";
  for (auto it = header.begin(); it != header.end(); ++it) {
    static const char* keys[] = {"zsculpt_recording", "scheme", "period", "mesh_hash", "scene",
                                 "initial_state",     "source"};
    if (std::find_if(std::begin(keys), std::end(keys),
                     [&](const char* k) { return it.key() == k; }) == std::end(keys))
      throw InvalidInputError(where + ": " + it.key() + ": unknown field");
  }
  const json& version = header.at("zsculpt_recording");
  if (!version.is_number_integer() || version.get<int>() != kRecordingVersion)
    throw InvalidInputError(where + ": unsupported recording version (this program reads " +
                            std::to_string(kRecordingVersion) + ")");
  if (!header.contains("scene") || !header.contains("scheme") || !header.contains("period"))
    throw InvalidInputError(where + ": the header needs scene, scheme and period");
  SessionSetup setup;
  try {
    setup.scene = io::sceneFromJson(header.at("scene"), path);
    // Recordings made before meshes were turned up (their scene has no "up", which
    // sceneToJson now always writes) loaded every file as it was: so does their replay.
    if (!header.at("scene").contains("up")) setup.scene.up = io::UpAxis::PlusZ;
  } catch (const InvalidInputError& e) {
    throw InvalidInputError(where + ": scene: " + e.what());
  }
  const json& scheme = header.at("scheme");
  if (!scheme.is_string()) throw InvalidInputError(where + ": scheme: expected a name");
  try {
    setup.scheme = schemeFromName(scheme.get<std::string>());
  } catch (const InvalidInputError& e) {
    throw InvalidInputError(where + ": scheme: " + e.what());
  }
  const json& period = header.at("period");
  if (!period.is_number() || !(period.get<double>() > 0.0) || !std::isfinite(period.get<double>()))
    throw InvalidInputError(where + ": period: expected a positive number of seconds");
  setup.period = period.get<double>();
  if (header.contains("mesh_hash"))
    meshHashOut = parseHex(header.at("mesh_hash"), where + ": mesh_hash");
  io::MeshLoadReport loadReport;
  setup.mesh = io::loadMeshSource(setup.scene.mesh, &loadReport, setup.scene.up);
  if (meshHashOut && meshHash(setup.mesh) != *meshHashOut)
    throw InvalidInputError(
        path + ": the mesh " + setup.scene.mesh +
        " is not the one this session was recorded with (its hash differs)" +
        (loadReport.facesReversed > 0
             ? "; this version winds its faces consistently on import (" +
                   std::to_string(loadReport.facesReversed) +
                   " reversed), which a recording made before that cannot replay"
             : ""));
  if (header.contains("initial_state")) {
    const json& s = header.at("initial_state");
    if (!s.is_object() || !s.contains("position") || !s.contains("velocity"))
      throw InvalidInputError(where + ": initial_state: needs position and velocity");
    State state;
    const Index n = setup.mesh.numVertices();
    state.position = pointsFromJson(s.at("position"), where + ": initial_state/position", n);
    state.velocity = pointsFromJson(s.at("velocity"), where + ": initial_state/velocity", n);
    if (s.contains("time")) {
      if (!s.at("time").is_number())
        throw InvalidInputError(where + ": initial_state/time: not a number");
      state.time = s.at("time").get<double>();
    }
    setup.initial = std::move(state);
  }
  return setup;
}

}  // namespace

nlohmann::json recordingHeader(const SessionSetup& setup, const std::string& recordingPath) {
  ordered_json h = ordered_json::object();
  h["zsculpt_recording"] = kRecordingVersion;
  h["source"] = setup.scene.sourcePath.empty() ? setup.scene.mesh : setup.scene.sourcePath;
  h["scheme"] = std::string(schemeName(setup.scheme));
  h["period"] = setup.period;
  h["mesh_hash"] = hex(meshHash(setup.mesh));
  h["scene"] = io::sceneToJson(setup.scene, recordingPath);
  if (setup.initial) {
    ordered_json s = ordered_json::object();
    s["position"] = pointsJson(setup.initial->position);
    s["velocity"] = pointsJson(setup.initial->velocity);
    s["time"] = setup.initial->time;
    h["initial_state"] = s;
  }
  // Returned as plain json for the API; its dump keeps the order of insertion only as
  // ordered_json, so the recorder writes the ordered form itself.
  return json::parse(h.dump());
}

Recording readRecording(const std::string& path) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec))
    throw IOError(path + ": is a folder, not a recording");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw IOError(path + ": cannot open: " + std::strerror(errno));
  Recording rec;
  std::string line;
  int number = 0;
  std::uint64_t lastCycle = 0;
  int footerLine = 0;  // the line of end_cycle, which ends the session: nothing may follow
  while (std::getline(in, line)) {
    ++number;
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    const std::string where = path + ": line " + std::to_string(number);
    if (footerLine)
      throw InvalidInputError(where + ": comes after the footer (end_cycle, line " +
                              std::to_string(footerLine) + "), which ends the session");
    json j;
    // A key given twice in one object: the parser keeps the last silently (a footer's
    // "end_cycle" twice read the second). Refused, as the scene reader refuses it.
    std::vector<std::set<std::string>> keys;
    std::string twice;
    auto noDuplicateKeys = [&](int, json::parse_event_t event, json& parsed) {
      if (event == json::parse_event_t::object_start) {
        keys.emplace_back();
      } else if (event == json::parse_event_t::object_end) {
        if (!keys.empty()) keys.pop_back();
      } else if (event == json::parse_event_t::key && !keys.empty()) {
        const std::string key = parsed.get<std::string>();
        if (!keys.back().insert(key).second && twice.empty()) twice = key;
      }
      return true;
    };
    try {
      j = json::parse(line, noDuplicateKeys);
    } catch (const json::exception& e) {
      std::string what = e.what();
      const auto close = what.find("] ");
      if (close != std::string::npos) what.erase(0, close + 2);
      throw InvalidInputError(where + ": " + what);
    }
    if (!twice.empty()) throw InvalidInputError(where + ": " + twice + ": given twice");
    if (!j.is_object()) throw InvalidInputError(where + ": expected a JSON object");
    if (j.contains("zsculpt_recording")) {
      if (rec.setup || !rec.commands.empty() || !rec.ui.empty())
        throw InvalidInputError(where + ": the header must be the first line");
      rec.setup = setupFromHeader(j, path, rec.meshHash);
    } else if (j.contains("end_cycle")) {
      // Strict, as the header is: a misspelt "state_hash" would leave the replay uncompared.
      for (auto it = j.begin(); it != j.end(); ++it)
        if (it.key() != "end_cycle" && it.key() != "time" && it.key() != "state_hash")
          throw InvalidInputError(where + ": " + it.key() +
                                  ": unknown field of the footer (end_cycle, time, state_hash)");
      if (j.contains("time") &&
          (!j.at("time").is_number() || !std::isfinite(j.at("time").get<double>()) ||
           j.at("time").get<double>() < 0.0))
        throw InvalidInputError(where + ": time: expected a number of seconds >= 0");
      footerLine = number;
      const json& e = j.at("end_cycle");
      if (!e.is_number_unsigned())
        throw InvalidInputError(where + ": end_cycle: expected a cycle count");
      rec.endCycle = e.get<std::uint64_t>();
      if (*rec.endCycle > kMaxRecordedCycle)
        throw InvalidInputError(where + ": end_cycle " + std::to_string(*rec.endCycle) +
                                " is more cycles than a session records (at most " +
                                std::to_string(kMaxRecordedCycle) + ")");
      if (j.contains("state_hash"))
        rec.stateHash = parseHex(j.at("state_hash"), where + ": state_hash");
    } else if (j.contains("ui")) {
      rec.ui.emplace_back(number, std::move(j));
    } else {
      if (!j.contains("cycle") || !j.at("cycle").is_number_unsigned())
        throw InvalidInputError(where + ": expected \"cycle\" (a step count) with the command");
      const std::uint64_t cycle = j.at("cycle").get<std::uint64_t>();
      if (cycle > kMaxRecordedCycle)
        throw InvalidInputError(where + ": cycle " + std::to_string(cycle) +
                                " is more cycles than a session records (at most " +
                                std::to_string(kMaxRecordedCycle) + ")");
      if (cycle < lastCycle)
        throw InvalidInputError(where + ": cycle " + std::to_string(cycle) + " comes after cycle " +
                                std::to_string(lastCycle));
      lastCycle = cycle;
      j.erase("cycle");
      rec.commands.push_back({cycle, commandFromJson(j, where)});
    }
  }
  if (in.bad()) throw IOError(path + ": read error");
  if (rec.endCycle && !rec.commands.empty() && rec.commands.back().cycle > *rec.endCycle)
    throw InvalidInputError(path + ": a command comes after end_cycle");
  return rec;
}

// ---- Recorder --------------------------------------------------------------------------------

Recorder::Recorder(std::string path, const SessionSetup& setup) : path_(std::move(path)) {
  ordered_json h = ordered_json::object();
  const json plain = recordingHeader(setup, path_);
  // Fixed key order for people reading the file.
  for (const char* key : {"zsculpt_recording", "source", "scheme", "period", "mesh_hash"})
    h[key] = plain.at(key);
  h["scene"] = io::sceneToJson(setup.scene, path_);
  if (plain.contains("initial_state")) h["initial_state"] = plain.at("initial_state");
  text_ = h.dump() + "\n";
  // Fail early (before a whole session is lost) when the file cannot be written.
  io::checkOutputFile(path_);
  // The final save makes a missing folder; made now, it takes the journal from the start.
  const std::filesystem::path folder = std::filesystem::path(path_).parent_path();
  if (!folder.empty() && !std::filesystem::exists(folder))
    io::ensureWritableDirectory(folder.string());
  // The journal: what a session killed outright leaves. Without one (a folder that takes
  // the recording but not a second file) the session is recorded as before.
  // A recording to a device or a pipe (/dev/null) is not one to recover: no journal.
  std::error_code ec;
  const auto kind = std::filesystem::status(path_, ec).type();
  if (kind == std::filesystem::file_type::not_found ||
      kind == std::filesystem::file_type::regular) {
    std::string name;
    int error = 0;
    for (int n = 1; n <= 99 && journal_ < 0; ++n) {
      // An earlier session's journal (it was killed) is kept: the next free name is taken.
      name = path_;
      name += ".partial";
      if (n > 1) name += '.' + std::to_string(n);
      journal_ = ::open(name.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
      error = errno;
      if (journal_ >= 0)
        journalPath_ = name;
      else if (error != EEXIST)
        break;
    }
    if (journal_ < 0 && error == EEXIST) {
      journalProblem_ = path_;
      journalProblem_ +=
          ".partial to .partial.99: all taken by journals of killed sessions "
          "(replay or remove them)";
    } else if (journal_ < 0) {
      journalProblem_ = name;
      journalProblem_ += ": cannot create: ";
      journalProblem_ += std::strerror(error);
    }
  }
  journal(text_);
}

Recorder::~Recorder() {
  if (finished_) return;
  try {
    write(false);
    closeJournal(true);
  } catch (const std::exception&) {
    // Destructors must not throw; finish() reports write errors. The journal stays.
    closeJournal(false);
  }
}

void Recorder::journal(const std::string& line) {
  // One write a line: a process killed between two lines leaves whole lines.
  std::size_t done = 0;
  while (journal_ >= 0 && done < line.size()) {
    const ssize_t wrote = ::write(journal_, line.data() + done, line.size() - done);
    if (wrote > 0) {
      done += static_cast<std::size_t>(wrote);
    } else if (!(wrote < 0 && errno == EINTR)) {
      // A full disk (or a file size limit): the part of the line that went out is cut off
      // again, so that the journal ends on a whole line and replays; journaling stops.
      // Should the cut fail too, a replay names the broken last line.
      [[maybe_unused]] const int cut = ::ftruncate(journal_, static_cast<off_t>(journalBytes_));
      closeJournal(false);
      return;
    }
  }
  journalBytes_ += static_cast<std::int64_t>(done);
}

void Recorder::closeJournal(bool remove) {
  if (journal_ < 0) return;
  ::close(journal_);
  journal_ = -1;
  if (remove) {
    std::error_code ec;
    std::filesystem::remove(journalPath_, ec);
  }
}

void Recorder::record(std::uint64_t cycle, const Command& command) {
  ordered_json line = ordered_json::object();
  line["cycle"] = cycle;
  const json c = commandToJson(command);
  line["type"] = c.at("type");
  for (auto it = c.begin(); it != c.end(); ++it)
    if (it.key() != "type") line[it.key()] = it.value();
  std::string text = line.dump();
  text += '\n';
  std::lock_guard lock(mutex_);
  text_ += text;
  journal(text);
}

void Recorder::finish(std::uint64_t endCycle, const State& finalState) {
  ordered_json footer = ordered_json::object();
  footer["end_cycle"] = endCycle;
  footer["time"] = finalState.time;
  footer["state_hash"] = hex(stateHash(finalState));
  {
    std::lock_guard lock(mutex_);
    footer_ = footer.dump() + "\n";
  }
  write(true);
  finished_ = true;
  closeJournal(true);
}

std::size_t Recorder::size() const {
  std::lock_guard lock(mutex_);
  return text_.size();
}

void Recorder::write(bool withFooter) {
  std::lock_guard lock(mutex_);
  io::writeFileAtomically(path_, [&](std::ostream& out) {
    out << text_;
    if (withFooter) out << footer_;
  });
}

// ---- replay ------------------------------------------------------------------------------------

ReplayResult replay(const Recording& recording, const ReplayOptions& options) {
  if (!recording.setup)
    throw InvalidInputError(
        "recording: no header line (a script without a model cannot be replayed)");
  Session session(*recording.setup);
  ReplayResult result;
  std::uint64_t end = recording.endCycle.value_or(options.endCycle);
  if (!recording.endCycle && !recording.commands.empty())
    end = std::max(end, recording.commands.back().cycle);

  const bool writing = !options.outDir.empty();
  std::unique_ptr<render::OffscreenRenderer> renderer;
  std::unique_ptr<FrameBuilder> builder;
  ViewSettings view;
  render::Camera camera;
  Snapshot snapshot;
  if (writing) {
    io::checkCreatableDirectory(options.outDir);  // made by the first file written
    if (options.frames) {
      try {
        renderer = std::make_unique<render::OffscreenRenderer>();
        renderer->checkSize(options.width, options.height, "--size");
      } catch (const IOError& e) {
        renderer.reset();
        result.notices.push_back(std::string("frames skipped: ") + e.what());
      }
    }
    if (renderer) {
      const Mesh& mesh = session.model().mesh;
      builder = std::make_unique<FrameBuilder>(mesh);
      view.levels = affordableLevels(mesh, options.levels);
      builder->setLevels(view.levels);
      view.colourByProperty = options.property.has_value();
      session.fill(snapshot, options.property.value_or(Property::Stiffness));
      render::Frame& f = builder->build(snapshot, view, camera);
      render::frameScene(f, static_cast<double>(options.width) / options.height);
      camera = f.camera;
      applyCameraSettings(recording.setup->scene.camera, camera);
    }
  }
  std::ostringstream csv;
  csv.precision(17);
  if (writing) csv << "step,time,kinetic,potential,total,px,py,pz,lx,ly,lz\n";
  auto row = [&](std::uint64_t step) {
    const Diagnostics d = session.simulation().diagnostics();
    csv << step << ',' << session.simulation().time() << ',' << d.kinetic << ','
        << d.potential.total() << ',' << d.total() << ',' << d.momentum.x() << ',' << d.momentum.y()
        << ',' << d.momentum.z() << ',' << d.angularMomentum.x() << ',' << d.angularMomentum.y()
        << ',' << d.angularMomentum.z() << '\n';
  };
  auto frame = [&](const std::string& name) {
    if (!renderer) return;
    session.fill(snapshot, options.property.value_or(Property::Stiffness));
    renderer->renderPng(builder->build(snapshot, view, camera), options.width, options.height,
                        (std::filesystem::path(options.outDir) / name).string());
    ++result.framesWritten;
    if (name.rfind("frame_", 0) == 0) ++result.numberedFramesWritten;
  };
  auto frameName = [](std::uint64_t cycle) {
    char name[32];
    std::snprintf(name, sizeof name, "frame_%06llu.png", static_cast<unsigned long long>(cycle));
    return std::string(name);
  };

  size_t next = 0;
  std::vector<std::string> notices;
  if (writing) row(0);
  for (std::uint64_t cycle = 0;; ++cycle) {
    while (next < recording.commands.size() && recording.commands[next].cycle == cycle) {
      const Command& c = recording.commands[next].command;
      try {
        session.apply(c);
      } catch (const InvalidInputError& e) {
        throw InvalidInputError("recording: command " + std::to_string(next + 1) + " (" +
                                std::string(commandName(c)) + " at cycle " + std::to_string(cycle) +
                                ") was refused: " + e.what());
      }
      ++next;
      ++result.commands;
    }
    if (cycle == end) break;
    if (session.advance() == Session::Outcome::Diverged) ++result.divergences;
    session.takeNotices(notices);
    if (writing) {
      row(cycle + 1);
      if (options.frameEvery > 0 && (cycle + 1) % options.frameEvery == 0)
        frame(frameName(cycle + 1));
    }
  }
  for (std::string& n : notices) result.notices.push_back(std::move(n));
  result.cycles = session.cycle();
  result.finalState = session.state();
  result.stateHash = stateHash(result.finalState);
  if (recording.stateHash) result.matchesRecording = *recording.stateHash == result.stateHash;
  if (writing) {
    const std::filesystem::path dir(options.outDir);
    io::saveState(result.finalState, (dir / "final_state.csv").string());
    io::writeFileAtomically((dir / "diagnostics.csv").string(),
                            [&](std::ostream& out) { out << csv.str(); });
    if (options.frameEvery == 0 || end % options.frameEvery != 0) frame("final.png");
  }
  return result;
}

}  // namespace zsculpt::app
