#pragma once
// Every file zsculpt writes goes through here: written to a temporary name in the same
// folder, flushed to disk, then renamed over the target, so a crash or a kill during a save
// leaves either the old file or the new one, never a half-written one.

#include <functional>
#include <ostream>
#include <string>

namespace zsculpt::io {

/// Where a save to `path` writes: the file at the end of its chain of symbolic links (one
/// still to be made for a dangling link), or `path` itself with inPlace for an existing device
/// or pipe (or a descriptor named by number). Throws IOError "<path>: <reason>" for a target
/// no save could take (a loop of links, a name too long).
struct SaveTarget {
  std::string path;
  bool inPlace = false;
};
SaveTarget saveTarget(const std::string& path);

/// Calls `write` with a stream to a temporary file next to `path`, then fsyncs and renames
/// it to `path`. On any failure the temporary file is removed, `path` is untouched, and
/// IOError "<path>: <reason>" is thrown. A symbolic link is followed (the link stays, the
/// file it names is replaced); an existing device or pipe (/dev/stdout, /dev/null) is
/// written in place, not replaced.
void writeFileAtomically(const std::string& path, const std::function<void(std::ostream&)>& write);

/// Same for a file produced by a library that writes to a path itself (assimp, stb):
/// `writeTo` receives the temporary path to write. A device or pipe is refused (the library
/// writes to a file by name).
/// (No program path uses it now: meshes and images are made in memory and written through
/// writeFileAtomically; it stays for libraries that can only write by name.)
void writeFileAtomicallyVia(const std::string& path,
                            const std::function<void(const std::string& temporaryPath)>& writeTo);

/// Before the work whose result goes to `path`: throws IOError "<path>: <reason>" unless a
/// save there could succeed (a file name, not a folder; its folder exists or can be made
/// and is writable; an existing device or pipe is writable). Makes nothing: the save makes
/// the folder.
void checkOutputFile(const std::string& path);

/// Throws IOError "<dir>: <reason>" unless `dir` exists (or can be created) and is writable.
void ensureWritableDirectory(const std::string& dir);

/// ensureWritableDirectory's checks without making anything: `dir` is a writable folder, or
/// the nearest folder above it that exists is one (the writes make the rest). For the checks
/// before a run, so that a refused run leaves no empty folder behind.
void checkCreatableDirectory(const std::string& dir);

}  // namespace zsculpt::io
