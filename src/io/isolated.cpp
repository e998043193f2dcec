#include "zsculpt/io/isolated.h"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <new>

#include "zsculpt/core/errors.h"

namespace zsculpt::io {

namespace {

// The first byte of the child's answer: what follows is the result or an error's message.
enum Tag : char {
  kResult = 'R',
  kIOError = 'I',
  kInvalidInput = 'V',
  kTopology = 'T',
  kSolver = 'S',
  kOutOfMemory = 'M',
  kOther = 'X',
};

bool writeAll(int fd, const char* data, std::size_t size) {
  while (size > 0) {
    const ssize_t n = ::write(fd, data, size);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    data += n;
    size -= static_cast<std::size_t>(n);
  }
  return true;
}

[[noreturn]] void answerAndExit(int fd, Tag tag, const std::string& body) {
  const char first = tag;
  const bool sent = writeAll(fd, &first, 1) && writeAll(fd, body.data(), body.size());
  ::close(fd);
  // _exit: no atexit handlers and no flushing of the parent's stdio buffers, which the
  // child holds copies of.
  ::_exit(sent ? 0 : 1);
}

#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
constexpr bool kSanitized = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer) || \
    __has_feature(memory_sanitizer)
constexpr bool kSanitized = true;
#else
constexpr bool kSanitized = false;
#endif
#else
constexpr bool kSanitized = false;
#endif

// RLIMIT_AS counts the address space the child inherited from the parent (its libraries,
// its heap, other threads' stacks), so the limit is what the child has plus the budget.
void limitMemory(std::uint64_t budget) {
  if (budget == 0 || kSanitized) return;
  std::ifstream statm("/proc/self/statm");
  std::uint64_t pages = 0;
  if (!(statm >> pages)) return;
  const std::uint64_t limit = pages * static_cast<std::uint64_t>(::sysconf(_SC_PAGESIZE)) + budget;
  const rlimit wanted{limit, limit};
  ::setrlimit(RLIMIT_AS, &wanted);
}

[[noreturn]] void runChild(int fd, const std::function<std::string()>& work,
                           std::uint64_t memoryBytes) {
  try {
    limitMemory(memoryBytes);
    answerAndExit(fd, kResult, work());
  } catch (const TopologyError& e) {
    answerAndExit(fd, kTopology, e.what());
  } catch (const InvalidInputError& e) {
    answerAndExit(fd, kInvalidInput, e.what());
  } catch (const IOError& e) {
    answerAndExit(fd, kIOError, e.what());
  } catch (const SolverError& e) {
    answerAndExit(fd, kSolver, e.what());
  } catch (const std::bad_alloc&) {
    answerAndExit(fd, kOutOfMemory, "");
  } catch (const std::exception& e) {
    answerAndExit(fd, kOther, e.what());
  } catch (...) {
    answerAndExit(fd, kOther, "unknown error");
  }
}

std::string duration(std::chrono::milliseconds time) {
  return time.count() % 1000 == 0 ? std::to_string(time.count() / 1000) + " s"
                                  : std::to_string(time.count()) + " ms";
}

std::string signalName(int signal) {
  const char* text = ::sigdescr_np(signal);
  return std::to_string(signal) + (text != nullptr ? std::string(", ") + text : std::string());
}

// Kills and reaps the child whatever happens to the parent's reading.
struct Child {
  pid_t pid;
  bool reaped = false;
  int status = 0;
  int wait() {
    while (!reaped) {
      if (::waitpid(pid, &status, 0) == pid)
        reaped = true;
      else if (errno != EINTR)
        break;
    }
    return status;
  }
  ~Child() {
    if (!reaped) {
      ::kill(pid, SIGKILL);
      wait();
    }
  }
};

}  // namespace

bool isolationLimitsMemory() {
  return !kSanitized;
}

std::string runIsolated(const std::string& name, const std::function<std::string()>& work,
                        const IsolationLimits& limits) {
  int fds[2];
  if (::pipe2(fds, O_CLOEXEC) != 0) return work();
  const pid_t pid = ::fork();
  if (pid < 0) {
    ::close(fds[0]);
    ::close(fds[1]);
    return work();  // no child to be had (process or memory limits): read here
  }
  if (pid == 0) {
    ::close(fds[0]);
    runChild(fds[1], work, limits.memoryBytes);
  }
  ::close(fds[1]);
  Child child{pid};
  std::string answer;
  bool timedOut = false;
  const auto deadline = std::chrono::steady_clock::now() + limits.timeout;
  char buffer[1 << 16];
  for (;;) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) {
      timedOut = true;
      break;
    }
    pollfd wanted{fds[0], POLLIN, 0};
    const int ready =
        ::poll(&wanted, 1, static_cast<int>(std::min<long long>(left.count(), 1 << 30)));
    if (ready < 0 && errno == EINTR) continue;
    if (ready < 0) break;
    if (ready == 0) continue;  // the deadline is checked above
    const ssize_t n = ::read(fds[0], buffer, sizeof buffer);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;  // end of the answer (or an error reading it: judged below)
    answer.append(buffer, static_cast<std::size_t>(n));
  }
  ::close(fds[0]);
  if (timedOut) {
    ::kill(pid, SIGKILL);
    child.wait();
    throw IOError(name + ": reading took longer than " + duration(limits.timeout) +
                  " and was stopped (a damaged file can make the importer loop)");
  }
  const int status = child.wait();
  if (WIFSIGNALED(status))
    throw IOError(name + ": the importer crashed reading the file (signal " +
                  signalName(WTERMSIG(status)) +
                  "); the file is damaged or uses something assimp mishandles");
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0 || answer.empty())
    throw IOError(name + ": the importer stopped without an answer (exit status " +
                  std::to_string(WIFEXITED(status) ? WEXITSTATUS(status) : -1) + ")");
  const char tag = answer.front();
  answer.erase(0, 1);
  const std::string& body = answer;
  switch (tag) {
    case kResult:
      return answer;
    case kTopology:
      throw TopologyError(body);
    case kInvalidInput:
      throw InvalidInputError(body);
    case kIOError:
      throw IOError(body);
    case kSolver:
      throw SolverError(body);
    case kOutOfMemory:
      throw IOError(name + ": out of memory while reading");
    default:
      throw IOError(name + ": " + body);
  }
}

}  // namespace zsculpt::io
