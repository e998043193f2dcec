#include <cstdlib>
#include <filesystem>

#include "zsculpt/app/session.h"
#include "zsculpt/core/errors.h"

namespace zsculpt::app {

std::string defaultScenePath() {
  namespace fs = std::filesystem;
  const fs::path relative = fs::path("assets") / "scenes" / "default.json";
  std::error_code ec;
  if (const char* dir = std::getenv("ZSCULPT_DATA_DIR"); dir != nullptr && *dir != '\0') {
    const fs::path p = fs::path(dir) / relative;
    if (fs::is_regular_file(p, ec)) return p.string();
    throw IOError(p.string() + ": not found (ZSCULPT_DATA_DIR is set to " + dir + ")");
  }
  // This file is src/app/default_scene.cpp of the source tree (CMake compiles it by its
  // absolute path), so the tree's root is two folders up.
  const fs::path root = fs::path(__FILE__).parent_path().parent_path().parent_path();
  const fs::path p = root / relative;
  if (fs::is_regular_file(p, ec)) return p.string();
  throw IOError(
      p.string() +
      ": the default scene is not found; set ZSCULPT_DATA_DIR to the folder holding assets/");
}

}  // namespace zsculpt::app
