#pragma once
// Internal to the cli module: `zsculpt reproduce WHAT --out DIR`, one function per table or
// figure of the paper, each in its own reproduce_<what>.cpp. Each writes its data (CSV,
// JSON) and, where rendering exists, PNGs into `out`, prints what it wrote and a summary
// beside the paper's numbers, and returns the exit status.

#include <string>

namespace zsculpt::cli {

struct ReproduceOptions {
  std::string out;  // output folder (created if missing)
  bool quick = false;  // smaller runs for tests
};

int reproduceTable1(const ReproduceOptions& options);
int reproduceFigure3(const ReproduceOptions& options);
int reproduceFigure5(const ReproduceOptions& options);
int reproduceFigure6(const ReproduceOptions& options);
int reproduceFigure7(const ReproduceOptions& options);
int reproduceFigure8(const ReproduceOptions& options);
int reproduceFigure9(const ReproduceOptions& options);
int reproduceFigure10(const ReproduceOptions& options);

}  // namespace zsculpt::cli
