#pragma once
// Standard error shared by a progress bar and the warnings a run tells as it goes: a warning
// first clears the bar's line (it was glued onto "[#####....]  42%  frame 12/30"), and the
// bar draws itself again on its next update.

#include <string>

namespace zsculpt::cli {

/// "zsculpt: warning: TEXT" on a line of its own.
void warn(const std::string& text);

/// The progress bar's side: it drew its line (true) or ended it (false); and whether a
/// warning has cleared it since, so that it must be drawn again.
void progressLineDrawn(bool drawn);
bool progressLineCleared();

}  // namespace zsculpt::cli
