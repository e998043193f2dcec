#pragma once
// Line breaks for the window's messages at spaces only. Dear ImGui's own wrapping also
// breaks after '.' and ',', so a message such as "time step 0.05795 s" could be drawn as
// "time step 0." over "05795 s": a number cut in two reads as two numbers.

#include <string_view>

namespace zsculpt::app {

/// The end of the first line of `text` in at most `width` (as `measure(std::string_view)`
/// gives widths): the greatest run of whole words that fits, broken at a space or a
/// newline. A word wider than `width` on its own takes a line of its own rather than being
/// cut. The next line starts after the returned position's spaces (skipLineBreak).
template <typename Measure>
std::size_t wrapLineEnd(std::string_view text, float width, Measure&& measure) {
  const std::size_t newline = text.find('\n');
  const std::string_view line = text.substr(0, newline);
  if (measure(line) <= width) return line.size();
  std::size_t fits = 0;  // end of the longest run of whole words that fits
  for (std::size_t space = line.find(' '); space != std::string_view::npos;
       space = line.find(' ', space + 1)) {
    if (space == 0) continue;
    if (measure(line.substr(0, space)) > width) break;
    fits = space;
  }
  if (fits > 0) return fits;
  // No break fits: the first word alone, however wide.
  const std::size_t first = line.find(' ', line.find_first_not_of(' '));
  return first == std::string_view::npos ? line.size() : first;
}

/// Where the line after one ending at `end` starts: past one newline or the spaces there.
inline std::size_t skipLineBreak(std::string_view text, std::size_t end) {
  if (end < text.size() && text[end] == '\n') return end + 1;
  while (end < text.size() && text[end] == ' ') ++end;
  return end;
}

}  // namespace zsculpt::app
