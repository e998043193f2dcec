#pragma once
// Internal to the cli module: `zsculpt reproduce WHAT --out DIR`, one function per table or
// figure of the paper, each in its own reproduce_<what>.cpp. Each writes its data (CSV,
// JSON) and, where rendering exists, PNGs into `out`, prints what it wrote and a summary
// beside the paper's numbers, and returns the exit status.

#include <string>
#include <vector>

#include "zsculpt/render/image.h"
#include "zsculpt/render/renderer.h"

namespace zsculpt::cli {

struct ReproduceOptions {
  std::string out;     // output folder (created if missing)
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

/// The figures' images: panels of kPanelWidth x kPanelHeight rendered offscreen (OSMesa),
/// placed side by side kPanelGap pixels apart on white, as the paper's figures show them.
inline constexpr int kPanelWidth = 640;
inline constexpr int kPanelHeight = 480;
inline constexpr int kPanelGap = 6;

/// One panel: a copy of the rendered frame (the renderer's image is reused).
inline render::Image renderPanel(render::OffscreenRenderer& renderer, const render::Frame& frame) {
  return renderer.render(frame, kPanelWidth, kPanelHeight);
}

/// The panels side by side, written atomically as a PNG.
inline void savePanels(const std::string& path, const std::vector<render::Image>& panels) {
  std::vector<const render::Image*> row;
  for (const render::Image& panel : panels) row.push_back(&panel);
  render::savePng(path, render::composeRow(row, kPanelGap));
}

}  // namespace zsculpt::cli
