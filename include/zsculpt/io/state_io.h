#pragma once
// State files (../shared/notes/cli.md, "Files"): CSV with the header `x,y,z,vx,vy,vz` and
// one row per vertex in vertex order, written with 17 significant digits so that reading
// a file back gives bit-identical doubles. Used by --state-out and --state-in.

#include <iosfwd>
#include <string>

#include "zsculpt/physics/properties.h"

namespace zsculpt::io {

inline constexpr const char* kStateHeader = "x,y,z,vx,vy,vz";

/// Writes the header and one row per vertex. Throws InvalidInputError "<name>: vertex i has
/// a non-finite position or velocity" before writing anything, so every file reads back.
void writeState(std::ostream& out, const State& state, const std::string& name = "state");
/// writeState to `path`, atomically. Throws IOError or InvalidInputError "<path>: ...".
void saveState(const State& state, const std::string& path);

/// Reads a state of `expectedVertices` vertices (-1: any count); time is 0. Throws
/// InvalidInputError "<name>: line L: <reason>" for a wrong header, a wrong column count, a
/// field that is not a number or not finite, and "<name>: R rows, expected N" for a row
/// count different from the model's vertex count.
State readState(std::istream& in, const std::string& name, Index expectedVertices);
/// readState from `path`; IOError "<path>: <reason>" when it cannot be opened.
State loadState(const std::string& path, Index expectedVertices);

}  // namespace zsculpt::io
