#include "console.h"

#include <cstdio>
#include <iostream>

namespace zsculpt::cli {

namespace {
bool lineDrawn = false;  // a bar's line is on the terminal, without its line end
bool lineCleared = false;
}  // namespace

void warn(const std::string& text) {
  std::cerr.flush();
  if (lineDrawn) {
    std::fputs("\r\033[K", stderr);  // back to the line's start and clear it
    lineDrawn = false;
    lineCleared = true;
  }
  std::cerr << "zsculpt: warning: " << text << "\n";
}

void progressLineDrawn(bool drawn) {
  lineDrawn = drawn;
  lineCleared = false;
}

bool progressLineCleared() {
  return lineCleared;
}

}  // namespace zsculpt::cli
