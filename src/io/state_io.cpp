#include "zsculpt/io/state_io.h"

#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <istream>
#include <ostream>
#include <vector>

#include "zsculpt/core/errors.h"
#include "zsculpt/io/atomic_file.h"

namespace zsculpt::io {

namespace {

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r'))
    s.remove_suffix(1);
  return s;
}

[[noreturn]] void lineError(const std::string& name, size_t line, const std::string& reason) {
  throw InvalidInputError(name + ": line " + std::to_string(line) + ": " + reason);
}

}  // namespace

void writeState(std::ostream& out, const State& state, const std::string& name) {
  const Index n = static_cast<Index>(state.position.rows());
  if (state.velocity.rows() != n)
    throw InvalidInputError(name + ": " + std::to_string(n) + " positions but " +
                            std::to_string(state.velocity.rows()) + " velocities");
  for (Index v = 0; v < n; ++v)
    if (!state.position.row(v).allFinite() || !state.velocity.row(v).allFinite())
      throw InvalidInputError(name + ": vertex " + std::to_string(v) +
                              " has a non-finite position or velocity");
  out << kStateHeader << '\n';
  // 17 significant digits round-trip every double; to_chars is locale-independent.
  char buffer[32];
  for (Index v = 0; v < n; ++v) {
    for (int c = 0; c < 6; ++c) {
      const double value = c < 3 ? state.position(v, c) : state.velocity(v, c - 3);
      const auto result =
          std::to_chars(buffer, buffer + sizeof buffer, value, std::chars_format::general, 17);
      if (c > 0) out << ',';
      out.write(buffer, result.ptr - buffer);
    }
    out << '\n';
  }
}

void saveState(const State& state, const std::string& path) {
  // Validate before creating anything: no partial output.
  for (Index v = 0; v < state.position.rows(); ++v)
    if (!state.position.row(v).allFinite() ||
        (v < state.velocity.rows() && !state.velocity.row(v).allFinite()))
      throw InvalidInputError(path + ": vertex " + std::to_string(v) +
                              " has a non-finite position or velocity");
  writeFileAtomically(path, [&](std::ostream& out) { writeState(out, state, path); });
}

State readState(std::istream& in, const std::string& name, Index expectedVertices) {
  std::string text;
  size_t lineNumber = 0;
  // The header is read a character at a time up to a bound: a file without line breaks
  // (/dev/zero, a binary) is refused at once instead of read whole into one line.
  constexpr size_t kLongestHeader = 4096;
  for (int c = in.get(); c != std::char_traits<char>::eof() && c != '\n'; c = in.get()) {
    if (text.size() == kLongestHeader)
      lineError(name, 1,
                "expected the header " + std::string(kStateHeader) + ", got a line longer than " +
                    std::to_string(kLongestHeader) + " characters");
    text.push_back(static_cast<char>(c));
  }
  if (text.empty() && !in)
    throw InvalidInputError(name + ": empty file, expected the header " +
                            std::string(kStateHeader));
  ++lineNumber;
  std::string_view header = trim(text);
  if (header.size() >= 3 && header.substr(0, 3) == "\xEF\xBB\xBF") header.remove_prefix(3);
  if (header != kStateHeader) {
    std::string shown(header.substr(0, 60));
    for (char& c : shown)
      if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) c = '?';
    lineError(name, lineNumber,
              "expected the header " + std::string(kStateHeader) + ", got '" + shown + "'");
  }
  std::vector<double> values;
  while (std::getline(in, text)) {
    ++lineNumber;
    std::string_view line = trim(text);
    if (line.empty()) continue;
    int column = 0;
    size_t start = 0;
    while (true) {
      const size_t comma = line.find(',', start);
      std::string_view field =
          trim(line.substr(start, comma == std::string_view::npos ? line.npos : comma - start));
      // from_chars refuses a leading '+', which hand-edited files may have.
      if (field.size() > 1 && field.front() == '+' && field[1] != '-') field.remove_prefix(1);
      ++column;
      if (column > 6) lineError(name, lineNumber, "more than 6 columns");
      double value = 0.0;
      const auto result = std::from_chars(field.data(), field.data() + field.size(), value);
      // The field as one printable line (a NUL or a carriage return in a damaged file
      // would cut the message or break it).
      std::string shown(field.substr(0, 40));
      for (char& c : shown)
        if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) c = '?';
      if (field.empty() || result.ec == std::errc::invalid_argument ||
          result.ptr != field.data() + field.size())
        lineError(name, lineNumber,
                  "column " + std::to_string(column) + ": '" + shown + "' is not a number");
      // Out of range: too large (infinite, as 1e999) or too small (1e-400, which is not 0).
      if (result.ec == std::errc::result_out_of_range &&
          std::isfinite(std::strtod(std::string(field).c_str(), nullptr)))
        lineError(name, lineNumber,
                  "column " + std::to_string(column) + ": " + shown + " is too small for a double");
      if (result.ec == std::errc::result_out_of_range || !std::isfinite(value))
        lineError(name, lineNumber,
                  "column " + std::to_string(column) + ": " + shown + " is not finite");
      values.push_back(value);
      if (comma == std::string_view::npos) break;
      start = comma + 1;
    }
    if (column != 6) lineError(name, lineNumber, std::to_string(column) + " columns, expected 6");
  }
  if (in.bad()) throw IOError(name + ": read error");
  const Index rows = static_cast<Index>(values.size() / 6);
  if (expectedVertices >= 0 && rows != expectedVertices)
    throw InvalidInputError(name + ": " + std::to_string(rows) + " rows, expected " +
                            std::to_string(expectedVertices) + " (one per vertex of the model)");
  State state;
  state.position.resize(rows, 3);
  state.velocity.resize(rows, 3);
  for (Index v = 0; v < rows; ++v)
    for (int c = 0; c < 3; ++c) {
      state.position(v, c) = values[6 * v + c];
      state.velocity(v, c) = values[6 * v + 3 + c];
    }
  return state;
}

State loadState(const std::string& path, Index expectedVertices) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) throw IOError(path + ": is a folder");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw IOError(path + ": cannot open: " + std::strerror(errno));
  return readState(in, path, expectedVertices);
}

}  // namespace zsculpt::io
