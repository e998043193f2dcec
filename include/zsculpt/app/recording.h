#pragma once
// Recorded sessions (`zsculpt open --record FILE`, `zsculpt replay FILE --out DIR`) and
// scripts (`--script FILE`, the same format).
//
// JSON lines, one object per line:
//
//   {"zsculpt_recording": 1, "scheme": "default", "period": 0.17, "mesh_hash": "...",
//    "scene": {...the scene with its properties as full arrays...},
//    "initial_state": {"position": [[x,y,z],...], "velocity": [...], "time": 0}}   header
//   {"cycle": 12, "type": "drag_start", "vertex": 7, "target": [1, 2, 3]}          commands
//   {"cycle": 12, "type": "dab", "property": "stiffness", ...}
//   {"end_cycle": 480, "time": 81.6, "state_hash": "..."}                          footer
//
// A command line's cycle is the number of steps taken when the solver applied it, so a
// replay that applies the same commands at the same cycles, from the same scene, steps the
// same arithmetic in the same order: the final state is bit-identical (the footer's hash
// checks it). Doubles are written in the shortest form that reads back to the same bits.
//
// Scripts may omit the header (the model comes from the command line) and the footer, and
// may hold "ui" lines that the window interprets (script.h); replay ignores those.

#include <cstdint>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "zsculpt/app/commands.h"
#include "zsculpt/app/session.h"

namespace zsculpt::app {

inline constexpr int kRecordingVersion = 1;

struct RecordedCommand {
  std::uint64_t cycle = 0;
  Command command;
};

/// The largest cycle a recording may name: 2^40, over five hundred years of cycles at 60 a
/// second. A larger one is a damaged file, and replaying to it would not end.
inline constexpr std::uint64_t kMaxRecordedCycle = std::uint64_t{1} << 40;

struct Recording {
  /// Absent in a script without a header.
  std::optional<SessionSetup> setup;
  std::optional<std::uint64_t> meshHash;
  std::vector<RecordedCommand> commands;
  /// "ui" lines of a script, in file order, each with its line number.
  std::vector<std::pair<int, nlohmann::json>> ui;
  /// From the footer (absent when the session did not end cleanly, or in scripts).
  std::optional<std::uint64_t> endCycle;
  std::optional<std::uint64_t> stateHash;
};

/// The header line for a session.
nlohmann::json recordingHeader(const SessionSetup& setup, const std::string& recordingPath);
/// Reads a recording or a script. Throws IOError "<path>: <reason>" when it cannot be read
/// and InvalidInputError "<path>: line L: <reason>" for a malformed line. Does not load the
/// mesh: replay does (and checks its hash).
Recording readRecording(const std::string& path);

/// Collects the commands a solver applies and writes the recording atomically on finish().
/// record() is called by the solver thread; finish() after it stopped. Until then every line
/// is also appended, one write each, to a journal beside the recording (journalPath():
/// "<path>.partial", or "<path>.partial.2", ".3", ... where an earlier session's journal
/// is still there: it is never overwritten), which finish() or the destructor removes once
/// the recording is written: a session killed outright (kill -9, a crash, power lost after
/// the system wrote it out) leaves the journal, a recording without a footer that replays
/// to its last command.
class Recorder {
 public:
  Recorder(std::string path, const SessionSetup& setup);
  /// Writes what was recorded so far (no footer) if finish() was not called.
  ~Recorder();
  Recorder(const Recorder&) = delete;
  Recorder& operator=(const Recorder&) = delete;

  void record(std::uint64_t cycle, const Command& command);
  /// Appends the footer and writes the file atomically. Throws IOError "<path>: ...".
  void finish(std::uint64_t endCycle, const State& finalState);
  [[nodiscard]] const std::string& path() const { return path_; }
  /// Empty when there is no journal (a device such as /dev/null, or none could be made).
  [[nodiscard]] const std::string& journalPath() const { return journalPath_; }
  /// Why a recording to a file has no journal ("<path>.partial: <reason>"), or empty: the
  /// window says it, since a session killed outright then loses its recording.
  [[nodiscard]] const std::string& journalProblem() const { return journalProblem_; }
  [[nodiscard]] std::size_t size() const;

 private:
  void write(bool withFooter);
  void journal(const std::string& line);
  void closeJournal(bool remove);

  std::string path_;
  std::string journalPath_;
  std::string journalProblem_;
  std::int64_t journalBytes_ = 0;  // the journal's length in whole lines
  int journal_ = -1;  // the journal's file descriptor, or -1 (none: it could not be made)
  mutable std::mutex mutex_;
  std::string text_;
  std::string footer_;
  bool finished_ = false;
};

struct ReplayOptions {
  /// Output folder: final_state.csv, diagnostics.csv, frames. Empty: nothing is written.
  std::string outDir;
  /// A PNG frame every this many cycles (0: only the final frame); needs OSMesa.
  std::uint64_t frameEvery = 0;
  bool frames = true;
  int width = 1280;
  int height = 720;
  /// Colour the surface by this property (absent: plain surface).
  std::optional<Property> property;
  int levels = 2;
  /// Run to this cycle if the recording has no footer (0: the last command's cycle).
  std::uint64_t endCycle = 0;
};

struct ReplayResult {
  State finalState;
  std::uint64_t cycles = 0;
  std::uint64_t commands = 0;
  std::uint64_t divergences = 0;
  std::uint64_t stateHash = 0;
  /// Whether the recording's footer hash equals stateHash (absent: no footer).
  std::optional<bool> matchesRecording;
  int framesWritten = 0;
  int numberedFramesWritten = 0;  ///< of them, frame_*.png (the others: final.png)
  std::vector<std::string> notices;
};

/// Re-runs a recorded session headless: the same scene, the same commands at the same
/// cycles. Throws InvalidInputError for a recording without a header, a mesh whose hash
/// differs from the recorded one, or a command the session refuses (it was applied when
/// recorded, so the recording does not belong to this model).
ReplayResult replay(const Recording& recording, const ReplayOptions& options = {});

}  // namespace zsculpt::app
