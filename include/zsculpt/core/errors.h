#pragma once
// The small hierarchy of typed exceptions every module throws (after pmp-library).
// Each carries a one-line, user-facing message: "<what is at fault>: <reason>".
// The command line turns any of them into `zsculpt: error: <message>` and exit code 2
// (DivergenceError: exit code 3).

#include <stdexcept>
#include <string>

namespace zsculpt {

/// Base of every error zsculpt reports to a user.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Input that is well-formed but invalid: a negative mass, an index out of range,
/// a NaN coordinate, a rigidity outside [0, 1], an unknown property name.
class InvalidInputError : public Error {
 public:
  using Error::Error;
};

/// A mesh whose connectivity cannot be used: repeated vertex in a face, empty mesh,
/// zero-length edge.
class TopologyError : public InvalidInputError {
 public:
  using InvalidInputError::InvalidInputError;
};

/// A file that is missing, unreadable, unwritable, or in an unsupported format.
class IOError : public Error {
 public:
  using Error::Error;
};

/// A numerical procedure that could not produce a result (e.g. an eigen-solver that did
/// not converge).
class SolverError : public Error {
 public:
  using Error::Error;
};

/// A simulation whose state went non-finite or whose energy ran away.
class DivergenceError : public SolverError {
 public:
  using SolverError::SolverError;
};

}  // namespace zsculpt

/// Throws InvalidInputError with the file and line when a condition that callers must
/// guarantee does not hold (geometry-central style). Used for API misuse, not user input.
#define ZSCULPT_ASSERT(cond, msg)                                                                 \
  do {                                                                                            \
    if (!(cond))                                                                                  \
      throw ::zsculpt::InvalidInputError(std::string(__FILE__) + ":" + std::to_string(__LINE__) + \
                                         ": " + (msg));                                           \
  } while (0)
