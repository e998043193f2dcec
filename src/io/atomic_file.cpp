#include "zsculpt/io/atomic_file.h"

#include <fcntl.h>
#include <poll.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <charconv>
#include <cstring>
#include <filesystem>
#include <random>
#include <streambuf>
#include <string_view>
#include <vector>

#include "zsculpt/core/errors.h"

namespace zsculpt::io {

namespace fs = std::filesystem;

namespace {

[[noreturn]] void fail(const std::string& path, const std::string& reason) {
  throw IOError(path + ": " + reason);
}

std::string errnoText(int error) {
  return std::strerror(error);
}

/// An ostream buffer over a POSIX descriptor, so that write errors keep their errno
/// (std::ofstream reports only "failed") and the descriptor can be fsynced.
class FdOutBuf : public std::streambuf {
 public:
  explicit FdOutBuf(int fd) : fd_(fd), buffer_(1 << 16) {
    setp(buffer_.data(), buffer_.data() + buffer_.size());
  }
  [[nodiscard]] int error() const { return error_; }

 protected:
  int_type overflow(int_type ch) override {
    if (!flushBuffer()) return traits_type::eof();
    if (!traits_type::eq_int_type(ch, traits_type::eof())) {
      *pptr() = traits_type::to_char_type(ch);
      pbump(1);
    }
    return traits_type::not_eof(ch);
  }
  int sync() override { return flushBuffer() ? 0 : -1; }

 private:
  bool flushBuffer() {
    if (error_ != 0) return false;
    const char* p = pbase();
    while (p < pptr()) {
      const ssize_t written = ::write(fd_, p, static_cast<size_t>(pptr() - p));
      if (written < 0) {
        if (errno == EINTR) continue;
        if (errno == EAGAIN || errno == EWOULDBLOCK) {
          // A descriptor inherited non-blocking (a caller's stdout): wait until it takes more.
          pollfd wait{fd_, POLLOUT, 0};
          if (::poll(&wait, 1, -1) >= 0 || errno == EINTR) continue;
        }
        error_ = errno;
        return false;
      }
      p += written;
    }
    setp(buffer_.data(), buffer_.data() + buffer_.size());
    return true;
  }

  int fd_;
  std::vector<char> buffer_;
  int error_ = 0;
};

/// The folder `path` lives in ("." for a bare file name).
fs::path parentOf(const fs::path& path) {
  fs::path parent = path.parent_path();
  return parent.empty() ? fs::path(".") : parent;
}

void checkTarget(const std::string& path) {
  const fs::path p(path);
  if (path.empty() || !p.has_filename()) fail(path.empty() ? "\"\"" : path, "not a file name");
  std::error_code ec;
  if (fs::is_directory(p, ec)) fail(path, "is a directory");
}

/// A name in the same folder as `path` (rename is atomic only within one file system),
/// hidden, unique per process and call, and ending in the target's extension so that
/// libraries which pick a format or companion file names from the extension still work.
std::string temporaryName(const fs::path& path) {
  static std::atomic<unsigned> counter{0};
  static const unsigned seed = std::random_device{}();
  char suffix[40];
  std::snprintf(suffix, sizeof suffix, ".tmp.%ld.%08x", static_cast<long>(::getpid()),
                seed ^ (counter.fetch_add(1) * 2654435761u));
  // Built with append: GCC 12 misreports -Wrestrict on chained operator+ here.
  std::string name(".");
  name.append(path.filename().string());
  name.append(suffix);
  name.append(path.extension().string());
  return (parentOf(path) / name).string();
}

/// Creates the temporary file exclusively; returns its descriptor.
int createTemporary(const std::string& path, std::string& temporary) {
  // The folder is made at the first write into it (checkOutputFile only checked it could be),
  // so that a run refused before it wrote anything leaves no empty folder behind.
  try {
    ensureWritableDirectory(parentOf(path).string());
  } catch (const IOError& e) {
    fail(path, std::string("its folder: ") + e.what());
  }
  for (int attempt = 0; attempt < 16; ++attempt) {
    temporary = temporaryName(path);
    const int fd = ::open(temporary.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
    if (fd >= 0) return fd;
    if (errno == EEXIST) continue;
    fail(path, "cannot create a file in " + parentOf(path).string() + ": " + errnoText(errno));
  }
  fail(path, "cannot find a free temporary file name");
}

void syncFile(const std::string& path, const std::string& temporary) {
  const int fd = ::open(temporary.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) fail(path, "the written file is gone: " + errnoText(errno));
  const bool synced = ::fsync(fd) == 0;
  const int error = errno;
  ::close(fd);
  if (!synced) fail(path, "cannot flush to disk: " + errnoText(error));
}

/// Renames the temporary over the target and makes the rename itself durable.
void commit(const std::string& path, const std::string& temporary) {
  if (::rename(temporary.c_str(), path.c_str()) != 0) fail(path, errnoText(errno));
  const int dir = ::open(parentOf(path).c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dir >= 0) {
    ::fsync(dir);  // best effort: the data is in place; some file systems refuse this
    ::close(dir);
  }
}

/// Where a save goes. A regular file (or a new one) is replaced atomically; a symbolic link
/// is followed, so that the link stays and the file it names is replaced; anything else that
/// exists (a device such as /dev/stdout or /dev/null, a pipe) is written in place: renaming
/// over it would put a regular file where the device was.
/// The descriptor a path names by number (/dev/stdout, /dev/stderr, /dev/fd/N,
/// /proc/self/fd/N), or -1. Such a path is written through that descriptor as it stands:
/// reopened (or followed to the file it is), `>> log` would be overwritten from its start,
/// or replaced.
int namedDescriptor(const std::string& path) {
  if (path == "/dev/stdout") return 1;
  if (path == "/dev/stderr") return 2;
  // Any other name of the same file as standard output or error (/dev/./stdout,
  // /proc/thread-self/fd/1, a link to /dev/stdout, the very file `>> log` appends to).
  struct stat named {};
  if (::stat(path.c_str(), &named) == 0)
    for (int fd : {1, 2}) {
      struct stat open {};
      if (::fstat(fd, &open) == 0 && open.st_dev == named.st_dev && open.st_ino == named.st_ino)
        return fd;
    }
  for (const char* prefix : {"/dev/fd/", "/proc/self/fd/"}) {
    const std::string_view p(prefix);
    if (path.size() <= p.size() || path.compare(0, p.size(), p) != 0) continue;
    int fd = -1;
    const char* end = path.data() + path.size();
    const auto [ptr, ec] = std::from_chars(path.data() + p.size(), end, fd);
    if (ec == std::errc() && ptr == end && fd >= 0) return fd;
  }
  return -1;
}

SaveTarget resolveTarget(const std::string& path) {
  checkTarget(path);
  if (namedDescriptor(path) >= 0) return {path, true};
  std::error_code ec;
  const fs::file_status status = fs::status(path, ec);  // follows links
  if (fs::exists(status) && !fs::is_regular_file(status)) return {path, true};
  // A symbolic link: the file it names, by following the chain link by link (a dangling
  // link names a file still to be made; weakly_canonical would give the link itself).
  fs::path target(path);
  for (int depth = 0; fs::is_symlink(fs::symlink_status(target, ec)); ++depth) {
    if (depth == 40) fail(path, "too many levels of symbolic links");
    const fs::path next = fs::read_symlink(target, ec);
    if (ec) fail(path, "cannot follow the link: " + ec.message());
    target = next.is_absolute() ? next : target.parent_path() / next;
  }
  if (target != fs::path(path)) checkTarget(target.string());
  return {target.string(), false};
}

/// Writes to an existing device or pipe (or a descriptor named by number) in place.
void writeInPlace(const std::string& path, const std::function<void(std::ostream&)>& write) {
  int fd = namedDescriptor(path);
  const bool own = fd < 0;
  if (own) {
    // Non-blocking to open: a pipe nobody reads is an error (ENXIO), not a hang after all the
    // work; then blocking again for the writes.
    fd = ::open(path.c_str(), O_WRONLY | O_CLOEXEC | O_NOCTTY | O_NONBLOCK);
    if (fd < 0) {
      const int error = errno;
      std::error_code ec;
      fail(path, error == ENXIO && fs::is_fifo(path, ec) ? std::string("no process reads the pipe")
                                                         : errnoText(error));
    }
    const int flags = ::fcntl(fd, F_GETFL);
    if (flags >= 0) ::fcntl(fd, F_SETFL, flags & ~O_NONBLOCK);
  }
  int error = 0;
  bool good = false;
  try {
    FdOutBuf buffer(fd);
    std::ostream out(&buffer);
    write(out);
    out.flush();
    error = buffer.error();
    good = static_cast<bool>(out);
  } catch (...) {
    if (own) ::close(fd);
    throw;
  }
  if (own) ::close(fd);
  if (error != 0) fail(path, errnoText(error));
  if (!good) fail(path, "write failed");
}

/// access() says yes, for root, to a folder no file can be made in (/proc): the run did its
/// work and then failed to write (a QA pass). A file is made in `folder` and removed.
void probeFileCreation(const fs::path& folder, const std::string& name, const std::string& what) {
  const std::string probe = temporaryName(folder / ".zsculpt-probe");
  const int fd = ::open(probe.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
  if (fd < 0) {
    if (errno != EEXIST) fail(name, what + "no file can be made in it (" + errnoText(errno) + ")");
    return;
  }
  ::close(fd);
  ::unlink(probe.c_str());
}

/// The folder exists and may be written, or can be made; with `probe`, a file is made and
/// removed there (checkFileOutput probes with its own file's name instead).
void checkFolderCreatable(const std::string& dir, bool probe) {
  const std::string name = dir.empty() ? std::string(".") : dir;
  std::error_code ec;
  const fs::path p(name);
  if (fs::exists(p, ec)) {
    if (!fs::is_directory(p, ec)) fail(name, "not a folder");
    if (::access(name.c_str(), W_OK | X_OK) != 0) fail(name, "not writable: " + errnoText(errno));
    if (probe) probeFileCreation(p, name, "not writable: ");
    return;
  }
  // create_directories would make the missing folders in the nearest one that exists: that
  // one must be a folder the program may write in.
  fs::path existing = p;
  do {
    existing = existing.has_relative_path() ? existing.parent_path() : fs::path();
    if (existing.empty()) existing = ".";
  } while (!fs::exists(existing, ec) && existing != ".");
  if (!fs::is_directory(existing, ec))
    fail(name, "cannot create the folder: " + existing.string() + " is not a folder");
  if (::access(existing.c_str(), W_OK | X_OK) != 0)
    fail(name, "cannot create the folder: " + existing.string() + ": " + errnoText(errno));
  if (probe)
    probeFileCreation(existing, name, "cannot create the folder: " + existing.string() + ": ");
}

}  // namespace

void writeFileAtomically(const std::string& requested,
                         const std::function<void(std::ostream&)>& write) {
  const SaveTarget target = resolveTarget(requested);
  if (target.inPlace) {
    writeInPlace(target.path, write);
    return;
  }
  const std::string& path = target.path;
  std::string temporary;
  int fd = createTemporary(path, temporary);
  try {
    FdOutBuf buffer(fd);
    std::ostream out(&buffer);
    write(out);
    out.flush();
    if (buffer.error() != 0) fail(path, errnoText(buffer.error()));
    if (!out) fail(path, "write failed");
    if (::fsync(fd) != 0) fail(path, "cannot flush to disk: " + errnoText(errno));
    const int closed = ::close(fd);
    fd = -1;
    if (closed != 0) fail(path, errnoText(errno));
    commit(path, temporary);
  } catch (...) {
    if (fd >= 0) ::close(fd);
    ::unlink(temporary.c_str());
    throw;
  }
}

void writeFileAtomicallyVia(const std::string& requested,
                            const std::function<void(const std::string&)>& writeTo) {
  const SaveTarget target = resolveTarget(requested);
  // A library writes to a name of its own choosing; a device or pipe has no such name.
  if (target.inPlace) fail(requested, "not a file: a device or pipe cannot take this output");
  const std::string& path = target.path;
  std::string temporary;
  // Created (and so reserved) before the library opens it by name.
  ::close(createTemporary(path, temporary));
  try {
    writeTo(temporary);
    syncFile(path, temporary);
    commit(path, temporary);
  } catch (...) {
    ::unlink(temporary.c_str());
    throw;
  }
}

void checkOutputFile(const std::string& path) {
  const SaveTarget target = resolveTarget(path);
  if (target.inPlace) {
    const int fd = namedDescriptor(path);
    const int flags = fd >= 0 ? ::fcntl(fd, F_GETFL) : 0;
    const bool writable = fd >= 0 ? flags >= 0 && (flags & O_ACCMODE) != O_RDONLY
                                  : ::access(target.path.c_str(), W_OK) == 0;
    if (!writable) fail(path, "not writable");
    return;
  }
  const fs::path parent = parentOf(target.path);
  // A folder that is still to be made is probed in the nearest one that exists; one that
  // exists is probed below with the save's own temporary name.
  std::error_code missing;
  checkFolderCreatable(parent.string(), !fs::is_directory(parent.empty() ? "." : parent, missing));
  // access() passes a name too long for the folder and, for root, a folder no file can be
  // made in (/proc): the write failed only after the work. The save's temporary name is the
  // longest name written, so that is what is checked; where the folder exists, a probe file
  // of that name is made and removed.
  const std::string temporary = temporaryName(target.path);
  const std::string folder = parent.empty() ? std::string(".") : parent.string();
  std::error_code ec;
  if (fs::is_directory(folder, ec)) {
    const int fd = ::open(temporary.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
    if (fd < 0) {
      const int error = errno;
      const std::size_t length = fs::path(target.path).filename().string().size();
      if (error == ENAMETOOLONG)
        fail(path, "the file name is too long for its folder (" + std::to_string(length) +
                       " bytes, and a save adds " +
                       std::to_string(fs::path(temporary).filename().string().size() - length) +
                       " to it for its temporary file)");
      if (error != EEXIST)
        fail(path, "cannot create a file in " + folder + ": " + errnoText(error));
    } else {
      ::close(fd);
      ::unlink(temporary.c_str());
    }
  } else {
    const long longest = ::pathconf(".", _PC_NAME_MAX);
    const std::size_t length = fs::path(temporary).filename().string().size();
    if (longest > 0 && length > static_cast<std::size_t>(longest))
      fail(path, "the file name is too long (a save's temporary name would take " +
                     std::to_string(length) + " bytes, more than the " + std::to_string(longest) +
                     " a name may have)");
  }
}

void checkCreatableDirectory(const std::string& dir) {
  checkFolderCreatable(dir, true);
}

void ensureWritableDirectory(const std::string& dir) {
  const std::string name = dir.empty() ? std::string(".") : dir;
  std::error_code ec;
  const fs::path p(name);
  if (!fs::exists(p, ec)) {
    fs::create_directories(p, ec);
    if (ec) fail(name, "cannot create the folder: " + ec.message());
  }
  if (!fs::is_directory(p, ec)) fail(name, "not a folder");
  if (::access(name.c_str(), W_OK | X_OK) != 0) fail(name, "not writable: " + errnoText(errno));
}

SaveTarget saveTarget(const std::string& path) {
  return resolveTarget(path);
}

}  // namespace zsculpt::io
