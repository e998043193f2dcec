#pragma once
// The entry points of the fuzz targets (fuzz/fuzz_*.cpp), shared with the regression test
// in tests/test_reliability.cpp so that a saved crash input is replayed through exactly the
// code that found it. Each entry returns normally when the input was accepted or rejected
// with a typed zsculpt::Error; anything else (another exception, a crash, a sanitizer
// report) is a bug. docs/reliability.md describes the targets and how to run them.

#include <unistd.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <iostream>
#include <sstream>
#include <streambuf>
#include <string>
#include <string_view>
#include <vector>

#include "zsculpt/cli/cli.h"
#include "zsculpt/core/errors.h"
#include "zsculpt/io/mesh_io.h"
#include "zsculpt/io/scene.h"
#include "zsculpt/io/state_io.h"
#include "zsculpt/mesh/builtin.h"

namespace zsculpt::fuzz {

/// Built-in models named in fuzz inputs must stay small: every run of digits in a built-in
/// name is at most two digits (so "builtin:torus:99:99" at most), one for the lattice, whose
/// count is cubed (a 76-lattice, 438,976 vertices, took over 10 s to build under ASan:
/// tests/regressions/scene/lattice_of_76_is_not_small), or the input is skipped. A 4096 x
/// 4096 torus is a valid request that takes gigabytes, not a bug.
inline bool smallBuiltin(std::string_view text) {
  if (text.find("builtin") == std::string_view::npos) return true;
  const size_t most = text.find("lattice") == std::string_view::npos ? 2 : 1;
  size_t run = 0;
  for (char c : text) {
    run = (c >= '0' && c <= '9') ? run + 1 : 0;
    if (run > most) return false;
  }
  return true;
}

/// Scene files: parse and validate; when the scene names a small built-in model, also
/// build the model (the checks against the mesh and every override).
inline void scene(const std::uint8_t* data, std::size_t size) {
  try {
    const io::SceneDescription description =
        io::parseScene(std::string_view(reinterpret_cast<const char*>(data), size), "fuzz.json");
    if (isBuiltinName(description.mesh) && smallBuiltin(description.mesh))
      (void)io::buildModel(description, makeBuiltin(description.mesh));
  } catch (const Error&) {
  }
}

/// The formats the mesh target tries, picked by the input's first byte.
inline constexpr const char* kMeshHints[] = {"obj", "ply", "off", "stl", "gltf", "glb"};
inline constexpr std::size_t kMeshHintCount = sizeof kMeshHints / sizeof kMeshHints[0];

/// Mesh import from memory through assimp: byte 0 picks the format, the rest is the file.
inline void mesh(const std::uint8_t* data, std::size_t size) {
  if (size < 2) return;
  try {
    (void)io::loadMeshFromMemory(data + 1, size - 1, kMeshHints[data[0] % kMeshHintCount]);
  } catch (const Error&) {
  }
}

/// State files: byte 0 picks the expected vertex count (0: any, else byte - 1), the rest is
/// the file.
inline void state(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return;
  const Index expected = data[0] == 0 ? -1 : static_cast<Index>(data[0]) - 1;
  std::istringstream in(std::string(reinterpret_cast<const char*>(data + 1), size - 1));
  try {
    (void)io::readState(in, "fuzz.csv", expected);
  } catch (const Error&) {
  }
}

/// The command line: one argument per line of the input, after `zsculpt`. Only `info` and
/// `simulate` are run (the others open windows or write folders), with no '/' in any
/// argument (so nothing outside the current folder is read or written: run it in a
/// temporary folder), small built-ins, and --steps replaced by at most 7 steps for
/// `simulate`. Returns the exit status, or -1 for a skipped input.
inline int commandLine(const std::uint8_t* data, std::size_t size) {
  std::vector<std::string> args;
  {
    std::string_view text(reinterpret_cast<const char*>(data), size);
    size_t start = 0;
    while (start <= text.size()) {
      const size_t end = std::min(text.find('\n', start), text.size());
      args.emplace_back(text.substr(start, end - start));
      start = end + 1;
    }
  }
  if (args.empty() || (args[0] != "info" && args[0] != "simulate") || args.size() > 64) return -1;
  const bool simulate = args[0] == "simulate";
  std::vector<std::string> kept;
  for (size_t i = 0; i < args.size(); ++i) {
    const std::string& a = args[i];
    if (a.find('/') != std::string::npos || a.find('\0') != std::string::npos || !smallBuiltin(a))
      return -1;
    if (i > 0)
      for (const char* other : {"info", "simulate", "open", "demo", "render", "subdivide",
                                "reproduce", "bench", "replay"})
        if (a == other) return -1;
    // The run length is the fuzzer's to choose only up to a few steps.
    if (a == "--steps" || a == "--time") {
      ++i;
      continue;
    }
    if (a.starts_with("--steps=") || a.starts_with("--time=")) continue;
    kept.push_back(a);
  }
  if (simulate) {
    kept.emplace_back("--steps");
    kept.emplace_back(std::to_string(size % 8));
  }
  std::vector<std::string> storage{"zsculpt"};
  storage.insert(storage.end(), kept.begin(), kept.end());
  std::vector<char*> argv;
  for (std::string& s : storage) argv.push_back(s.data());
  argv.push_back(nullptr);
  return cli::run(static_cast<int>(storage.size()), argv.data());
}

/// Silences std::cout and std::cerr while alive (the CLI's output is not what is tested;
/// sanitizer reports go to the file descriptor and stay visible).
class QuietStreams {
 public:
  QuietStreams() : out_(std::cout.rdbuf(&null_)), err_(std::cerr.rdbuf(&null_)) {}
  ~QuietStreams() {
    std::cout.rdbuf(out_);
    std::cerr.rdbuf(err_);
  }
  QuietStreams(const QuietStreams&) = delete;
  QuietStreams& operator=(const QuietStreams&) = delete;

 private:
  struct NullBuffer : std::streambuf {
    int_type overflow(int_type c) override { return traits_type::not_eof(c); }
  };
  NullBuffer null_;
  std::streambuf* out_;
  std::streambuf* err_;
};

}  // namespace zsculpt::fuzz
