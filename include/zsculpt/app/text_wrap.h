#pragma once
// Line breaks for the window's messages. Dear ImGui's own wrapping also breaks after '.' and
// ',', so a message such as "time step 0.05795 s" could be drawn as "time step 0." over
// "05795 s": a number cut in two reads as two numbers. Here lines break at spaces; only a
// word wider than a whole line (a long path) is broken, after its last '/' that fits, else
// at the last whole UTF-8 character that fits, so that nothing is clipped away.

#include <cstddef>
#include <string_view>

namespace zsculpt::app {

namespace detail {

inline bool isContinuationByte(char c) {
  return (static_cast<unsigned char>(c) & 0xC0u) == 0x80u;
}

/// The end of the longest head of `word` that fits in `width`: after its last '/' that
/// fits (if that keeps a quarter of it or more), else after its last whole character that fits;
/// at least one character.
template <typename Measure>
std::size_t breakInsideWord(std::string_view word, float width, Measure& measure) {
  std::size_t fits = 0, slash = 0;
  float used = 0.0f;
  for (std::size_t at = 0; at < word.size();) {
    std::size_t next = at + 1;
    while (next < word.size() && isContinuationByte(word[next])) ++next;
    used += measure(word.substr(at, next - at));
    if (used > width) break;
    if (word[at] == '/') slash = next;
    fits = next;
    at = next;
  }
  // After a '/' when that keeps a quarter of what fits or more (not "/" alone on a line).
  if (slash > 0 && slash < word.size() && 4 * slash >= fits) return slash;
  if (fits > 0) return fits;
  std::size_t one = 1;  // not even one character fits: one anyway
  while (one < word.size() && isContinuationByte(word[one])) ++one;
  return one;
}

}  // namespace detail

/// The end of the first line of `text` in at most `width` (as `measure(std::string_view)`
/// gives widths, which add up over pieces of text, as ImGui's do): the whole line up to a
/// newline if it fits, else the longest run of whole words that fits, else (a first word
/// wider than the line) the head of that word that fits (detail::breakInsideWord). Measures
/// each word once.
template <typename Measure>
std::size_t wrapLineEnd(std::string_view text, float width, Measure&& measure) {
  const std::string_view line = text.substr(0, text.find('\n'));
  float used = 0.0f;
  std::size_t fits = 0;
  for (std::size_t at = 0; at < line.size();) {
    // The next word with the spaces before it.
    const std::size_t begin = line.find_first_not_of(' ', at);
    std::size_t end = begin == std::string_view::npos ? line.size() : line.find(' ', begin);
    if (end == std::string_view::npos) end = line.size();
    used += measure(line.substr(at, end - at));
    if (used > width) break;
    fits = at = end;
  }
  if (fits == line.size() || fits > 0) return fits;
  const std::size_t first = line.find_first_not_of(' ');
  const std::size_t lead = first == std::string_view::npos ? 0 : first;
  std::size_t wordEnd = line.find(' ', lead);
  if (wordEnd == std::string_view::npos) wordEnd = line.size();
  const float leadWidth = lead > 0 ? measure(line.substr(0, lead)) : 0.0f;
  return lead +
         detail::breakInsideWord(line.substr(lead, wordEnd - lead), width - leadWidth, measure);
}

/// Where the line after one ending at `end` starts: past the spaces there and one newline.
inline std::size_t skipLineBreak(std::string_view text, std::size_t end) {
  while (end < text.size() && text[end] == ' ') ++end;
  if (end < text.size() && text[end] == '\n') ++end;
  return end;
}

/// Calls `emit(std::string_view)` with each line of `text` wrapped to `width`, in order; an
/// empty text is one empty line. The pieces are views into `text`: nothing is allocated.
template <typename Measure, typename Emit>
void forEachWrappedLine(std::string_view text, float width, Measure&& measure, Emit&& emit) {
  std::size_t start = 0;
  do {
    const std::string_view rest = text.substr(start);
    const std::size_t end = wrapLineEnd(rest, width, measure);
    emit(rest.substr(0, end));
    start += skipLineBreak(rest, end);
  } while (start < text.size());
}

}  // namespace zsculpt::app
